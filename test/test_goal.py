"""ball_world_goal with the world, both as processes: the ball reaches its goal, stays there,
is knocked away by another ball and comes back; and its command line.

The claims come from the closed loop, not from runs of this test: with the true mass, kp = kd
= 4 is critically damped (2 rad/s), so from 6.4 m away the ball is within 2 cm after about
4 s and approaches without overshoot; a 0.1 kg ball at 3 m/s hitting the 0.5 kg ball head on
gives it 1 m/s, which such a loop turns into an excursion of 1 / (2 e) = 0.18 m. A model of
the loop on the World itself (impulses every 3 steps of 1/60 s, applied one step late)
reaches 2 cm at 4.2 s, stays within 2 cm, is knocked 0.17 m and is back within 2 cm 3.6 s
later. Both processes run on simulated time (publish_clock / use_sim_time), so the machine's
load cannot change these figures; the limits below leave about a factor of two. Times count
from the first step the ball moves (its first push): the controller may take any time to
find the world.
"""
import math
import signal
import time

from ball_world_testing.harness import executable, finish, Probe, RECEIVE_QOS, run_tool
from geometry_msgs.msg import PoseArray, Vector3Stamped
import numpy as np
import pytest
from simulation_interfaces.msg import Result
from simulation_interfaces.srv import DeleteEntity
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ball_world.tools.goal import REPORT_SECONDS


GOAL = (6.0, 7.0)
MASS, KICKER_MASS, KICK_SPEED = 0.5, 0.1, 3.0
WORLD = ['-p', 'publish_clock:=true', '-p', 'markers.rate_hz:=0.0', '-p', 'random.count:=0',
         '-p', 'balls.x:=[2.0, 8.0]', '-p', 'balls.y:=[2.0, 3.0]',
         '-p', 'balls.vx:=[0.0, 0.0]', '-p', 'balls.vy:=[0.0, 0.0]',
         '-p', 'balls.radius:=[0.3, 0.2]', '-p', f'balls.mass:=[{MASS}, {KICKER_MASS}]']
CONTROLLER = ['-p', f'goal:=[{GOAL[0]}, {GOAL[1]}]', '-p', f'mass:={MASS}',
              '-p', 'use_sim_time:=true']
REACH_S = 8.0          # simulated seconds from the first push to within TOLERANCE
TOLERANCE = 0.02       # m
HOLD_S = 3.0           # simulated seconds it must then stay within HOLD_TOLERANCE
HOLD_TOLERANCE = 0.05  # m
BUMP = 0.1             # m the kick must move it at least (it did get hit)
RETURN_S = 8.0         # simulated seconds from the kick back to within TOLERANCE
DEADLINE = 90.0        # wall seconds for any phase: a liveness limit only


class Watch(Probe):
    """Sees the world's poses with their simulated time, and kicks the other ball."""

    def __init__(self):
        super().__init__('goal_probe', timeout=DEADLINE)
        self.times, self.positions = [], []
        self.node.create_subscription(PoseArray, 'balls', self._on_balls, RECEIVE_QOS)
        self.kicks = self.node.create_publisher(Vector3Stamped, 'impulse', RECEIVE_QOS)

    def _on_balls(self, msg):
        self.times.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
        self.positions.append([(p.position.x, p.position.y) for p in msg.poses])

    def distance(self, index=-1):
        return math.dist(self.positions[index][0], GOAL)

    def since_moved(self, row, start):
        """Simulated seconds since the ball in `row` first left `start` (0 until it has)."""
        moved = next((t for t, p in zip(self.times, self.positions) if p[row] != start), None)
        return 0.0 if moved is None else self.times[-1] - moved

    def kick_ball_1_at_ball_0(self):
        self.spin_until(lambda: self.kicks.get_subscription_count() > 0, 'the world')
        ball_0, ball_1 = np.array(self.positions[-1])
        direction = (ball_0 - ball_1) / np.linalg.norm(ball_0 - ball_1)
        msg = Vector3Stamped()
        msg.header.frame_id = 'ball_1'
        msg.vector.x, msg.vector.y = KICKER_MASS * KICK_SPEED * direction
        self.kicks.publish(msg)
        return self.times[-1]


@pytest.fixture
def watch():
    watcher = Watch()
    yield watcher
    watcher.close()


@pytest.fixture
def start(processes):
    """Starts executables with ROS arguments; stops them all at the end, checks they exit 0."""

    def run(name, *args):
        processes.start([executable(name), '--ros-args', *args])

    yield run
    for process in processes.started:
        process.send_signal(signal.SIGINT)
    ends = [finish(process) for process in processes.started]
    for code, _, err in ends:
        assert code == 0 and 'Traceback' not in err, err


def test_goal_reaches_holds_and_recovers_from_a_bump(watch, start):
    start('ball_world_goal', *CONTROLLER)
    start('ball_world', *WORLD)  # started second: the control starts at t = 0
    watch.spin_until(lambda: watch.positions and (
        watch.distance() < TOLERANCE or watch.since_moved(0, (2.0, 2.0)) > REACH_S), 'the goal')
    reached = watch.times[-1]
    assert watch.distance() < TOLERANCE, (
        f'{watch.distance():.3f} m from the goal after {reached:.2f} s')

    watch.spin_until(lambda: watch.times[-1] >= reached + HOLD_S, 'the hold')
    held = [watch.distance(i) for i, t in enumerate(watch.times) if t >= reached]
    assert max(held) < HOLD_TOLERANCE

    kicked = watch.kick_ball_1_at_ball_0()
    first = len(watch.times)

    def excursion():
        return max((watch.distance(i) for i in range(first, len(watch.times))), default=0)

    watch.spin_until(lambda: watch.times[-1] > kicked + RETURN_S or (
        excursion() > BUMP and watch.distance() < TOLERANCE), 'the return')
    assert excursion() > BUMP, 'the kicked ball never hit the held one'
    assert watch.distance() < TOLERANCE, (
        f'{watch.distance():.3f} m from the goal {watch.times[-1] - kicked:.2f} s after '
        f'the kick (excursion {excursion():.2f} m)')
    print(f'reached {TOLERANCE} m at t = {reached:.2f} s, held within {max(held):.4f} m, '
          f'knocked {excursion():.3f} m away, back {watch.times[-1] - kicked:.2f} s after '
          'the kick')


def run_goal(*args):
    return run_tool('ball_world_goal', *args)


def test_help_prints_usage_and_parameters():
    code, out, err = run_goal('--help')
    assert code == 0, err
    assert out.startswith('usage: ball_world_goal')
    for name in ('ball', 'goal', 'kp', 'kd', 'max_impulse', 'rate_hz', 'mass', 'use_sim_time'):
        assert f'\n  {name} ' in out


@pytest.mark.parametrize('args, problem', [
    (('--ros-args', '-p', 'kp:=-1.0'),
     "parameter 'kp': expected a number >= 0 and <= 1e+06, got -1.0"),
    (('--ros-args', '-p', 'kp:=1e308'),
     "parameter 'kp': expected a number >= 0 and <= 1e+06, got 1e+308"),
    (('--ros-args', '-p', 'kd:=inf'), "parameter 'kd': expected a number >= 0 and <= 1e+06"),
    (('--ros-args', '-p', 'rate_hz:=1e-300'),
     "parameter 'rate_hz': expected a number >= 0.001 and <= 1000, got 1e-300"),
    (('--ros-args', '-p', 'rate_hz:=1e300'), "parameter 'rate_hz': expected a number >= 0.001"),
    (('--ros-args', '-p', 'goal:=[1.0]'), "parameter 'goal': expected two numbers [x, y]"),
    (('--ros-args', '-p', 'mass:=0'), "parameter 'mass': expected a number > 0, got 0"),
    (('--ros-args', '-p', 'rate_hz:=fast'), "parameter 'rate_hz'"),
    (('--ros-args', '-p', 'ball:=3'), "parameter 'ball': expected a ball name"),
    (('--ros-args', '-p', 'max_impulse:=nan'), "parameter 'max_impulse'"),
    (('--ros-args', '-p'), 'bad ROS arguments'),
    (('--goal', '1', '2'), 'unrecognized arguments: --goal 1 2'),
])
def test_bad_start_is_one_line_and_exit_2(args, problem):
    code, out, err = run_goal(*args)
    assert code == 2
    assert problem in err and len(err.strip().splitlines()) == 1, err


# Balls that come and go ---------------------------------------------------------------------

THREE = ['-p', 'publish_clock:=true', '-p', 'markers.rate_hz:=0.0', '-p', 'random.count:=0',
         '-p', 'balls.x:=[2.0, 2.0, 8.0]', '-p', 'balls.y:=[2.0, 8.0, 3.0]',
         '-p', 'balls.vx:=[0.0, 0.0, 0.0]', '-p', 'balls.vy:=[0.0, 0.0, 0.0]',
         '-p', 'balls.radius:=[0.3, 0.3, 0.2]', '-p', f'balls.mass:=[0.3, {MASS}, 0.1]']


def test_goal_follows_its_ball_by_name_when_rows_move_and_holds_while_it_is_gone(
        watch, processes):
    """ball_1 is held; deleting ball_0 moves ball_1 to row 0 and ball_2 (at rest far away)
    to row 1. A controller taking row 1 as ball_1 would push ball_1 by ball_2's state and
    throw it off its goal; one that reads entity_names keeps it there. Deleting ball_1 then
    stops its pushes (one warning) instead of pushing a ball that is gone, until a reset
    brings it back."""
    controller = processes.start([executable('ball_world_goal'), '--ros-args', *CONTROLLER,
                                  '-p', 'ball:=ball_1'])
    started = time.monotonic()
    world = processes.start([executable('ball_world'), '--ros-args', *THREE])
    pushes = []  # (the world's time when it arrived, the ball pushed)
    watch.node.create_subscription(
        Vector3Stamped, 'impulse', lambda msg: pushes.append(
            (watch.times[-1] if watch.times else 0.0, msg.header.frame_id)), RECEIVE_QOS)

    def distance_of(index):
        return math.dist(watch.positions[-1][index], GOAL)

    watch.spin_until(lambda: watch.positions and (
        distance_of(1) < TOLERANCE or watch.since_moved(1, (2.0, 8.0)) > REACH_S), 'the goal',
        process=world)
    assert distance_of(1) < TOLERANCE

    deleted = watch.call(DeleteEntity, '/ball_world/delete_entity',
                         DeleteEntity.Request(entity='ball_0'))
    assert deleted.result.result == Result.RESULT_OK, deleted.result.error_message
    watch.spin_until(lambda: len(watch.positions[-1]) == 2, 'the deletion', process=world)
    since = watch.times[-1]
    first = len(watch.times)
    watch.spin_until(lambda: watch.times[-1] >= since + HOLD_S, 'the hold', process=world)
    held = [math.dist(positions[0], GOAL) for positions in watch.positions[first:]]
    assert max(held) < HOLD_TOLERANCE, f'ball_1 went {max(held):.3f} m from its goal'
    assert max(math.dist(positions[1], (8.0, 3.0)) for positions in
               watch.positions[first:]) < 1e-12  # nothing pushed ball_2

    # The controller reports its distance every REPORT_SECONDS of wall time while its ball
    # is there: hold it at least one report (and a margin for a busy machine) before it goes.
    # A quick run deleted it first, and the report asserted below never came.
    watch.spin_until(lambda: time.monotonic() - started > REPORT_SECONDS + 2.0,
                     'a report period of the controller', process=world)
    deleted = watch.call(DeleteEntity, '/ball_world/delete_entity',
                         DeleteEntity.Request(entity='ball_1'))
    assert deleted.result.result == Result.RESULT_OK, deleted.result.error_message
    gone, since = len(pushes), watch.times[-1]

    def quiet():
        # 3 s of the world's time without a push at ball_1: a controller that went on
        # pushing (20 a second) never gets there.
        last = max((t for t, name in pushes[gone:] if name == 'ball_1'), default=since)
        return watch.times[-1] >= last + 3.0
    watch.spin_until(quiet, 'the pushes at the deleted ball_1 to stop', process=world)
    # Pushes already on their way when ball_1 went may still arrive: a second's worth at
    # most (counted, not timed: a controller held up by a busy machine sends none meanwhile).
    late = [name for _, name in pushes[gone:] if name == 'ball_1']
    assert len(late) <= 20, f'{len(late)} pushes at a ball that is gone'

    # A reset brings ball_1 back (a deleted name cannot be spawned again in its segment):
    # the controller pushes it again.
    assert watch.call(Trigger, '/ball_world/reset', Trigger.Request()).success
    back = len(pushes)
    watch.spin_until(lambda: len(pushes) > back, 'pushes after the reset', process=world)

    for process in (controller, world):
        process.send_signal(signal.SIGINT)
    code, _, err = finish(controller)
    assert code == 0 and 'Traceback' not in err, err
    assert err.count('ball_1 is not in the world') == 1, err
    assert err.count('ball_1 is back: pushing again') == 1, err
    assert 'm from the goal, at (' in err  # the periodic report
    assert finish(world)[0] == 0


def test_without_a_world_it_says_what_it_waits_for(processes, tmp_path):
    """Once at start what it waits for, then a warning every REPORT_SECONDS (waited for
    with a liveness deadline, never timed)."""
    log = tmp_path / 'goal.log'
    controller = processes.start([executable('ball_world_goal'), '--ros-args',
                                  '-r', '__ns:=/nobody_here'], log=log)
    deadline = time.monotonic() + DEADLINE
    while 'no ball_world heard yet' not in log.read_text():
        assert controller.poll() is None, log.read_text()
        assert time.monotonic() < deadline, log.read_text()
        time.sleep(0.2)
    controller.send_signal(signal.SIGINT)
    code, _, _ = finish(controller)
    text = log.read_text()
    assert code == 0, text
    assert text.count('waiting for /nobody_here/state and /nobody_here/entity_names') == 1, text
    assert 'no ball_world heard yet on /nobody_here/state' in text, text


# Pushes are always finite ----------------------------------------------------------------------

@pytest.mark.parametrize('overrides, state, pushed', [
    # A mass whose push overflows a float is still shortened to max_impulse.
    ({'mass': 1e308}, (2.0, 2.0, 0.0, 0.0), 0.5),
    # The largest gains and speeds the world can have: finite, shortened.
    ({'kp': 1e6, 'kd': 1e6}, (0.0, 10.0, -1e5, 1e5), 0.5),
    # A state no world publishes (1.7e308 m away): not sent at all.
    ({'kp': 1e6}, (1.7e308, 2.0, 0.0, 0.0), None),
    # At the goal, at rest: nothing to push.
    ({}, (GOAL[0], GOAL[1], 0.0, 0.0), None),
])
def test_every_push_is_finite_and_at_most_max_impulse(overrides, state, pushed):
    """The controller's arithmetic on the edge of what floats hold, in a context of its own."""
    import rclpy
    from rclpy.parameter import Parameter
    from std_msgs.msg import String
    from ball_world.tools.goal import GoalController

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        values = {'ball': 'ball_1', 'goal': list(GOAL), **overrides}
        controller = GoalController(context=context, parameter_overrides=[
            Parameter(name, value=value) for name, value in values.items()])
        sent = []
        controller.publisher = type('Publisher', (), {'publish': lambda self, m: sent.append(
            (m.vector.x, m.vector.y, m.vector.z))})()
        controller.on_names(String(data='ball_0\nball_1'))
        controller.on_state(Float64MultiArray(data=[1.0, 1.0, 0.0, 0.0, *state]))
        controller.on_timer()
        if pushed is None:
            assert sent == []
        else:
            ((jx, jy, jz),) = sent
            assert all(math.isfinite(v) for v in (jx, jy)) and jz == 0.0
            assert math.hypot(jx, jy) == pytest.approx(pushed, rel=1e-12)
        controller.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
