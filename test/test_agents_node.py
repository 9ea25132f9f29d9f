"""Agents through real processes: the node in a process of its own, cmd_vel from a Probe.

The Probe is a separate rclpy context (its own DDS participant), as teleop_twist_keyboard or
a Nav2 controller would be. Speeds are checked against closed forms in steps of simulated
time (odom's stamps), never against the wall clock.
"""
import math
import re

from ball_world_testing.harness import finish, node_command, RECEIVE_QOS, run_tool
from geometry_msgs.msg import PoseArray, Twist, TwistStamped
from nav_msgs.msg import Odometry
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from tf2_msgs.msg import TFMessage

STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Two agents in a 100 m box, far from everything: nothing but the drive moves them.
WORLD = ('rate_hz:=50.0', 'markers.rate_hz:=0.0', 'random.count:=0', 'arena:=[0, 0, 100, 100]',
         'balls.x:=[10.0, 10.0, 50.0]', 'balls.y:=[50.0, 20.0, 80.0]',
         'balls.vx:=[0.0, 0.0, 0.0]', 'balls.vy:=[0.0, 0.0, 0.0]',
         'balls.radius:=[0.5, 0.5, 0.5]', 'balls.mass:=[2.0, 1.0, 1.0]',
         'agents:=[ball_0, ball_1]', 'agent.max_accel:=4.0', 'agent.cmd_timeout:=0.5')
DT_NS = 20_000_000


def twist(x=0.0, y=0.0, z=0.0, wz=0.0):
    message = Twist()
    message.linear.x, message.linear.y, message.linear.z = x, y, z
    message.angular.z = wz
    return message


def stamp_ns(message):
    return message.header.stamp.sec * 10**9 + message.header.stamp.nanosec


def step_of(message):
    return stamp_ns(message) // DT_NS


def forward(odom):
    return odom.twist.twist.linear.x


def publish_until(probe, publisher, message, condition, what, process):
    """Publish `message` until condition() holds, as a controller repeats its command.

    Our side matched is not the node's side matched: what is sent before the node has
    matched our publisher is lost, so no test counts on its first messages arriving, nor on
    sending a number of them within a time.
    """
    def sent():
        if condition():
            return True
        publisher.publish(message)
        return False
    probe.spin_until(sent, what, process=process)


def test_cmd_vel_reaches_the_speed_in_max_accel_time_holds_it_then_stops(probe, processes):
    # A command in force for 2 s of simulated time, not WORLD's 0.5 s: the speed is checked
    # held over steps in which this probe must send a command at least every cmd_timeout,
    # which a busy machine may not let it do within 0.5 s of the node's steps.
    process = processes.start(node_command(*WORLD, 'agent.cmd_timeout:=2.0'))
    odom = probe.listen(Odometry, 'ball_0/odom')
    other = probe.listen(Odometry, 'ball_1/odom')
    command = probe.node.create_publisher(Twist, 'ball_0/cmd_vel', 10)
    probe.spin_until(lambda: len(odom) > 5 and command.get_subscription_count() > 0,
                     'odom and a reader of cmd_vel', process=process)
    # 1 m/s forward, repeated (as a controller does) until the agent has driven 30 steps,
    # then silence.

    def driven():
        moving = [m for m in odom if forward(m) > 0.0]
        return moving and step_of(odom[-1]) >= step_of(moving[0]) + 30
    publish_until(probe, command, twist(x=1.0), driven, 'the agent to drive 30 steps', process)
    moving = [m for m in odom if forward(m) > 0.0]
    start = step_of(moving[0])  # the first step the command acted on
    # 1 m/s at 4 m/s^2: 0.25 s = 12.5 steps of 20 ms: full speed from the 13th step on.
    for message in odom:
        k = step_of(message) - start + 1
        if 1 <= k <= 12:
            assert forward(message) == pytest.approx(4.0 * k * 0.02, abs=1e-9)
    probe.spin_until(lambda: any(forward(m) == 0.0 and step_of(m) > start + 40 for m in odom),
                     'the agent to stop after the timeout', process=process)
    held = [forward(m) for m in odom if start + 13 <= step_of(m) <= start + 30]
    assert held and all(v == pytest.approx(1.0, abs=1e-12) for v in held)
    stopped = next(m for m in odom if forward(m) == 0.0 and step_of(m) > start)
    last_heard = max(step_of(m) for m in odom if forward(m) == pytest.approx(1.0, abs=1e-12))
    # Braking from 1 m/s at 4 m/s^2 takes 0.25 s: about 13 steps after the last full speed.
    assert step_of(stopped) - last_heard <= 14
    assert all(forward(m) == 0.0 for m in other)  # ball_1 heard nothing
    process.send_signal(2)
    code, _, err = finish(process)
    assert code == 0 and 'Traceback' not in err


def test_odom_is_the_state_row_and_tf_composes_world_to_base_link(probe, processes):
    process = processes.start(node_command(*WORLD, 'frame_prefix:=w/'))
    odom = probe.listen(Odometry, 'ball_1/odom')
    tf = probe.listen(TFMessage, '/tf')
    static = probe.listen(TFMessage, '/tf_static', qos=STATIC_QOS)
    balls = probe.listen(PoseArray, 'balls')
    state = probe.listen(Float64MultiArray, 'state')
    command = probe.node.create_publisher(Twist, 'ball_1/cmd_vel', 10)
    probe.spin_until(lambda: command.get_subscription_count() > 0 and static,
                     'a reader of cmd_vel and /tf_static', process=process)
    publish_until(probe, command, twist(x=0.8, y=0.3, wz=1.0),
                  lambda: len(odom) > 40 and forward(odom[-1]) != 0.0, 'odom of the agent driving',
                  process)
    [transforms] = [m.transforms for m in static[-1:]]
    assert [(t.header.frame_id, t.child_frame_id) for t in transforms] == [
        ('world', 'w/ball_0/odom'), ('world', 'w/ball_1/odom')]
    for t in transforms:
        assert (t.transform.translation.x, t.transform.translation.y,
                t.transform.rotation.z, t.transform.rotation.w) == (0.0, 0.0, 0.0, 1.0)
    poses = {stamp_ns(m): m.poses[1].position for m in balls}
    # state carries no stamp: its rows are found by position. A ball held against a wall can
    # end two steps at one position with different velocities, so keep every row seen there.
    rows = {}
    for message in state:
        x, y, vx, vy = message.data[4:8]
        rows.setdefault((x, y), []).append((vx, vy))
    compared = 0
    for message in odom:
        pose = message.pose.pose
        assert message.header.frame_id == 'w/ball_1/odom'
        assert message.child_frame_id == 'w/ball_1/base_link'
        position = poses.get(stamp_ns(message))
        if position is None:
            continue  # that step's balls message has not arrived
        assert (pose.position.x, pose.position.y) == (position.x, position.y)  # bit for bit
        seen = rows.get((position.x, position.y))
        if seen is None:
            continue  # nor its state message
        yaw = 2.0 * math.atan2(pose.orientation.z, pose.orientation.w)
        body = message.twist.twist.linear
        cos, sin = math.cos(yaw), math.sin(yaw)
        in_body = [(cos * vx + sin * vy, cos * vy - sin * vx) for vx, vy in seen]
        assert any((body.x, body.y) == pytest.approx(row, abs=1e-12) for row in in_body), \
            (body.x, body.y, in_body)
        compared += 1
    assert compared > 20
    composed = 0
    for message in tf:
        [mine] = [t for t in message.transforms if t.child_frame_id == 'w/ball_1/base_link']
        assert mine.header.frame_id == 'w/ball_1/odom'
        position = poses.get(stamp_ns(mine))
        if position is None:
            continue
        # world -> odom is the identity: world -> base_link is odom -> base_link.
        assert (mine.transform.translation.x, mine.transform.translation.y) == (
            position.x, position.y)
        composed += 1
    assert composed > 20
    process.send_signal(2)
    assert finish(process)[0] == 0


def test_teleop_twist_keyboard_protocol_one_twist_per_key_and_z_ignored(probe, processes):
    """teleop_twist_keyboard sends one Twist per key press; t and b set linear.z only."""
    process = processes.start(node_command(*WORLD))
    odom = probe.listen(Odometry, 'ball_0/odom')
    command = probe.node.create_publisher(Twist, 'ball_0/cmd_vel', 10)
    probe.spin_until(lambda: command.get_subscription_count() > 0 and odom,
                     'a reader of cmd_vel', process=process)
    command.publish(twist(z=0.5))  # key t: up, which a planar drive ignores
    probe.spin_for(0.5)
    assert all(forward(m) == 0.0 and m.pose.pose.position.z == 0.0 for m in odom)
    seen = len(odom)
    key_u = twist(x=0.5, wz=1.0)  # forward and left, once (again if it was lost: see below)
    sent_at = []

    def driving():
        # The node may not have matched us yet: a press is repeated only after 30 steps
        # without an effect (a command is in force for 25).
        if any(forward(m) > 0.4 for m in odom[seen:]):
            return True
        if not sent_at or len(odom) >= sent_at[-1] + 30:
            command.publish(key_u)
            sent_at.append(len(odom))
        return False
    probe.spin_until(driving, 'the agent to drive', process=process)
    probe.spin_until(lambda: forward(odom[-1]) == 0.0 and odom[-1].twist.twist.angular.z == 0.0,
                     'the agent to stop after cmd_timeout', process=process)
    turned = [m.twist.twist.angular.z for m in odom[seen:]]
    assert max(turned) == 1.0
    process.send_signal(2)
    assert finish(process)[0] == 0


def test_twist_stamped_when_asked_and_names_under_a_namespace(probe, processes):
    process = processes.start(node_command(*WORLD, 'agent.cmd_vel_stamped:=true',
                                           ros_args=('-r', '__ns:=/sim2')))
    odom = probe.listen(Odometry, '/sim2/ball_1/odom')
    command = probe.node.create_publisher(TwistStamped, '/sim2/ball_1/cmd_vel', 10)
    probe.spin_until(lambda: command.get_subscription_count() > 0 and odom,
                     'a reader of /sim2/ball_1/cmd_vel', process=process)
    message = TwistStamped()
    message.header.frame_id = 'ball_1/base_link'
    message.twist.linear.y = 0.5
    publish_until(probe, command, message,
                  lambda: odom[-1].twist.twist.linear.y == pytest.approx(0.5, abs=1e-12),
                  'the agent to move left', process)
    process.send_signal(2)
    assert finish(process)[0] == 0


def test_hostile_cmd_vel_leaves_the_node_stepping_and_listening(probe, processes):
    process = processes.start(node_command(*WORLD))
    balls = probe.listen(PoseArray, 'balls', keep=stamp_ns)
    odom = probe.listen(Odometry, 'ball_0/odom')
    publishers = [probe.node.create_publisher(Twist, 'ball_0/cmd_vel', RECEIVE_QOS)
                  for _ in range(3)]
    probe.spin_until(lambda: all(p.get_subscription_count() for p in publishers),
                     'readers of cmd_vel', process=process)
    # A good command followed first: the node has then matched at least publishers[0], whose
    # bad messages below must all be refused. Then the flood, once the agent has stopped.
    publish_until(probe, publishers[0], twist(x=1.0),
                  lambda: odom and forward(odom[-1]) == pytest.approx(1.0, abs=1e-12),
                  'a good command to be followed', process)
    probe.spin_until(lambda: forward(odom[-1]) == 0.0, 'the agent to stop after cmd_timeout',
                     process=process)
    bad = [twist(x=math.nan), twist(x=1e308), twist(wz=-math.inf), twist(y=1e300)]
    before, still = len(balls), len(odom)
    for round_ in range(300):  # 3,600 bad messages from three publishers
        for publisher in publishers:
            for message in bad:
                publisher.publish(message)
        if round_ % 20 == 0:
            probe.spin_for(0.01)
    probe.spin_until(lambda: len(balls) > before + 50, 'fifty more steps', process=process)
    assert all(forward(m) == 0.0 for m in odom[still:])  # nothing bad moved it
    stamps = list(balls)
    assert all(b - a == DT_NS for a, b in zip(stamps, stamps[1:]))  # no step skipped
    publish_until(probe, publishers[0], twist(x=1.0),
                  lambda: forward(odom[-1]) == pytest.approx(1.0, abs=1e-12),
                  'a good command to be followed after the flood', process)
    process.send_signal(2)
    code, _, err = finish(process)
    assert code == 0 and 'Traceback' not in err
    assert 'refused cmd_vel for ball_0' in err
    assert err.count('refused cmd_vel') <= 3  # at most one warning per 5 s


def test_a_recorded_run_with_agents_resimulates_bit_for_bit(probe, processes, tmp_path):
    path = tmp_path / 'agents.mcap'
    process = processes.start(node_command(*WORLD, f'record.mcap:={path}'))
    odom = probe.listen(Odometry, 'ball_1/odom')
    command = probe.node.create_publisher(Twist, 'ball_1/cmd_vel', 10)
    probe.spin_until(lambda: command.get_subscription_count() > 0 and odom,
                     'a reader of cmd_vel', process=process)

    publish_until(probe, command, twist(x=1.0, y=-0.5, wz=2.0), lambda: forward(odom[-1]) > 0.0,
                  'the command to be followed', process)
    # max_steps now, not at start: a run of fixed length could end before a slow discovery.
    # The node may be past it already: it then stops at its next step.
    last = step_of(odom[-1]) + 20
    probe.set_parameters('/ball_world', {'max_steps': last})
    code, _, err = finish(process)
    assert code == 0, err
    assert f'max_steps {last} reached' in err, err
    code, out, err = run_tool('ball_world_resim', str(path))
    assert code == 0, out + err
    resimulated = re.search(r'all ([0-9]+) recorded steps re-simulate bit-identically', out)
    assert resimulated and int(resimulated.group(1)) >= last + 1, out  # steps 0 to last
    code, out, _ = run_tool('ball_world_info', str(path))
    commands = re.search(r'agents: +2 \(ball_0, ball_1\), ([0-9]+) commands', out)
    assert commands and int(commands.group(1)) >= 1, out


def test_spawned_agent_is_a_robot_driven_and_turned_through_the_services(probe, processes):
    from simulation_interfaces.msg import EntityCategory, Result
    from simulation_interfaces.srv import GetEntityInfo, SetEntityState, SpawnEntity
    process = processes.start(node_command(*WORLD))
    probe.spin_until(lambda: probe.node.count_publishers('/balls') > 0, 'the world',
                     process=process)
    request = SpawnEntity.Request(name='rover', uri='ball',
                                  resource_string='{radius: 0.3, agent: true}')
    request.initial_pose.pose.position.x, request.initial_pose.pose.position.y = 50.0, 50.0
    spawned = probe.call(SpawnEntity, '/ball_world/spawn_entity', request)
    assert spawned.result.result == Result.RESULT_OK, spawned.result.error_message
    info = probe.call(GetEntityInfo, '/ball_world/get_entity_info',
                      GetEntityInfo.Request(entity='rover'))
    assert info.info.category.category == EntityCategory.CATEGORY_ROBOT
    plain = probe.call(GetEntityInfo, '/ball_world/get_entity_info',
                       GetEntityInfo.Request(entity='ball_2'))
    assert plain.info.category.category == EntityCategory.CATEGORY_DYNAMIC_OBJECT
    odom = probe.listen(Odometry, 'rover/odom')
    probe.spin_until(lambda: odom, 'the new agent odom', process=process)
    turn = SetEntityState.Request(entity='rover')
    turn.state.pose.position.x, turn.state.pose.position.y = 50.0, 50.0
    turn.state.pose.orientation.z = math.sin(0.6)
    turn.state.pose.orientation.w = math.cos(0.6)
    answer = probe.call(SetEntityState, '/ball_world/set_entity_state', turn)
    assert answer.result.result == Result.RESULT_OK, answer.result.error_message
    probe.spin_until(lambda: abs(2 * math.atan2(odom[-1].pose.pose.orientation.z,
                                                odom[-1].pose.pose.orientation.w) - 1.2)
                     < 1e-12, 'the heading set to 1.2 rad', process=process)
    tilted = SetEntityState.Request(entity='rover')
    tilted.state.pose.position.x, tilted.state.pose.position.y = 50.0, 50.0
    tilted.state.pose.orientation.x, tilted.state.pose.orientation.w = 0.6, 0.8
    refused = probe.call(SetEntityState, '/ball_world/set_entity_state', tilted)
    assert refused.result.result == SetEntityState.Response.INVALID_POSE
    command = probe.node.create_publisher(Twist, 'rover/cmd_vel', 10)
    probe.spin_until(lambda: command.get_subscription_count() > 0, 'rover/cmd_vel',
                     process=process)
    publish_until(probe, command, twist(x=1.0),
                  lambda: forward(odom[-1]) == pytest.approx(1.0, abs=1e-12),
                  'the spawned agent to drive', process)
    velocity = odom[-1].twist.twist.linear
    assert velocity.y == pytest.approx(0.0, abs=1e-12)  # forward along its heading
    process.send_signal(2)
    assert finish(process)[0] == 0


def test_a_world_without_agents_adds_nothing_to_the_graph(probe, processes):
    process = processes.start(node_command('rate_hz:=50.0', 'markers.rate_hz:=0.0'))
    probe.spin_until(lambda: probe.node.count_publishers('/balls') > 0, 'the world',
                     process=process)
    probe.spin_for(1.0)  # discovery of anything else the node might have made
    assert 'ball_world_agents' not in probe.node.get_node_names()
    assert probe.node.count_publishers('/tf') == 0
    assert probe.node.count_publishers('/tf_static') == 0
    process.send_signal(2)
    assert finish(process)[0] == 0


@pytest.mark.parametrize('value, words', [
    ('[ball_99]', "no ball named 'ball_99' to make an agent"),
    ('[ball_1, ball_1]', "'ball_1' is listed twice"),
    ('[1]', "parameter 'agents'"),
])
def test_unknown_agents_stop_the_start_with_one_line(value, words):
    code, out, err = run_tool('ball_world', '--ros-args', '-p', 'random.count:=3',
                              '-p', f'agents:={value}')
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and words in lines[0] and 'Traceback' not in err + out, err
