"""The node as users run it: a separate process, found on PATH, talked to over DDS."""
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from geometry_msgs.msg import PoseArray, Vector3Stamped
from node_process import finish
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray

EXECUTABLE = str(Path(sys.executable).parent / 'ball_world')
ROOT = Path(__file__).resolve().parents[1]


def start_node(*ros_args, tmp_path=None):
    return subprocess.Popen([EXECUTABLE, '--ros-args', *ros_args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=os.environ.copy())


@pytest.fixture
def probe():
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin_until(predicate, timeout=60.0):
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, 'timed out waiting'
            executor.spin_once(timeout_sec=0.05)

    node.spin_until = spin_until
    yield node
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_subprocess_publishes_at_rate_takes_impulses_and_stops_at_max_steps(probe):
    process = start_node('-p', 'rate_hz:=50.0', '-p', 'max_steps:=400', '-p',
                         'markers.rate_hz:=0.0')
    try:
        balls, states = [], []
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

        probe.create_subscription(PoseArray, 'balls', balls.append, qos)
        probe.create_subscription(Float64MultiArray, 'state', states.append, qos)
        impulses = probe.create_publisher(Vector3Stamped, 'impulse', qos)
        probe.spin_until(lambda: len(balls) >= 60 and impulses.get_subscription_count() > 0)

        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in balls])
        assert np.all(np.diff(stamps) == 20_000_000)  # exactly dt = 1 / 50 s

        # An impulse on ball 3 changes its velocity (by J/m up to what a collision adds).
        msg = Vector3Stamped()
        msg.header.frame_id = 'ball_3'
        msg.vector.x = 50.0
        impulses.publish(msg)
        seen = len(states)
        probe.spin_until(lambda: len(states) > seen + 5)
        speeds = [np.hypot(*np.array(s.data).reshape(-1, 4)[3, 2:]) for s in states]
        assert max(speeds[seen:]) > 10.0 > max(speeds[:seen])
        code, _, err = finish(process)
        assert code == 0, err
        assert 'max_steps 400 reached' in err
    finally:
        if process.poll() is None:
            process.kill()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signals_shut_down_cleanly(sig, probe):
    process = start_node('-p', 'rate_hz:=100.0')
    try:
        balls = []
        probe.create_subscription(PoseArray, 'balls', balls.append, 10)
        probe.spin_until(lambda: len(balls) >= 3)
        process.send_signal(sig)
        code, out, err = finish(process)
        assert code == 0, err
        assert 'Traceback' not in err + out
    finally:
        if process.poll() is None:
            process.kill()


@pytest.mark.parametrize('content, parameter', [
    ('random.radius: [0.5, 0.1]', 'random.radius'),
    ('balls.x: [1.0]\n    balls.y: [1.0, 2.0]', 'balls.y'),
    ('arena: [0.0, 0.0, 1.0e100, 10.0]', 'arena'),
    ('random.count: 100000', 'random.count'),
    ('rate_hz: -5.0', 'rate_hz'),
    ('rate_hz: 1.0e-300', 'rate_hz'),  # with dt 0: steps of 1e300 s
    ('walls: [1.0e-200, 1.0, 0.0, 1.0]', 'walls'),  # no length once rounded
    ('random.radius: [1.0e-9, 1.0e-9]', 'random.radius'),  # 1e8 substeps per step
    ('balls.x: [1.0, 3.0]\n    balls.y: [1.0, 1.0]\n    balls.vx: [1.0, 0.0]\n'
     '    balls.vy: [0.0, 0.0]\n    balls.radius: [0.5, 0.5]\n'
     '    balls.mass: [1.0e308, 1.0e308]', 'balls.mass'),
    ('frame_id: ' + 'f' * 300, 'frame_id'),
    ('dt: 3601.0', 'dt'),
])
def test_bad_parameter_file_exits_non_zero_with_one_clear_line(tmp_path, content, parameter):
    params = tmp_path / 'bad.yaml'
    params.write_text(f'/**:\n  ros__parameters:\n    {content}\n')
    code, out, err = finish(start_node('--params-file', str(params)))
    assert code != 0
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert parameter in lines[0] and 'Traceback' not in err


def test_integers_for_doubles_and_an_empty_arena_are_taken_as_users_mean_them():
    code, _, err = finish(start_node('-p', 'rate_hz:=0', '-p', 'dt:=1', '-p', 'max_steps:=2',
                                     '-p', 'arena:=[]', '-p', 'random.count:=0',
                                     '-p', 'walls:=[0, 0, 10, 0]', '-p', 'random_count:=5'))
    assert code == 0, err
    assert '0 balls' in err and '1 walls' in err and 'dt 1 s' in err
    assert "ignoring unknown parameter 'random_count'; did you mean 'random.count'?" in err


def test_help_prints_usage_and_starts_nothing():
    result = subprocess.run([EXECUTABLE, '--help'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    assert result.stdout.startswith('usage: ball_world')
    assert 'random.count (integer, default 20; 0 to 100000)' in result.stdout


def test_installed_defaults_file_starts_the_node():
    code, _, err = finish(start_node('--params-file', str(ROOT / 'config' / 'ball_world.yaml'),
                                     '-p', 'max_steps:=3', '-p', 'rate_hz:=0.0', '-p',
                                     'dt:=0.01'))
    assert code == 0, err
    assert '20 balls' in err
