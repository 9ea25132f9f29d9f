"""ball_world_goal: bring one ball to a goal point and hold it there, pushing with impulses.

This node is also a tutorial: it is the smallest useful program that works with ball_world,
and yours can start as a copy of it. Read it top to bottom. It does three things:

  1. listens to the world's `state` topic: one row (x, y, vx, vy) per ball, every step;
  2. every 1 / rate_hz seconds, computes how hard to push the ball with a PD controller:
         acceleration a = kp * (goal - position) - kd * velocity
         impulse      J = mass * a * T          (T = 1 / rate_hz: a force held for T)
     shortened to max_impulse if it is longer (a real actuator is limited too);
  3. publishes J on the world's `impulse` topic, addressed to the ball by its name.

The world applies an impulse before its next step (v += J / m) and lets the ball collide as
usual, so other balls still bump it: the controller then pushes it back.

Mass: the impulse a velocity change needs is proportional to the ball's mass, which the world
does not publish yet; the `mass` parameter gives it (default 0.2 kg, about a ball of the
default world). A wrong mass scales both gains by assumed / true mass: up to about 9 times too
heavy still settles (slower, overdamped), too light overshoots.

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
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from std_msgs.msg import Float64MultiArray

from ball_world.tools import goal_drive
from ball_world.tools.goal_drive import AgentGoal

PROG = 'ball_world_goal'
#: Drive an agent through cmd_vel and odom instead (tools/goal_drive.py).
AGENT_FLAG = '--agent'
PARAMETERS = """\
ROS parameters (after --ros-args; integers are taken for numbers):
  ball         name of the ball to hold (default ball_0)
  goal         [x, y] of the goal point, m (default [5.0, 5.0], the default arena's centre)
  kp           gain on the distance to the goal, 1/s^2 (default 4.0)
  kd           gain on the velocity, 1/s (default 4.0: critically damped with kp 4.0)
  max_impulse  longest push per command, N s (default 0.5)
  rate_hz      commands per second (default 20.0)
  mass         mass of the ball, kg (default 0.2)
  use_sim_time true: run on the world's /clock (start the world with publish_clock:=true)"""


class ParameterError(ValueError):
    """A parameter value the controller cannot work with; the message names it."""


class GoalController(Node):
    """Reads the world's state, pushes one ball towards its goal at a fixed rate."""

    def __init__(self):
        super().__init__('ball_world_goal')
        # Parameters, checked once at start (see PARAMETERS for their meaning).
        self.ball = self.parameter('ball', 'ball_0', str)
        self.goal = self.parameter('goal', [5.0, 5.0], list)
        self.kp = self.parameter('kp', 4.0, float, low=0.0)
        self.kd = self.parameter('kd', 4.0, float, low=0.0)
        self.max_impulse = self.parameter('max_impulse', 0.5, float, low=0.0, strict=True)
        rate_hz = self.parameter('rate_hz', 20.0, float, low=0.0, strict=True)
        self.mass = self.parameter('mass', 0.2, float, low=0.0, strict=True)
        self.period = 1.0 / rate_hz

        # Relative names: with -r __ns:=/sim2 this node talks to the world in /sim2.
        self.state = None
        self.create_subscription(Float64MultiArray, 'state', self.on_state, 1)
        # Reliable, like the world's impulse subscription: a push must not be lost.
        self.publisher = self.create_publisher(
            Vector3Stamped, 'impulse',
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.timer = self.create_timer(self.period, self.on_timer)
        self.get_logger().info(
            f'holding {self.ball} at ({self.goal[0]:g}, {self.goal[1]:g}) with kp {self.kp:g}, '
            f'kd {self.kd:g}, mass {self.mass:g} kg, at most {self.max_impulse:g} N s per '
            f'push, {rate_hz:g} pushes/s')

    def on_state(self, msg):
        # Keep only the latest state; rows are x, y, vx, vy, in the order of the poses.
        self.state = msg.data

    def on_timer(self):
        if self.state is None:
            return  # the world has not spoken yet
        # Which row is our ball? The world names its balls ball_0, ball_1, ... in pose order
        # (when it publishes its list of entity names, take the names from there instead).
        names = [f'ball_{i}' for i in range(len(self.state) // 4)]
        if self.ball not in names:
            self.get_logger().warning(f'no {self.ball} in a world of {len(names)} balls',
                                      throttle_duration_sec=5.0)
            return
        row = names.index(self.ball)
        x, y, vx, vy = self.state[4 * row:4 * row + 4]

        # PD control: accelerate towards the goal, brake in proportion to the speed.
        ax = self.kp * (self.goal[0] - x) - self.kd * vx
        ay = self.kp * (self.goal[1] - y) - self.kd * vy
        # That acceleration held for one period is a velocity change of a * T, which an
        # impulse of mass * a * T makes. Keep its direction, limit its length.
        jx, jy = self.mass * ax * self.period, self.mass * ay * self.period
        length = math.hypot(jx, jy)
        if length > self.max_impulse:
            jx, jy = jx * self.max_impulse / length, jy * self.max_impulse / length

        msg = Vector3Stamped()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.ball  # the world applies it to the ball of this name
        msg.vector.x, msg.vector.y = jx, jy  # z stays 0: the world is the z = 0 plane
        self.publisher.publish(msg)

    def parameter(self, name, default, kind, low=None, strict=False):
        """Declare a parameter and return its value as `kind`, or raise ParameterError.

        dynamic_typing lets `-p kp:=4` (an integer) stand for 4.0.
        """
        value = self.declare_parameter(
            name, default, ParameterDescriptor(dynamic_typing=True)).value
        if kind is str and isinstance(value, str) and value:
            return value
        if kind is float and _is_number(value) and (
                low is None or value > low or (value == low and not strict)):
            return float(value)
        if kind is list and isinstance(value, (list, tuple)) and len(value) == 2 \
                and all(_is_number(v) for v in value):
            return [float(v) for v in value]
        if kind is float:
            wanted = f"a number {'>' if strict else '>='} {low:g}"
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
        rclpy.init(args=argv)
        agent = AGENT_FLAG in remove_ros_args(argv)[1:]
        node = AgentGoal(GoalController.parameter) if agent else GoalController()
        # Short waits, as the world node does: a shut-down context ends the loop within
        # 0.1 s even if the wake-up of a signal that shut it down was missed.
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
    except ParameterError as error:
        fail(error)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass  # Ctrl-C or SIGTERM: a normal way to stop
    except Exception:  # noqa: B902
        # A signal that lands while rclpy takes a message surfaces as whatever that call
        # raises (a RuntimeError from its conversion): a stop too, once the context is down.
        if rclpy.ok():
            raise
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
