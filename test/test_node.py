"""The node in-process: topics, stamps, impulses, services, parameters, determinism."""
from ball_world_testing.harness import InProcessWorld
from geometry_msgs.msg import Vector3Stamped
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ball_world.core import parameters as table
from ball_world.core.limits import MAX_SIM_TIME_NS
from ball_world.ros.node import BallWorld, StartupError
from ball_world.ros.parameters import descriptor

ONE_BALL = {'random.count': 0, 'balls.x': [5.0], 'balls.y': [5.0], 'balls.vx': [0.5],
            'balls.vy': [0.0], 'balls.radius': [0.5], 'balls.mass': [0.5]}


@pytest.fixture
def harness_factory():
    made = []

    def make(**parameters):
        parameters.setdefault('markers.rate_hz', 0.0)
        made.append(InProcessWorld(**parameters))
        return made[-1]

    yield make
    for harness in made:
        harness.close()


def state_rows(msg):
    return np.array(msg.data).reshape(-1, 4)


def test_balls_and_state_stamps_advance_by_exactly_dt(harness_factory):
    h = harness_factory(rate_hz=200.0, dt=0.01, **{'random.count': 30})
    h.spin_until(lambda: len(h.balls) >= 20 and len(h.states) >= 20)
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in h.balls]
    assert np.all(np.diff(stamps) == 10_000_000)
    assert all(m.header.frame_id == 'world' for m in h.balls)
    last = h.balls[-1]
    assert len(last.poses) == 30
    assert all(p.position.z == 0.0 and p.orientation.w == 1.0 for p in last.poses)
    # The published poses of a step are the state rows of the same step.
    for pose_msg, state_msg in zip(h.balls, h.states):
        rows = state_rows(state_msg)
        assert [[p.position.x, p.position.y] for p in pose_msg.poses] == rows[:, :2].tolist()
    dims = h.states[-1].layout.dim
    assert [(d.label, d.size, d.stride) for d in dims] == [('ball', 30, 120),
                                                           ('x_y_vx_vy', 4, 4)]


def test_impulse_changes_velocity_by_j_over_m_at_the_next_step(harness_factory):
    h = harness_factory(**ONE_BALL)
    assert h.call(SetBool, 'pause', SetBool.Request(data=True)).success
    h.impulse('ball_0', 1.0, -0.5)
    h.spin_until(lambda: h.node.simulation.queued == 1)
    h.states.clear()
    assert h.call(Trigger, 'step', Trigger.Request()).success
    h.spin_until(lambda: h.states)
    assert state_rows(h.states[-1])[0, 2:].tolist() == [0.5 + 1.0 / 0.5, -0.5 / 0.5]


@pytest.mark.parametrize('frame_id, vector, reason', [
    ('ball_7', (1.0, 0.0, 0.0), 'unknown_ball'),
    ('', (1.0, 0.0, 0.0), 'empty_frame_id'),
    ('ball_x', (1.0, 0.0, 0.0), 'unknown_ball'),
    ('ball_01', (1.0, 0.0, 0.0), 'unknown_ball'),
    ('ball_' + '1' * 5000, (1.0, 0.0, 0.0), 'unknown_ball'),  # once int() raised past 4,300
    ('ball_' + '9' * 19, (1.0, 0.0, 0.0), 'unknown_ball'),
    ('ball_0\n', (1.0, 0.0, 0.0), 'unknown_ball'),
    ('x' * 300_000, (1.0, 0.0, 0.0), 'unknown_ball'),
    ('ball_0', (float('nan'), 0.0, 0.0), 'non_finite'),
    ('ball_0', (0.0, float('inf'), 0.0), 'non_finite'),
    ('ball_0', (1.0, 0.0, 0.1), 'nonzero_z'),
    ('ball_0', (1e308, 1e308, 0.0), 'overflow'),
    ('ball_0', (1e9, 0.0, 0.0), 'too_fast'),
])
def test_bad_impulses_are_rejected_counted_and_never_applied(harness_factory, frame_id,
                                                             vector, reason):
    h = harness_factory(**ONE_BALL)
    h.call(SetBool, 'pause', SetBool.Request(data=True))
    before = h.node.simulation.world.velocities.copy()
    h.impulse(frame_id, *vector)
    h.spin_until(lambda: h.node.simulation.rejected.get(reason, 0) == 1
                 or h.node.simulation.queued)
    h.call(Trigger, 'step', Trigger.Request())
    assert h.node.simulation.rejected == {reason: 1}
    assert h.node.simulation.world.velocities.tolist() == before.tolist()
    # The node keeps stepping after a rejection.
    h.call(SetBool, 'pause', SetBool.Request(data=False))
    step = h.node.simulation.step_index
    h.spin_until(lambda: h.node.simulation.step_index > step + 3)


def test_pause_step_and_reset_do_what_they_say(harness_factory):
    h = harness_factory(rate_hz=100.0)
    response = h.call(SetBool, 'pause', SetBool.Request(data=True))
    assert response.success and 'paused' in response.message
    again = h.call(SetBool, 'pause', SetBool.Request(data=True))
    assert again.success and 'already paused' in again.message
    step = h.node.simulation.step_index
    for _ in range(5):
        h.executor.spin_once(timeout_sec=0.02)
    assert h.node.simulation.step_index == step  # paused: the timer steps nothing
    assert h.call(Trigger, 'step', Trigger.Request()).success
    assert h.node.simulation.step_index == step + 1
    h.call(SetBool, 'pause', SetBool.Request(data=False))
    refused = h.call(Trigger, 'step', Trigger.Request())
    assert not refused.success and 'not paused' in refused.message
    h.spin_until(lambda: h.node.simulation.step_index > step + 5)
    h.call(SetBool, 'pause', SetBool.Request(data=True))
    h.node.set_parameters([Parameter('random.count', value=5)])
    assert h.call(Trigger, 'reset', Trigger.Request()).success
    assert h.node.simulation.step_index == 0
    assert len(h.node.simulation.world) == 5
    five = h.node.simulation.world.positions.tolist()
    h.node.set_parameters([Parameter('random.count', value=20)])
    assert h.call(Trigger, 'reset', Trigger.Request()).success
    # Random balls are drawn in order, so the first five are those of the 5-ball world.
    assert h.node.simulation.world.positions[:5].tolist() == five


def test_invalid_parameter_values_are_refused_and_kept(harness_factory):
    h = harness_factory()
    result = h.node.set_parameters([Parameter('random.radius', value=[0.5, 0.1])])[0]
    assert not result.successful and 'random.radius' in result.reason
    assert list(h.node.get_parameter('random.radius').value) == [0.1, 0.3]
    result = h.node.set_parameters([Parameter('record.mcap', value='x.mcap')])[0]
    assert not result.successful
    assert h.node.get_parameter('record.mcap').value == ''
    result = h.node.set_parameters([Parameter('rate_hz', value=-1.0)])[0]
    assert not result.successful


def test_rate_change_takes_effect_at_once(harness_factory):
    h = harness_factory(rate_hz=10.0)
    assert h.node.set_parameters([Parameter('rate_hz', value=250.0)])[0].successful
    assert h.node._timer.timer_period_ns == 4_000_000


def test_markers_hold_a_sphere_per_ball_and_the_walls(harness_factory):
    h = harness_factory(**{'markers.rate_hz': 20.0, 'random.count': 7})
    got = []
    # Transient local: a late subscriber still gets the last array.
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    h.probe.node.create_subscription(MarkerArray, 'markers', got.append, qos)
    h.spin_until(lambda: got)
    markers = [m for msg in got for m in msg.markers if m.ns == 'balls']
    spheres = {m.id: m for m in markers}
    assert sorted(spheres) == list(range(7))
    radii = h.node.simulation.world.radii
    assert [spheres[i].scale.x for i in range(7)] == (2 * radii).tolist()
    walls = [m for msg in got for m in msg.markers if m.ns == 'walls']
    assert len(walls[-1].points) == 8


def test_bad_world_parameters_stop_the_node_with_the_name():
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(StartupError, match='balls.radius'):
            BallWorld(context=context, parameter_overrides=[
                Parameter(name, value=value) for name, value in
                {**ONE_BALL, 'balls.radius': [-1.0]}.items()])
    finally:
        rclpy.try_shutdown(context=context)


def test_same_parameters_and_impulses_give_bit_identical_poses(harness_factory):
    runs = []
    for _ in range(2):
        h = harness_factory(**{'random.count': 40, 'random.seed': 7})
        h.call(SetBool, 'pause', SetBool.Request(data=True))
        h.call(Trigger, 'reset', Trigger.Request())
        for k in range(60):
            if k in (5, 30):
                h.impulse(f'ball_{k % 40}', 0.3, -0.2)
                h.spin_until(lambda: h.node.simulation.queued == 1)
            h.call(Trigger, 'step', Trigger.Request())
        runs.append(h.node.simulation.world.positions.tobytes())
    assert runs[0] == runs[1]


def test_garbage_bytes_and_stale_stamps_are_rejected_and_stepping_goes_on(harness_factory):
    h = harness_factory(**ONE_BALL)
    h.call(SetBool, 'pause', SetBool.Request(data=True))
    before = h.node.simulation.world.velocities.copy()
    step = h.node.simulation.step_index
    h.spin_until(lambda: h.impulses.get_subscription_count() > 0)
    for garbage in (b'', b'\x00\x01\x00\x00', b'\x00\x01\x00\x00' + b'\xff' * 40,
                    bytes(range(256))):
        h.impulses.publish(garbage)  # a raw publisher: bytes that are not a Vector3Stamped
    stale = Vector3Stamped()
    stale.header.frame_id = 'ball_0'
    stale.header.stamp.sec = 7 * 24 * 3600  # a week of simulated time ahead, and 1970
    stale.vector.x = 1.0
    h.impulses.publish(stale)
    rejected = h.node.simulation.rejected
    h.spin_until(lambda: sum(rejected.values()) == 5)
    assert rejected == {'malformed_message': 4, 'stamp_out_of_range': 1}
    assert h.call(Trigger, 'step', Trigger.Request()).success
    assert h.node.simulation.step_index == step + 1
    # Only the step itself moved the ball: its velocity is untouched.
    assert h.node.simulation.world.velocities.tolist() == before.tolist()


def test_reset_discards_queued_impulses_and_says_how_many(harness_factory):
    h = harness_factory(**ONE_BALL)
    h.call(SetBool, 'pause', SetBool.Request(data=True))
    for _ in range(100):
        h.impulse('ball_0', 0.01, 0.0)
    h.spin_until(lambda: h.node.simulation.queued == 100)
    response = h.call(Trigger, 'reset', Trigger.Request())
    assert response.success
    assert response.message.endswith('discarded 100 queued impulses')
    assert h.node.simulation.discarded == 100 and h.node.simulation.applied == 0
    assert h.node.simulation.queued == 0
    assert h.node.simulation.world.velocities.tolist() == [[0.5, 0.0]]


def test_world_parameters_can_be_set_one_by_one_and_are_checked_at_reset(harness_factory):
    h = harness_factory(**{'random.count': 0})
    h.call(SetBool, 'pause', SetBool.Request(data=True))
    for name, value in (('balls.x', [2.0, 4.0]), ('balls.y', [5.0, 5.0])):
        assert h.node.set_parameters([Parameter(name, value=value)])[0].successful
    refused = h.call(Trigger, 'reset', Trigger.Request())
    assert not refused.success and "'balls.vx': has 0 entries but balls.x has 2" in \
        refused.message and 'world unchanged' in refused.message
    assert len(h.node.simulation.world) == 0
    for name, value in (('balls.vx', [1.0, -1.0]), ('balls.vy', [0.0, 0.0]),
                        ('balls.radius', [0.5, 0.5]), ('balls.mass', [1, 2])):
        assert h.node.set_parameters([Parameter(name, value=value)])[0].successful, name
    assert h.call(Trigger, 'reset', Trigger.Request()).success
    assert h.node.simulation.world.masses.tolist() == [1.0, 2.0]


def test_every_parameter_reads_back_typed_and_integers_convert(harness_factory):
    h = harness_factory()
    client = AsyncParameterClient(h.probe.node, 'ball_world')
    h.spin_until(client.services_are_ready)
    names = [parameter.name for parameter in table.PARAMETERS]
    future = client.get_parameters(names)
    h.spin_until(future.done)
    values = future.result().values
    assert [v.type for v in values] == [descriptor(p).type for p in table.PARAMETERS]
    assert list(values[names.index('walls')].double_array_value) == []
    future = client.set_parameters([Parameter('markers.rate_hz', value=2),
                                    Parameter('arena', value=[0, 0, 20, 20])])
    h.spin_until(future.done)
    assert all(result.successful for result in future.result().results)
    assert h.node.get_parameter('markers.rate_hz').value == 2.0
    assert list(h.node.get_parameter('arena').value) == [0.0, 0.0, 20.0, 20.0]


def test_rates_across_the_whole_range_keep_the_node_answering(harness_factory):
    h = harness_factory(dt=0.01, **ONE_BALL)
    for rate in (1e-300, 1e-10, 0.5, 1e6, 0.0):
        assert h.node.set_parameters([Parameter('rate_hz', value=rate)])[0].successful, rate
        h.spin_until(lambda: h.call(SetBool, 'pause',
                                    SetBool.Request(data=False)).success)
    step = h.node.simulation.step_index
    h.spin_until(lambda: h.node.simulation.step_index > step + 50)  # rate 0: full speed
    assert h.node.set_parameters([Parameter('rate_hz', value=1e-300)])[0].successful
    step = h.node.simulation.step_index
    for _ in range(20):
        h.executor.spin_once(timeout_sec=0.01)
    assert h.node.simulation.step_index <= step + 1


def test_the_run_stops_before_ros_time_runs_out(harness_factory):
    h = harness_factory(dt=3600.0, rate_hz=0.0, **{**ONE_BALL, 'balls.vx': [0.0]})
    simulation = h.node.simulation
    last = MAX_SIM_TIME_NS // simulation.dt_ns
    simulation.step_index = last - 2  # as if the run had gone on for 68 years
    h.spin_until(lambda: h.node.finished)
    assert simulation.step_index == last
    assert simulation.stamp_ns // 10**9 < 2**31


def test_start_paused_holds_step_zero_until_resumed(harness_factory):
    h = harness_factory(start_paused=True, rate_hz=100.0)
    for _ in range(10):
        h.executor.spin_once(timeout_sec=0.02)
    assert h.node.simulation.step_index == 0
    h.call(SetBool, 'pause', SetBool.Request(data=False))
    h.spin_until(lambda: h.node.simulation.step_index > 2)


def test_a_large_reset_builds_while_the_old_world_keeps_publishing(harness_factory):
    h = harness_factory(rate_hz=100.0, **{'random.count': 5})
    # Large enough that its build spans many 10 ms steps; 60,000 balls (3.4 MB a step to
    # publish and hear) took minutes on a loaded machine and told nothing more
    h.node.set_parameters([Parameter('random.count', value=20_000),
                           Parameter('arena', value=[0.0, 0.0, 300.0, 300.0])])
    client = h.probe.node.create_client(Trigger, '/ball_world/reset')
    h.spin_until(client.service_is_ready)
    steps_while_building = []
    step_once = h.node.step_once

    def watched_step():
        steps_while_building.append(h.node._resetting)
        return step_once()

    h.node.step_once = watched_step
    future = client.call_async(Trigger.Request())
    h.spin_until(future.done, timeout=120.0)
    assert future.result().success, future.result().message
    assert any(steps_while_building), 'the old world stopped while the new one was built'
    h.spin_until(lambda: len(h.balls[-1].poses) == 20_000)
