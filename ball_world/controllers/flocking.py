"""Reynolds' boids (Computer Graphics 21(4), 1987) for diff-drive robots: a flock.

Each robot steers towards the sum of three wishes computed from the robots within
NEIGHBOUR_RADIUS of it (their true poses: a flock needs every robot's neighbours, which is
why a swarm's controller sees all its robots at once): keep apart from those closer than
SEPARATION (separation), head as they head (alignment) and move to their centre
(cohesion); and a fourth from its own scan, away from walls and balls within AVOID_DISTANCE.
The wished direction becomes a turn rate (proportional to the heading error, clamped) and a
speed that slows while the turn is large. Neighbours are found with a k-d tree
(scipy.spatial.cKDTree), so a call costs O(N log N): 10,000 robots in a few milliseconds.
"""
import numpy as np
from scipy.spatial import cKDTree

NEIGHBOUR_RADIUS = 3.0  # m
SEPARATION = 0.6  # m
WEIGHTS = {'separation': 1.5, 'alignment': 1.0, 'cohesion': 0.6, 'avoid': 2.0}
CRUISE_SPEED = 0.5  # m/s
TURN_GAIN = 2.0  # rad/s per rad of heading error
MAX_TURN = 2.0  # rad/s
AVOID_DISTANCE = 0.6  # m


class Flocking:
    """Separation, alignment, cohesion and avoidance (module docstring)."""

    def act(self, obs):
        xy, yaw = obs.truth[:, :2], obs.truth[:, 2]
        heading = np.column_stack((np.cos(yaw), np.sin(yaw)))
        wish = heading.copy()  # with nobody near: keep going
        pairs = cKDTree(xy).query_pairs(NEIGHBOUR_RADIUS, output_type='ndarray')
        if len(pairs):
            wish += self._flock(xy, heading, pairs)
        wish += WEIGHTS['avoid'] * self._avoid(obs, heading)
        wished = np.arctan2(wish[:, 1], wish[:, 0])
        error = np.arctan2(np.sin(wished - yaw), np.cos(wished - yaw))
        commands = np.zeros((len(yaw), 3))
        commands[:, 0] = CRUISE_SPEED * np.clip(np.cos(error), 0.0, 1.0)
        commands[:, 2] = np.clip(TURN_GAIN * error, -MAX_TURN, MAX_TURN)
        return commands

    @staticmethod
    def _flock(xy, heading, pairs):
        """The separation, alignment and cohesion wishes (N, 2) from neighbour pairs."""
        count = len(xy)
        first, second = pairs[:, 0], pairs[:, 1]
        offset = xy[second] - xy[first]  # from first to second
        distance = np.hypot(offset[:, 0], offset[:, 1])
        neighbours = np.bincount(first, minlength=count) + np.bincount(second, minlength=count)
        centre = np.zeros((count, 2))
        np.add.at(centre, first, offset)
        np.add.at(centre, second, -offset)
        align = np.zeros((count, 2))
        np.add.at(align, first, heading[second])
        np.add.at(align, second, heading[first])
        close = distance < SEPARATION
        push = np.zeros((count, 2))
        away = offset[close] / np.maximum(distance[close], 1e-9)[:, None] ** 2
        np.add.at(push, first[close], -away)
        np.add.at(push, second[close], away)
        some = np.maximum(neighbours, 1)[:, None]
        return (WEIGHTS['separation'] * push + WEIGHTS['alignment'] * align / some
                + WEIGHTS['cohesion'] * centre / some)

    @staticmethod
    def _avoid(obs, heading):
        """Away from each scan's beams closer than AVOID_DISTANCE, weighted by closeness,
        in the world frame (N, 2)."""
        count, beams = obs.scan.shape
        if beams == 0:
            return np.zeros((count, 2))
        angles = obs.fan[0] + obs.fan[1] * np.arange(beams)
        ranges = np.nan_to_num(obs.scan.astype(np.float64), nan=np.inf, neginf=0.0)
        weight = np.clip(AVOID_DISTANCE - ranges, 0.0, None) / AVOID_DISTANCE
        forward = -(weight * np.cos(angles)).sum(axis=1)  # body frame: away from the hits
        left = -(weight * np.sin(angles)).sum(axis=1)
        cos, sin = heading[:, 0], heading[:, 1]
        return np.column_stack((cos * forward - sin * left, sin * forward + cos * left))
