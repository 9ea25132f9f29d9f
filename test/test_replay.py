"""ball_world_replay across processes: what a subscriber receives, when, and how it stops.

The replay runs as a child process in the test run's own DDS domain (conftest); this test
subscribes in-process through a probe with an rclpy context of its own, and waits with
deadlines, never fixed sleeps. Timing is checked from below only (a loaded machine can only
make a replay later): the arrivals span at least half the recorded time.
"""
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from ball_world_testing.harness import DEADLINE, finish
import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from visualization_msgs.msg import MarkerArray

from ball_world.msgs.cdr import decode_pose_array
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink, OFFERED_QOS_PROFILES
from ball_world.simulation import Simulation
from ball_world.tools.replay import argument_parser, message_class, played_topics, qos_profile

ROOT = Path(__file__).resolve().parents[1]
DT = 0.05  # 20 Hz
TOPICS = ('/balls', '/state', '/stats', '/impulse', '/markers')


@pytest.fixture(scope='module')
def recording_path(tmp_path_factory):
    """50 steps at 20 Hz (51 step messages per topic) with two impulses."""
    path = tmp_path_factory.mktemp('replay') / 'run.mcap'
    simulation = Simulation({'rate_hz': 1 / DT, 'random.count': 10, 'random.seed': 2},
                            sinks=[McapSink(path)])
    for _ in range(50):
        if simulation.step_index in (9, 30):
            simulation.queue_impulse('ball_1', 0.1, -0.2)
        simulation.step()
    simulation.close()
    return path


def start_replay(processes, path, *args):
    """The replay of this source tree (not an installed one) in a child process."""
    env = dict(os.environ,
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    return processes.start([sys.executable, '-m', 'ball_world.tools.replay', str(path),
                            '--wait-for-subscribers', '--delay', '0.3', *args],
                           cwd=ROOT, env=env)


def subscribe(probe, topics_types):
    """Raw subscriptions; returns {topic: [(arrival monotonic time, bytes)]}."""
    return {topic: probe.listen(message_class(type_name), topic,
                                keep=lambda data: (time.monotonic(), data), raw=True)
            for topic, type_name in topics_types.items()}


def clock_ns(data):
    """The time a raw /clock message carries (CDR: a 4-byte header, sec, nanosec)."""
    return (int.from_bytes(data[4:8], 'little', signed=True) * 10**9
            + int.from_bytes(data[8:12], 'little'))


def test_replay_publishes_the_recording_in_order_with_its_timing_and_clock(
        recording_path, probe, processes):
    recording = Recording(recording_path)
    recorded = {topic: [] for topic in TOPICS}
    for message in recording.messages(TOPICS):
        recorded[message.topic].append(message)
    # markers: a DELETEALL at the start, then every 0.1 s of simulated time (0 to 2.5 s)
    assert [len(recorded[t]) for t in TOPICS] == [51, 51, 51, 2, 1 + 26]
    received = subscribe(probe, {**{t: recording.topics[t].type for t in TOPICS},
                                 '/clock': 'rosgraph_msgs/msg/Clock'})
    child = start_replay(processes, recording_path, '--clock')
    assert probe.wait_for(lambda: all(
        len(received[t]) >= len(recorded[t]) for t in TOPICS), timeout=DEADLINE), \
        {t: len(v) for t, v in received.items()}
    code, _, err = finish(child)
    assert code == 0, err
    # The last /clock (keep_last 1: the newest is never dropped) may still be on its way
    probe.wait_for(lambda: received['/clock'] and clock_ns(received['/clock'][-1][1])
                   == recorded['/balls'][-1].log_time_ns, timeout=DEADLINE)
    for topic in TOPICS[:-1]:
        assert [data for _, data in received[topic]] == \
            [message.data for message in recorded[topic]], topic
    # rclpy-serialized markers carry stray padding bytes, which the middleware may not
    # forward: compare them as messages
    assert [deserialize_message(data, MarkerArray) for _, data in received['/markers']] == \
        [deserialize_message(message.data, MarkerArray) for message in recorded['/markers']]
    stamps = [decode_pose_array(data)[0] for _, data in received['/balls']]
    assert stamps == [round(k * DT * 1e9) for k in range(51)]
    clock = [clock_ns(data) for _, data in received['/clock']]
    # /clock is keep_last 1 and not waited for: some may be missed (how many depends on the
    # machine's load), none made up; over half of them rules out a clock that skips steps.
    assert clock == sorted(set(clock)) and len(clock) > len(recorded['/balls']) // 2
    assert set(clock) <= {m.log_time_ns for m in recorded['/balls']}
    assert clock[-1] == recorded['/balls'][-1].log_time_ns
    # Paced by log time: a replay that ignored it would send the 51 steps within milliseconds.
    arrivals = [t for t, _ in received['/balls']]
    assert arrivals[-1] - arrivals[0] >= 0.5 * 50 * DT, arrivals[-1] - arrivals[0]


def test_replay_loops_filters_remaps_and_stops_cleanly_on_sigterm(recording_path, probe,
                                                                  processes):
    received = subscribe(probe, {'/replay/balls': 'geometry_msgs/msg/PoseArray',
                                 '/replay/state': 'std_msgs/msg/Float64MultiArray'})
    child = start_replay(processes, recording_path, '--topics', '/balls', '--loop', '--rate',
                         '5', '--start-offset', '2.0', '--remap-prefix', '/replay')
    # from 2.0 s on: steps 40-50, 11 per pass; more than 11 proves it loops
    assert probe.wait_for(lambda: len(received['/replay/balls']) >= 25, timeout=DEADLINE)
    child.send_signal(signal.SIGTERM)
    code, _, err = finish(child)
    assert code == 0, err
    stamps = [decode_pose_array(data)[0] for _, data in received['/replay/balls']]
    assert stamps[:22] == [round(k * DT * 1e9) for k in range(40, 51)] * 2
    assert received['/replay/state'] == []
    assert 'stopped' in err


def test_replay_refuses_bad_arguments_before_starting_ros(recording_path):
    for args, complaint in ((['--rate', '0'], '--rate must be > 0'),
                            (['--topics', '/nope'], 'no such topic in the recording: /nope'),
                            (['--remap-prefix', 'replay'], "must start with '/'")):
        result = subprocess.run([sys.executable, '-m', 'ball_world.tools.replay',
                                 str(recording_path), *args], cwd=ROOT, capture_output=True,
                                text=True, timeout=DEADLINE)
        assert result.returncode == 2 and complaint in result.stderr


def test_qos_comes_from_the_recorded_offer_in_either_rosbag2_format():
    jazzy = qos_profile(OFFERED_QOS_PROFILES)
    assert (jazzy.reliability, jazzy.durability, jazzy.history, jazzy.depth) == \
        (ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST, 10)
    humble = qos_profile('- history: 1\n  depth: 5\n  reliability: 2\n  durability: 1\n')
    assert (humble.reliability, humble.durability, humble.depth) == \
        (ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.TRANSIENT_LOCAL, 5)
    unknown = qos_profile('')
    assert (unknown.reliability, unknown.depth) == (ReliabilityPolicy.RELIABLE, 10)


def test_a_recorded_clock_plays_unless_clock_publishes_its_own(tmp_path):
    path = tmp_path / 'clock.mcap'
    simulation = Simulation({'rate_hz': 1 / DT, 'random.count': 3, 'publish_clock': True},
                            sinks=[McapSink(path)])
    simulation.step()
    simulation.close()
    recording = Recording(path)
    parser = argument_parser()
    assert '/clock' in played_topics(parser.parse_args([str(path)]), recording)
    assert '/clock' not in played_topics(parser.parse_args([str(path), '--clock']), recording)
    result = subprocess.run([sys.executable, '-m', 'ball_world.tools.replay', str(path),
                             '--clock', '--topics', '/balls', '/clock'], cwd=ROOT,
                            capture_output=True, text=True, timeout=DEADLINE)
    assert result.returncode == 2
    assert result.stderr.strip() == ('ball_world_replay: --clock publishes /clock itself: '
                                     'leave it out of --topics')
