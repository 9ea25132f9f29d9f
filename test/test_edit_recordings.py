"""World edits in recordings: written, read back, re-simulated, converted and counted.

A run is driven through Simulation as the node drives it (impulses queued, spawns named and
generated, deletions that shift the arrays, state sets, a reset), next to a sink keeping
every record: that is the truth the MCAP, its readers, resim, to_rrd and info must match.
Edit payloads are then crafted as a hostile user would: every tool must answer one line and
exit 2, and resim must place a changed edit at its step. Last, the same through the node's
simulation_interfaces services and the installed ball_world_resim.
"""
import contextlib
import io
import json
import math

from ball_world_testing.harness import (executable, finish, InProcessWorld, open_rrd,
                                        read_mcap_ros2, read_rosbags, rewrite_recording,
                                        run_tool, Truth)
from geometry_msgs.msg import PoseStamped
from mcap.records import Channel, Message
import numpy as np
import pytest
from simulation_interfaces.msg import (Result, SimulationState, SpawnEntity as SpawnEntityMsg)
from simulation_interfaces.srv import (DeleteEntity, SetEntityState, SetSimulationState,
                                       SpawnEntities, SpawnEntity, StepSimulation)
from std_msgs.msg import String
from visualization_msgs.msg import Marker

from ball_world.core.edits import Ball
from ball_world.msgs.cdr import decode_string, encode_string
from ball_world.recording.mcap_reader import feed_sinks, MAX_EDIT_TEXT, Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.rerun_log import BALLS, IMPULSES, LABELS, STEP
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import info, resim, to_rrd

FIRST = {'rate_hz': 20.0, 'random.count': 0, 'balls.x': [2.0, 8.0, 5.0, 2.0],
         'balls.y': [2.0, 2.0, 8.0, 8.0], 'balls.vx': [1.5, -1.5, 0.0, 1.0],
         'balls.vy': [0.5, 0.5, -1.0, -1.0], 'balls.radius': [0.5, 0.5, 0.4, 0.3],
         'balls.mass': [1.0, 1.0, 2.0, 0.5]}
SECOND = {**FIRST, 'balls.x': [3.0, 7.0], 'balls.y': [3.0, 7.0], 'balls.vx': [1.0, -1.0],
          'balls.vy': [0.0, 0.5], 'balls.radius': [0.4, 0.6], 'balls.mass': [1.0, 3.0]}
BACKENDS = {'numpy': {'physics.backend': 'numpy'}, 'numba': {'physics.backend': 'numba'},
            'exact': {'physics.mode': 'exact'}}
EDITS = '/edits'


def spawn(simulation, name, x, y, vx=0.0, vy=0.0, radius=0.25, mass=1.0, rename=False):
    """Spawn one ball; it must be accepted (the script places it where it fits)."""
    [got], _ = simulation.spawn([SpawnRequest(name, rename, Ball(x, y, vx, vy, radius, mass))])
    assert isinstance(got, str), got
    return got


def steps(simulation, count):
    for _ in range(count):
        simulation.step()


def edited_run(simulation):
    """Impulses and edits interleaved in every way the node can interleave them."""
    steps(simulation, 3)
    # step 4: an impulse, a named spawn, an impulse to the spawned ball
    simulation.queue_impulse('ball_1', 0.1, 0.2)
    spawn(simulation, 'probe', 5.0, 5.0, 1.0, -0.5, radius=0.3, mass=1.5)
    simulation.queue_impulse('probe', 0.2, 0.1)
    simulation.step()
    # step 5: ball_3 pushed, then ball_0 deleted (ball_3 moves down), pushed again; ball_2
    # pushed, then its state set (which the push must not outlast): five events in this order
    simulation.queue_impulse('ball_3', -0.05, 0.1)
    simulation.delete('ball_0')
    simulation.queue_impulse('ball_3', 0.05, 0.0)
    simulation.queue_impulse('ball_2', 0.3, 0.0)
    simulation.set_state('ball_2', 7.0, 5.0, 0.0, 1.0)
    simulation.step()
    # step 6: two balls in one request, one of them with a generated name
    results, _ = simulation.spawn([
        SpawnRequest('', True, Ball(1.0, 5.0, 0.5, 0.0, 0.2, 0.7)),
        SpawnRequest('twin', False, Ball(9.0, 5.0, -0.5, 0.0, 0.2, 0.7))])
    assert results == ['ball_4', 'twin']
    steps(simulation, 5)
    # step 11: the spawned ball goes; an impulse for it afterwards is rejected, not recorded
    simulation.delete('probe')
    simulation.queue_impulse('probe', 1.0, 0.0)
    steps(simulation, 5)
    simulation.reset(SECOND | {key: value for key, value in simulation.parameters.items()
                               if key.startswith('physics.')})
    # a new segment may use the name again
    spawn(simulation, 'probe', 5.0, 2.0, 0.0, 1.0)
    simulation.queue_impulse('probe', 0.0, -0.1)
    steps(simulation, 5)
    simulation.delete('ball_1')
    steps(simulation, 3)
    simulation.close()


def record_edited_run(path, backend='numpy'):
    truth = Truth()
    edited_run(Simulation(FIRST | BACKENDS[backend], sinks=[McapSink(path), truth]))
    return truth


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp('edits') / 'edited.mcap'
    return path, record_edited_run(path)


def call(tool, *args):
    """(exit code, stdout, stderr) of a tool's main run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = tool.main([str(arg) for arg in args])
    return code, out.getvalue(), err.getvalue()


def bits_equal(a, b):
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    return a.shape == b.shape and bool((a.view(np.uint64) == b.view(np.uint64)).all())


# Writing and reading back ----------------------------------------------------------------

def test_the_script_makes_every_kind_of_edit(recorded):
    _, truth = recorded
    edits = [(r.step, e.kind, e.name, e.impulses_before) for r in truth.records for e in r.edits]
    assert edits == [(4, 'spawn', 'probe', 1), (5, 'delete', 'ball_0', 1),
                     (5, 'set_state', 'ball_2', 3), (6, 'spawn', 'ball_4', 0),
                     (6, 'spawn', 'twin', 0), (11, 'delete', 'probe', 0),
                     (1, 'spawn', 'probe', 0), (6, 'delete', 'ball_1', 0)]


def test_feed_sinks_rebuilds_names_radii_masses_edits_and_impulses(recorded):
    path, truth = recorded
    fed = Truth()
    assert feed_sinks(path, [fed]) == len(truth.records)
    assert [world.names for world, _ in fed.segments] == \
        [world.names for world, _ in truth.segments]
    for got, want in zip(fed.records, truth.records, strict=True):
        assert (got.step, got.log_time_ns, got.names, got.world_changed) == \
            (want.step, want.log_time_ns, want.names, want.world_changed)
        assert bits_equal(got.radii, want.radii) and bits_equal(got.masses, want.masses)
        assert got.edits == want.edits
        # each impulse names the index its ball had when it was applied, as the node did
        assert got.impulses == want.impulses
        assert got.balls_cdr == want.balls_cdr
    step5 = fed.records[5]
    assert [i.ball for i in step5.impulses] == [3, 2, 1]
    assert step5.names == ('ball_1', 'ball_2', 'ball_3', 'probe')


def test_edits_are_interleaved_with_impulses_in_the_order_they_were_applied(recorded):
    path, truth = recorded
    recording = Recording(path)
    step5 = truth.records[5]
    order = [(m.topic, decode_string(m.data) if m.topic == EDITS else None)
             for m in recording.messages(['/impulse', EDITS])
             if m.log_time_ns == step5.log_time_ns]
    assert order == [('/impulse', None), (EDITS, step5.edits[0].text), ('/impulse', None),
                     ('/impulse', None), (EDITS, step5.edits[1].text)]
    assert json.loads(step5.edits[1].text) == {
        'kind': 'set_state', 'name': 'ball_2', 'x': 7.0, 'y': 5.0, 'vx': 0.0, 'vy': 1.0,
        'radius': 0.0, 'mass': 0.0, 'impulses_before': 3}


@pytest.mark.parametrize('reader', [read_mcap_ros2, read_rosbags])
def test_other_readers_decode_the_edits(recorded, reader):
    path, truth = recorded
    expected = [(r.log_time_ns, e.text) for r in truth.records for e in r.edits]
    assert [(log_time, msg.data) for _, log_time, msg in reader(path, [EDITS])] == expected


def test_markers_start_over_with_the_new_balls_after_a_spawn_or_deletion(recorded):
    path, truth = recorded
    markers = {}
    for _, log_time, msg in read_mcap_ros2(path, ['/markers']):
        markers.setdefault(log_time, []).append(msg.markers)
    changed = [r for r in truth.records if r.world_changed]
    assert [r.step for r in changed] == [4, 5, 6, 11, 1, 6]
    for record in changed:
        clear, spheres = markers[record.log_time_ns]
        assert [m.action for m in clear] == [Marker.DELETEALL]
        spheres = [m for m in spheres if m.type == Marker.SPHERE]
        assert [m.scale.x for m in spheres] == (2.0 * record.radii).tolist()
        assert [[m.pose.position.x, m.pose.position.y] for m in spheres] == \
            record.positions.tolist()


def test_a_run_without_edits_records_no_edits_topic(tmp_path):
    path = tmp_path / 'plain.mcap'
    simulation = Simulation(FIRST, sinks=[McapSink(path)])
    steps(simulation, 3)
    simulation.close()
    recording = Recording(path)
    assert EDITS not in recording.topics
    assert recording.segments[0].topics['edits'] == EDITS
    assert call(info, path)[1].count('edits:       0') == 1


# Re-simulation ---------------------------------------------------------------------------

@pytest.mark.parametrize('backend', sorted(BACKENDS))
def test_resim_reproduces_an_edited_run_bit_for_bit(tmp_path, backend):
    path = tmp_path / f'{backend}.mcap'
    record_edited_run(path, backend)
    code, out, err = call(resim, path)
    assert code == 0, out + err
    assert 'segment 0: 16 steps compared (last step 15), 5 impulses, 6 edits: identical' in out
    assert 'segment 1: 9 steps compared (last step 8), 1 impulses, 2 edits: identical' in out


def rewrite_edits(source, target, change):
    """The recording with each edit's fields passed through change(position, fields): the
    fields to write, or None to leave the edit out."""
    channels = set()
    position = -1

    def edit(item):
        nonlocal position
        if isinstance(item, Channel) and item.topic == EDITS:
            channels.add(item.id)
        if isinstance(item, Message) and item.channel_id in channels:
            position += 1
            fields = change(position, json.loads(decode_string(item.data)))
            if fields is None:
                return None
            return Message(**{**vars(item), 'data': encode_string(json.dumps(fields))})
        return item
    return rewrite_recording(source, target, edit=edit)


@pytest.mark.parametrize('position, change, first', [
    (0, {'x': 5.5}, 'segment 0 step 4 ball 4 balls x: recorded 5.05'),
    (0, {'name': 'ball_2'}, "segment 0 step 4 spawned name: recorded 'ball_2', re-simulated"),
    (2, None, 'segment 0 step 5 ball 1 balls x'),
    (1, {'name': 'ball_9'}, "segment 0 step 5 delete refused: recorded 'ball_9'"),
    (6, {'vy': 0.5}, 'segment 1 step 1 ball 2 balls y'),
])
def test_resim_finds_a_changed_edit_at_its_step(recorded, tmp_path, position, change, first):
    path, _ = recorded
    changed = rewrite_edits(
        path, tmp_path / 'changed.mcap',
        lambda at, fields: fields if at != position else
        None if change is None else {**fields, **change})
    code, out, err = call(resim, changed)
    assert code == 1, out + err
    assert f'first difference: {first}' in out


# Rerun -----------------------------------------------------------------------------------

def rrd_columns(path):
    """{(entity, component): {step: value}} of the one recording in an .rrd."""
    reader = open_rrd(path)
    (store,) = reader.recordings()
    content = {}
    for chunk in reader.stream(store=store):
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        logged_steps = batch.column(STEP).to_pylist()
        for index, field in enumerate(batch.schema):
            if (field.metadata or {}).get(b'rerun:kind') == b'data':
                column = content.setdefault((chunk.entity_path, field.name), {})
                column.update(zip(logged_steps, batch.column(index).to_pylist()))
    return content


def test_to_rrd_shows_balls_come_and_go_with_their_names_and_radii(recorded, tmp_path):
    path, truth = recorded
    output = tmp_path / 'edited.rrd'
    code, out, err = call(to_rrd, path, '-o', output)
    assert code == 0, err
    content = rrd_columns(output)
    expected_names, expected_radii = {}, {}
    base, shown = 0, None
    for previous, record in zip([None, *truth.records], truth.records):
        if previous is not None and record.step == 0:
            base += previous.step + 1  # the step timeline goes on across the reset
        expected_names[base + record.step] = set(record.names)
        if record.names != shown:
            shown = record.names
            expected_radii[base + record.step] = record.radii.astype(np.float32).tolist()
    # Every step names the balls it has (placed apart, so a crowded one may be left out),
    # never a ball that has gone.
    labels = content[(f'/{LABELS}', 'Points2D:labels')]
    assert sorted(labels) == sorted(expected_names)
    assert all(set(labels[k]) <= expected_names[k] and labels[k] for k in labels)
    assert content[(f'/{BALLS}', 'Points2D:radii')] == expected_radii
    assert sorted(expected_radii) == [0, 4, 5, 6, 11, 16, 17, 22]
    # At step 5 ball_3 was pushed before and after ball_0 went: both arrows name ball_3.
    arrows = content[(f'/{IMPULSES}', 'Points2D:labels')][5]
    assert [label.split(':')[0] for label in arrows] == ['ball_1', 'probe', 'ball_3', 'ball_3',
                                                         'ball_2']


# info and replay -------------------------------------------------------------------------

def test_info_counts_edits_by_kind_and_lists_them(recorded):
    path, _ = recorded
    code, out, err = call(info, path)
    assert code == 0, err
    assert 'edits:       8 (4 spawn, 3 delete, 1 set_state)' in out
    assert ('  segment 0 step 4: spawn probe at (5, 5), v (1, -0.5), radius 0.3 m, mass '
            '1.5 kg') in out
    assert '  segment 0 step 5: set_state ball_2 to (7, 5), v (0, 1)' in out
    assert '  segment 1 step 6: delete ball_1' in out
    assert f'  {EDITS}  std_msgs/msg/String  8' in out


def test_replay_plays_the_edits_in_order(recorded, probe, processes):
    path, truth = recorded
    heard = probe.listen(String, EDITS, keep=lambda msg: msg.data)
    player = processes.start([executable('ball_world_replay'), path, '--topics', EDITS,
                              '--wait-for-subscribers'])
    expected = [e.text for r in truth.records for e in r.edits]
    probe.spin_until(lambda: len(heard) >= len(expected), 'the replayed edits',
                     process=player)
    assert finish(player)[0] == 0
    assert heard == expected


# Hostile edits ---------------------------------------------------------------------------

def edit_text(**changes):
    fields = {'kind': 'spawn', 'name': 'probe', 'x': 5.0, 'y': 5.0, 'vx': 1.0, 'vy': -0.5,
              'radius': 0.3, 'mass': 1.5, 'impulses_before': 1}
    return json.dumps({**fields, **changes})


HOSTILE = {
    'bad kind': (edit_text(kind='explode'), "kind is 'explode', not one of spawn"),
    'kind not text': (edit_text(kind=['spawn']), "kind is ['spawn']"),
    'NaN': (edit_text(x=math.nan), 'x is nan, not a finite number'),
    'infinity': (edit_text(vy=-math.inf), 'vy is -inf, not a finite number'),
    'huge number': (edit_text().replace('5.0', '1' * 400, 1), 'x is too large for a float'),
    'number as text': (edit_text(mass='1.5'), "mass is '1.5', not a number"),
    '300-character name': (edit_text(name='b' * 300), "name 'bbbb"),
    'name not a name': (edit_text(name='ball 1; rm'), "name 'ball 1; rm' is not an entity "
                                                      'name'),
    'tiny radius': (edit_text(radius=1e-9), 'radius 1e-09 is outside 0.001 to 1000'),
    'impulses_before too many': (edit_text(impulses_before=3), 'impulses_before is 3, not a '
                                                               'count from 0 to the 2'),
    'impulses_before negative': (edit_text(impulses_before=-1), 'impulses_before is -1'),
    'impulses_before not whole': (edit_text(impulses_before=1.0), 'impulses_before is 1.0'),
    'impulses_before true': (edit_text(impulses_before=True), 'impulses_before is True'),
    'field missing': (json.dumps({'kind': 'delete', 'name': 'probe'}), 'not an edit with the '
                                                                       'fields'),
    'field added': (edit_text(colour='red'), 'not an edit with the fields'),
    'not an object': ('[1, 2, 3]', 'not an edit with the fields'),
    'deep JSON': ('[' * 2000 + ']' * 2000, 'nests too deeply'),
    'nested value': (edit_text(name={'a': {'b': {'c': [[[]]]}}}), "name {'a': {'b'"),
    'not JSON': ('spawn probe at 5 5', 'does not parse'),
    'long text': (edit_text(name='n' * (MAX_EDIT_TEXT + 1 - len(edit_text(name='')))),
                  'the text is 4,097 characters long; at most 4,096'),
    '10 MB string': (edit_text(name='n' * 10_000_000), 'the message is 10,000,'),
}


def with_first_edit(source, target, data):
    """The recording with the bytes of its first edit message replaced by `data`."""
    channels = set()
    first = True

    def edit(item):
        nonlocal first
        if isinstance(item, Channel) and item.topic == EDITS:
            channels.add(item.id)
        if isinstance(item, Message) and item.channel_id in channels and first:
            first = False
            return Message(**{**vars(item), 'data': data})
        return item
    return rewrite_recording(source, target, edit=edit)


def refused_by_every_tool(path, tmp_path):
    """The one line each of info, resim and to_rrd answers with (exit 2, no output file)."""
    lines = set()
    for tool, args in ((info, [path]), (resim, [path]),
                       (to_rrd, [path, '-o', tmp_path / 'out.rrd'])):
        code, out, err = call(tool, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1, (tool.__name__, out, err)
        assert not (tmp_path / 'out.rrd').exists()
        lines.add(err.strip().split(f'{path}: ', 1)[1])
    return lines


@pytest.mark.parametrize('case', sorted(HOSTILE))
def test_a_hostile_edit_gets_one_line_and_exit_2_from_every_tool(recorded, tmp_path, case):
    path, _ = recorded
    text, words = HOSTILE[case]
    bad = with_first_edit(path, tmp_path / 'bad.mcap', encode_string(text))
    (line,) = refused_by_every_tool(bad, tmp_path)  # the same words from every tool
    assert line.startswith('segment 0 step 4: recorded edit 0: ') and words in line, line
    assert len(line) < 400


@pytest.mark.parametrize('data, words', [
    (b'\x00\x01\x00\x00\xff\xff\xff\x7fspawn', 'not a std_msgs/String: CDR buffer truncated'),
    (b'\x00\x01\x00\x00\x03\x00\x00\x00\xff\xfe\x00', 'not a std_msgs/String'),
    (b'\x00\x01', 'not a std_msgs/String'),
])
def test_edit_bytes_that_are_no_string_are_refused(recorded, tmp_path, data, words):
    path, _ = recorded
    (line,) = refused_by_every_tool(with_first_edit(path, tmp_path / 'bad.mcap', data),
                                    tmp_path)
    assert words in line, line


def test_impulses_before_may_not_go_back_within_a_step(recorded, tmp_path):
    path, _ = recorded
    bad = rewrite_edits(path, tmp_path / 'back.mcap', lambda at, fields: fields if at != 2
                        else {**fields, 'impulses_before': 0})
    (line,) = refused_by_every_tool(bad, tmp_path)
    assert line == 'segment 0 step 5: recorded edit 1: impulses_before goes back from 1 to 0'


@pytest.mark.parametrize('position, change, words', [
    (0, {'name': 'ball_1'}, "segment 0 step 4: a recorded edit spawns 'ball_1', a name its "
                            'segment already used'),
    (6, {'name': 'ball_0'}, "segment 1 step 1: a recorded edit spawns 'ball_0'"),
    (1, {'name': 'nobody'}, "segment 0 step 5: a recorded edit deletes 'nobody', which is no "
                            'ball then'),
    (2, {'name': 'probe_2'}, "segment 0 step 5: a recorded edit sets the state of 'probe_2'"),
    (5, None, 'step 11 of segment 0 has 5 balls, not 6'),
])
def test_to_rrd_refuses_edits_the_node_could_not_have_made(recorded, tmp_path, position, change,
                                                           words):
    """Well-formed edits that contradict the recording: to_rrd cannot draw them (exit 2);
    resim re-simulates and reports where they differ (exit 1)."""
    path, _ = recorded
    bad = rewrite_edits(path, tmp_path / 'bad.mcap', lambda at, fields: fields
                        if at != position else None if change is None else {**fields, **change})
    code, _, err = call(to_rrd, bad, '-o', tmp_path / 'out.rrd')
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert not (tmp_path / 'out.rrd').exists()
    assert call(resim, bad)[0] == 1


# Through the node -------------------------------------------------------------------------

def pose_at(x, y):
    pose = PoseStamped()
    pose.pose.position.x, pose.pose.position.y = x, y
    pose.pose.orientation.w = 1.0
    return pose


def test_edits_made_through_the_services_re_simulate_exactly(tmp_path):
    path = tmp_path / 'served.mcap'
    world = InProcessWorld(**{**FIRST, 'rate_hz': 100.0, 'markers.rate_hz': 0.0,
                              'record.mcap': str(path)})
    try:
        paused = world.call(SetSimulationState, 'set_simulation_state',
                            SetSimulationState.Request(state=SimulationState(
                                state=SimulationState.STATE_PAUSED)))
        assert paused.result.result == Result.RESULT_OK
        step = StepSimulation.Request(steps=3)
        assert world.call(StepSimulation, 'step_simulation', step).result.result == \
            Result.RESULT_OK
        spawned = world.call(SpawnEntity, 'spawn_entity', SpawnEntity.Request(
            name='guest', uri='ball', resource_string='{radius: 0.3, mass: 2.0, velocity: '
            '[0.5, 0.25]}', initial_pose=pose_at(5.0, 5.0)))
        assert spawned.result.result == Result.RESULT_OK, spawned.result.error_message
        world.impulse('guest', 0.4, -0.2)
        world.spin_until(lambda: world.simulation.queued == 1, 'the impulse to be queued')
        assert world.call(StepSimulation, 'step_simulation', step).result.result == \
            Result.RESULT_OK
        placed = SetEntityState.Request(entity='guest')
        placed.state.pose = pose_at(6.0, 4.0).pose
        placed.state.twist.linear.x, placed.state.twist.linear.y = -1.0, 0.5
        answer = world.call(SetEntityState, 'set_entity_state', placed)
        assert answer.result.result == Result.RESULT_OK, answer.result.error_message
        world.impulse('guest', 0.0, 0.3)
        world.spin_until(lambda: world.simulation.queued == 1, 'the impulse to be queued')
        assert world.call(DeleteEntity, 'delete_entity', DeleteEntity.Request(
            entity='ball_0')).result.result == Result.RESULT_OK
        requests = [SpawnEntityMsg(name=name, allow_renaming=True,
                                   initial_pose=pose_at(x, 5.0)) for name, x in
                    (('ball_1', 1.0), ('', 9.0))]
        for request in requests:
            request.entity_resource.uri = 'ball'
        both = world.call(SpawnEntities, 'spawn_entities', SpawnEntities.Request(
            spawn_requests=requests))
        assert [r.entity_name for r in both.results] == ['ball_4', 'ball_5']
        assert world.call(StepSimulation, 'step_simulation', step).result.result == \
            Result.RESULT_OK
        assert world.simulation.names == ('ball_1', 'ball_2', 'ball_3', 'guest', 'ball_4',
                                          'ball_5')
    finally:
        world.close()
    code, out, err = run_tool('ball_world_resim', str(path))
    assert code == 0, out + err
    assert '2 impulses, 5 edits: identical' in out
    code, out, err = run_tool('ball_world_info', str(path))
    assert 'edits:       5 (3 spawn, 1 delete, 1 set_state)' in out
