"""The node under the failures a long run meets: SIGKILL, a full disk, stalled readers, signals.

Each test starts the node as users do (the installed console script, a separate process,
talked to over DDS) and checks the promise the README makes about that failure: a SIGKILL
loses at most the last flush period and `ball_world_repair` gives a file every reader opens;
a recording that cannot be written is reported once and stepping goes on; no subscriber can
hold stepping up; SIGINT and SIGTERM finish both recordings. The last test runs the core for
tens of thousands of steps and checks its invariants.

A run that must not end before a probe has been discovered is started without max_steps at
a modest rate; once the probe hears it, max_steps and rate_hz are set through the parameter
service. That keeps every test free of timing assumptions about DDS discovery.
"""
import os
import signal
import sys
import time

from ball_world_testing.harness import (finish, read_mcap, read_mcap_ros2, read_rosbags,
                                        rrd_ball_steps, run_rerun, run_tool)
from geometry_msgs.msg import PoseArray
import numpy as np
import pytest
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import CHUNK_BYTES
from ball_world.simulation import Simulation

DT_NS = 10_000_000  # dt = 0.01 s in every run here
#: Generous: the machine has two noisy cores, and a test only fails on a hang.
EXIT_TIMEOUT = 120.0
DISCOVERY_TIMEOUT = 60.0
#: What a SIGKILL may lose at 100 Hz: the README's 1 s flush period, plus a few steps by which
#: a flush can wait behind the step timer.
LOSS_LIMIT_STEPS = 100 + 10
PROBE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
RECORDING_FAILED = 'recording to McapSink stopped'


def step_of(msg):
    return (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) // DT_NS


def listen(probe, qos=PROBE_QOS):
    """The steps of the `balls` messages the probe hears, as they arrive."""
    return probe.listen(PoseArray, 'balls', keep=step_of, qos=qos)


def spin_until_exit(probe, steps, process):
    """Listen while the node runs; then take what its last messages left queued."""
    probe.spin_until(lambda: process.poll() is not None, 'the node to exit',
                     timeout=EXIT_TIMEOUT)
    probe.drain(lambda: len(steps))


# SIGKILL ----------------------------------------------------------------------------------

def read_with_every_reader(path):
    """Open the file with mcap (which must find its summary), mcap_ros2 and rosbags; return
    the /balls steps each sees."""
    mcap_steps = [log_time // DT_NS for _, log_time, _ in read_mcap(path, ['/balls'])]
    ros2_steps = [step_of(msg) for _, _, msg in read_mcap_ros2(path, ['/balls'])]
    rosbags_steps = [step_of(msg) for _, _, msg in read_rosbags(path, ['/balls'])]
    return mcap_steps, ros2_steps, rosbags_steps


@pytest.mark.parametrize('seed, balls', [
    # 30 balls: a 1 MB chunk holds about 4 s of steps, so only the 1 s flush keeps the loss
    # small. 200 balls: chunks are cut every ~0.6 s, and the kill may tear one mid-write.
    (1, 30), (2, 200)])
def test_sigkill_loses_at_most_a_flush_period_and_repair_satisfies_every_reader(
        seed, balls, probes, processes, tmp_path):
    rng = np.random.default_rng(seed)
    kill_at = 250 + int(rng.integers(0, 100))  # steps received: past two flushes
    path = tmp_path / 'killed.mcap'
    process = processes.start_node(
        'rate_hz:=100.0', f'random.count:={balls}', f'random.seed:={seed}',
        'arena:=[0.0, 0.0, 25.0, 25.0]', 'markers.rate_hz:=0.0', f'record.mcap:={path}')
    probe = probes()
    steps = listen(probe)
    probe.spin_until(lambda: steps and steps[-1] >= kill_at, f'step {kill_at}',
                     DISCOVERY_TIMEOUT, process)
    process.send_signal(signal.SIGKILL)
    process.communicate(timeout=EXIT_TIMEOUT)
    assert process.returncode == -signal.SIGKILL
    last_received = max(steps)
    assert not Recording(path).has_summary

    repaired = tmp_path / 'repaired.mcap'
    code, _, err = run_tool('ball_world_repair', path, '-o', repaired, timeout=EXIT_TIMEOUT)
    assert code == 0, err
    recording = Recording(repaired)
    assert recording.has_summary
    steps = list(recording.steps())
    numbers = [step.step for step in steps]
    assert numbers and numbers == list(range(len(numbers))), 'no step was flushed'
    assert all(step.complete for step in steps)
    # The node steps at most 100 times per second of wall time and flushes every second; a
    # step the probe heard was certainly published.
    lost = last_received - numbers[-1]
    assert lost <= LOSS_LIMIT_STEPS, (last_received, numbers[-1])

    for seen in read_with_every_reader(repaired):
        assert seen == numbers
    code, out, err = run_tool('ball_world_resim', repaired, timeout=EXIT_TIMEOUT)
    assert code == 0, out + err


# A recording that cannot be written --------------------------------------------------------

def test_file_size_limit_mid_run_is_reported_once_and_stepping_goes_on(probes, processes,
                                                                       tmp_path):
    path, rrd_path = tmp_path / 'limited.mcap', tmp_path / 'limited.rrd'
    # Every file the node writes may hold 1.2 MB: two MCAP chunks of 500 balls (~0.5 MB each
    # after lz4), or ~300 steps of the .rrd; the next write fails with EFBIG.
    limit = 1_200_000
    process = processes.start_node(
        'rate_hz:=100.0', 'dt:=0.01', 'random.count:=500', 'arena:=[0.0, 0.0, 30.0, 30.0]',
        'markers.rate_hz:=0.0', f'record.mcap:={path}', f'record.rerun:={rrd_path}',
        limit_file_size=limit)
    probe = probes()
    steps = listen(probe)
    probe.spin_until(lambda: steps, 'the first step', DISCOVERY_TIMEOUT, process)
    max_steps = max(600, steps[-1] + 500)  # the .rrd reaches the limit too
    probe.set_parameters('ball_world', {'max_steps': max_steps, 'rate_hz': 0.0})
    spin_until_exit(probe, steps, process)
    code, _, err = finish(process, EXIT_TIMEOUT)
    assert code == 0, err  # not killed by SIGXFSZ: Python ignores it, the write fails
    assert f'max_steps {max_steps} reached' in err
    assert err.count(RECORDING_FAILED) == 1, err
    failure = next(line for line in err.splitlines() if RECORDING_FAILED in line)
    assert f'{path}: File too large' in failure  # EFBIG, with the path
    assert err.count('recording to RerunSink stopped') == 1, err
    assert os.path.getsize(rrd_path) <= limit

    assert os.path.getsize(path) <= limit
    recording = Recording(path)  # what was written before the failure is readable
    numbers = [step.step for step in recording.steps()]
    assert numbers == list(range(len(numbers)))
    # The failing write held at most one chunk of steps after the last recorded one; the
    # probe heard steps far beyond it, so publishing went on after the recording stopped.
    step_bytes = 500 * (56 + 32) + 400
    failed_at_most = len(numbers) + CHUNK_BYTES // step_bytes + 1
    assert max(steps) > failed_at_most + 100, (max(steps), failed_at_most)


@pytest.mark.parametrize('parameter, path', [
    ('record.mcap', '/dev/full'), ('record.mcap', '/proc/ball_world.mcap'),
    ('record.mcap', 'FILE/run.mcap'), ('record.rerun', 'FILE/run.rrd'),
    ('record.rerun', '/dev/full'), ('record.rerun', '/proc/ball_world.rrd')])
def test_unwritable_recording_stops_the_start_with_one_line(parameter, path, processes,
                                                            tmp_path):
    if path.startswith('FILE'):  # a path under a regular file: root cannot bypass that
        regular = tmp_path / 'a_file'
        regular.write_text('not a directory')
        path = path.replace('FILE', str(regular))
    code, out, err = finish(processes.start_node(f'{parameter}:={path}', 'max_steps:=5'),
                            EXIT_TIMEOUT)
    assert code != 0
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert f"parameter '{parameter}'" in lines[0] and path in lines[0]
    assert 'Traceback' not in err + out


# Subscribers cannot hold stepping up --------------------------------------------------------

#: A subscriber in its own process: prints 'heard' at its first `balls`, then spins on.
SUBSCRIBER = """
import rclpy
from geometry_msgs.msg import PoseArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
rclpy.init()
node = rclpy.create_node('far_subscriber')
heard = []
def on_balls(msg):
    if not heard:
        print('heard', flush=True)
    heard.append(1)
node.create_subscription(PoseArray, 'balls', on_balls,
                         QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
rclpy.spin(node)
"""


def start_subscribers(count, processes):
    """SUBSCRIBER processes, returned once each has heard the node.

    They talk to it over UDP only: a process frozen while Fast DDS's shared-memory transport
    delivers to it can stall delivery to every other reader of the topic, this test's probes
    included (Fast DDS's behaviour, not the node's: docs/reliability.md), and the probes must
    go on hearing the node for the test to pace itself. The node still has a reliable reader
    that never answers, and one that vanished.
    """
    environment = dict(os.environ, FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    started = [processes.start([sys.executable, '-c', SUBSCRIBER], stderr=None,
                               env=environment)
               for _ in range(count)]
    for process in started:
        assert process.stdout.readline().strip() == 'heard'  # or it died: readline gives ''
    return started


def test_stalled_and_vanished_subscribers_never_block_stepping(probes, processes):
    process = processes.start_node('rate_hz:=100.0', 'dt:=0.01', 'random.count:=2000',
                                   'arena:=[0.0, 0.0, 60.0, 60.0]', 'markers.rate_hz:=0.0')
    # Readers that never take a message: one keeps the last, one keeps all.
    stalled = listen(probes('stalled'), QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                                                   reliability=ReliabilityPolicy.RELIABLE))
    hoarding = listen(probes('hoarding'), QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL,
                                                     reliability=ReliabilityPolicy.RELIABLE))
    # Readers in processes that stop answering: one frozen, one killed without a goodbye (its
    # reader stays matched until its lease runs out).
    frozen, vanished = start_subscribers(2, processes)
    vanishing = probes('vanishing')  # destroyed mid-run, the orderly way
    vanishing_steps = listen(vanishing)
    control = probes('control')
    control_steps = listen(control)  # matched now: a reader that joins later may wait long
    vanishing.spin_until(lambda: vanishing_steps, 'the first step', DISCOVERY_TIMEOUT, process)
    control.spin_until(lambda: control_steps, 'the first step', DISCOVERY_TIMEOUT, process)
    deadline = time.monotonic() + DISCOVERY_TIMEOUT
    while min(stalled.subscription.get_publisher_count(),
              hoarding.subscription.get_publisher_count()) == 0:
        assert time.monotonic() < deadline, 'a stalled reader never matched'
        time.sleep(0.05)  # readers that are never spun: their DDS threads do the matching
    frozen.send_signal(signal.SIGSTOP)
    vanished.send_signal(signal.SIGKILL)
    try:
        # As fast as it can, with no end yet: the end is set once a reader has left mid-run (a
        # max_steps set now could be reached before this process had heard a few steps).
        control.set_parameters('ball_world', {'rate_hz': 0.0})
        seen = len(vanishing_steps)
        vanishing.spin_until(lambda: len(vanishing_steps) > seen + 5, f'step {seen + 5}',
                             DISCOVERY_TIMEOUT, process)
        vanishing.node.destroy_subscription(vanishing_steps.subscription)
        vanishing.close()
        left_at = max(vanishing_steps)
        control.spin_until(lambda: control_steps[-1] > left_at + 5,
                           'five steps after a reader left', DISCOVERY_TIMEOUT, process)
        max_steps = control_steps[-1] + 500  # the node may be past it: it stops at once then
        control.set_parameters('ball_world', {'max_steps': max_steps})
        code, _, err = finish(process, EXIT_TIMEOUT)
    finally:
        frozen.send_signal(signal.SIGCONT)
    assert code == 0, err
    assert f'max_steps {max_steps} reached' in err


# Signals while recording ------------------------------------------------------------------

@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_while_recording_finishes_mcap_and_rrd(sig, probes, processes, tmp_path):
    mcap_path, rrd_path = tmp_path / 'run.mcap', tmp_path / 'run.rrd'
    process = processes.start_node(
        'rate_hz:=100.0', 'random.count:=100', 'markers.rate_hz:=0.0',
        'arena:=[0.0, 0.0, 20.0, 20.0]', f'record.mcap:={mcap_path}', f'record.rerun:={rrd_path}')
    probe = probes()
    steps = listen(probe)
    probe.spin_until(lambda: steps and steps[-1] >= 150, 'step 150', DISCOVERY_TIMEOUT, process)
    process.send_signal(sig)
    code, out, err = finish(process, EXIT_TIMEOUT)
    assert code == 0, err
    assert 'Traceback' not in out + err

    recording = Recording(mcap_path)
    assert recording.has_summary
    numbers = [step.step for step in recording.steps()]
    assert numbers == list(range(len(numbers))) and numbers[-1] >= max(steps)
    verify = run_rerun('rrd', 'verify', rrd_path, timeout=EXIT_TIMEOUT)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    (rrd_steps,) = rrd_ball_steps(rrd_path)  # one recording
    assert rrd_steps == numbers  # the .rrd ends on the same step as the MCAP


# The core over a long run -------------------------------------------------------------------

def test_twenty_thousand_steps_keep_every_ball_inside_and_conserve_energy():
    arena = (0.0, 0.0, 20.0, 20.0)
    simulation = Simulation({'random.count': 300, 'random.seed': 7, 'arena': list(arena),
                             'walls': [5.0, 5.0, 15.0, 12.0], 'dt': 0.01, 'rate_hz': 0.0})
    world = simulation.world
    energy = world.kinetic_energy()
    lower, upper = np.array(arena[:2]), np.array(arena[2:])
    for _ in range(20_000):
        record, rejected = simulation.step()
        positions = record.positions
        assert np.all(np.isfinite(positions)) and np.all(np.isfinite(record.velocities))
        assert np.all((positions > lower) & (positions < upper)), record.step
    assert simulation.step_index == 20_000 and not rejected
    assert abs(world.kinetic_energy() - energy) / energy < 1e-9
