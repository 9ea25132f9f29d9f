"""ball_world_goal: bring one ball to a goal point and hold it there, pushing with impulses.

This node is also a tutorial: it is the smallest useful program that works with ball_world,
and yours can start as a copy of it. Read it top to bottom. It does four things:

  1. listens to the world's `entity_names` topic (latched: the names of the balls, one per
     line, in the order of the rows of `state`; it changes when balls are spawned or
     deleted, since a deletion moves the rows after it up);
  2. listens to the world's `state` topic: one row (x, y, vx, vy) per ball, every step;
  3. every 1 / rate_hz seconds, finds its ball's row by name and computes how hard to push
     it with a PD controller:
         acceleration a = kp * (goal - position) - kd * velocity
         impulse      J = mass * a * T          (T = 1 / rate_hz: a force held for T)
     shortened to max_impulse if it is longer (a real actuator is limited too);
  4. publishes J on the world's `impulse` topic, addressed to the ball by its name.

The world applies an impulse before its next step (v += J / m) and lets the ball collide as
usual, so other balls still bump it: the controller then pushes it back. While its ball is
not in the world (deleted, or not spawned yet) it says so once and pushes nothing until the
ball is back; without a world it says what it waits for; every REPORT_SECONDS it reports
the ball's distance to the goal.

Mass: the impulse a velocity change needs is proportional to the ball's mass. The world
tells it through its ~/get_entity_info service (GetEntityInfo: "ball, radius ... m, mass
... kg"); this node takes it from the `mass` parameter (default 0.2 kg, about a ball of the
default world). A wrong mass scales both gains by assumed / true mass: up to about 9 times
too heavy still settles (slower, overdamped), too light overshoots.

Time: the timer runs on the node's clock. With the world's publish_clock:=true and this node's
use_sim_time:=true it runs on simulated time, so T is exact even when the world runs slower
or faster than real time; on wall time it assumes the world keeps real time.

    ros2 run ball_world ball_world_goal --ros-args -p ball:=ball_3 -p goal:=[2.0,8.0]
"""
import math
import sys

from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import ParameterDescriptor
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from std_msgs.msg import Float64MultiArray, String

from ball_world.ros.rcl_init import creating_node
from ball_world.ros.stopping import stopped_by_signal
from ball_world.tools import goal_drive
from ball_world.tools.goal_drive import AgentGoal

PROG = 'ball_world_goal'
#: Largest gain taken (kp in 1/s^2, kd in 1/s). A loop sampled at 20 Hz is unstable long
#: before it (kp T^2 or kd T of order 1), and far larger ones (1e308) overflow the push.
MAX_GAIN = 1e6
#: Pushes per second taken: a timer's period must fit rclpy's nanoseconds (1e-300 Hz does
#: not) and must not be 0 ns (1e300 Hz would spin a core for nothing).
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 1e3
#: Seconds between the reports of the distance to the goal, and between the warnings while
#: no world (no `state`) is heard.
REPORT_SECONDS = 5.0
#: How the world publishes `entity_names`: latched (transient local), so a controller started
#: after the world still gets the names.
NAMES_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Drive an agent through cmd_vel and odom instead (tools/goal_drive.py).
AGENT_FLAG = '--agent'
PARAMETERS = """\
ROS parameters (after --ros-args; integers are taken for numbers):
  ball         name of the ball to hold (default ball_0)
  goal         [x, y] of the goal point, m (default [5.0, 5.0], the default arena's centre)
  kp           gain on the distance to the goal, 1/s^2 (default 4.0; at most 1e6)
  kd           gain on the velocity, 1/s (default 4.0: critically damped with kp 4.0;
               at most 1e6)
  max_impulse  longest push per command, N s (default 0.5)
  rate_hz      commands per second (default 20.0; 0.001 to 1000)
  mass         mass of the ball, kg (default 0.2)
  use_sim_time true: run on the world's /clock (start the world with publish_clock:=true)"""


class ParameterError(ValueError):
    """A parameter value the controller cannot work with; the message names it."""


class GoalController(Node):
    """Reads the world's state, pushes one ball towards its goal at a fixed rate."""

    def __init__(self, **kwargs):
        super().__init__('ball_world_goal', **kwargs)
        # Parameters, checked once at start (see PARAMETERS for their meaning).
        self.ball = self.parameter('ball', 'ball_0', str)
        self.goal = self.parameter('goal', [5.0, 5.0], list)
        self.kp = self.parameter('kp', 4.0, float, low=0.0, high=MAX_GAIN)
        self.kd = self.parameter('kd', 4.0, float, low=0.0, high=MAX_GAIN)
        self.max_impulse = self.parameter('max_impulse', 0.5, float, low=0.0, strict=True)
        rate_hz = self.parameter('rate_hz', 20.0, float, low=MIN_RATE_HZ, high=MAX_RATE_HZ)
        self.mass = self.parameter('mass', 0.2, float, low=0.0, strict=True)
        self.period = 1.0 / rate_hz

        # Relative names: with -r __ns:=/sim2 this node talks to the world in /sim2.
        self.state = None
        self.names = None  # the balls' names in the order of the rows of state
        self.create_subscription(Float64MultiArray, 'state', self.on_state, 1)
        self.create_subscription(String, 'entity_names', self.on_names, NAMES_QOS)
        # Reliable, like the world's impulse subscription: a push must not be lost.
        self.publisher = self.create_publisher(
            Vector3Stamped, 'impulse',
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.timer = self.create_timer(self.period, self.on_timer)
        self.missing = False  # whether "not in the world" was said (said once)
        # Reports and warnings go by the steady clock: with use_sim_time and no world, the
        # node's own clock (and so self.timer) stands still.
        self.create_timer(REPORT_SECONDS, self.on_report,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'holding {self.ball} at ({self.goal[0]:g}, {self.goal[1]:g}) with kp {self.kp:g}, '
            f'kd {self.kd:g}, mass {self.mass:g} kg, at most {self.max_impulse:g} N s per '
            f'push, {rate_hz:g} pushes/s; waiting for {self.resolve_topic_name("state")} '
            f'and {self.resolve_topic_name("entity_names")} from a ball_world')

    def on_state(self, msg):
        # Keep only the latest state; rows are x, y, vx, vy, in the order of the poses.
        self.state = msg.data

    def on_names(self, msg):
        # The names, one per line, in the order of the rows of state (an empty world: '').
        # The world publishes them when balls come or go, before its next state: the state
        # held now has the old rows, so it is dropped until the next one arrives.
        self.names = msg.data.split('\n') if msg.data else []
        self.state = None

    def row(self):
        """Our ball's (x, y, vx, vy) in the latest state, or None (no state or no ball)."""
        if self.state is None or self.names is None \
                or len(self.state) != 4 * len(self.names) or self.ball not in self.names:
            return None
        row = self.names.index(self.ball)
        return self.state[4 * row:4 * row + 4]

    def on_report(self):
        """Every REPORT_SECONDS: the distance to the goal, or what is missing."""
        if self.state is None and self.names is None:
            self.get_logger().warning(
                f'no ball_world heard yet on {self.resolve_topic_name("state")} and '
                f'{self.resolve_topic_name("entity_names")}; is it running, in this '
                'namespace and ROS domain?')
            return
        row = self.row()
        if row is not None:
            x, y = row[0], row[1]
            distance = math.hypot(self.goal[0] - x, self.goal[1] - y)
            self.get_logger().info(f'{self.ball} is {distance:.3g} m from the goal, at '
                                   f'({x:.3f}, {y:.3f})')

    def on_timer(self):
        if self.state is None or self.names is None:
            return  # the world has not spoken yet (or an edit's state is on its way)
        if len(self.state) != 4 * len(self.names):
            return  # a state from before an edit whose names came first
        if self.ball not in self.names:
            if not self.missing:
                self.missing = True
                self.get_logger().warning(f'{self.ball} is not in the world (deleted?): not '
                                          'pushing until it is back')
            return
        if self.missing:
            self.missing = False
            self.get_logger().info(f'{self.ball} is back: pushing again')
        # Which row is our ball? The one its name has in the names published last.
        x, y, vx, vy = self.row()

        # PD control: accelerate towards the goal, brake in proportion to the speed.
        ax = self.kp * (self.goal[0] - x) - self.kd * vx
        ay = self.kp * (self.goal[1] - y) - self.kd * vy
        # That acceleration held for one period is a velocity change of a * T, which an
        # impulse of mass * a * T makes. Keep its direction, limit its length (taken from
        # the acceleration's direction, so that an impulse too long for a float is still
        # shortened to max_impulse rather than turned into inf / inf = NaN).
        accel = math.hypot(ax, ay)
        if not math.isfinite(accel):
            self.get_logger().warning(f'push on {self.ball} not finite (state {x}, {y}, {vx}, '
                                      f'{vy}); not sent', throttle_duration_sec=5.0)
            return
        if accel == 0.0:
            return
        length = min(self.mass * accel * self.period, self.max_impulse)
        jx, jy = ax / accel * length, ay / accel * length

        msg = Vector3Stamped()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.ball  # the world applies it to the ball of this name
        msg.vector.x, msg.vector.y = jx, jy  # z stays 0: the world is the z = 0 plane
        self.publisher.publish(msg)

    def parameter(self, name, default, kind, low=None, strict=False, high=None):
        """Declare a parameter and return its value as `kind`, or raise ParameterError.

        dynamic_typing lets `-p kp:=4` (an integer) stand for 4.0.
        """
        value = self.declare_parameter(
            name, default, ParameterDescriptor(dynamic_typing=True)).value
        if kind is str and isinstance(value, str) and value:
            return value
        if kind is float and _is_number(value) and (
                low is None or value > low or (value == low and not strict)) and (
                high is None or value <= high):
            return float(value)
        if kind is list and isinstance(value, (list, tuple)) and len(value) == 2 \
                and all(_is_number(v) for v in value):
            return [float(v) for v in value]
        if kind is float:
            wanted = f"a number {'>' if strict else '>='} {low:g}" + (
                f' and <= {high:g}' if high is not None else '')
        else:
            wanted = 'a ball name such as ball_0' if kind is str else 'two numbers [x, y]'
        raise ParameterError(f"parameter '{name}': expected {wanted}, got {value!r}")


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


def main(args=None):
    argv = sys.argv if args is None else args
    if not command_line_ok(argv):
        return
    node = None
    try:
        with stopped_by_signal():
            rclpy.init(args=argv)
            agent = AGENT_FLAG in remove_ros_args(argv)[1:]
            with creating_node(PROG):
                node = AgentGoal(GoalController.parameter) if agent else GoalController()
            # Short waits, as the world node does: a shut-down context ends the loop within
            # 0.1 s even if the wake-up of a signal that shut it down was missed.
            while rclpy.ok():
                rclpy.spin_once(node, timeout_sec=0.1)
    except ParameterError as error:
        fail(error)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def command_line_ok(argv):
    """Print usage for --help; exit with one line on arguments that are not ROS ones."""
    try:
        own = remove_ros_args(argv)[1:]
    except Exception as error:  # noqa: B902 - rcl reports bad arguments as generic errors
        fail(f'bad ROS arguments: {error}')
    if own in (['-h'], ['--help']):
        print(f'usage: {PROG} [--ros-args -p NAME:=VALUE ...]\n\n{__doc__}\n{PARAMETERS}\n\n'
              f'usage: {PROG} {AGENT_FLAG} [--ros-args -p NAME:=VALUE ...]\n\n'
              f'{goal_drive.__doc__}\n{goal_drive.PARAMETERS}')
        return False
    own = [arg for arg in own if arg != AGENT_FLAG]
    if own:
        fail(f"unrecognized arguments: {' '.join(own)} (see --help)")
    return True


def fail(message):
    print(f'{PROG}: {message}', file=sys.stderr)
    sys.exit(2)


if __name__ == '__main__':
    main()
