"""Agents (core.agents through the Simulation): the drive rule against closed forms.

dt is 1/64 s and the limits are powers of two or small integers, so the closed forms
(v = a t, yaw = n w dt) are exact binary numbers and most comparisons are exact.
"""
import math

import numpy as np
import pytest

from ball_world.core.agents import (Agents, body_to_world, check_command, CommandRejected,
                                    Limits, world_to_body)
from ball_world.core.edits import Ball, EditRefused
from ball_world.core.scenario import ScenarioError
from ball_world.simulation import build, Simulation, SpawnRequest

DT = 1.0 / 64


def one_agent(**overrides):
    """A ball of 1 kg at rest in an empty plane (no walls), ball_0, an agent."""
    parameters = {'rate_hz': 64.0, 'arena': [], 'random.count': 0, 'balls.x': [0.0],
                  'balls.y': [0.0], 'balls.vx': [0.0], 'balls.vy': [0.0],
                  'balls.radius': [0.5], 'balls.mass': [1.0], 'agents': ['ball_0'],
                  'physics.backend': 'numpy'}
    parameters.update(overrides)
    return Simulation(parameters)


def speed(simulation, name='ball_0'):
    return float(np.hypot(*simulation.world.velocities[simulation.index_of[name]]))


def test_reaches_the_commanded_speed_in_v_over_max_accel_and_holds_it():
    simulation = one_agent(**{'agent.cmd_timeout': 0.0})
    simulation.command('ball_0', 2.0, 0.0, 0.0)
    # 2 m/s at 4 m/s^2: 0.5 s, 32 steps of 1/64 s, each adding 4/64 m/s.
    for k in range(1, 33):
        simulation.step()
        assert speed(simulation) == pytest.approx(4.0 * k * DT, abs=1e-12)
    assert simulation.world.velocities[0].tolist() == pytest.approx([2.0, 0.0], abs=1e-12)
    for _ in range(50):
        record, _ = simulation.step()
        assert record.impulses == ()  # settled: no impulse chases the last ulp
    assert simulation.world.velocities[0].tolist() == pytest.approx([2.0, 0.0], abs=1e-12)
    # Travelled: 0.5 s accelerating (a t^2 / 2 = 0.5 m, as a sum of steps) then 2 m/s.
    x = float(simulation.world.positions[0, 0])
    assert x == pytest.approx(sum(4.0 * k * DT * DT for k in range(1, 33)) + 2.0 * 50 * DT,
                              abs=1e-9)


def test_the_drive_is_an_impulse_m_dv_recorded_with_its_step():
    simulation = one_agent(**{'balls.mass': [3.0]})
    simulation.command('ball_0', 1.0, 0.0, 0.0)
    record, _ = simulation.step()
    [impulse] = record.impulses
    assert impulse.frame_id == 'ball_0'
    assert (impulse.jx, impulse.jy) == pytest.approx((3.0 * 4.0 * DT, 0.0), abs=1e-15)
    assert record.commands[0].name == 'ball_0'
    assert (record.commands[0].vx, record.commands[0].wz) == (1.0, 0.0)
    record, _ = simulation.step()
    assert record.commands == ()


def test_commanded_speed_is_clamped_to_max_speed_along_its_direction():
    simulation = one_agent(**{'agent.max_accel': 1e6, 'agent.max_speed': 1.0})
    simulation.command('ball_0', 3.0, 4.0, 0.0)
    simulation.step()
    assert simulation.world.velocities[0].tolist() == pytest.approx([0.6, 0.8], abs=1e-15)


def test_stops_after_the_timeout_braking_at_max_accel():
    simulation = one_agent(**{'agent.cmd_timeout': 0.5})
    simulation.command('ball_0', 2.0, 0.0, 0.0)
    speeds = []
    for _ in range(80):
        simulation.step()
        speeds.append(speed(simulation))
    # In force for 0.5 s (steps 1 to 32): up to 2 m/s; then braking 32 steps to rest.
    assert speeds[31] == pytest.approx(2.0, abs=1e-12)
    assert speeds[32] == pytest.approx(2.0 - 4.0 * DT, abs=1e-12)
    assert speeds[62] == pytest.approx(4.0 * DT, abs=1e-12)
    assert speeds[63:] == [0.0] * 17


def test_zero_timeout_holds_the_last_command():
    simulation = one_agent(**{'agent.cmd_timeout': 0.0})
    simulation.command('ball_0', 1.0, 0.0, 0.0)
    for _ in range(64 * 5):
        simulation.step()
    assert speed(simulation) == pytest.approx(1.0, abs=1e-12)


def test_an_agent_without_a_command_is_held_at_rest():
    simulation = one_agent(**{'balls.vx': [1.5]})
    for _ in range(16):
        simulation.step()
    assert speed(simulation) == pytest.approx(1.5 - 16 * 4.0 * DT, abs=1e-12)
    for _ in range(8):
        simulation.step()
    assert speed(simulation) == 0.0


def test_yaw_after_n_steps_is_n_wz_dt_and_the_rate_is_clamped():
    simulation = one_agent(**{'agent.cmd_timeout': 0.0})
    simulation.command('ball_0', 0.0, 0.0, 0.5)
    for n in range(1, 41):
        record, _ = simulation.step()
        assert record.agents.yaws[0] == n * 0.5 * DT
    simulation.command('ball_0', 0.0, 0.0, -100.0)  # max_yaw_rate 3 rad/s
    for n in range(1, 11):
        record, _ = simulation.step()
        assert record.agents.yaws[0] == 40 * 0.5 * DT - n * 3.0 * DT


def test_yaw_stays_in_minus_pi_to_pi_and_collisions_do_not_turn_it():
    simulation = one_agent(**{'agent.cmd_timeout': 0.0, 'agent.max_yaw_rate': 1000.0})
    simulation.command('ball_0', 0.0, 0.0, 100.0)
    total = 0.0
    for _ in range(200):
        record, _ = simulation.step()
        total += 100.0 * DT
        yaw = float(record.agents.yaws[0])
        assert -math.pi <= yaw <= math.pi
        assert math.cos(yaw) == pytest.approx(math.cos(total), abs=1e-9)
        assert math.sin(yaw) == pytest.approx(math.sin(total), abs=1e-9)


def test_heading_is_kinematic_a_collision_does_not_turn_it():
    parameters = {'rate_hz': 64.0, 'arena': [], 'random.count': 0, 'balls.x': [0.0, 2.0],
                  'balls.y': [0.0, 0.0], 'balls.vx': [0.0, -4.0], 'balls.vy': [0.0, 0.0],
                  'balls.radius': [0.5, 0.5], 'balls.mass': [1.0, 1.0], 'agents': ['ball_0'],
                  'physics.backend': 'numpy'}
    simulation = Simulation(parameters)
    collisions = 0
    for _ in range(32):
        record, _ = simulation.step()
        collisions += record.ball_ball
        assert record.agents.yaws[0] == 0.0
    assert collisions >= 1


@pytest.mark.parametrize('yaw', [0.0, 0.3, math.pi / 2, 2.5, -1.0, math.pi])
def test_body_to_world_is_the_rotation_by_the_heading(yaw):
    simulation = one_agent(**{'agent.max_accel': 1e6, 'agent.max_speed': 10.0})
    simulation.set_state('ball_0', 0.0, 0.0, 0.0, 0.0, yaw=yaw)
    simulation.command('ball_0', 1.0, 0.5, 0.0)
    simulation.step()
    vx, vy = simulation.world.velocities[0].tolist()
    assert vx == pytest.approx(math.cos(yaw) - 0.5 * math.sin(yaw), abs=1e-15)
    assert vy == pytest.approx(math.sin(yaw) + 0.5 * math.cos(yaw), abs=1e-15)
    assert world_to_body(yaw, vx, vy) == pytest.approx((1.0, 0.5), abs=1e-15)
    assert body_to_world(yaw, 1.0, 0.0) == (math.cos(yaw), math.sin(yaw))


def test_agents_are_found_by_name_across_deletions_and_spawns():
    parameters = {'rate_hz': 64.0, 'arena': [], 'random.count': 0,
                  'balls.x': [0.0, 5.0, 10.0], 'balls.y': [0.0, 0.0, 0.0],
                  'balls.vx': [0.0] * 3, 'balls.vy': [0.0] * 3, 'balls.radius': [0.5] * 3,
                  'balls.mass': [1.0] * 3, 'agents': ['ball_2'], 'physics.backend': 'numpy',
                  'agent.max_accel': 1e6}
    simulation = Simulation(parameters)
    simulation.delete('ball_0')
    [name], _ = simulation.spawn([SpawnRequest('rover', False, Ball(0.0, 5.0, 0.0, 0.0, 0.5,
                                                                    1.0), agent=True)])
    assert name == 'rover'
    assert simulation.pending_edits[-1].text.endswith('"agent": true}')
    simulation.command('ball_2', 0.0, 1.0, 0.0)
    simulation.command('rover', -1.0, 0.0, 0.0)
    record, _ = simulation.step()
    assert record.agents.names == ('ball_2', 'rover')
    assert record.agents.indices.tolist() == [1, 2]
    assert simulation.world.velocities.tolist() == [[0.0, 0.0], [0.0, 1.0], [-1.0, 0.0]]
    simulation.delete('ball_2')
    record, _ = simulation.step()
    assert record.agents.names == ('rover',)
    with pytest.raises(CommandRejected):
        simulation.command('ball_2', 1.0, 0.0, 0.0)


@pytest.mark.parametrize('agents, words', [
    (['ball_3'], "no ball named 'ball_3' to make an agent; the world starts with ball_0 to "
                 'ball_2'),
    (['rover'], "no ball named 'rover'"),
    (['ball_1', 'ball_1'], "'ball_1' is listed twice"),
    (['ball_01'], "no ball named 'ball_01'"),
])
def test_unknown_agent_names_are_refused_with_one_line(agents, words):
    with pytest.raises(ScenarioError) as refused:
        build({'random.count': 3, 'agents': agents})
    assert str(refused.value) == f"parameter 'agents': {words}" or words in str(refused.value)
    assert str(refused.value).startswith("parameter 'agents': ")
    assert '\n' not in str(refused.value)


@pytest.mark.parametrize('command, reason', [
    ((math.nan, 0.0, 0.0), 'non_finite'),
    ((0.0, math.inf, 0.0), 'non_finite'),
    ((0.0, 0.0, -math.inf), 'non_finite'),
    ((1e308, 0.0, 0.0), 'too_large'),
    ((0.0, 0.0, 2e6), 'too_large'),
])
def test_bad_commands_are_refused_and_counted(command, reason):
    simulation = one_agent()
    simulation.command('ball_0', 1.0, 0.0, 0.0)
    with pytest.raises(CommandRejected) as refused:
        simulation.command('ball_0', *command)
    assert refused.value.reason == reason
    assert simulation.rejected == {f'cmd_vel_{reason}': 1}
    record, _ = simulation.step()
    assert [c.vx for c in record.commands] == [1.0]  # the good one stands
    with pytest.raises(CommandRejected):
        check_command('ball_0', *command)


def test_set_state_sets_an_agent_heading_and_refuses_one_for_a_ball():
    simulation = Simulation({'random.count': 2, 'agents': ['ball_1'],
                             'physics.backend': 'numpy'})
    x, y = simulation.world.positions[1].tolist()
    simulation.set_state('ball_1', x, y, 0.0, 0.0, yaw=1.25)
    assert '"yaw": 1.25' in simulation.pending_edits[-1].text
    assert simulation.agents.yaw('ball_1') == 1.25
    x, y = simulation.world.positions[0].tolist()
    with pytest.raises(EditRefused):
        simulation.set_state('ball_0', x, y, 0.0, 0.0, yaw=0.5)
    simulation.set_state('ball_0', x, y, 0.0, 0.0, yaw=0.0)
    assert 'yaw' not in simulation.pending_edits[-1].text


def test_a_world_without_agents_records_as_before():
    simulation = Simulation({'random.count': 20, 'physics.backend': 'numpy'})
    plain = Simulation({'random.count': 20, 'physics.backend': 'numpy'})
    for _ in range(30):
        record, _ = simulation.step()
        assert record.agents is None and record.commands == () and record.impulses == ()
        other, _ = plain.step()
        assert record.balls_cdr == other.balls_cdr


def test_commands_replayed_at_their_steps_give_the_same_run_bit_for_bit():
    parameters = {'random.count': 30, 'agents': ['ball_0', 'ball_7'], 'random.seed': 3,
                  'physics.backend': 'numpy'}
    live = Simulation(parameters)
    script = {3: [('ball_0', 1.5, 0.2, 1.0)], 40: [('ball_7', -2.0, 0.0, -0.5)],
              41: [('ball_0', 0.0, 0.0, 0.0), ('ball_0', 0.5, 0.5, 3.0)]}
    recorded = []
    for k in range(1, 120):
        for command in script.get(k, []):
            live.command(*command)
        recorded.append(live.step()[0])
    again = Simulation(parameters)
    for record in recorded:
        for command in record.commands:
            again.command(command.name, command.vx, command.vy, command.wz)
        count, _ = again.apply_drive()
        replayed, _ = again.step()
        assert [i.cdr for i in replayed.impulses] == [i.cdr for i in record.impulses]
        assert count == len(record.impulses)
        assert replayed.balls_cdr == record.balls_cdr
        assert replayed.state_cdr == record.state_cdr
        assert replayed.agents.yaws.tobytes() == record.agents.yaws.tobytes()


def test_agents_alone_follow_limits_and_report_names():
    agents = Agents(['a', 'b'], Limits(max_speed=1.0, max_accel=2.0, max_yaw_rate=1.0,
                                       cmd_timeout=0.0))
    assert agents.names == ('a', 'b') and len(agents) == 2 and 'a' in agents
    agents.command('b', 1.0, 0.0, 0.0, since_ns=10)
    velocities = np.zeros((2, 2))
    masses = np.array([1.0, 2.0])
    assert agents.impulses(velocities, masses, {'a': 0, 'b': 1}, 10**9 // 4, 5) == []
    [(name, jx, jy)] = agents.impulses(velocities, masses, {'a': 0, 'b': 1}, 10**9 // 4, 10)
    assert (name, jx, jy) == ('b', 2.0 * 0.5, 0.0)


def test_resource_string_says_agent_true_and_nothing_else_goes():
    from ball_world.core.edits import parse_resource, parse_spawn
    assert parse_spawn('{radius: 0.3, agent: true}')[3] is True
    assert parse_spawn('{radius: 0.3}')[3] is False
    assert parse_resource('{radius: 0.3, agent: true}')[0] == 0.3
    with pytest.raises(EditRefused, match='agent must be true or false'):
        parse_spawn('{agent: 1}')


@pytest.mark.parametrize('z, w, yaw', [
    (0.0, 1.0, 0.0), (math.sin(0.4), math.cos(0.4), 0.8), (1.0, 0.0, math.pi),
    (-math.sin(1.0), math.cos(1.0), -2.0), (0.0, -1.0, 0.0)])
def test_a_pose_rotated_about_z_gives_the_heading(z, w, yaw):
    from geometry_msgs.msg import Pose
    from ball_world.ros.sim_interfaces import planar_pose
    pose = Pose()
    pose.position.x, pose.position.y = 1.0, 2.0
    pose.orientation.z, pose.orientation.w = z, w
    x, y, got = planar_pose(pose, '', 'world')
    assert (x, y) == (1.0, 2.0)
    assert math.cos(got) == pytest.approx(math.cos(yaw), abs=1e-12)
    assert math.sin(got) == pytest.approx(math.sin(yaw), abs=1e-12)


@pytest.mark.parametrize('q, words', [
    ((0.1, 0.0, 0.0, 0.995), 'is a rotation'), ((0.0, 0.0, 0.5, 0.5), 'not a unit'),
    ((0.0, 0.0, math.nan, 1.0), 'not finite')])
def test_a_pose_rotated_otherwise_is_refused_as_invalid_pose(q, words):
    from geometry_msgs.msg import Pose
    from ball_world.core.edits import INVALID_POSE
    from ball_world.ros.sim_interfaces import planar_pose
    pose = Pose()
    (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w) = q
    with pytest.raises(EditRefused, match=words) as refused:
        planar_pose(pose, '', 'world')
    assert refused.value.kind == INVALID_POSE


def test_odom_and_tf_bytes_carry_the_step_bit_for_bit_and_the_body_twist():
    from ball_world.msgs.agent_cdr import decode_odometry, decode_tf_message
    simulation = one_agent(**{'agent.cmd_timeout': 0.0, 'frame_prefix': 'w1/'})
    first = simulation.last_record.agents
    static = decode_tf_message(first.tf_static_cdr)
    assert static.frame_ids == ['world'] and static.child_frame_ids == ['w1/ball_0/odom']
    assert static.transforms.tolist() == [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]]
    simulation.command('ball_0', 1.0, 0.0, 0.5)
    for _ in range(100):
        record, _ = simulation.step()
        assert record.agents.tf_static_cdr is None
    odom = decode_odometry(record.agents.odom_cdr[0])
    assert (odom.frame_id, odom.child_frame_id) == ('w1/ball_0/odom', 'w1/ball_0/base_link')
    assert odom.stamp_ns == record.stamp_ns
    assert odom.pose[:2].tobytes() == record.positions[0].tobytes()
    yaw = float(record.agents.yaws[0])
    half = [math.sin(yaw / 2), math.cos(yaw / 2)]
    assert odom.pose[5:7].tolist() == pytest.approx(half, abs=1e-15)
    # Turning at 0.5 rad/s at 1 m/s: in the body frame the agent goes straight ahead.
    assert odom.twist.tolist() == pytest.approx([1.0, 0.0, 0.0, 0.0, 0.0, 0.5], abs=1e-12)
    tf = decode_tf_message(record.agents.tf_cdr)
    assert tf.child_frame_ids == ['w1/ball_0/base_link']
    assert tf.transforms[0, :2].tobytes() == record.positions[0].tobytes()


def test_tf_static_follows_a_new_frame_id():
    from ball_world.msgs.agent_cdr import decode_tf_message
    simulation = one_agent()
    simulation.step()
    simulation.frame_id = 'map'
    record, _ = simulation.step()
    assert decode_tf_message(record.agents.tf_static_cdr).frame_ids == ['map']
    record, _ = simulation.step()
    assert record.agents.tf_static_cdr is None


def test_the_drive_applied_at_once_is_bit_for_bit_the_drive_one_by_one(monkeypatch):
    parameters = {'random.count': 60, 'random.seed': 11, 'physics.backend': 'numpy',
                  'agents': [f'ball_{i}' for i in range(0, 60, 3)], 'agent.cmd_timeout': 0.0}
    batched = Simulation(parameters)
    single = Simulation(parameters)
    monkeypatch.setattr(single, '_apply_at_once', lambda *drive: False)
    for simulation in (batched, single):
        for k, name in enumerate(simulation.agents.names):
            simulation.command(name, 0.1 * k - 1.0, 0.05 * k, 0.3 * (k % 5) - 0.6)
    for _ in range(40):
        one, _ = batched.step()
        other, _ = single.step()
        assert len(one.impulses) > 1
        assert [(i.ball, i.jx, i.jy, i.cdr) for i in one.impulses] == [
            (i.ball, i.jx, i.jy, i.cdr) for i in other.impulses]
        assert one.state_cdr == other.state_cdr


def test_impulses_encoded_together_are_the_bytes_of_one_at_a_time():
    from ball_world.msgs.cdr import encode_vector3_stamped
    from ball_world.msgs.impulse_batch import encode_impulses
    names = ['b', 'ball_12', 'rover_with_a_long_name', 'x1234567']
    xs, ys = [1.5, -2e-300, 0.0, 7.0], [math.pi, 1e300, -0.0, 2.0]
    for stamp in (0, 16_666_667, -1_700_000_000, 2**31 * 10**9 - 1):
        assert encode_impulses(stamp, names, xs, ys) == [
            encode_vector3_stamped(stamp, n, x, y, 0.0) for n, x, y in zip(names, xs, ys)]


def test_commands_given_in_code_are_recorded_as_their_messages():
    from geometry_msgs.msg import Twist, TwistStamped
    from rclpy.serialization import deserialize_message
    for stamped in (False, True):
        simulation = one_agent(**{'agent.cmd_vel_stamped': stamped})
        simulation.command('ball_0', 0.5, -0.25, 1.5)
        record, _ = simulation.step()
        message = deserialize_message(record.commands[0].cdr,
                                      TwistStamped if stamped else Twist)
        twist = message.twist if stamped else message
        assert (twist.linear.x, twist.linear.y, twist.angular.z) == (0.5, -0.25, 1.5)
        if stamped:
            assert message.header.stamp.nanosec == simulation.dt_ns
