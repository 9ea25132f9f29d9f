"""ball_world_goal --agent: drive an agent (a ball that is a robot) to a goal point.

This is turtlesim's classic "go to goal" exercise, on a robot that takes velocity commands:
it does not push the ball with impulses (see goal.py for that) but, like a Nav2 controller,

  1. listens to the agent's `<ball>/odom` (nav_msgs/Odometry: pose with the heading as a
     quaternion, ground truth here);
  2. every 1 / rate_hz seconds computes a body-frame command from the distance d and the
     heading error e (the angle from the robot's heading to the goal):
         yaw rate  w = kw * e                      (turn towards the goal)
         forward   v = min(kv * d, max_speed) * max(cos e, 0)
                                                   (drive when facing it, slow down near it)
     and once within `tolerance`, v = w = 0, which holds the robot there;
  3. publishes the command on `<ball>/cmd_vel` (geometry_msgs/Twist, or TwistStamped when
     the world takes that: agent.cmd_vel_stamped, seen on the graph once odom arrives).

The world turns commands into accelerations limited by agent.max_accel, so the robot's
velocity follows the command smoothly; a command must come at least every agent.cmd_timeout
or the robot brakes, which this loop does at rate_hz.

    ros2 run ball_world ball_world_goal --agent --ros-args -p ball:=ball_0 -p goal:=[2.0,8.0]
"""
import math

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ball_world.tools.teleop_drive import command_type, stamped

PARAMETERS = """\
ROS parameters with --agent (after --ros-args):
  ball         name of the agent to drive (default ball_0)
  goal         [x, y] of the goal point, m (default [5.0, 5.0])
  kv           forward speed per metre of distance, 1/s (default 1.0)
  kw           yaw rate per radian of heading error, 1/s (default 3.0)
  max_speed    fastest forward command, m/s (default 1.0)
  tolerance    distance at which it stops, m (default 0.05)
  rate_hz      commands per second (default 20.0)
  use_sim_time true: run on the world's /clock (publish_clock, on by default)"""


def heading(orientation):
    """The yaw of a planar quaternion (rotation about z), rad."""
    return 2.0 * math.atan2(orientation.z, orientation.w)


def command(x, y, yaw, goal, kv, kw, max_speed, tolerance):
    """(forward m/s, yaw rate rad/s) toward goal from (x, y) facing yaw; (0, 0) when there."""
    dx, dy = goal[0] - x, goal[1] - y
    distance = math.hypot(dx, dy)
    if distance <= tolerance:
        return 0.0, 0.0
    error = math.remainder(math.atan2(dy, dx) - yaw, 2.0 * math.pi)
    forward = min(kv * distance, max_speed) * max(math.cos(error), 0.0)
    return forward, kw * error


class AgentGoal(Node):
    """Reads an agent's odom, sends it cmd_vel toward a goal at a fixed rate."""

    def __init__(self, parameter):
        super().__init__('ball_world_goal')
        # parameter(node, name, default, kind, low=..., strict=...) declares and checks one
        # parameter, as the ball mode does (goal.GoalController.parameter).
        self.ball = parameter(self, 'ball', 'ball_0', str)
        self.goal = parameter(self, 'goal', [5.0, 5.0], list)
        self.kv = parameter(self, 'kv', 1.0, float, low=0.0, strict=True)
        self.kw = parameter(self, 'kw', 3.0, float, low=0.0, strict=True)
        self.max_speed = parameter(self, 'max_speed', 1.0, float, low=0.0, strict=True)
        self.tolerance = parameter(self, 'tolerance', 0.05, float, low=0.0, strict=True)
        rate_hz = parameter(self, 'rate_hz', 20.0, float, low=0.0, strict=True)
        self.odom = None
        self.create_subscription(Odometry, f'{self.ball}/odom', self.on_odom, 1)
        self.publisher = None  # made once the world is heard: its cmd_vel type is then known
        self.create_timer(1.0 / rate_hz, self.on_timer)
        self.get_logger().info(
            f'driving agent {self.ball} to ({self.goal[0]:g}, {self.goal[1]:g}) on '
            f'{self.resolve_topic_name(self.ball + "/cmd_vel")}, kv {self.kv:g}, kw '
            f'{self.kw:g}, at most {self.max_speed:g} m/s, {rate_hz:g} commands/s')

    def on_odom(self, msg):
        self.odom = msg  # the latest pose is all the controller needs

    def on_timer(self):
        if self.odom is None:
            self.get_logger().warning(
                f'no odometry on {self.resolve_topic_name(self.ball + "/odom")} yet: is '
                f'{self.ball} an agent (agents:=[{self.ball}])?', throttle_duration_sec=5.0)
            return
        if self.publisher is None:
            self.publisher = self.create_publisher(
                command_type(self, f'{self.ball}/cmd_vel'), f'{self.ball}/cmd_vel',
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        pose = self.odom.pose.pose
        forward, rate = command(pose.position.x, pose.position.y, heading(pose.orientation),
                                self.goal, self.kv, self.kw, self.max_speed, self.tolerance)
        msg = Twist()
        msg.linear.x, msg.angular.z = forward, rate
        self.publisher.publish(stamped(self, msg) if self.publisher.msg_type is TwistStamped
                               else msg)
