"""ball_world_goal --agent: an agent driven to its goal through cmd_vel and odom, as processes.

The closed form behind the limits: from (2, 2) facing +x, the goal (6, 7) is 6.4 m away at
51 degrees; kw = 3/s turns the heading error down with a time constant of 1/3 s, then the
robot drives at max_speed 1 m/s (reached in 0.25 s at agent.max_accel 4) and slows as
kv * d inside 1 m, so it arrives in about 8 s of simulated time after its first command;
15 s leaves a margin, and both processes run on simulated time. The time is counted from
the first step the agent moves, not from the world's start: the controller may take any
time to start and find the world.
"""
import math
import signal

from ball_world_testing.harness import executable, finish, Probe, RECEIVE_QOS, run_tool
from nav_msgs.msg import Odometry
import pytest

from ball_world.tools.goal_drive import command

GOAL = (6.0, 7.0)
WORLD = ['-p', 'publish_clock:=true', '-p', 'markers.rate_hz:=0.0', '-p', 'random.count:=0',
         '-p', 'balls.x:=[2.0]', '-p', 'balls.y:=[2.0]', '-p', 'balls.vx:=[0.0]',
         '-p', 'balls.vy:=[0.0]', '-p', 'balls.radius:=[0.3]', '-p', 'balls.mass:=[0.5]',
         '-p', 'agents:=[ball_0]']
TOLERANCE = 0.05
REACH_S = 15.0


@pytest.mark.parametrize('x, y, yaw, forward, rate', [
    (0.0, 5.0, 0.0, 1.0, 0.0),                     # facing it, far: full speed
    (0.0, 5.0, math.pi / 2, 0.0, -3 * math.pi / 2),  # at right angles: turn only
    (5.0, 0.0, 0.0, 0.0, 3 * math.pi / 2),         # goal to the left: turn left
    (4.9, 5.0, 0.0, 0.1, 0.0),                     # near: kv * d
    (5.0, 5.0 + 0.04, 1.0, 0.0, 0.0),              # within tolerance: stop
])
def test_go_to_goal_command_closed_form(x, y, yaw, forward, rate):
    got = command(x, y, yaw, (5.0, 5.0), kv=1.0, kw=3.0, max_speed=1.0, tolerance=TOLERANCE)
    assert got == pytest.approx((forward, rate), abs=1e-12)


def test_agent_reaches_its_goal_and_stops_there(processes):
    probe = Probe('goal_agent_probe', timeout=90.0)
    try:
        odom = probe.listen(Odometry, 'ball_0/odom', qos=RECEIVE_QOS)
        world = processes.start([executable('ball_world'), '--ros-args', *WORLD])
        controller = processes.start([
            executable('ball_world_goal'), '--agent', '--ros-args', '-p',
            f'goal:=[{GOAL[0]}, {GOAL[1]}]', '-p', 'use_sim_time:=true'])

        def distance(message):
            p = message.pose.pose.position
            return math.hypot(p.x - GOAL[0], p.y - GOAL[1])

        def seconds(message):
            return message.header.stamp.sec + message.header.stamp.nanosec * 1e-9

        probe.spin_until(lambda: odom and distance(odom[-1]) <= TOLERANCE
                         and odom[-1].twist.twist.linear.x == 0.0,
                         'the agent to arrive and stop', process=world)
        arrived = next(m for m in odom if distance(m) <= TOLERANCE)
        moved = next(m for m in odom if m.twist.twist.linear.x != 0.0
                     or m.twist.twist.angular.z != 0.0)
        assert seconds(arrived) - seconds(moved) <= REACH_S
        later = seconds(odom[-1]) + 2.0
        probe.spin_until(lambda: seconds(odom[-1]) >= later, 'two more seconds',
                         process=world)
        assert distance(odom[-1]) <= 2 * TOLERANCE  # held there
    finally:
        probe.close()
    for process in (controller, world):
        process.send_signal(signal.SIGINT)
        code, _, err = finish(process)
        assert code == 0 and 'Traceback' not in err, err


def test_help_describes_the_agent_mode():
    code, out, _ = run_tool('ball_world_goal', '--help')
    assert code == 0 and '--agent' in out and 'cmd_vel' in out
