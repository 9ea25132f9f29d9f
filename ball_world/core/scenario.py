"""Parameters to a World: the arena, extra walls, explicit balls and random balls.

Every way a set of parameters can fail to make a valid world raises ScenarioError naming
the parameter, so the node can stop with one clear line instead of a traceback. Values are
first checked one by one against the parameter table (core.parameters), then as a world:
balls inside the arena and clear of walls and of each other, radii and masses within the
limits (core.limits), and no ball able to go faster than the world can step.

Building is O(N) in time and memory: overlaps are found with the broadphase grid, never
with an N x N matrix, so the largest world (limits.MAX_BALLS) builds in about a second.

Random balls come from numpy's PCG64 generator seeded with `random.seed`, so the same
parameters give the same world on any machine with the same numpy. The random numbers are
drawn in blocks, but consumed in the same order and transformed with the same arithmetic as
one `rng.uniform(low, high)` call each, so worlds are identical to those of earlier versions.

A map (`map`, core.occupancy_map) adds solid cells: explicit balls may not overlap them (nor
reach outside the grid), and random balls go in free cells (inside `arena` if one is given):
a free cell is drawn uniformly, then a point uniformly inside it, so the balls are uniform
over the free area and the same seed gives the same world. The world is built from the
loaded map, never from files: the node loads it once, a re-simulation from the recording.
"""
import math
from typing import NamedTuple, Optional

import numpy as np

from ball_world.core import limits
from ball_world.core.broadphase import grid_pairs, wall_pairs
from ball_world.core.parameters import (BALL_FIELDS, checked, DEFAULTS, list_text,
                                        number_text, ParameterError)
from ball_world.core.solid_cells import CellQueries
from ball_world.core.static_geometry import check_run_count
from ball_world.core.world import BACKENDS, numba_installed, Walls, World

#: ScenarioError is the parameter table's error: a world is refused by naming a parameter.
ScenarioError = ParameterError

__all__ = ['BALL_FIELDS', 'build_scene', 'build_world', 'DEFAULTS', 'describe', 'Scene',
           'ScenarioError', 'step_duration_ns']

#: Placement tries per random ball before giving up on fitting them all.
PLACEMENT_TRIES = 2000
#: Tries for all random balls together, per ball: a nearly full arena fails in bounded time.
PLACEMENT_TRIES_PER_BALL = 100
#: Random balls are refused at once when their expected area would exceed this fraction of
#: the arena: random sequential placement jams near 0.547, so the tries would only fail.
MAX_RANDOM_AREA_FRACTION = 0.5
#: Random numbers drawn per block while placing balls.
_DRAW_BLOCK = 8192


def step_duration_ns(params):
    """Simulated nanoseconds per step from `dt` (or 1 / `rate_hz` when dt is 0).

    dt is kept in whole nanoseconds, rounded to the nearest and at least 1 ns, so every value
    in dt's range runs; step k ends at exactly k * dt_ns.
    """
    params = checked(params)
    rate = params['rate_hz']
    dt = params['dt']
    if dt == 0.0:
        if rate == 0.0:
            raise ScenarioError('dt', 'dt is 0 (meaning 1 / rate_hz) but rate_hz is 0 too; '
                                'set dt > 0 to run as fast as possible')
        dt = 1.0 / rate
        if dt > limits.MAX_DT:
            raise ScenarioError('rate_hz', f'{number_text(rate)} Hz with dt 0 means steps of '
                                           f'{dt:.3g} s, longer than the {limits.MAX_DT:g} s '
                                           'a step may last; set dt or raise rate_hz')
    return max(1, round(dt * 1e9))


def arena_walls(params):
    """The four walls of the `arena` box (bottom, right, top, left), or none."""
    return _arena_walls(checked(params))


def _arena_walls(params):
    arena = params['arena']
    if not arena:
        return np.empty((0, 4)), None
    xmin, ymin, xmax, ymax = arena  # ordered: the parameter table checks it
    walls = np.array([
        [xmin, ymin, xmax, ymin],
        [xmax, ymin, xmax, ymax],
        [xmax, ymax, xmin, ymax],
        [xmin, ymax, xmin, ymin],
    ])
    return walls, arena


def _extra_walls(params):
    """The `walls` parameter as (M, 4) segments, each at least MIN_WALL_LENGTH long."""
    walls = np.array(params['walls'], dtype=np.float64).reshape(-1, 4)
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    short = np.flatnonzero(~(lengths >= limits.MIN_WALL_LENGTH))
    if len(short):
        k = int(short[0])
        raise ScenarioError('walls', f'wall {k} {list_text(walls[k])} is '
                                     f'{number_text(lengths[k])} m long; walls must be at least '
                                     f'{number_text(limits.MIN_WALL_LENGTH)} m')
    return walls


def _first_wall_overlap(positions, radii, walls):
    """(ball, wall) of the first ball closer to a wall than its radius, or None."""
    if len(positions) == 0 or len(walls) == 0:
        return None
    balls, indices = wall_pairs(positions, radii, Walls(walls), 0.0)
    if len(balls) == 0:
        return None
    first = int(np.argmin(balls))
    return int(balls[first]), int(indices[first])


def _first_ball_overlap(positions, radii):
    """(i, j) of the first pair of overlapping balls (i < j, lowest i then j), or None."""
    a, b, _ = grid_pairs(positions, radii, 0.0)
    if len(a) == 0:
        return None
    first = int(np.lexsort((b, a))[0])
    return int(a[first]), int(b[first])


def _explicit_balls(params, arena, walls, cells):
    """The `balls.*` parameters, checked: equal lengths, inside, not overlapping."""
    columns = {name: np.array(params[name], dtype=np.float64) for name in BALL_FIELDS}
    n = len(columns['balls.x'])
    for name in BALL_FIELDS:
        if len(columns[name]) != n:
            raise ScenarioError(name, f'has {len(columns[name])} entries but balls.x has {n}; '
                                      'all six balls.* lists need one entry per ball (set them '
                                      'one by one: the world is checked at ~/reset)')
    x = columns['balls.x']
    y = columns['balls.y']
    radius = columns['balls.radius']
    if arena is not None and n:
        xmin, ymin, xmax, ymax = arena
        outside = np.flatnonzero(~((xmin + radius <= x) & (x <= xmax - radius)
                                   & (ymin + radius <= y) & (y <= ymax - radius)))
        if len(outside):
            i = int(outside[0])
            raise ScenarioError('balls.x', f'ball {i} at ({number_text(x[i])}, '
                                           f'{number_text(y[i])}) with radius '
                                           f'{number_text(radius[i])} is not inside the arena '
                                           f'{list_text(arena)}')
    positions = np.stack((x, y), axis=1)
    if cells is not None:
        hit = cells.first_overlapping_ball(positions, radius)
        if hit is not None:
            i, what = hit
            raise ScenarioError('balls.x', f'ball {i} at ({number_text(x[i])}, '
                                           f'{number_text(y[i])}) with radius '
                                           f'{number_text(radius[i])} overlaps '
                                           f'{cells.describe(what)}')
    overlap = _first_wall_overlap(positions, radius, walls)
    if overlap is not None:
        i, k = overlap
        raise ScenarioError('walls', f'wall {k} overlaps ball {i} at ({number_text(x[i])}, '
                                     f'{number_text(y[i])})')
    overlap = _first_ball_overlap(positions, radius)
    if overlap is not None:
        raise ScenarioError('balls.x', f'ball {overlap[0]} overlaps ball {overlap[1]}')
    velocities = np.stack((columns['balls.vx'], columns['balls.vy']), axis=1)
    return positions, velocities, radius, columns['balls.mass']


class _Occupancy:
    """A dict of grid cells holding placed balls, for O(1) overlap checks while placing."""

    def __init__(self, cell):
        self.cell = cell
        self.cells = {}

    def _key(self, x, y):
        return (math.floor(x / self.cell), math.floor(y / self.cell))

    def add(self, x, y, r):
        self.cells.setdefault(self._key(x, y), []).append((x, y, r))

    def overlaps(self, x, y, r):
        cx, cy = self._key(x, y)
        for ix in (cx - 1, cx, cx + 1):
            for iy in (cy - 1, cy, cy + 1):
                for (ox, oy, orad) in self.cells.get((ix, iy), ()):
                    reach = r + orad
                    if (x - ox) ** 2 + (y - oy) ** 2 < reach * reach:
                        return True
        return False


class _Uniform:
    """rng.uniform(low, high) one number at a time, drawn from the generator in blocks.

    numpy computes uniform(low, high) as low + (high - low) * u with u the next double of
    the generator; doing the same with u taken from rng.random(block) gives the same
    numbers, without a numpy call per number.
    """

    def __init__(self, rng):
        self._rng = rng
        self._block = []
        self._next = 0

    def __call__(self, low, high):
        if self._next == len(self._block):
            self._block = self._rng.random(_DRAW_BLOCK).tolist()
            self._next = 0
        u = self._block[self._next]
        self._next += 1
        return low + (high - low) * u


def clear_of_walls(x, y, r, walls):
    """Whether a ball at (x, y) of radius r keeps at least r from every wall segment."""
    start = walls[:, 0:2]
    edge = walls[:, 2:4] - start
    t = np.clip(((x - start[:, 0]) * edge[:, 0] + (y - start[:, 1]) * edge[:, 1])
                / (edge[:, 0] ** 2 + edge[:, 1] ** 2), 0.0, 1.0)
    dx = x - (start[:, 0] + t * edge[:, 0])
    dy = y - (start[:, 1] + t * edge[:, 1])
    return bool(np.all(dx * dx + dy * dy >= r * r))


class _Region(NamedTuple):
    """Where random balls go: the arena box, or a map's free cells (inside the arena)."""

    name: str  # 'the arena', "the map's free area"
    area: float  # m^2
    cells: Optional[CellQueries]  # the map's, or None
    free: Optional[np.ndarray]  # flat indices of the free cells to draw from


def _region(params, arena, cells):
    count = params['random.count']
    if cells is None:
        if arena is None:
            raise ScenarioError('random.count', f'{count} random balls need an arena to be '
                                                'placed in; set arena or random.count: 0')
        xmin, ymin, xmax, ymax = arena
        return _Region('the arena', (xmax - xmin) * (ymax - ymin), None, None)
    name = "the map's free area" + (' inside the arena' if arena is not None else '')
    free = cells.free(arena)
    if not len(free):
        raise ScenarioError('random.count', f'{count} random balls need free cells, and '
                                            f'{name} is empty; set random.count: 0')
    return _Region(name, cells.free_area(arena), cells, free)


def _inside(arena, x, y, r):
    xmin, ymin, xmax, ymax = arena
    return xmin + r <= x <= xmax - r and ymin + r <= y <= ymax - r


def _random_balls(params, arena, walls, placed, cells=None):
    """`random.count` balls placed uniformly in the arena or the map's free cells,
    overlapping nothing."""
    count = params['random.count']
    rmin, rmax = params['random.radius']
    speed = params['random.speed']
    density = params['random.density']
    empty = (np.empty((0, 2)), np.empty((0, 2)), np.empty(0), np.empty(0))
    if count == 0:
        return empty
    region = _region(params, arena, cells)
    for r in (rmin, rmax):
        mass = density * math.pi * r * r
        if not limits.MIN_MASS <= mass <= limits.MAX_MASS:
            raise ScenarioError('random.density', f'gives a ball of radius {number_text(r)} m '
                                                  f'a mass of {mass:.3g} kg, outside '
                                                  f'{number_text(limits.MIN_MASS)} to '
                                                  f'{number_text(limits.MAX_MASS)} kg')
    if arena is not None:
        xmin, ymin, xmax, ymax = arena
        if 2 * rmin > min(xmax - xmin, ymax - ymin):
            raise ScenarioError('random.radius', f'balls of radius {number_text(rmin)} do not '
                                                 'fit in the arena')
    mean_area = math.pi * (rmax ** 3 - rmin ** 3) / (3 * (rmax - rmin)) if rmax > rmin \
        else math.pi * rmin * rmin
    fraction = count * mean_area / region.area
    if fraction > MAX_RANDOM_AREA_FRACTION:
        raise ScenarioError('random.count', f'{count:,} random balls would cover about '
                                            f'{fraction:.0%} of {region.name}; random '
                                            f'placement cannot fit more than '
                                            f'{MAX_RANDOM_AREA_FRACTION:.0%}: lower '
                                            'random.count or random.radius, or enlarge '
                                            f'{region.name}')
    positions, _, radii, _ = placed
    occupancy = _Occupancy(2.0 * max(rmax, float(radii.max()) if len(radii) else rmax))
    for (x, y), r in zip(positions.tolist(), radii.tolist()):
        occupancy.add(x, y, r)

    uniform = _Uniform(np.random.default_rng(params['random.seed']))
    budget = PLACEMENT_TRIES_PER_BALL * count + PLACEMENT_TRIES
    out = np.empty((count, 6))
    for i in range(count):
        r = uniform(rmin, rmax)
        for _ in range(min(PLACEMENT_TRIES, budget)):
            budget -= 1
            if cells is None:
                x = uniform(xmin + r, max(xmin + r, xmax - r))
                y = uniform(ymin + r, max(ymin + r, ymax - r))
            else:
                x, y = _in_free_cell(uniform, region)
                if arena is not None and not _inside(arena, x, y, r):
                    continue
                if cells.first_overlap(x, y, r) is not None:
                    continue
            if occupancy.overlaps(x, y, r):
                continue
            if len(walls) and not clear_of_walls(x, y, r, walls):
                continue
            break
        else:
            raise ScenarioError('random.count', f'placed only {i} of {count} random balls '
                                                'without overlap; lower random.count or '
                                                f'random.radius, or enlarge {region.name}')
        occupancy.add(x, y, r)
        heading = uniform(0.0, 2.0 * math.pi)
        magnitude = uniform(0.0, speed)
        out[i] = (x, y, magnitude * math.cos(heading), magnitude * math.sin(heading), r,
                  density * math.pi * r * r)
    return out[:, 0:2], out[:, 2:4], out[:, 4], out[:, 5]


def _in_free_cell(uniform, region):
    """A point drawn uniformly in a free cell drawn uniformly (uniform over the free area)."""
    free = region.free
    pick = min(int(uniform(0.0, float(len(free)))), len(free) - 1)
    row, column = divmod(int(free[pick]), region.cells.cells.columns)
    cells = region.cells.cells
    x = cells.origin_x + (column + uniform(0.0, 1.0)) * cells.resolution
    y = cells.origin_y + (row + uniform(0.0, 1.0)) * cells.resolution
    return x, y


def _check_world_limits(params, box, walls, explicit_count, radii):
    """Counts and radius spread of the whole world against core.limits."""
    total = explicit_count + params['random.count']
    if total > limits.MAX_BALLS:
        name = 'random.count' if params['random.count'] else 'balls.x'
        raise ScenarioError(name, f'{explicit_count:,} explicit and '
                                  f'{params["random.count"]:,} random balls make '
                                  f'{total:,}; a world holds at most {limits.MAX_BALLS:,}')
    if len(box) + len(walls) > limits.MAX_WALLS:
        raise ScenarioError('walls', f'{len(walls)} walls and the arena make '
                                     f'{len(box) + len(walls)}; a world holds at most '
                                     f'{limits.MAX_WALLS}')
    if len(radii) and radii.max() > limits.MAX_RADIUS_RATIO * radii.min():
        name = 'random.radius' if params['random.count'] else 'balls.radius'
        raise ScenarioError(name, f'radii from {number_text(radii.min())} to '
                                  f'{number_text(radii.max())} m differ by more than '
                                  f'{limits.MAX_RADIUS_RATIO:g} times, the most one world '
                                  'can hold')


def _check_speeds(world, params, dt_ns):
    """No ball may ever be faster than the world can step (limits.MAX_SUBSTEPS)."""
    limit = world.speed_limit(dt_ns * 1e-9)
    reachable = world.reachable_speed()
    if reachable <= limit:
        return
    name = 'balls.vx' if len(params['balls.x']) else 'random.speed'
    raise ScenarioError(name, f'the balls carry enough energy for one of them to reach '
                              f'{reachable:.3g} m/s, faster than the {limit:.3g} m/s this '
                              f'world can step in {limits.MAX_SUBSTEPS:,} substeps (a quarter '
                              'of the smallest radius per substep); lower the speeds or dt, '
                              'or raise the smallest radius or mass')


class Scene(NamedTuple):
    """A built world and what placing balls in it asks of its map (None without one)."""

    world: World
    cells: Optional[CellQueries]


def build_world(params, occupancy_map=None):
    """Build the World the parameters describe, or raise ScenarioError naming the culprit.

    occupancy_map: the loaded map (core.occupancy_map.OccupancyMap) when `map` names one.
    """
    return build_scene(params, occupancy_map).world


def map_cells(params, occupancy_map):
    """CellQueries of the map's solid cells (None without a map), checked against `map`."""
    params = checked(params)
    if not params['map']:
        return None
    if occupancy_map is None:
        raise ScenarioError('map', 'names a map, but none was loaded (the world is built from '
                                   "the map's files read by ball_world.map_files, or from a "
                                   "recording's copy)")
    cells = occupancy_map.solid_cells(params['map.unknown_solid'])
    try:  # before anything the runs' number decides is built
        check_run_count(cells)
    except ValueError as error:
        raise ScenarioError('map', str(error)) from None
    return CellQueries(cells)


def build_scene(params, occupancy_map=None):
    """The World the parameters describe and its map's CellQueries (see build_world)."""
    params = checked(params)
    dt_ns = step_duration_ns(params)
    box, arena = _arena_walls(params)
    walls = _extra_walls(params)
    explicit_count = len(params['balls.x'])
    rmin, rmax = params['random.radius']
    radii_bound = np.array(params['balls.radius']
                           + ([rmin, rmax] if params['random.count'] else []))
    _check_world_limits(params, box, walls, explicit_count, radii_bound)
    cells = map_cells(params, occupancy_map)
    explicit = _explicit_balls(params, arena, walls, cells)
    extra = _random_balls(params, arena, walls, explicit, cells)
    positions, velocities, radii, masses = (
        np.concatenate((a, b)) for a, b in zip(explicit, extra))
    if params['physics.mode'] == 'exact' and not numba_installed():
        raise ScenarioError('physics.mode', "'exact' needs the numba package (pip install "
                                            "numba); use 'seed'")
    world = World(positions, velocities, radii, masses, walls=np.concatenate((box, walls)),
                  backend=_physics_backend(params), mode=params['physics.mode'],
                  solid_cells=None if cells is None else cells.cells)
    _check_speeds(world, params, dt_ns)
    return Scene(world, cells)


def physics_backend(params):
    """The `physics.backend` parameter, checked: 'numpy', or 'numba' where it is installed."""
    return _physics_backend(checked(params))


def _physics_backend(params):
    backend = params['physics.backend']
    if backend == 'auto':
        return 'numba' if numba_installed() else 'numpy'
    if backend not in BACKENDS:
        raise ScenarioError('physics.backend', f'expected one of {", ".join(BACKENDS)}, got '
                                               f'{backend!r}')
    if backend == 'numba' and not numba_installed():
        raise ScenarioError('physics.backend', "'numba' needs the numba package (pip install "
                                               "numba); use 'numpy' or 'auto'")
    return backend


def describe(world, dt_ns):
    """One readable line about a world, for the node's start-up log."""
    n = len(world)
    if n:
        radii = f'radius {world.radii.min():.3g}-{world.radii.max():.3g} m, '
    else:
        radii = ''
    return (f'{n} balls ({radii}kinetic energy {world.kinetic_energy():.6g} J), '
            f'{len(world.walls)} walls, dt {dt_ns / 1e9:.6g} s, {world.backend} backend')
