"""ball_world_wander: a robot that roams on its own and keeps off whatever its lidar sees.

This is Stage's classic `wander` controller, and a starting point for your own: read it top
to bottom. Every scan it does three things:

  1. looks at the corridor ahead: the beams whose end points lie in front of the robot,
     within `avoid_distance` of its centre and within `half_width` of its path (the robot's
     radius and a margin), and at its flanks (any end point closer than `half_width`);
  2. when something is there, stops and turns in place, away from it: towards the side
     (left or right half of the scan) that sees further, and keeps turning that way until
     the corridor is clear (turning back and forth would leave it stuck in a corner);
  3. when nothing is, drives forward at `speed`, turning at a yaw rate that it picks at
     random every `wander_seconds`, so it does not run in circles or straight lines.

It needs no map: a wall, a pillar and a ball are all things to keep off, and the scan shows
them alike (a tracker is another matter: ball_world_tracker leaves `/map`'s solid cells out,
as they are no objects to follow). It publishes one geometry_msgs/Twist on `<agent>/cmd_vel`
per scan: linear.x forward, angular.z the yaw rate, as any diff-drive base takes them
(ball_world's `agent.drive` `diff` or `omni` alike). Everything above the node class is
plain Python and numpy: `Wander.command` is what the tests drive with the world's own scans,
without ROS.

    ros2 run ball_world ball_world_wander --ros-args -p agent:=ball_0
"""
import math
import sys
from typing import NamedTuple

import numpy as np

PROG = 'ball_world_wander'
PARAMETERS = """\
ROS parameters (after --ros-args; integers are taken for numbers):
  agent           entity name of the robot (default ball_0): reads <agent>/scan, drives
                  <agent>/cmd_vel
  speed           forward speed when the way is clear, m/s (default 0.6)
  turn_rate       yaw rate when turning away, rad/s (default 1.5)
  avoid_distance  how far ahead to look, m from the robot's centre (default 0.9)
  half_width      half the corridor's width, m (default 0.45: a 0.3 m robot and a margin)
  wander_rate     largest random yaw rate while roaming, rad/s (default 0.5)
  wander_seconds  how long a random yaw rate is held, s of scan time (default 2.0)
  seed            seed of the random yaw rates (default 0)"""


class Options(NamedTuple):
    """The controller's tuning (see PARAMETERS)."""

    speed: float = 0.6
    turn_rate: float = 1.5
    avoid_distance: float = 0.9
    half_width: float = 0.45
    wander_rate: float = 0.5
    wander_seconds: float = 2.0


class Wander:
    """Stage's wander: scan in, (forward speed, yaw rate) out. Keeps a little state: the
    side it turns to while blocked, and the random yaw rate while roaming."""

    def __init__(self, options=Options(), seed=0):
        self.options = options
        self.random = np.random.default_rng(seed)
        self.turning = 0.0  # +1 left, -1 right while blocked; 0 while the way is clear
        self.wander = 0.0  # yaw rate while roaming, rad/s
        self.wander_until = -math.inf  # scan time when a new one is drawn

    def command(self, ranges, angle_min, angle_increment, range_max, time):
        """(forward m/s, yaw rate rad/s) for a scan (REP 117 ranges) taken at `time` s."""
        options = self.options
        ranges = np.asarray(ranges, dtype=np.float64)
        angles = angle_min + angle_increment * np.arange(len(ranges))
        # REP 117: +inf sees nothing within range_max, -inf is closer than range_min.
        reach = np.where(np.isneginf(ranges), 0.0, ranges)
        with np.errstate(invalid='ignore'):  # inf x 0: NaN, which compares as False
            ahead = reach * np.cos(angles)  # end points in the robot's frame
            beside = reach * np.sin(angles)
        # 1. Anything in the corridor ahead, or right at the robot's flanks?
        in_corridor = (ahead > 0.0) & (ahead < options.avoid_distance) \
            & (np.abs(beside) < options.half_width)
        at_flank = (np.abs(angles) <= 0.5 * math.pi) & (reach < options.half_width)
        if (in_corridor | at_flank).any():
            # 2. Turn in place towards the side that sees further, and keep that side.
            if self.turning == 0.0:
                seen = np.minimum(reach, range_max)
                left = seen[angles > 0.0].sum()
                right = seen[angles < 0.0].sum()
                self.turning = 1.0 if left >= right else -1.0
            return 0.0, self.turning * options.turn_rate
        # 3. The way is clear: forward, with a random turn now and then.
        self.turning = 0.0
        if time >= self.wander_until:
            self.wander = float(self.random.uniform(-options.wander_rate, options.wander_rate))
            self.wander_until = time + options.wander_seconds
        return options.speed, self.wander


class ParameterError(ValueError):
    """A parameter the controller cannot take; the message names it."""


def _node_class():
    """The ROS node, made on first use so the controller above imports without ROS."""
    from geometry_msgs.msg import Twist
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.node import Node
    from sensor_msgs.msg import LaserScan

    class WanderNode(Node):
        """<agent>/scan in, <agent>/cmd_vel out, one command per scan."""

        def __init__(self):
            super().__init__('ball_world_wander')
            agent = self.declare_parameter('agent', 'ball_0').value
            if not (isinstance(agent, str) and agent):
                raise ParameterError(f"parameter 'agent': expected a name, got {agent!r}")
            values = {}
            for name, default in Options()._asdict().items():
                value = self.declare_parameter(
                    name, default, ParameterDescriptor(dynamic_typing=True)).value
                if isinstance(value, bool) or not isinstance(value, (int, float)) \
                        or not math.isfinite(value) or value < 0:
                    raise ParameterError(f"parameter '{name}': expected a number >= 0, got "
                                         f'{value!r}')
                values[name] = float(value)
            seed = self.declare_parameter('seed', 0).value
            if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
                raise ParameterError(f"parameter 'seed': expected an integer >= 0, got "
                                     f'{seed!r}')
            self.wander = Wander(Options(**values), seed)
            self.Twist = Twist
            # Relative names: under -r __ns:=/sim2 these are the world's in /sim2.
            self.cmd_vel = self.create_publisher(Twist, f'{agent}/cmd_vel', 10)
            self.create_subscription(LaserScan, f'{agent}/scan', self.on_scan, 10)
            self.get_logger().info(f'wandering {agent}: reading {agent}/scan, driving '
                                   f'{agent}/cmd_vel')

        def on_scan(self, msg):
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            forward, yaw_rate = self.wander.command(
                np.array(msg.ranges, dtype=np.float64), msg.angle_min, msg.angle_increment,
                msg.range_max, stamp)
            twist = self.Twist()
            twist.linear.x, twist.angular.z = forward, yaw_rate
            self.cmd_vel.publish(twist)

    return WanderNode


def main(args=None):
    from ball_world.tools import node_tool
    return node_tool.run(
        PROG, f'usage: {PROG} [--ros-args -p NAME:=VALUE ...]\n\n{__doc__}\n{PARAMETERS}',
        lambda: _node_class()(), (ParameterError,), args)


if __name__ == '__main__':
    sys.exit(main())
