"""An exact 2D laser scanner: the ranges a beam fan from a point sees among balls and walls.

What it computes: for each beam, the true distance from the scanner to the first ball, wall
or solid map cell the beam meets (ray-circle and ray-segment intersection in closed form,
`core.lidar_kernel`; a map's cells by a walk of its grid, where the distance is the closed
form of the first solid cell's edge), the scanner's own ball excluded. Then REP 117's
conventions for a sensor_msgs/LaserScan: +inf when nothing lies within range_max, -inf when
the first thing is closer than range_min. Then, if asked, Gaussian noise on the ranges that
are neither.

Two backends, one answer: `numpy` is the reference, every beam against every ball that can
be within range_max (vectorised, in chunks); `numba` tests each ball only against the beams
of its sector (`lidar_kernel.scan_sectors`). They evaluate the same closed forms and keep the
smallest, so they agree bit for bit, as the step's backends do; `test/test_lidar.py` checks
it.

Noise is reproducible: its generator is seeded by the world's `random.seed`, a stable hash
of the scanner's entity name (SHA-256, not Python's salted hash()) and the step number,
so a re-simulation draws the same noise for the same scan, whatever else ran before it.
No ROS and no I/O here; the node turns a scan into a LaserScan.
"""
import hashlib
import math
from typing import NamedTuple

import numpy as np

from ball_world.core import lidar_kernel, noise_seed
from ball_world.core.lidar_kernel import (circle_terms, crossing, rotate, segment_terms,
                                          start_cell)
from ball_world.core.static_geometry import ScanGrid
from ball_world.core.stepping import resolve_backend

#: Most (beam, ball) pairs the numpy reference evaluates at once (memory, not speed).
CHUNK_PAIRS = 1 << 20
#: A scan without a map: no cells to walk.
NO_MAP = ScanGrid()


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
        if not 0.0 <= self.range_min <= self.range_max or self.range_max <= 0.0:
            raise ValueError(f'scanner range_min {self.range_min:g} m must be >= 0 and at '
                             f'most range_max {self.range_max:g} m, which must be > 0')
        if self.noise_stddev < 0.0:
            raise ValueError(f'scanner noise_stddev {self.noise_stddev:g} m is negative')
        return self


def body_directions(fan):
    """Unit directions (cos, sin) of the fan's beams in the scanner's frame."""
    angles = fan.angle_min + np.arange(fan.samples) * fan.angle_increment
    return np.cos(angles), np.sin(angles)


def beam_directions(yaw, fan):
    """Unit directions (dx, dy) of the beams in the world frame, for a heading `yaw`: the
    body directions turned by yaw, with the kernel's own `rotate` (so the same bits)."""
    bx, by = body_directions(fan)
    return rotate(math.cos(yaw), math.sin(yaw), bx, by)


def _nearest(positions, radii, walls, grid, origin, cos_yaw, sin_yaw, body, exclude,
             range_max):
    """Each beam against every ball that can be within range_max and every wall, then along
    the map's cells (`grid`, a core.static_geometry.ScanGrid) up to that hit: the distance
    to the nearest hit (+inf for none) and the ball it is (-1: a wall, a map cell, or
    none)."""
    px, py = float(origin[0]), float(origin[1])
    dx, dy = rotate(cos_yaw, sin_yaw, body[0], body[1])
    near = (np.abs(positions[:, 0] - px) <= range_max + radii) & (
        np.abs(positions[:, 1] - py) <= range_max + radii)
    if 0 <= exclude < len(near):
        near[exclude] = False
    chosen = np.flatnonzero(near)
    cx = np.take(positions[:, 0], chosen)
    cy = np.take(positions[:, 1], chosen)
    r = np.take(radii, chosen)
    best = np.full(len(dx), np.inf)
    ball = np.full(len(dx), -1)
    rows = max(1, CHUNK_PAIRS // max(len(chosen), len(walls), 1))
    for start in range(0, len(dx), rows):
        part = slice(start, start + rows)
        ux = dx[part, None]
        uy = dy[part, None]
        if len(chosen):
            t_near, ahead, inside = circle_terms(px, py, ux, uy, cx, cy, r)
            hits = np.where(inside, 0.0, np.where(ahead, t_near, np.inf))
            first = hits.argmin(axis=1)
            best[part] = np.take_along_axis(hits, first[:, None], axis=1)[:, 0]
            ball[part] = np.where(np.isfinite(best[part]), np.take(chosen, first), -1)
        if len(walls):
            with np.errstate(divide='ignore', invalid='ignore'):
                t, hit = segment_terms(px, py, ux, uy, walls[:, 0], walls[:, 1], walls[:, 2],
                                       walls[:, 3])
            wall = np.where(hit, t, np.inf).min(axis=1)
            ball[part] = np.where(wall < best[part], -1, ball[part])
            best[part] = np.minimum(best[part], wall)
    if not grid.empty:
        cells = first_solid(px, py, dx, dy, np.minimum(best, range_max), grid)
        ball = np.where(cells < best, -1, ball)
        best = np.minimum(best, cells)
    return best, ball


def first_solid(px, py, dx, dy, bound, grid):
    """The reference walk of the map's cells: for each beam from (px, py) along the unit
    (dx[k], dy[k]), the distance to where it first enters a solid cell (or leaves the grid),
    if at most bound[k]; +inf otherwise; 0 from inside a solid cell.

    Amanatides and Woo's walk, every beam one cell per round, vectorised over the beams:
    each crossing is the closed form of its grid line (`lidar_kernel.crossing`), and a
    beam through a vertex (crossings of both axes equal) is stopped if any of the three
    cells it touches there is solid. `lidar_kernel.walk_beams` computes the same distances,
    crossing free squares at once.
    """
    solid = grid.solid
    origin_x, origin_y, resolution = (float(value) for value in grid.frame)
    ci = int(start_cell(px, origin_x, resolution))
    cj = int(start_cell(py, origin_y, resolution))
    out = np.full(len(dx), np.inf)
    if _solid_at(solid, np.array([ci]), np.array([cj]))[0]:
        out[:] = 0.0
        return out
    sx = np.sign(dx).astype(np.int64)
    sy = np.sign(dy).astype(np.int64)
    nx = np.where(sx > 0, ci + 1, ci)
    ny = np.where(sy > 0, cj + 1, cj)
    with np.errstate(divide='ignore', invalid='ignore'):
        ix = np.where(sx != 0, 1.0 / dx, 0.0)
        iy = np.where(sy != 0, 1.0 / dy, 0.0)
    tx = np.where(sx != 0, crossing(origin_x, nx, resolution, px, ix), np.inf)
    ty = np.where(sy != 0, crossing(origin_y, ny, resolution, py, iy), np.inf)
    beam = np.arange(len(dx))
    ci = np.full(len(dx), ci)
    cj = np.full(len(dx), cj)
    bound = np.asarray(bound, dtype=np.float64)
    while len(beam):
        t = np.minimum(tx, ty)
        going = t <= bound
        step_x = going & (tx <= ty)
        step_y = going & (ty <= tx)
        tie = step_x & step_y
        # Through a vertex: the cells beside the diagonal one count too.
        touched = tie & (_solid_at(solid, ci + sx, cj) | _solid_at(solid, ci, cj + sy))
        ci = ci + np.where(step_x, sx, 0)
        cj = cj + np.where(step_y, sy, 0)
        hit = going & (touched | _solid_at(solid, ci, cj))
        out[beam[hit]] = t[hit]
        nx = nx + np.where(step_x, sx, 0)
        ny = ny + np.where(step_y, sy, 0)
        tx = np.where(step_x, crossing(origin_x, nx, resolution, px, ix), tx)
        ty = np.where(step_y, crossing(origin_y, ny, resolution, py, iy), ty)
        keep = np.flatnonzero(going & ~hit)
        beam, ci, cj, nx, ny, tx, ty, sx, sy, ix, iy, bound = (
            np.take(a, keep) for a in (beam, ci, cj, nx, ny, tx, ty, sx, sy, ix, iy, bound))
    return out


def _solid_at(solid, i, j):
    """Whether cells (column i, row j) are solid (arrays); everything outside the grid is."""
    inside = (i >= 0) & (j >= 0) & (j < solid.shape[0]) & (i < solid.shape[1])
    value = np.ones(len(i), dtype=bool)
    value[inside] = solid[j[inside], i[inside]] != 0
    return value


def distances_numpy(positions, radii, walls, grid, origin, cos_yaw, sin_yaw, body, exclude,
                    range_min, range_max):
    """The reference: each beam against every ball that can be within range_max (and every
    wall, and the map's cells), the nearest hit kept; REP 117's infinities."""
    best, _ = _nearest(positions, radii, walls, grid, origin, cos_yaw, sin_yaw, body, exclude,
                       range_max)
    best[best < range_min] = -np.inf
    best[best > range_max] = np.inf
    return best


def distances_numba(positions, radii, walls, grid, origin, cos_yaw, sin_yaw, body, exclude,
                    range_min, range_max):
    """The compiled scan by sectors: the same ranges as distances_numpy."""
    out = np.empty(len(body[0]))
    lidar_kernel.scan_sectors(positions, radii, walls, grid.solid, _skips(grid), grid.frame,
                              float(origin[0]), float(origin[1]), cos_yaw, sin_yaw, body[0],
                              body[1], body[2], body[3], int(exclude), range_min, range_max,
                              out)
    return out


def ball_cells(positions, radii, reach):
    """The balls sorted into square cells for scan_agents: (cell_first, cell_balls, grid).

    The side is at least reach + the largest radius (so a ball a beam can meet within reach
    lies in its scanner's cell or a neighbour), and grows past it rather than make more
    cells than about the balls' count (a few balls far apart, a short reach). grid: x0, y0,
    side, columns, rows; cell (i, j) is i * rows + j, and holds cell_balls[cell_first[c]:
    cell_first[c + 1]] (ball indices)."""
    count = len(positions)
    if count == 0:
        return np.zeros(2, dtype=np.int64), np.zeros(0, dtype=np.int64), np.array(
            [0.0, 0.0, 1.0, 1.0, 1.0])
    low = positions.min(axis=0)
    extent = positions.max(axis=0) - low
    side = float(reach + radii.max())
    side = max(side, math.sqrt(float(extent[0]) * float(extent[1]) / count),
               float(extent.max()) / max(count, 1)) * (1.0 + 1e-9) + 1e-300
    x0, y0 = float(low[0]), float(low[1])
    columns = int(math.floor(float(extent[0]) / side)) + 1
    rows = int(math.floor(float(extent[1]) / side)) + 1
    # The kernel's expression, element by element, so ball and scanner agree on cells.
    i = np.clip(np.floor((positions[:, 0] - x0) / side).astype(np.int64), 0, columns - 1)
    j = np.clip(np.floor((positions[:, 1] - y0) / side).astype(np.int64), 0, rows - 1)
    keys = i * rows + j
    order = np.argsort(keys, kind='stable')
    first = np.zeros(columns * rows + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys, minlength=columns * rows), out=first[1:])
    return first, order.astype(np.int64), np.array([x0, y0, side, columns, rows],
                                                   dtype=np.float64)


def scan_many(positions, radii, walls, agents, yaws, fan, range_mins, backend='auto',
              grid=NO_MAP, pool=None, then=None):
    """The noiseless scans (A, samples) of the balls `agents` (indices), each from its centre
    at heading yaws[a] with range_min range_mins[a] and the fan's beams and range_max, its
    own ball excluded: row a equals Scanner(fan).distances(...) of that agent, bit for bit.

    numpy: one scan per agent (the reference); numba: one compiled call for all of them,
    the balls sorted into cells (ball_cells) so that a short range tests only the balls
    near each scanner (lidar_kernel.scan_agents).

    `pool` (None, or an object with `threads`, a count, and `run(function, items)`, which
    calls function on every item on its threads and returns when all are done): numba's
    call split into runs of agents (`agent_runs`) that its threads scan at once. The
    kernel holds no GIL, and each agent's scan reads only the shared scene and writes only
    its own row, so the rows are the same bits whatever thread made them.

    `then` (None, or a function of (low, high, rows)): called on each run's thread as soon
    as its scans are made, with the run's agents low:high and their rows of the result, for
    work on each scan alone (their noise: scans.AgentScans) to be shared by the threads too;
    with the numpy backend, once for all the rows."""
    positions = _float_array(positions).reshape(-1, 2)
    radii = _float_array(radii)
    walls = _segments(walls)
    agents = np.ascontiguousarray(agents, dtype=np.int64)
    yaws = _float_array(yaws)
    range_mins = _float_array(range_mins)
    body = body_directions(fan) + (float(fan.angle_min), float(fan.angle_increment))
    out = np.empty((len(agents), fan.samples))
    if resolve_backend(backend) == 'numpy':
        for row, (ball, yaw, low) in enumerate(zip(agents.tolist(), yaws.tolist(),
                                                   range_mins.tolist())):
            out[row] = distances_numpy(positions, radii, walls, grid, positions[ball],
                                       math.cos(yaw), math.sin(yaw), body, ball, low,
                                       fan.range_max)
        if then is not None:
            then(0, len(agents), out)
        return out
    first, balls, cells = ball_cells(positions, radii, fan.range_max)
    # math's cos and sin, as Scanner.distances takes them (numpy's may differ in the last
    # bit where it has vector versions of its own).
    headings = yaws.tolist()
    cos = np.array([math.cos(yaw) for yaw in headings])
    sin = np.array([math.sin(yaw) for yaw in headings])
    skips = _skips(grid)

    def scan(run):
        low, high = run
        lidar_kernel.scan_agents(positions, radii, walls, grid.solid, skips, grid.frame,
                                 first, balls, cells, agents[low:high], cos[low:high],
                                 sin[low:high], body[0], body[1], body[2], body[3],
                                 range_mins[low:high], float(fan.range_max), out[low:high])
        if then is not None:
            then(low, high, out[low:high])

    runs = agent_runs(len(agents), fan.samples, 1 if pool is None else pool.threads)
    if len(runs) == 1:
        scan(runs[0])
    else:
        pool.run(scan, runs)
    return out


#: Least beams (agents x samples) a run of agent_runs holds: a run's scans must cost far
#: more than handing it to a thread (tens of microseconds): 5,000 beams are 0.3-0.5 ms of
#: 12 m scans in the warehouse or of 2 m rings (docs/performance.md). One robot's scan
#: (360 beams) is never shared; 100 robots' are.
MIN_RUN_BEAMS = 5_000
#: Runs per thread: scans differ in cost (a beam down an aisle, a crowd of balls), so each
#: thread takes several runs in turn rather than one long one that may finish last.
RUNS_PER_THREAD = 4


def agent_runs(count, samples, threads):
    """[(low, high), ...]: `count` agents' scans cut into runs for `threads` threads, one
    run when there is one thread or the scans are too few to share (one robot's scan never
    waits on a thread)."""
    runs = min(threads * RUNS_PER_THREAD, count * samples // MIN_RUN_BEAMS) if threads > 1 else 1
    runs = max(runs, 1)
    edges = [count * k // runs for k in range(runs + 1)]
    return list(zip(edges[:-1], edges[1:]))


def _skips(grid):
    """The grid's free squares (lidar_kernel.free_squares), made the first time the
    compiled scan walks it (or prepare_grid asks) and kept with it."""
    if grid.skips is None:
        grid.skips = lidar_kernel.free_squares(grid.solid)
    return grid.skips


def prepare_grid(grid):
    """Make a map's free squares now (core.static_geometry.ScanGrid), so that the first
    scan does not: a world whose agents scan builds them before the node says it started
    (0.32 s at 4096 x 4096 cells)."""
    _skips(grid)


_DISTANCES = {'numpy': distances_numpy, 'numba': distances_numba}


class Scanner:
    """One scanner: its fan, its backend and its noise, ready to scan often.

    What is fixed for a scanner (body directions, the backend) is worked out once, so a scan
    costs the kernel and little else. `name` and `seed` choose the noise, with the step.
    """

    def __init__(self, fan, backend='auto', seed=0, name=''):
        self.fan = fan.check()
        self.backend = resolve_backend(backend)
        self._distances = _DISTANCES[self.backend]
        # (x, y, angle_min, increment): the beams' body directions and the angles they were
        # made from (the numba scan picks each object's beams by angle).
        self.body = body_directions(fan) + (float(fan.angle_min), float(fan.angle_increment))
        self.seed = int(seed)
        self.key = name_key(name)
        self.noise = (noise_seed.NoiseSeeds(self.seed, self.key) if fan.noise_stddev > 0.0
                      else None)

    def distances(self, positions, radii, walls, origin, yaw, exclude=-1, grid=NO_MAP):
        """REP 117 ranges without noise: the closed forms. positions (N, 2) and radii (N,)
        float64, walls a Walls or (M, 4) segments, grid the map's cells (a
        core.static_geometry.ScanGrid: a World's `static.scan_grid`; NO_MAP for none)."""
        fan = self.fan
        return self._distances(_float_array(positions), _float_array(radii), _segments(walls),
                               grid, origin, math.cos(yaw), math.sin(yaw), self.body, exclude,
                               fan.range_min, fan.range_max)

    def scan(self, positions, radii, walls, origin, yaw, exclude=-1, step=0, grid=NO_MAP):
        """One scan as LaserScan's `ranges`: the closed forms plus the noise of this step."""
        ranges = self.distances(positions, radii, walls, origin, yaw, exclude, grid)
        if self.fan.noise_stddev > 0.0:
            # default_rng([seed, key, step])'s numbers, made in a third of its time
            add_noise(ranges, self.fan.noise_stddev, self.noise.generator(step))
        return ranges


def _float_array(values):
    """values as a C-contiguous float64 array (no copy when it already is one)."""
    return np.ascontiguousarray(values, dtype=np.float64)


def _segments(walls):
    """A Walls' (or an array's) segments as (M, 4) C-contiguous float64: the array itself
    when it already is one, since typing a fresh reshaped view cost the compiled scan ~1 us
    (measured), a tenth of a scan at 1,000 balls."""
    segments = _float_array(getattr(walls, 'segments', walls))
    if segments.ndim == 2 and segments.shape[1] == 4:
        return segments
    return segments.reshape(-1, 4)


def name_key(name):
    """A stable 64-bit number for an entity name (the same in every process and run)."""
    return int.from_bytes(hashlib.sha256(name.encode('utf-8')).digest()[:8], 'little')


def add_noise(ranges, stddev, rng):
    """Gaussian noise of `stddev` metres on every finite range, in place; returns ranges.

    One draw per beam, hit or not, so a beam's noise does not depend on what the others
    hit. A noisy range may leave [range_min, range_max] by a few stddev; it is kept (not
    clipped, which would bias the mean), as real scanners report it.
    """
    if stddev > 0.0:
        noise = rng.normal(0.0, stddev, len(ranges))
        np.add(ranges, noise, out=ranges, where=np.isfinite(ranges))  # no masked copies
    return ranges


def scan(positions, radii, walls, origin, yaw, fan, exclude=-1, backend='auto', seed=0,
         name='', step=0, grid=NO_MAP):
    """One scan as LaserScan's `ranges`: exact distances, REP 117's infinities, seeded noise
    (see Scanner, which keeps what a scanner scanning often can)."""
    return Scanner(fan, backend, seed, name).scan(positions, radii, walls, origin, yaw,
                                                  exclude, step, grid)


def distances(positions, radii, walls, origin, yaw, fan, exclude=-1, backend='auto',
              grid=NO_MAP):
    """scan() without noise: each range equals its closed form."""
    return Scanner(fan, backend).distances(positions, radii, walls, origin, yaw, exclude, grid)


def seen_balls(positions, radii, walls, origin, yaw, fan, exclude=-1, grid=NO_MAP):
    """Indices of the balls that at least one beam meets first, within [range_min,
    range_max], without noise: the balls this scanner can see (ground truth for scoring);
    the map's cells (`grid`) hide what lies behind them."""
    walls = _segments(walls)
    best, ball = _nearest(_float_array(positions).reshape(-1, 2), _float_array(radii), walls,
                          grid, origin, math.cos(yaw), math.sin(yaw), body_directions(fan),
                          exclude, fan.range_max)
    return np.unique(ball[(ball >= 0) & (best >= fan.range_min) & (best <= fan.range_max)])


def hit_points(origin, yaw, fan, ranges):
    """World coordinates (K, 2) of the finite ranges' end points (for drawing a scan)."""
    dx, dy = beam_directions(yaw, fan)
    finite = np.flatnonzero(np.isfinite(ranges))
    r = np.take(ranges, finite)
    return np.column_stack((origin[0] + r * np.take(dx, finite),
                            origin[1] + r * np.take(dy, finite)))


def warm():
    """Compile (or load) the numba scan kernel and noise kernels, when numba is installed."""
    if lidar_kernel.available():
        lidar_kernel.warm()
        noise_seed.warm()
