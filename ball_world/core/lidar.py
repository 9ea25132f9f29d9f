"""An exact 2D laser scanner: the ranges a beam fan from a point sees among balls and walls.

What it computes: for each beam, the true distance from the scanner to the first ball or
wall the beam meets (ray-circle and ray-segment intersection in closed form,
`core.lidar_kernel`), the scanner's own ball excluded. Then REP 117's conventions for a
sensor_msgs/LaserScan: +inf when nothing lies within range_max, -inf when the first thing is
closer than range_min. Then, if asked, Gaussian noise on the ranges that are neither.

Two backends, one answer: `numpy` is the reference, every beam against every ball that can
be within range_max (vectorised, in chunks); `numba` walks each beam through a grid
(`lidar_kernel.scan_grid`). They evaluate the same closed forms and keep the smallest, so
they agree bit for bit, as the step's backends do; `test/test_lidar.py` checks it.

Noise is reproducible: its generator is seeded by the world's `random.seed`, a stable hash
of the scanner's entity name (SHA-256, not Python's salted hash()) and the step number,
so a re-simulation draws the same noise for the same scan, whatever else ran before it.
No ROS and no I/O here; the node turns a scan into a LaserScan.
"""
import hashlib
import math
from typing import NamedTuple

import numpy as np

from ball_world.core import lidar_kernel
from ball_world.core.lidar_kernel import circle_terms, segment_terms
from ball_world.core.stepping import resolve_backend

#: Most (beam, ball) pairs the numpy reference evaluates at once (memory, not speed).
CHUNK_PAIRS = 1 << 20


class Fan(NamedTuple):
    """What a scanner is: its beams (body frame, rad), its limits (m) and its noise (m).

    Beam k points at angle_min + k * angle_increment from the scanner's heading, as in
    sensor_msgs/LaserScan.
    """

    angle_min: float
    angle_increment: float
    samples: int
    range_min: float
    range_max: float
    noise_stddev: float = 0.0

    @classmethod
    def full_turn(cls, samples=360, range_min=0.1, range_max=12.0, noise_stddev=0.0):
        """`samples` beams evenly over a whole turn from -pi (a common 2D lidar)."""
        return cls(-math.pi, 2.0 * math.pi / samples, samples, range_min, range_max,
                   noise_stddev)

    @property
    def angle_max(self):
        """Angle of the last beam, as LaserScan's angle_max."""
        return self.angle_min + (self.samples - 1) * self.angle_increment

    def check(self):
        """Raise ValueError naming the first value that cannot make a scanner."""
        values = (self.angle_min, self.angle_increment, self.range_min, self.range_max,
                  self.noise_stddev)
        if not all(math.isfinite(value) for value in values):
            raise ValueError(f'scanner values must be finite: {self}')
        if self.samples < 1:
            raise ValueError(f'a scanner needs at least one beam, not {self.samples}')
        if not 0.0 <= self.range_min < self.range_max:
            raise ValueError(f'scanner range_min {self.range_min:g} m must be >= 0 and below '
                             f'range_max {self.range_max:g} m')
        if self.noise_stddev < 0.0:
            raise ValueError(f'scanner noise_stddev {self.noise_stddev:g} m is negative')
        return self


def beam_directions(yaw, fan):
    """Unit directions (dx, dy) of the beams in the world frame, for a heading `yaw`.

    Computed once here and handed to either backend, so that both see the same bits
    (numpy's and numba's cos and sin are not promised to round alike).
    """
    angles = yaw + (fan.angle_min + np.arange(fan.samples) * fan.angle_increment)
    return np.cos(angles), np.sin(angles)


def _walls_array(walls):
    """Wall segments as a contiguous (M, 4) float64 array, from a Walls or an array."""
    segments = getattr(walls, 'segments', walls)
    return np.ascontiguousarray(np.asarray(segments, dtype=np.float64).reshape(-1, 4))


def distances_numpy(positions, radii, walls, origin, directions, exclude, reach):
    """The reference: distance to the first hit of each beam, +inf beyond `reach`."""
    px, py = float(origin[0]), float(origin[1])
    dx, dy = directions
    near = (np.abs(positions[:, 0] - px) <= reach + radii) & (
        np.abs(positions[:, 1] - py) <= reach + radii)
    if 0 <= exclude < len(near):
        near[exclude] = False
    chosen = np.flatnonzero(near)
    cx = np.take(positions[:, 0], chosen)
    cy = np.take(positions[:, 1], chosen)
    r = np.take(radii, chosen)
    best = np.full(len(dx), np.inf)
    rows = max(1, CHUNK_PAIRS // max(len(chosen), 1))
    for start in range(0, len(dx), rows):
        ux = dx[start:start + rows, None]
        uy = dy[start:start + rows, None]
        if len(chosen):
            t_near, ahead, inside = circle_terms(px, py, ux, uy, cx, cy, r)
            hits = np.where(inside, 0.0, np.where(ahead, t_near, np.inf))
            best[start:start + rows] = hits.min(axis=1)
        if len(walls):
            with np.errstate(divide='ignore', invalid='ignore'):
                t, hit = segment_terms(px, py, ux, uy, walls[:, 0], walls[:, 1], walls[:, 2],
                                       walls[:, 3])
            best[start:start + rows] = np.minimum(best[start:start + rows],
                                                  np.where(hit, t, np.inf).min(axis=1))
    best[best > reach] = np.inf
    return best


def distances_numba(positions, radii, walls, origin, directions, exclude, reach):
    """The compiled walk through a grid: the same distances as distances_numpy."""
    out = np.empty(len(directions[0]))
    lidar_kernel.scan_grid(np.ascontiguousarray(positions, dtype=np.float64),
                           np.ascontiguousarray(radii, dtype=np.float64), walls,
                           float(origin[0]), float(origin[1]), directions[0], directions[1],
                           int(exclude), float(reach), out)
    return out


_DISTANCES = {'numpy': distances_numpy, 'numba': distances_numba}


def distances(positions, radii, walls, origin, yaw, fan, exclude=-1, backend='auto'):
    """True distance along each beam of `fan` from `origin` (heading `yaw`) to the first ball
    or wall, +inf where there is none within fan.range_max; ball `exclude` is not seen."""
    directions = beam_directions(yaw, fan)
    return _DISTANCES[resolve_backend(backend)](
        np.asarray(positions, dtype=np.float64).reshape(-1, 2),
        np.asarray(radii, dtype=np.float64).reshape(-1), _walls_array(walls), origin,
        directions, exclude, fan.range_max)


def rep117(distances_, fan):
    """Ranges as REP 117 wants them: -inf where the first hit is closer than range_min
    (+inf, nothing within range_max, is already there)."""
    ranges = np.array(distances_, dtype=np.float64)
    ranges[ranges < fan.range_min] = -np.inf
    return ranges


def name_key(name):
    """A stable 64-bit number for an entity name (the same in every process and run)."""
    return int.from_bytes(hashlib.sha256(name.encode('utf-8')).digest()[:8], 'little')


def noise_generator(seed, name, step):
    """The generator of one scan's noise: seeded by (seed, name_key(name), step)."""
    return np.random.default_rng([int(seed), name_key(name), int(step)])


def add_noise(ranges, stddev, rng):
    """Gaussian noise of `stddev` metres on every finite range, in place; returns ranges.

    One draw per beam, hit or not, so a beam's noise does not depend on what the others
    hit. A noisy range may leave [range_min, range_max] by a few stddev; it is kept (not
    clipped, which would bias the mean), as real scanners report it.
    """
    if stddev > 0.0:
        noise = rng.normal(0.0, stddev, len(ranges))
        finite = np.isfinite(ranges)
        ranges[finite] += noise[finite]
    return ranges


def scan(positions, radii, walls, origin, yaw, fan, exclude=-1, backend='auto', seed=0,
         name='', step=0):
    """One scan as LaserScan's `ranges`: exact distances, REP 117's infinities, seeded noise.

    `name` and `step` (with `seed`) choose the noise; with fan.noise_stddev 0 they do not
    matter and the ranges are the closed forms.
    """
    ranges = rep117(distances(positions, radii, walls, origin, yaw, fan, exclude, backend),
                    fan)
    if fan.noise_stddev > 0.0:
        add_noise(ranges, fan.noise_stddev, noise_generator(seed, name, step))
    return ranges


def hit_points(origin, yaw, fan, ranges):
    """World coordinates (K, 2) of the finite ranges' end points (for drawing a scan)."""
    dx, dy = beam_directions(yaw, fan)
    finite = np.flatnonzero(np.isfinite(ranges))
    r = np.take(ranges, finite)
    return np.column_stack((origin[0] + r * np.take(dx, finite),
                            origin[1] + r * np.take(dy, finite)))


def warm():
    """Compile (or load) the numba scan kernel, when numba is installed."""
    if lidar_kernel.available():
        lidar_kernel.warm()
