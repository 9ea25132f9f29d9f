"""Split recordings (issue 23) whole with closing records (issue 19) and agents (issue 21).

A split run is driven through Simulation with a SplitMcapSink, as the node drives it: edits
made after a segment's last step (its closing record) must land in the open file and be
counted in metadata.yaml; with agents, each file alone must re-simulate bit for bit, which
takes the agents' headings and commands in force at the step it resumes from.
"""
import base64
import json
import math
import re
import struct

from ball_world_testing.harness import (finish, node_command, rewrite_recording, run_tool,
                                        Truth)
from geometry_msgs.msg import Twist
from mcap.reader import make_reader
from nav_msgs.msg import Odometry
import pytest
from rclpy.serialization import serialize_message
from test_agents_node import forward, publish_until, step_of, twist, WORLD as AGENT_WORLD
from test_closing_edits import _node_edits_then_stops
from test_edit_recordings import FIRST, SECOND, spawn
from test_split_recordings import assert_resume_state_refused, crafted_resume, NODE_TIMEOUT
import yaml

from ball_world.core.agents import Command
from ball_world.core.edits import Ball
from ball_world.recording.mcap_reader import feed_sinks
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.recording_set import open_recording
from ball_world.recording.split_writer import SplitMcapSink
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import info, resim

STEP_NS = 50_000_000  # FIRST and SECOND run at 20 Hz


def metadata(directory):
    return yaml.safe_load((directory / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']


def statistics(path):
    with open(path, 'rb') as stream:
        return make_reader(stream).get_summary().statistics


def close_with_edits(simulation, name):
    """A push that a spawn applies, the spawn and a deletion, all after the last step."""
    simulation.queue_impulse('ball_1', 0.1, 0.2)
    spawn(simulation, name, 5.0, 5.0, 1.0, -0.5, radius=0.3, mass=1.5)
    simulation.delete('ball_0')


def test_closing_records_of_a_split_run_go_to_the_open_file(tmp_path, capsys):
    directory = tmp_path / 'closing'
    simulation = Simulation(FIRST, sinks=[SplitMcapSink(directory, max_seconds=1.0)])
    for _ in range(45):  # files of steps 0-19, 20-39, then 40-45
        simulation.step()
    close_with_edits(simulation, 'late')
    simulation.reset(SECOND)
    for _ in range(5):
        simulation.step()
    close_with_edits(simulation, 'later')
    simulation.close()

    names = metadata(directory)['relative_file_paths']
    assert names == ['closing_0.mcap', 'closing_1.mcap', 'closing_2.mcap']
    closing = [(s.segment, s.step, len(s.impulses), len(s.edits))
               for s in open_recording(directory).steps() if s.closing]
    assert closing == [(0, 46, 1, 2), (1, 6, 1, 2)]
    # metadata.yaml counts the closing records' messages and ends at the last one's time
    meta = metadata(directory)
    last = statistics(directory / names[-1])
    assert meta['files'][-1]['message_count'] == last.message_count
    end_ns = 47 * STEP_NS + 6 * STEP_NS  # segment 1 starts after segment 0's closing step
    assert last.message_end_time == end_ns
    assert meta['duration']['nanoseconds'] == end_ns
    assert meta['message_count'] == sum(statistics(directory / n).message_count
                                        for n in names)

    assert resim.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert 'segment 0: 46 steps compared (last step 45)' in out, out
    assert out.count('after the last step 1 impulses and 2 edits: identical') == 2, out
    # the last file alone: segment 0 from its resume state, its closing record, segment 1
    assert resim.main([str(directory / names[-1])]) == 0
    out = capsys.readouterr().out
    assert 'segment 0: 6 steps compared (last step 45)' in out, out
    assert out.count('after the last step 1 impulses and 2 edits: identical') == 2, out
    assert info.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert 'edits:       4 (2 spawn, 2 delete)' in out
    # the closing records are no steps: 45 + 5 steps, each segment's last the one before
    assert 'steps:       50 after the initial states' in out, out
    assert ('steps 0-45 (+ 2 edits and 1 impulse after the last step), dt 50 ms' in out
            and 'steps 0-5 (+ 2 edits and 1 impulse after the last step)' in out), out
    assert info.main([str(directory / names[-1])]) == 0
    out = capsys.readouterr().out
    assert 'steps:       11 after the initial states' in out, out
    assert 'steps 40-45 (+ 2 edits and 1 impulse after the last step)' in out, out


def test_info_says_a_closing_record_is_no_step(tmp_path, capsys):
    """One file, two segments: a closing record of one edit, then one of an edit and a push
    it applied; info reads them from the file's index, as any finished file."""
    path = tmp_path / 'closed.mcap'
    simulation = Simulation(FIRST, sinks=[McapSink(path)])
    for _ in range(3):
        simulation.step()
    simulation.delete('ball_2')
    simulation.reset(SECOND)
    simulation.step()
    close_with_edits(simulation, 'late')
    simulation.close()
    assert info.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert 'steps:       4 after the initial states (6 messages on /balls)' in out, out
    assert '  0: from log time 0 s, steps 0-3 (+ 1 edit after the last step), dt' in out, out
    assert ('  1: from log time 0.25 s, steps 0-1 (+ 2 edits and 1 impulse after the last '
            'step), dt') in out, out


AGENTS = {'rate_hz': 50.0, 'random.count': 12, 'random.seed': 5,
          'agents': ['ball_0', 'ball_3'], 'agent.cmd_timeout': 1.0}
# step -> commands (agent, forward, left, yaw rate) given before it; files roll every 25
# steps, so commands given at 24 and 48 are in force where the next file resumes
SCRIPT = {2: [('ball_0', 1.5, 0.0, 2.0)], 3: [('ball_3', -0.5, 0.5, 0.0)],
          24: [('ball_0', 0.0, 0.0, -1.0), ('ball_0', 0.8, -0.2, 0.5)],
          48: [('rover', 1.0, 0.0, 1.0), ('ball_3', 3.0, 0.0, -5.0)],
          80: [('ball_3', 0.3, 0.1, 0.7)]}


def agents_run(directory, steps=110, also=(), **overrides):
    """A split run with agents driven through Simulation.command, as the node drives them:
    a spawned agent, a heading set, a deleted agent, commands before several rolls; `also`,
    more sinks."""
    simulation = Simulation({**AGENTS, **overrides},
                            sinks=[SplitMcapSink(directory, max_seconds=0.5), *also])
    for k in range(1, steps + 1):
        if k == 30:
            [name], _ = simulation.spawn([SpawnRequest('rover', False,
                                                       Ball(9.0, 9.0, 0.0, 0.0, 0.15, 0.5),
                                                       agent=True)])
            assert name == 'rover'
        if k == 40:
            x, y = simulation.world.positions[simulation.index_of['ball_3']].tolist()
            simulation.set_state('ball_3', x, y, 0.0, 0.0, yaw=2.5)
        for name, vx, vy, wz in SCRIPT.get(k, []):
            twist = Twist()
            twist.linear.x, twist.linear.y, twist.angular.z = vx, vy, wz
            simulation.command(name, vx, vy, wz, serialize_message(twist))
        if k == 90:
            simulation.delete('ball_0')
        simulation.step()
    simulation.close()
    return metadata(directory)['relative_file_paths']


def first_messages(path):
    """Topics of the messages at a file's first log time."""
    with open(path, 'rb') as stream:
        messages = [(channel.topic, message.log_time) for _, channel, message in
                    make_reader(stream).iter_messages(log_time_order=True)]
    return [topic for topic, time in messages if time == messages[0][1]]


@pytest.mark.parametrize('overrides', [{}, {'agent.cmd_timeout': 0.0},
                                       {'physics.backend': 'numpy'},
                                       {'physics.mode': 'exact'},
                                       {'physics.mode': 'exact', 'physics.backend': 'numpy'}],
                         ids=['timeout', 'hold', 'numpy', 'exact', 'exact-numpy'])
def test_each_file_of_a_split_run_with_agents_resimulates_alone(tmp_path, capsys, overrides):
    directory = tmp_path / 'agents'
    names = agents_run(directory, **overrides)
    assert len(names) == 5
    assert resim.main([str(directory)]) == 0, capsys.readouterr()
    assert 'all 111 recorded steps re-simulate bit-identically' in capsys.readouterr().out
    for name in names:
        assert resim.main([str(directory / name)]) == 0, (name, capsys.readouterr())
        assert 'bit-identically' in capsys.readouterr().out
        # each file starts with its frames: a lone reader needs /tf_static (latched once)
        assert '/tf_static' in first_messages(directory / name), name
    # the state a file resumes from holds the commands in force, as given
    resume = open_recording(directory / names[2]).segments[0].resume
    assert resume.step == 49 and resume.agents == ('ball_0', 'ball_3', 'rover')
    assert dict(resume.commands) == {
        'ball_0': Command(0.8, -0.2, 0.5, 24 * 20_000_000),
        'ball_3': Command(3.0, 0.0, -5.0, 48 * 20_000_000),
        'rover': Command(1.0, 0.0, 1.0, 48 * 20_000_000)}
    assert resume.yaws[1] != 2.5 and abs(resume.yaws[1]) <= math.pi  # turned since set


def test_each_file_of_a_split_run_with_agents_gives_the_sinks_its_drives_again(tmp_path):
    # the drives are not recorded: a file that resumes mid-segment makes them again from the
    # headings and commands of its resume state (recording.remade_drives), as the live run
    # applied them, bit for bit; so does the whole directory
    live = Truth()
    directory = tmp_path / 'agents'
    names = agents_run(directory, also=[live])
    by_step = {record.step: record for record in live.records}

    def applied(impulses):
        return [(i.ball, i.frame_id, i.drive, i.jx, i.jy, i.cdr) for i in impulses]

    for path in (directory, *(directory / name for name in names)):
        fed = Truth()
        feed_sinks(open_recording(path), [fed])
        assert any(i.drive for record in fed.records for i in record.impulses), path
        for record in fed.records:
            assert applied(record.impulses) == applied(by_step[record.step].impulses), (
                path, record.step)
    assert sum(i.drive for record in live.records for i in record.impulses) > 50


def test_a_file_resumed_without_its_commands_differs(tmp_path, capsys):
    """Proof that the commands in the state matter: dropped, the lone file diverges."""
    directory = tmp_path / 'agents'
    names = agents_run(directory, steps=60)

    def forget(values):
        if 'resume_state' in values:
            document = json.loads(values['resume_state'])
            document.update(commanded=[], commands='', since_ns=[])
            values['resume_state'] = json.dumps(document)
        return values

    rewrite_recording(directory / names[2], tmp_path / 'forgot.mcap', metadata=forget)
    assert resim.main([str(tmp_path / 'forgot.mcap')]) == 1
    assert 'first difference: segment 0 step 50' in capsys.readouterr().out


@pytest.mark.parametrize('state, words', [
    (lambda d: ('yaws', base64.b64encode(struct.pack('<3d', 0.0, 4.0, 0.0)).decode()),
     'yaws holds a value outside'),
    (lambda d: ('since_ns', [-1] * len(d['since_ns'])), 'since_ns is not a simulation time'),
    (lambda d: ('since_ns', [1.5] * len(d['since_ns'])), 'since_ns is not a simulation time'),
    (lambda d: ('agents', d['agents'] + ['ghost']), 'agents names an agent twice, or one'),
    (lambda d: ('commanded', d['commanded'][:1]), 'commands holds 72 bytes, not 3 float64'),
    (lambda d: ('commands', base64.b64encode(struct.pack('<9d', *[1e300] * 9)).decode()),
     'commands holds a value outside'),
])
def test_a_crafted_agent_resume_state_is_refused_in_one_line(tmp_path, capsys, state, words):
    directory = tmp_path / 'agents'
    names = agents_run(directory, steps=60)
    crafted = rewrite_recording(directory / names[2], tmp_path / 'crafted.mcap',
                                metadata=crafted_resume(state))
    assert_resume_state_refused(crafted, words, capsys)


def test_max_files_without_a_split_is_said_at_start(tmp_path, processes):
    path = tmp_path / 'one.mcap'
    bag = tmp_path / 'bag'
    # The three runs at once (each is mostly its start-up), each in a namespace of its own.
    runs = [processes.start_node('max_steps:=3', 'rate_hz:=0.0', 'dt:=0.05',
                                 'record.max_files:=2', *parameters,
                                 ros_args=['-r', f'__ns:=/run{k}'])
            for k, parameters in enumerate(((f'record.mcap:={path}',),
                                            ('record.max_seconds:=1.0', f'record.mcap:={bag}'),
                                            ()))]
    code, out, err = finish(runs[0], NODE_TIMEOUT)
    assert code == 0, err
    said = [line for line in (out + err).splitlines() if 'record.max_files' in line]
    assert len(said) == 1 and said[0].endswith(
        'record.max_files 2 has no effect: the recording is one file unless '
        'record.max_bytes or record.max_seconds is set'), out + err
    assert path.is_file()  # recorded as one file, as asked
    # with a split, or with nothing recorded, nothing is said
    for run in runs[1:]:
        code, out, err = finish(run, NODE_TIMEOUT)
        assert code == 0 and 'has no effect' not in out + err, err


def test_a_node_run_with_agents_split_resimulates_file_by_file(probe, processes, tmp_path,
                                                               capsys):
    """The node, cmd_vel from another participant, files of 50 steps: each file alone."""
    directory = tmp_path / 'node'
    process = processes.start(node_command(*AGENT_WORLD, f'record.mcap:={directory}',
                                           'record.max_seconds:=1.0'))
    odom = probe.listen(Odometry, 'ball_1/odom')
    command = probe.node.create_publisher(Twist, 'ball_1/cmd_vel', 10)
    probe.spin_until(lambda: command.get_subscription_count() > 0 and odom,
                     'a reader of cmd_vel', process=process)
    # The first command until it shows (the node may not have matched us yet), then a
    # changing one every 5 steps heard (0.1 s): one in force at most splits. No max_steps
    # at start: a run of fixed length could end before a slow discovery.
    publish_until(probe, command, twist(x=1.0, y=-0.5, wz=2.0),
                  lambda: forward(odom[-1]) > 0.0, 'the command to be followed', process)
    for k in range(1, 25):
        heard = len(odom)
        probe.spin_until(lambda: len(odom) >= heard + 5, 'five more steps', process=process)
        command.publish(twist(x=1.0 + 0.05 * k, y=-0.5, wz=2.0 - 0.2 * k))
    probe.set_parameters('/ball_world', {'max_steps': step_of(odom[-1]) + 5})
    code, _, err = finish(process, NODE_TIMEOUT)
    assert code == 0, err
    assert resim.main([str(directory)]) == 0
    resimulated = re.search(r'all ([0-9]+) recorded steps re-simulate bit-identically',
                            capsys.readouterr().out)
    last = int(resimulated.group(1)) - 1
    names = metadata(directory)['relative_file_paths']
    assert len(names) == last // 50 + 1  # steps 0-49, 50-99, ..., then the last ones
    commanded = 0
    for name in names:
        assert resim.main([str(directory / name)]) == 0, (name, capsys.readouterr())
        assert '/tf_static' in first_messages(directory / name), name
        resume = open_recording(directory / name).segments[0].resume
        commanded += bool(resume is not None and resume.commands)
    assert commanded >= 1  # a file resumed with a command in force, and re-simulated


def test_the_node_records_a_closing_record_in_a_split_run(probe, processes, tmp_path):
    """Pause, step, push, spawn, delete, Ctrl-C: through the node's writer thread too.

    Started paused, steps of 1 s split at the least record.max_seconds: a file every step.
    """
    directory = _node_edits_then_stops(probe, processes, tmp_path, 'sigint', 'dt:=1.0',
                                       'record.max_seconds:=1.0', 'start_paused:=true')
    names = metadata(directory)['relative_file_paths']
    assert len(names) == 2  # a file every step (dt 1 s): steps 0 and 1, then the edits
    steps = list(open_recording(directory).steps())
    last = steps[-2].step
    assert [(s.step, len(s.impulses), len(s.edits)) for s in steps if s.closing] == [
        (last + 1, 1, 2)] and steps[-1].closing
    for target in (directory, directory / names[-1]):  # the set, and its last file alone
        code, out, err = run_tool('ball_world_resim', str(target))
        assert code == 0, out + err
        assert 'after the last step 1 impulses and 2 edits: identical' in out, out
    code, out, err = run_tool('ball_world_info', str(directory))
    assert code == 0, err
    assert f'-{last} (+ 2 edits and 1 impulse after the last step)' in out, out
