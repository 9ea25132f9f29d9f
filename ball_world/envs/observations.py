"""What a robot sees, as Gymnasium spaces and as arrays: its scan, its goal and its twist.

One function (`observe`) builds the observation of any number of robot rows from plain arrays
(ranges, goal distances and bearings, forward speeds, yaw rates), and `navigate_observation`
builds one robot's from what a controller or a node reading the robot's scan and odom has
(ranges, pose, goal, twist) through it, so all of them share the same arithmetic.

- `scan` (beams,) float32: the lidar's ranges in m, beam 0 straight behind, counter-clockwise
  over a whole turn; REP 117's +inf (nothing within range_max) as range_max, its -inf
  (closer than range_min) as 0, and every range clipped to [0, range_max] (noise may push
  one a little beyond).
- `goal` (2,) float32: the distance to the goal, m (at most the world's diagonal), and its
  bearing in the robot's
  base_link, rad in [-pi, pi] (counter-clockwise from straight ahead).
- `twist` (2,) float32: the robot's forward speed (its world velocity along its heading,
  m/s, as odom's twist.linear.x; within the world's speed limit) and its yaw rate (rad/s,
  as twist.angular.z).
"""
import math

import gymnasium
import numpy as np

FLOAT = np.float32


def observation_space(fan, limits, reach, speed):
    """The Dict space of one robot's observation: `reach` bounds a goal's distance (the
    world's diagonal) and `speed` the forward speed (the world's speed limit, which no ball
    passes), so every bound is finite."""
    pi = FLOAT(math.pi)
    return gymnasium.spaces.Dict({
        'scan': gymnasium.spaces.Box(FLOAT(0.0), FLOAT(fan.range_max), (fan.samples,), FLOAT),
        'goal': gymnasium.spaces.Box(np.array([0.0, -pi], FLOAT),
                                     np.array([reach, pi], FLOAT), dtype=FLOAT),
        'twist': gymnasium.spaces.Box(np.array([-speed, -limits.max_yaw_rate], FLOAT),
                                      np.array([speed, limits.max_yaw_rate], FLOAT),
                                      dtype=FLOAT),
    })


def action_space(limits):
    """One robot's action: (forward speed m/s, yaw rate rad/s) within its limits."""
    return gymnasium.spaces.Box(np.array([-limits.max_speed, -limits.max_yaw_rate], FLOAT),
                                np.array([limits.max_speed, limits.max_yaw_rate], FLOAT),
                                dtype=FLOAT)


def goal_terms(positions, yaws, goals):
    """(distance (n,), bearing (n,)) of each goal from each robot, in its base_link."""
    dx = goals[:, 0] - positions[:, 0]
    dy = goals[:, 1] - positions[:, 1]
    cos, sin = np.cos(yaws), np.sin(yaws)
    return np.hypot(dx, dy), np.arctan2(cos * dy - sin * dx, cos * dx + sin * dy)


def forward_speeds(yaws, velocities):
    """Each robot's world velocity (n, 2) along its heading: odom's twist.linear.x."""
    return np.cos(yaws) * velocities[:, 0] + np.sin(yaws) * velocities[:, 1]


def observe(ranges, range_max, distance, bearing, forward, yaw_rates, reach, speed):
    """The observations of n robots as a dict of arrays with a leading axis of n (distance
    and forward speed clipped to the space's bounds `reach` and `speed`)."""
    scan = np.nan_to_num(ranges, posinf=range_max, neginf=0.0)
    np.clip(scan, 0.0, range_max, out=scan)
    return {'scan': scan.astype(FLOAT),
            'goal': np.stack((np.minimum(distance, reach), bearing), axis=1).astype(FLOAT),
            'twist': np.stack((np.clip(forward, -speed, speed), yaw_rates),
                              axis=1).astype(FLOAT)}


def navigate_observation(ranges, pose, goal, twist, space):
    """One robot's Navigate-v0 observation from plain arrays, as the environment builds it.

    ranges: the scan's ranges (float32 as a LaserScan carries them, or float64; REP 117's
    infinities allowed), beam 0 straight behind, counter-clockwise; pose: the robot's
    (x, y, yaw) and goal: the goal's (x, y), both in one frame (the world's, or the robot's
    odom frame with the goal put into it); twist: (v, w), the forward speed (odom's
    twist.linear.x) and the yaw rate (twist.angular.z); space: the environment's
    observation space (env.observation_space, or a loaded policy's), whose float32 bounds
    clip the range, the distance and the speed exactly as the environment's own bounds do.
    Returns the dict of float32 arrays a policy of Navigate-v0 takes.
    """
    x, y, yaw = (float(value) for value in pose)
    scan = np.array(ranges, dtype=np.float64).reshape(1, -1)
    if scan.shape[1] != space['scan'].shape[0]:
        raise ValueError(f'{scan.shape[1]} ranges for a {space["scan"].shape[0]}-beam scan')
    distance, bearing = goal_terms(np.array([[x, y]]), np.array([yaw]),
                                   np.array([[float(goal[0]), float(goal[1])]]))
    forward, yaw_rate = (float(value) for value in twist)
    observed = observe(scan, float(space['scan'].high[0]), distance, bearing,
                       np.array([forward]), np.array([yaw_rate]),
                       float(space['goal'].high[0]), float(space['twist'].high[0]))
    return {key: value[0] for key, value in observed.items()}
