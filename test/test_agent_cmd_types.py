"""cmd_vel of the other type (Twist to a TwistStamped world, or the reverse) is named, once.

DDS never matches the two, so without the hint nothing on either side says why a robot does
not move (issue 26, finding 5).
"""
from ball_world_testing.harness import finish, node_command
from geometry_msgs.msg import Twist, TwistStamped
import pytest

from ball_world.ros.agents import TYPE_CHECK_PERIOD

WORLD = ('rate_hz:=50.0', 'markers.rate_hz:=0.0', 'random.count:=2', 'agents:=[ball_0]',
         'agent.scan.samples:=0')


@pytest.mark.parametrize('stamped, sent, setting', [
    (False, TwistStamped, 'agent.cmd_vel_stamped:=true'),
    (True, Twist, 'agent.cmd_vel_stamped:=false')], ids=['stamped-to-twist', 'twist-to-stamped'])
def test_another_type_on_cmd_vel_is_named_once_with_the_setting(probe, processes, tmp_path,
                                                                stamped, sent, setting):
    log = tmp_path / 'node.log'
    process = processes.start(node_command(*WORLD, f'agent.cmd_vel_stamped:={stamped}'),
                              log=log)
    publisher = probe.node.create_publisher(sent, 'ball_0/cmd_vel', 10)
    probe.spin_until(lambda: probe.node.count_subscribers('ball_0/cmd_vel') > 0,
                     "the world's cmd_vel subscription", process=process)

    def hinted():
        publisher.publish(sent())
        return setting in log.read_text()
    probe.spin_until(hinted, 'the hint', process=process)
    probe.spin_for(3 * TYPE_CHECK_PERIOD)  # more looks at the graph: still one hint
    process.send_signal(2)
    code, _, _ = finish(process)
    text = log.read_text()
    assert code == 0, text
    hints = [line for line in text.splitlines() if setting in line]
    assert len(hints) == 1, text
    assert '/ball_0/cmd_vel' in hints[0] and sent.__name__ in hints[0]
    assert publisher.get_subscription_count() == 0  # indeed never matched


def test_the_tools_send_the_type_the_world_takes(probes):
    from ball_world.tools.teleop_drive import command_type, stamped
    world, tool = probes('world'), probes('tool')
    world.node.create_subscription(TwistStamped, 'rover/cmd_vel', lambda m: None, 10)
    world.node.create_subscription(Twist, 'ball_0/cmd_vel', lambda m: None, 10)
    tool.spin_until(lambda: tool.node.count_subscribers('rover/cmd_vel') > 0
                    and tool.node.count_subscribers('ball_0/cmd_vel') > 0, 'the graph')
    assert command_type(tool.node, 'rover/cmd_vel') is TwistStamped
    assert command_type(tool.node, 'ball_0/cmd_vel') is Twist
    assert command_type(tool.node, 'nobody/cmd_vel') is Twist
    message = Twist()
    message.linear.x = 0.5
    wrapped = stamped(tool.node, message, 'base_link')
    assert wrapped.twist.linear.x == 0.5 and wrapped.header.frame_id == 'base_link'
