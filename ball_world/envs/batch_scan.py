"""The scans of K worlds' robots in one compiled call: core.lidar_kernel's scan, world by world.

Why: a vector env scans once per world per step, and each scan through core.lidar.Scanner
pays a few microseconds of Python and of numba's dispatch around a kernel of about as many;
one call for all K pays them once. Each world's scan is the same kernel call with the same
arguments Scanner.distances gives it (the heading's cos and sin by math.cos and math.sin, the
scanner's body directions, the world's walls and map cells), so the ranges are the node's bit
for bit; the noise is added after, all robots in one call (core.noise_kernel: the draws of
Scanner's own generator, seeded by the episode's noise seed, the robot's name and the physics
step, as Scanner.scan adds them).

Without numba (core.lidar's numpy reference), `scan_worlds` is None and the caller scans
robot by robot through Scanner.scan: the same ranges.
"""
import math

import numpy as np

from ball_world.core import lidar, lidar_kernel
from ball_world.core.stepping import numba_installed


def _scan_worlds(positions, radii, walls, solid, skips, frame, origins, cos_yaw, sin_yaw, bx,
                 by, angle_min, increment, excludes, range_min, reach, out):
    """out[k]: lidar_kernel.scan_sectors of world k (positions[k], radii[k]) from origins[k]
    at the heading (cos_yaw[k], sin_yaw[k]), ball excludes[k] unseen."""
    for k in range(positions.shape[0]):
        lidar_kernel.scan_sectors(positions[k], radii[k], walls, solid, skips, frame,
                                  origins[k, 0], origins[k, 1], cos_yaw[k], sin_yaw[k], bx, by,
                                  angle_min, increment, excludes[k], range_min, reach, out[k])


if numba_installed():
    from numba import njit
    scan_worlds = njit(cache=True, nogil=True, error_model='numpy')(_scan_worlds)
else:
    scan_worlds = None


class BatchScanner:
    """Scans one robot in each of K worlds that share their walls and map (one fan)."""

    def __init__(self, fan, walls, grid):
        self.fan = fan
        body = lidar.body_directions(fan)
        self.bx = np.ascontiguousarray(body[0])
        self.by = np.ascontiguousarray(body[1])
        self.walls = np.ascontiguousarray(walls, dtype=np.float64).reshape(-1, 4)
        self.solid = grid.solid
        self.frame = grid.frame
        self.skips = lidar_kernel.free_squares(grid.solid)

    def ranges(self, positions, radii, origins, yaws, excludes):
        """(K, beams) REP 117 ranges without noise: positions (K, B, 2), radii (K, B),
        origins (K, 2), yaws (K,), excludes (K,) int64."""
        fan = self.fan
        out = np.empty((len(positions), fan.samples))
        cos_yaw = np.array([math.cos(yaw) for yaw in yaws.tolist()])
        sin_yaw = np.array([math.sin(yaw) for yaw in yaws.tolist()])
        scan_worlds(positions, radii, self.walls, self.solid, self.skips, self.frame, origins,
                    cos_yaw, sin_yaw, self.bx, self.by, float(fan.angle_min),
                    float(fan.angle_increment), excludes, fan.range_min, fan.range_max, out)
        return out
