"""ball_world_to_rrd draws a run with robots as the live view drew it: the same entities and
components, an agent's own drive never drawn (nor counted) as a push, its bumper hits, its
scans, and its true heading while its odometry drifts.

One run is logged live (RerunSink) and recorded (McapSink) at once, with what tells drives
and pushes apart: drives of two robots, pushes on a robot and on a ball, a push applied
before a spawn (so the drives do not start the step's impulses), and a robot driven into a
wall (a bumper hit). The recording holds the pushes only (recording.agent_topics: drives are
not recorded); the records fed from it (feed_sinks, recording.remade_drives) must hold the
live run's impulses, drives made again bit for bit, and the converted .rrd what the live
one holds. The same run recorded in the layout of the files made before (every drive on
`impulse`, again on `<name>/drive`) must still read, convert and re-simulate as it did.
"""
import contextlib

from ball_world_testing.harness import rewrite_recording, Truth, without_messages
import numpy as np
import pytest
from test_rerun import cores, read

from ball_world.core.edits import Ball
from ball_world.recording import agent_topics, mcap_writer
from ball_world.recording.mcap_reader import feed_sinks, Recording, RecordingError
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.rerun_agents import AGENTS, BUMPERS
from ball_world.recording.rerun_log import IMPULSES, RerunSink
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import resim, to_rrd

PARAMETERS = {'rate_hz': 60.0, 'random.count': 6, 'random.seed': 3,
              'balls.x': [9.0, 2.0], 'balls.y': [5.0, 2.0], 'balls.vx': [0.0, 0.0],
              'balls.vy': [0.0, 0.0], 'balls.radius': [0.2, 0.2], 'balls.mass': [1.0, 1.0],
              'agents': ['ball_0', 'ball_1'], 'agent.cmd_timeout': 0.0,
              'agent.odom.noise': [0.5, 0.5, 0.5, 0.5], 'agent.scan.samples': 36,
              'physics.backend': 'numpy'}
STEPS = 90
#: Steps before which something other than a drive is applied.
PUSH_AGENT, PUSH_BALL, SPAWN = 20, 40, 30


def play(sinks):
    """The run, into `sinks`; returns its records."""
    simulation = Simulation(PARAMETERS, sinks=sinks)
    simulation.command('ball_0', 1.5, 0.0, 0.0)  # into the wall at x = 10
    simulation.command('ball_1', 0.8, 0.0, 1.2)
    records = [simulation.last_record]
    for step in range(1, STEPS + 1):
        if step == PUSH_AGENT:
            simulation.queue_impulse('ball_0', 0.0, 0.4)
        if step == PUSH_BALL:
            simulation.queue_impulse('ball_3', 0.2, -0.1)
        if step == SPAWN:
            simulation.queue_impulse('ball_1', -0.3, 0.0)  # applied by the spawn, first
            results, _ = simulation.spawn([SpawnRequest('extra', False,
                                                        Ball(5.0, 8.5, 0.0, 0.0, 0.1, 0.1))])
            assert results == ['extra']
            simulation.queue_impulse('ball_2', 0.0, 0.1)  # after the drives
        records.append(simulation.step()[0])
    simulation.close()
    return records


@contextlib.contextmanager
def old_layout():
    """McapSinks write what they wrote before the drives were left out: every drive on
    `impulse` and again on `<name>/drive` (its bytes), no 'agent_drives' metadata."""
    before_step, metadata = agent_topics.before_step, mcap_writer.segment_metadata

    def with_drives(record, namespace, parameters):
        return before_step(record, namespace, parameters) + [
            (f'{namespace}/{impulse.frame_id}/{agent_topics.DRIVE}',
             agent_topics.TYPES[agent_topics.DRIVE], agent_topics.DRIVE, impulse.cdr)
            for impulse in record.impulses if impulse.drive]

    def without_key(world, info, topics):
        values = metadata(world, info, topics)
        del values[agent_topics.DRIVES_KEY]
        return values

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(agent_topics, 'recorded_impulses', tuple)
        patch.setattr(agent_topics, 'before_step', with_drives)
        patch.setattr(mcap_writer, 'segment_metadata', without_key)
        patch.setitem(mcap_writer.ROLE_QOS, agent_topics.DRIVE,
                      mcap_writer.offered_qos_profiles(10))
        yield


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp('recorded_agents')
    live, mcap = folder / 'live.rrd', folder / 'run.mcap'
    records = play([RerunSink(live), McapSink(mcap)])
    return live, mcap, records


@pytest.fixture(scope='module')
def old(tmp_path_factory):
    """The run recorded as files were before (old_layout), and its records."""
    mcap = tmp_path_factory.mktemp('old_layout') / 'old.mcap'
    with old_layout():
        records = play([McapSink(mcap)])
    return mcap, records


def fed(mcap):
    sink = Truth()
    feed_sinks(mcap, [sink])
    return sink.records


def flags(impulses):
    return [(impulse.frame_id, impulse.drive) for impulse in impulses]


def applied(impulses):
    return [(i.ball, i.frame_id, i.drive, i.jx, i.jy, i.cdr) for i in impulses]


def test_the_recording_holds_the_pushes_and_its_records_every_drive_again(run):
    _, mcap, records = run
    live = {record.step: record for record in records}
    recording = Recording(mcap)
    assert not [topic for topic in recording.topics if topic.endswith('/drive')]
    steps = [step for step in recording.steps() if step.complete]
    assert [step.step for step in steps] == list(range(STEPS + 1))
    for step in steps:
        assert flags(step.impulses) == [
            flag for flag in flags(live[step.step].impulses) if not flag[1]], step.step
    # what a sink fed from the file gets: the live run's impulses, drives made again, bit
    # for bit, in the order applied
    made = fed(mcap)
    assert [record.step for record in made] == list(range(STEPS + 1))
    for record in made:
        assert applied(record.impulses) == applied(live[record.step].impulses), record.step
    everything = [flag for record in made for flag in flags(record.impulses)]
    # a push on a robot reads as a push, its drive as a drive, in one file
    assert ('ball_0', True) in everything and ('ball_0', False) in everything
    assert sum(drive for _, drive in everything) > 50
    # the push the spawn applied, ball_1's drive (ball_0 is then at its commanded speed),
    # the push queued after the spawn
    assert flags(live[SPAWN].impulses) == [('ball_1', False), ('ball_1', True),
                                           ('ball_2', False)]


def test_to_rrd_draws_what_the_live_view_drew(run, tmp_path):
    live, mcap, records = run
    converted = tmp_path / 'converted.rrd'
    assert to_rrd.main([str(mcap), '-o', str(converted)]) == 0
    _, logged, _, _ = read(live)
    _, made, _, _ = read(converted)
    assert set(made) == set(logged)
    # the pushes only, as live: the drives (on every step a robot accelerates) are not there
    pushes = logged[(f'/{IMPULSES}', 'Arrows2D:vectors')]
    assert made[(f'/{IMPULSES}', 'Arrows2D:vectors')] == pushes
    # on screen for 30 steps (IMPULSE_SECONDS): one push at 20, two more at 30, one at 40;
    # each drawn twice, its dark casing then itself (rerun_casing): the cores count pushes
    assert {step: len(value or ()) for step, value in cores(pushes).items()} == {
        0: 0, PUSH_AGENT: 1, SPAWN: 3, PUSH_BALL: 4, 50: 3, 60: 1, 70: 0}
    # bumper hits (ball_0 against the wall) at the same steps, along the same impulse
    bumpers = logged[(f'/{BUMPERS}', 'Arrows2D:vectors')]
    assert any(bumpers.values())
    assert made[(f'/{BUMPERS}', 'Arrows2D:vectors')].keys() == bumpers.keys()
    for step, vectors in bumpers.items():
        assert np.allclose(made[(f'/{BUMPERS}', 'Arrows2D:vectors')][step], vectors,
                           atol=1e-6) if vectors else not made[
            (f'/{BUMPERS}', 'Arrows2D:vectors')][step]
    # the true heading, not the drifting odometry's
    headings = made[(f'/{AGENTS}', 'Arrows2D:vectors')]
    for step, vectors in logged[(f'/{AGENTS}', 'Arrows2D:vectors')].items():
        assert np.allclose(headings[step], vectors, atol=1e-6), step
    # every value of every other entity as logged live (scans to float32's ranges)
    for key, column in logged.items():
        assert made[key].keys() == column.keys(), key
        for step, value in column.items():
            other = made[key][step]
            if key[0].startswith('/arena/scans/') and value:
                assert np.allclose(np.asarray(other, dtype=np.float64),
                                   np.asarray(value, dtype=np.float64), atol=1e-5), key
            elif key[0] not in (f'/{AGENTS}', f'/{BUMPERS}'):
                assert other == value, (key, step)


def test_the_odometry_really_drifted_from_the_heading_drawn(run):
    _, mcap, records = run
    from ball_world.msgs.agent_cdr import decode_odometry
    from ball_world.scoring.planar_tf import yaw_of
    last = records[-1].agents
    odom_yaw = yaw_of(*decode_odometry(last.odom_cdr[1]).pose[3:7])
    assert abs(np.angle(np.exp(1j * (odom_yaw - last.yaws[1])))) > 0.01


def without_drives(source, target):
    """A copy of a recording without its drive topics: as recordings were before them."""
    return without_messages(source, target, lambda topic: topic.endswith('/drive'))


def test_an_older_recording_with_drive_topics_reads_and_resimulates_as_before(
        old, tmp_path, capsys):
    mcap, records = old
    live = {record.step: record for record in records}
    steps = [step for step in Recording(mcap).steps() if step.complete]
    for step in steps:  # the reader marks the drives from <name>/drive
        assert flags(step.impulses) == flags(live[step.step].impulses), step.step
    for record in fed(mcap):  # and hands them on as they are, not made twice
        assert applied(record.impulses) == applied(live[record.step].impulses), record.step
    assert resim.main([str(mcap)]) == 0, capsys.readouterr()
    # a drive message whose bytes are not those of the step's drive impulse
    forged = tmp_path / 'forged.mcap'
    forged_at = []

    def forge(topic, log_time, data):
        """ball_1's first drive impulse, its x changed."""
        if topic != '/ball_1/drive' or forged_at:
            return data
        forged_at.append(log_time)
        return data[:-24] + np.float64(0.125).tobytes() + data[-16:]

    rewrite_recording(mcap, forged, data=forge)
    with pytest.raises(RecordingError, match=r"step 1: the drive impulses of 'ball_0', "
                                             r"'ball_1' are not the step's impulses 0 to 1"):
        feed_sinks(forged, [])


def test_an_older_recording_without_drive_topics_reads_as_before(old, tmp_path, capsys):
    mcap, records = old
    older = tmp_path / 'older.mcap'
    without_drives(mcap, older)
    steps = [step for step in Recording(older).steps() if step.complete]
    assert all(not impulse.drive for step in steps for impulse in step.impulses)
    assert [len(step.impulses) for step in steps] == [len(r.impulses) for r in records]
    assert resim.main([str(older)]) == 0, capsys.readouterr()
    assert to_rrd.main([str(older), '-o', str(tmp_path / 'older.rrd')]) == 0


def test_resim_of_the_recording_makes_the_drives_again(run, capsys):
    _, mcap, _ = run
    assert resim.main([str(mcap)]) == 0, capsys.readouterr()
    assert (f'all {STEPS + 1} recorded steps re-simulate bit-identically'
            in capsys.readouterr().out)


def test_a_drives_metadata_value_not_known_is_one_line(run, tmp_path):
    _, mcap, _ = run
    bad = rewrite_recording(mcap, tmp_path / 'bad.mcap', metadata=lambda values: {
        **values, agent_topics.DRIVES_KEY: 'some other way'})
    with pytest.raises(RecordingError, match="'agent_drives' is 'some other way', not "
                                             "'made from the commands'"):
        Recording(bad)


def test_info_counts_the_drives_apart_and_lists_the_pushes(run, old, capsys):
    from ball_world.tools import info
    mcap, records = old
    assert info.main([str(mcap)]) == 0
    out = capsys.readouterr().out
    drives = sum(impulse.drive for record in records for impulse in record.impulses)
    total = sum(len(record.impulses) for record in records)
    assert drives > 50 and total == drives + 4
    assert f"impulses:    {total} (4 pushes, {drives} by the agents' drives)" in out
    assert pushes_listed(out) == PUSHES
    # the recording made now: the pushes only, and why
    assert info.main([str(run[1])]) == 0
    out = capsys.readouterr().out
    assert ("impulses:    4 (pushes; the agents' drives are not recorded: resim makes them "
            'again from the commands)') in out
    assert pushes_listed(out) == PUSHES


PUSHES = ['segment 0 step 20 ball_0', 'segment 0 step 30 ball_1', 'segment 0 step 30 ball_2',
          'segment 0 step 40 ball_3']


def pushes_listed(out):
    return [line.split(': ')[0].split(' (')[0].strip() + ' ' + line.split(': ')[1].split()[0]
            for line in out.splitlines() if line.startswith('  segment 0 step')
            and ' J = ' in line]


def test_after_a_step_it_cannot_follow_no_drive_is_guessed(run, tmp_path):
    # step 45 without its `state` (cut off): the velocities its successor's drive met are
    # not known, nor anything after; the steps before keep their drives made again
    _, mcap, records = run
    topics = {}

    def edit(item):
        kind = type(item).__name__
        if kind == 'Channel':
            topics[item.id] = item.topic
        elif (kind == 'Message' and topics[item.channel_id] == '/state'
              and item.log_time == records[45].log_time_ns):
            return None
        return item

    cut = rewrite_recording(mcap, tmp_path / 'cut.mcap', edit=edit)
    made = {record.step: record for record in fed(cut)}
    assert 45 not in made and len(made) == STEPS
    for step, record in made.items():
        expected = records[step].impulses
        if step > 45:
            expected = [i for i in expected if not i.drive]
        assert applied(record.impulses) == applied(expected), step
