"""A Navigate-v0 policy outside its environment: the observation from what a robot has.

A trained policy runs unchanged on a robot in two places (docs/learning.md, "From training
to ROS"): as a controller in the node (ball_world.controllers.navigate, from the arrays a
controller sees) and as a ROS node of its own (ball_world_navigate, from a robot's `scan`
and `odom` messages). Both build the observation through the one function the environment's
own observation is tested against (envs.observations.navigate_observation), so a policy
sees on a robot what it saw in training, bit for bit, when the robot's lidar is the
environment's (`check_fan`) and its odometry the truth (`agent.odom.noise` all 0, the
environment's odometry).

- `from_messages(scan, odom, goal, space)`: a sensor_msgs/LaserScan and a nav_msgs/Odometry
  (the goal in the odometry's frame);
- `from_controller(obs, goals, space)`: every row of a controller's Observation;
- `check_fan(angle_min, angle_increment, beams, space)`: refuses a lidar the policy was not
  trained on, in one line naming the node's parameters to set.
"""
import math

import numpy as np

from ball_world.core.orientation import quaternion_to_yaw
from ball_world.envs.arenas import scan_angles
from ball_world.envs.observations import navigate_observation

#: How far a scan's first beam and its increment may be from the policy's, rad (a float32
#: LaserScan carries them).
ANGLE_TOLERANCE = 1e-6


class FanMismatch(ValueError):
    """A lidar other than the one the policy was trained on; the message is one line."""


def check_fan(angle_min, angle_increment, beams, space):
    """Refuse a scan of another fan than the environment's for this observation space."""
    trained = int(space['scan'].shape[0])
    first, last = scan_angles(trained)
    increment = (last - first) / (trained - 1) if trained > 1 else 0.0
    if beams != trained or abs(angle_min - first) > ANGLE_TOLERANCE or (
            trained > 1 and abs(angle_increment - increment) > ANGLE_TOLERANCE):
        raise FanMismatch(
            f'the policy was trained on {trained} beams from {first:.6g} rad every '
            f'{increment:.6g} rad; the scan has {beams} from {angle_min:.6g} every '
            f'{angle_increment:.6g}: set agent.scan.samples:={trained} '
            f'agent.scan.angle_min:={first!r} agent.scan.angle_max:={last!r}')


def from_messages(scan, odom, goal, space):
    """The observation of a robot whose latest LaserScan is `scan` and Odometry `odom`
    (goal: (x, y) in odom's header frame)."""
    check_fan(scan.angle_min, scan.angle_increment, len(scan.ranges), space)
    pose = odom.pose.pose
    q = pose.orientation
    yaw = float(quaternion_to_yaw((q.x, q.y, q.z, q.w)))
    twist = odom.twist.twist
    return navigate_observation(np.array(scan.ranges, dtype=np.float32),
                                (pose.position.x, pose.position.y, yaw), goal,
                                (twist.linear.x, twist.angular.z), space)


def from_controller(obs, goals, space):
    """The observations (a dict of arrays, a leading axis of robots) of every row of a
    controller's Observation, robot i heading for goals[i] (x, y in frame_id)."""
    count, beams = obs.scan.shape
    if count:
        angle_min, increment = obs.fan[0], obs.fan[1]
        check_fan(angle_min, increment, beams, space)
    rows = [navigate_observation(obs.scan[row], obs.truth[row], goals[row],
                                 (obs.twist[row, 0], obs.twist[row, 2]), space)
            for row in range(count)]
    keys = ('scan', 'goal', 'twist')
    if not rows:
        return {key: np.zeros((0,) + space[key].shape, dtype=np.float32) for key in keys}
    return {key: np.stack([row[key] for row in rows]) for key in keys}


def reached(position, goal, tolerance):
    """Whether (x, y) is within `tolerance` of the goal's point."""
    return math.hypot(goal[0] - position[0], goal[1] - position[1]) <= tolerance
