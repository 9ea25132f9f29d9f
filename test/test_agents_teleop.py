"""ball_world_teleop drives an agent through cmd_vel (turtle_teleop_key's arrows) and still
pushes a plain ball with impulses: keys typed into a real terminal (tmux), a probe watching.
"""
from ball_world_testing.harness import finish, node_command, Probe
from nav_msgs.msg import Odometry
import pytest
from std_msgs.msg import Float64MultiArray
from test_teleop import Tmux

from ball_world.tools.teleop_drive import DEFAULT_SPEED, DEFAULT_TURN, twist_for

NAMESPACE = '/sim3'
WORLD = ['-p', 'random.count:=0', '-p', 'balls.x:=[2.0, 5.0]', '-p', 'balls.y:=[5.0, 5.0]',
         '-p', 'balls.vx:=[0.0, 0.0]', '-p', 'balls.vy:=[0.0, 0.0]',
         '-p', 'balls.radius:=[0.3, 0.3]', '-p', 'balls.mass:=[4.0, 4.0]',
         '-p', 'agents:=[ball_1]', '-p', 'rate_hz:=50.0', '-p', 'markers.rate_hz:=0.0',
         '-p', 'agent.cmd_timeout:=0.3']


def test_arrow_keys_are_turtlesim_twists():
    assert (twist_for('up', 2.0, 3.0).linear.x, twist_for('up', 2.0, 3.0).angular.z) == (2.0, 0)
    assert twist_for('down', 2.0, 3.0).linear.x == -2.0
    assert twist_for('left', 2.0, 3.0).angular.z == 3.0
    assert twist_for('right', 2.0, 3.0).angular.z == -3.0


@pytest.fixture
def terminal(tmp_path):
    tmux = Tmux(tmp_path)
    yield tmux
    tmux.close()


def test_teleop_drives_an_agent_and_pushes_a_ball(terminal, processes):
    probe = Probe('agent_teleop_probe', namespace=NAMESPACE, timeout=60.0)
    try:
        odom = probe.listen(Odometry, 'ball_1/odom')
        states = probe.listen(Float64MultiArray, 'state')
        node = processes.start(node_command(ros_args=['-r', f'__ns:={NAMESPACE}', *WORLD]))
        probe.spin_until(lambda: odom, 'the world', process=node)
        terminal.start('--ros-args', '-r', f'__ns:={NAMESPACE}', '-p', 'ball:=ball_1')
        # Selected, the agent gets its cmd_vel publisher before any key is pressed; the
        # line says so once the world has matched it.
        terminal.wait_for('ball     ball_1 (2 of 2) at (5.00, 5.00), a robot: arrows drive it')
        # Driving, never "push": the keys line says what the arrows do to a robot.
        terminal.wait_for(f'keys     drive ball_1: up/down forward/back, left/right turn '
                          f'({DEFAULT_SPEED:g} m/s, {DEFAULT_TURN:g} rad/s per key)')
        terminal.keys('Up')
        terminal.wait_for(f'status   drive: ball_1 forward +{DEFAULT_SPEED:g} m/s, turn +0')
        probe.spin_until(lambda: odom[-1].twist.twist.linear.x == DEFAULT_SPEED,
                         'the agent to reach the commanded speed')
        probe.spin_until(lambda: odom[-1].twist.twist.linear.x == 0.0,
                         'the agent to stop after agent.cmd_timeout')
        terminal.keys('Left')
        terminal.wait_for(f'status   drive: ball_1 forward +0 m/s, turn +{DEFAULT_TURN:g}')
        probe.spin_until(lambda: odom[-1].twist.twist.angular.z == DEFAULT_TURN,
                         'the agent to turn')
        moved = [m for m in states if any(m.data[2:4])]
        assert moved == []  # ball_0 was never pushed by the agent's keys
        terminal.keys('0', 'Right')  # ball_0 is a plain ball: pushed by an impulse
        terminal.wait_for('ball     ball_0 (1 of 2) at')
        terminal.wait_for('status   push 1: ball_0 by (+0.1, +0) N s')
        probe.spin_until(lambda: states and states[-1].data[2] == 0.1 / 4.0,
                         'ball_0 to move at J / m')
        terminal.keys('q')
        assert terminal.file('rc').strip() == '0'
    finally:
        probe.close()
    node.send_signal(2)
    assert finish(node)[0] == 0
