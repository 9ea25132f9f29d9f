"""ball_world_navigate: a trained Navigate-v0 policy as a ROS node of its own.

It reads one robot's `<agent>/scan` (sensor_msgs/LaserScan) and `<agent>/odom`
(nav_msgs/Odometry), builds the policy's observation from them with the function the
environment's observation is tested against (envs.deploy.from_messages: the same
observation, bit for bit, for the environment's lidar and noise-free odometry), and
publishes the policy's command on `<agent>/cmd_vel` (geometry_msgs/Twist) once per scan,
until the robot is within the environment's goal tolerance of `goal`; then it heads for the
next goal, if `goal` holds more than one, and after the last it stops the robot and says so
(or, with `loop`, starts again from the first). A node like any other: run it beside
ball_world, or beside a real robot whose lidar is the one the policy was trained with.

    ros2 run ball_world ball_world_navigate --ros-args -p agent:=ball_0 \\
      -p policy:=runs/navigate_ppo.zip -p goal:=[1.5,1.5]
"""
import math
import numbers
import sys

PROG = 'ball_world_navigate'
PARAMETERS = """\
ROS parameters (after --ros-args):
  agent   entity name of the robot (default ball_0): reads <agent>/scan and <agent>/odom,
          drives <agent>/cmd_vel
  policy  the policy file make learn saves (default runs/navigate_ppo.zip)
  goal    [x, y], m, in the odometry's frame, or [x1, y1, x2, y2, ...]: goals in turn
          (default [1.5, 1.5])
  loop    after the last goal, the first again (default false)"""


class ParameterError(ValueError):
    """A parameter the node cannot take; the message names it."""


def _node_class():
    """The ROS node, made on first use so the module imports without ROS."""
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.node import Node
    from sensor_msgs.msg import LaserScan

    from ball_world.envs.deploy import FanMismatch, from_messages, reached
    from ball_world.envs.policy import load_policy
    from ball_world.envs.rewards import GOAL_TOLERANCE

    class NavigateNode(Node):
        """<agent>/scan and <agent>/odom in, <agent>/cmd_vel out, one command per scan."""

        def __init__(self):
            super().__init__('ball_world_navigate')
            agent = self.declare_parameter('agent', 'ball_0').value
            if not (isinstance(agent, str) and agent):
                raise ParameterError(f"parameter 'agent': expected a name, got {agent!r}")
            goal = self.declare_parameter('goal', [1.5, 1.5],
                                          ParameterDescriptor(dynamic_typing=True)).value
            if not isinstance(goal, (list, tuple)) or not goal or len(goal) % 2 or not all(
                    isinstance(v, numbers.Real) and not isinstance(v, bool)
                    and math.isfinite(v) for v in goal):
                raise ParameterError(f"parameter 'goal': expected [x, y] in m (or more pairs "
                                     f'x, y), got {goal!r}')
            self.goals = [(float(goal[i]), float(goal[i + 1])) for i in range(0, len(goal), 2)]
            self.index = 0
            self.goal = self.goals[0]
            self.loop = self.declare_parameter('loop', False).value is True
            self.path = self.declare_parameter('policy', 'runs/navigate_ppo.zip').value
            self.odom = None
            self.arrived = False
            self.Twist = Twist
            self.tolerance = GOAL_TOLERANCE
            self.reached, self.from_messages, self.FanMismatch = (reached, from_messages,
                                                                  FanMismatch)
            self.agent = agent
            self.topics = (Twist, Odometry, LaserScan)

        def start(self):
            """Load the policy (torch's import takes seconds: after the node is made, so
            rcl_init's watchdog times the node alone) and start driving."""
            self.policy = load_policy(self.path)  # PolicyError: one line
            agent = self.agent
            twist, odometry, scan = self.topics
            self.cmd_vel = self.create_publisher(twist, f'{agent}/cmd_vel', 10)
            self.create_subscription(odometry, f'{agent}/odom', self.on_odom, 10)
            self.create_subscription(scan, f'{agent}/scan', self.on_scan, 10)
            self.get_logger().info(f'driving {agent} to ({self.goal[0]:g}, {self.goal[1]:g}) '
                                   f'with {self.path}: reading {agent}/scan and {agent}/odom')

        def on_odom(self, msg):
            self.odom = msg

        def on_scan(self, msg):
            if self.odom is None or self.arrived:
                return
            position = self.odom.pose.pose.position
            twist = self.Twist()
            if self.reached((position.x, position.y), self.goal, self.tolerance):
                index = self.index + 1
                if index == len(self.goals) and self.loop:
                    index = 0
                if index == len(self.goals):
                    self.arrived = True
                    self.get_logger().info(f'at the goal ({position.x:.3f}, {position.y:.3f}):'
                                           ' stopped')
                    self.cmd_vel.publish(twist)
                    return
                self.get_logger().info(f'at the goal ({self.goal[0]:g}, {self.goal[1]:g}); '
                                       f'next ({self.goals[index][0]:g}, '
                                       f'{self.goals[index][1]:g})')
                self.index, self.goal = index, self.goals[index]
            observation = self.from_messages(msg, self.odom, self.goal,
                                             self.policy.observation_space)
            twist.linear.x, twist.angular.z = self.policy(observation)
            self.cmd_vel.publish(twist)

    return NavigateNode


def main(args=None):
    from ball_world.envs.deploy import FanMismatch
    from ball_world.envs.policy import PolicyError
    from ball_world.tools import node_tool
    return node_tool.run(
        PROG, f'usage: {PROG} [--ros-args -p NAME:=VALUE ...]\n\n{__doc__}\n{PARAMETERS}',
        lambda: _node_class()(), (ParameterError, PolicyError, FanMismatch), args)


if __name__ == '__main__':
    sys.exit(main())
