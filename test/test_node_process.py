"""The node as users run it: the installed executable in a process of its own, over DDS."""
from pathlib import Path
import signal
import time

from ball_world_testing.harness import finish, node_command, RECEIVE_QOS, run_tool
from geometry_msgs.msg import PoseArray, Vector3Stamped
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray

ROOT = Path(__file__).resolve().parents[1]
#: One step at rate_hz 50.
DT_NS = 20_000_000


def stamp_ns(message):
    return message.header.stamp.sec * 10**9 + message.header.stamp.nanosec


def speed_of_ball_3(state):
    return np.hypot(*np.array(state.data).reshape(-1, 4)[3, 2:])


def test_subprocess_steps_dt_apart_takes_impulses_and_stops_at_max_steps(probe, processes):
    """Nothing here depends on how fast the machine is: stamps are simulated time, the
    impulse is sent until it shows, and max_steps is set once the test has seen what it
    needs (a max_steps given at start could end the run before a slow discovery)."""
    process = processes.start(node_command('rate_hz:=50.0', 'markers.rate_hz:=0.0'))
    balls = probe.listen(PoseArray, 'balls')
    states = probe.listen(Float64MultiArray, 'state')
    impulses = probe.node.create_publisher(Vector3Stamped, 'impulse', RECEIVE_QOS)
    probe.spin_until(lambda: len(balls) >= 60 and impulses.get_subscription_count() > 0,
                     '60 steps and a reader of impulse', process=process)

    # An impulse on ball 3 changes its velocity (by J/m up to what a collision adds). Our
    # side matched need not mean the node's side has: it is sent again after five steps
    # without an effect.
    msg = Vector3Stamped()
    msg.header.frame_id = 'ball_3'
    msg.vector.x = 50.0
    seen = len(states)
    sent_at = []

    def pushed():
        if any(speed_of_ball_3(s) > 10.0 for s in states[seen:]):
            return True
        if not sent_at or len(states) >= sent_at[-1] + 5:
            impulses.publish(msg)
            sent_at.append(len(states))
        return False
    probe.spin_until(pushed, 'ball 3 to take the impulse', process=process)
    assert max(speed_of_ball_3(s) for s in states[:seen]) < 10.0

    # Stop a few steps after the last one heard (or at once if the node is already past it).
    last = stamp_ns(balls[-1]) // DT_NS
    probe.set_parameters('/ball_world', {'max_steps': last + 10})
    code, _, err = finish(process)
    assert code == 0, err
    assert f'max_steps {last + 10} reached' in err
    probe.drain(lambda: len(balls))
    stamps = np.array([stamp_ns(m) for m in balls])
    assert stamps[0] % DT_NS == 0 and np.all(np.diff(stamps) == DT_NS)  # exactly 1 / 50 s


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signals_shut_down_cleanly(sig, probe, processes):
    process = processes.start(node_command('rate_hz:=100.0'))
    balls = probe.listen(PoseArray, 'balls', qos=10)
    probe.spin_until(lambda: len(balls) >= 3, 'three steps')
    process.send_signal(sig)
    code, out, err = finish(process)
    assert code == 0, err
    assert 'Traceback' not in err + out


def test_ctrl_c_after_falling_behind_says_so_once_without_an_rcl_error(probe, processes):
    """The last word on dropped steps comes after Ctrl-C has taken the context down: it is
    said on the console, not through the node's /rosout publisher, which would make rcl
    print 'Failed to publish log message to rosout' instead of ending quietly."""
    process = processes.start(node_command(
        'rate_hz:=100000.0', 'random.count:=3000', 'arena:=[0.0, 0.0, 200.0, 200.0]'))
    balls = probe.listen(PoseArray, 'balls', qos=10)
    probe.spin_until(lambda: len(balls) >= 20, 'twenty steps')
    time.sleep(1.5)  # over 0.5 s behind the schedule at any speed: steps are dropped
    process.send_signal(signal.SIGINT)
    code, out, err = finish(process)
    assert code == 0, err
    assert err.count('steps of wall time were dropped behind the 100000 Hz schedule') == 1, err
    assert 'rosout' not in err + out and 'Traceback' not in err + out


def run_node(*ros_args):
    """(exit code, stdout, stderr) of the node run with these ROS arguments to its end."""
    return run_tool('ball_world', '--ros-args', *ros_args)


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
    code, out, err = run_node('--params-file', str(params))
    assert code != 0
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert parameter in lines[0] and 'Traceback' not in err


def test_integers_for_doubles_and_an_empty_arena_are_taken_as_users_mean_them():
    code, _, err = run_node('-p', 'rate_hz:=0', '-p', 'dt:=1', '-p', 'max_steps:=2',
                            '-p', 'arena:=[]', '-p', 'random.count:=0',
                            '-p', 'walls:=[0, 0, 10, 0]', '-p', 'random_count:=5')
    assert code == 0, err
    assert '0 balls' in err and '1 walls' in err and 'dt 1 s' in err
    assert "ignoring unknown parameter 'random_count'; did you mean 'random.count'?" in err


def test_help_prints_usage_and_starts_nothing():
    code, out, _ = run_tool('ball_world', '--help')
    assert code == 0
    assert out.startswith('usage: ball_world')
    assert 'random.count (integer, default 20; 0 to 100,000)' in out


def test_installed_defaults_file_starts_the_node():
    code, _, err = run_node('--params-file', str(ROOT / 'config' / 'ball_world.yaml'),
                            '-p', 'max_steps:=3', '-p', 'rate_hz:=0.0', '-p', 'dt:=0.01')
    assert code == 0, err
    assert '20 balls' in err


def test_parameters_before_ros_args_are_warned_about_not_silently_dropped():
    # rclpy reads only what follows --ros-args: `ball_world -p rate_hz:=30` used to run at the
    # default rate without a word.
    code, _, err = run_tool('ball_world', '-p', 'dt:=0.5', '--ros-args', '-p', 'max_steps:=1',
                            '-p', 'rate_hz:=0.0', '-p', 'dt:=0.25')
    assert code == 0, err
    assert ("ball_world: warning: ignoring '-p dt:=0.5': ROS arguments go after --ros-args, "
            'e.g. ball_world --ros-args -p dt:=0.5') in err
    assert 'dt 0.25 s' in err  # the value after --ros-args is the one that acts


def test_first_log_line_is_short_and_the_names_are_at_debug_level():
    code, _, err = run_node('-p', 'max_steps:=1', '-p', 'rate_hz:=0.0', '-p', 'dt:=0.5',
                            '--log-level', 'ball_world:=debug')
    assert code == 0, err
    lines = [line for line in err.splitlines() if '[ball_world]' in line]
    assert 'world: 20 balls' in lines[0] and len(lines[0]) < 200, lines[0]
    names = next(line for line in lines if 'publishing /balls' in line)
    assert '[DEBUG]' in names and 'spawn_entity' in names and '/ball_world/step' in names
