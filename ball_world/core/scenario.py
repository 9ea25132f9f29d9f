"""Parameters to a World: the arena, extra walls, explicit balls and random balls.

Every way a set of parameters can fail to make a valid world raises ScenarioError naming
the parameter, so the node can stop with one clear line instead of a traceback. Random
balls come from numpy's PCG64 generator seeded with `random.seed`, so the same parameters
give the same world on any machine with the same numpy.
"""
import math

import numpy as np

from ball_world.core.world import BACKENDS, numba_installed, World

#: The defaults of INTERFACE.md; config/ball_world.yaml repeats them for users.
DEFAULTS = {
    'rate_hz': 60.0,
    'dt': 0.0,
    'max_steps': 0,
    'frame_id': 'world',
    'arena': [0.0, 0.0, 10.0, 10.0],
    'walls': [],
    'balls.x': [],
    'balls.y': [],
    'balls.vx': [],
    'balls.vy': [],
    'balls.radius': [],
    'balls.mass': [],
    'random.count': 20,
    'random.seed': 0,
    'random.radius': [0.1, 0.3],
    'random.speed': 2.0,
    'random.density': 1.0,
    'publish_clock': False,
    'record.mcap': '',
    'record.rerun': '',
    'physics.backend': 'numpy',
}

BALL_FIELDS = ('balls.x', 'balls.y', 'balls.vx', 'balls.vy', 'balls.radius', 'balls.mass')

#: Placement tries per random ball before giving up on fitting them all.
PLACEMENT_TRIES = 2000


class ScenarioError(ValueError):
    """A parameter value that cannot make a valid world; `parameter` names it."""

    def __init__(self, parameter, reason):
        super().__init__(f"parameter '{parameter}': {reason}")
        self.parameter = parameter
        self.reason = reason


def _floats(params, name):
    values = params.get(name, DEFAULTS.get(name))
    try:
        array = np.array(list(values), dtype=np.float64)
    except (TypeError, ValueError):
        raise ScenarioError(name, f'expected a list of numbers, got {values!r}') from None
    bad = np.flatnonzero(~np.isfinite(array))
    if len(bad):
        raise ScenarioError(name, f'entry {bad[0]} is not finite ({array[bad[0]]})')
    return array


def _number(params, name, minimum=None, strictly_above=None):
    value = params.get(name, DEFAULTS.get(name))
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(name, f'expected a number, got {value!r}')
    if not math.isfinite(value):
        raise ScenarioError(name, f'must be finite, got {value}')
    if minimum is not None and value < minimum:
        raise ScenarioError(name, f'must be >= {minimum}, got {value}')
    if strictly_above is not None and value <= strictly_above:
        raise ScenarioError(name, f'must be > {strictly_above}, got {value}')
    return value


def step_duration_ns(params):
    """Simulated nanoseconds per step from `dt` (or 1 / `rate_hz` when dt is 0)."""
    rate = _number(params, 'rate_hz', minimum=0.0)
    dt = _number(params, 'dt', minimum=0.0)
    if dt == 0.0:
        if rate == 0.0:
            raise ScenarioError('dt', 'dt is 0 (meaning 1 / rate_hz) but rate_hz is 0 too; '
                                'set dt > 0 to run as fast as possible')
        dt = 1.0 / rate
    dt_ns = round(dt * 1e9)
    if dt_ns < 1:
        raise ScenarioError('dt', f'must be at least 1 ns, got {dt}')
    return dt_ns


def arena_walls(params):
    """The four walls of the `arena` box (bottom, right, top, left), or none."""
    arena = _floats(params, 'arena')
    if len(arena) == 0:
        return np.empty((0, 4)), None
    if len(arena) != 4:
        raise ScenarioError('arena', f'expected [xmin, ymin, xmax, ymax] or [], got {len(arena)} '
                                     'numbers')
    xmin, ymin, xmax, ymax = arena
    if not (xmin < xmax and ymin < ymax):
        raise ScenarioError('arena', f'needs xmin < xmax and ymin < ymax, got {list(arena)}')
    walls = np.array([
        [xmin, ymin, xmax, ymin],
        [xmax, ymin, xmax, ymax],
        [xmax, ymax, xmin, ymax],
        [xmin, ymax, xmin, ymin],
    ])
    return walls, arena


def extra_walls(params):
    """The `walls` parameter as (M, 4) segments of non-zero length."""
    flat = _floats(params, 'walls')
    if len(flat) % 4:
        raise ScenarioError('walls', f'expected x1, y1, x2, y2 per wall: {len(flat)} numbers is '
                                     'not a multiple of 4')
    walls = flat.reshape(-1, 4)
    for k, (x1, y1, x2, y2) in enumerate(walls):
        if x1 == x2 and y1 == y2:
            raise ScenarioError('walls', f'wall {k} has zero length')
    return walls


def _distance_to_segments(point, walls):
    start = walls[:, 0:2]
    edge = walls[:, 2:4] - start
    t = np.clip(((point - start) * edge).sum(axis=1) / (edge * edge).sum(axis=1), 0.0, 1.0)
    nearest = start + t[:, None] * edge
    return np.sqrt(((point - nearest) ** 2).sum(axis=1))


def explicit_balls(params, arena, walls):
    """The `balls.*` parameters, checked: equal lengths, positive, inside, not overlapping."""
    columns = {name: _floats(params, name) for name in BALL_FIELDS}
    n = len(columns['balls.x'])
    for name in BALL_FIELDS:
        if len(columns[name]) != n:
            raise ScenarioError(name, f'has {len(columns[name])} entries but balls.x has {n}; '
                                      'all six balls.* lists need one entry per ball')
    radius = columns['balls.radius']
    mass = columns['balls.mass']
    for name, values in (('balls.radius', radius), ('balls.mass', mass)):
        bad = np.flatnonzero(values <= 0.0)
        if len(bad):
            raise ScenarioError(name, f'ball {bad[0]} has {values[bad[0]]}; must be > 0')
    x = columns['balls.x']
    y = columns['balls.y']
    for i in range(n):
        if arena is not None:
            xmin, ymin, xmax, ymax = arena
            if not (xmin + radius[i] <= x[i] <= xmax - radius[i]
                    and ymin + radius[i] <= y[i] <= ymax - radius[i]):
                raise ScenarioError('balls.x', f'ball {i} at ({x[i]}, {y[i]}) with radius '
                                               f'{radius[i]} is not inside the arena '
                                               f'{list(arena)}')
        if len(walls):
            distance = _distance_to_segments(np.array([x[i], y[i]]), walls)
            k = int(np.argmin(distance))
            if distance[k] < radius[i]:
                raise ScenarioError('walls', f'wall {k} overlaps ball {i} at ({x[i]}, {y[i]})')
    if n > 1:
        delta = np.stack((x, y), axis=1)
        d2 = ((delta[:, None, :] - delta[None, :, :]) ** 2).sum(axis=2)
        reach = radius[:, None] + radius[None, :]
        overlap = np.argwhere(np.triu(d2 < reach * reach, k=1))
        if len(overlap):
            i, j = overlap[0]
            raise ScenarioError('balls.x', f'ball {i} overlaps ball {j}')
    positions = np.stack((x, y), axis=1)
    velocities = np.stack((columns['balls.vx'], columns['balls.vy']), axis=1)
    return positions, velocities, radius, mass


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


def random_balls(params, arena, walls, placed):
    """`random.count` balls placed uniformly in the arena, overlapping nothing."""
    count = params.get('random.count', DEFAULTS['random.count'])
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise ScenarioError('random.count', f'must be a whole number >= 0, got {count!r}')
    seed = params.get('random.seed', DEFAULTS['random.seed'])
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ScenarioError('random.seed', f'must be a whole number >= 0, got {seed!r}')
    radius_range = _floats(params, 'random.radius')
    if len(radius_range) != 2 or not (0.0 < radius_range[0] <= radius_range[1]):
        raise ScenarioError('random.radius', f'expected [min, max] with 0 < min <= max, got '
                                             f'{list(radius_range)}')
    speed = _number(params, 'random.speed', minimum=0.0)
    density = _number(params, 'random.density', strictly_above=0.0)
    empty = (np.empty((0, 2)), np.empty((0, 2)), np.empty(0), np.empty(0))
    if count == 0:
        return empty
    if arena is None:
        raise ScenarioError('random.count', f'{count} random balls need an arena to be placed '
                                            'in; set arena or random.count: 0')
    xmin, ymin, xmax, ymax = arena
    rmin, rmax = radius_range
    if 2 * rmin > min(xmax - xmin, ymax - ymin):
        raise ScenarioError('random.radius', f'balls of radius {rmin} do not fit in the arena')
    positions, velocities, radii, masses = placed
    occupancy = _Occupancy(2.0 * max(rmax, float(radii.max()) if len(radii) else rmax))
    for (x, y), r in zip(positions, radii):
        occupancy.add(float(x), float(y), float(r))

    rng = np.random.default_rng(seed)
    out = np.empty((count, 6))
    for i in range(count):
        r = float(rng.uniform(rmin, rmax))
        for _ in range(PLACEMENT_TRIES):
            x = float(rng.uniform(xmin + r, max(xmin + r, xmax - r)))
            y = float(rng.uniform(ymin + r, max(ymin + r, ymax - r)))
            if occupancy.overlaps(x, y, r):
                continue
            if len(walls) and _distance_to_segments(np.array([x, y]), walls).min() < r:
                continue
            break
        else:
            raise ScenarioError('random.count', f'placed only {i} of {count} random balls '
                                                'without overlap; lower random.count or '
                                                'random.radius, or enlarge the arena')
        occupancy.add(x, y, r)
        heading = float(rng.uniform(0.0, 2.0 * math.pi))
        magnitude = float(rng.uniform(0.0, speed))
        out[i] = (x, y, magnitude * math.cos(heading), magnitude * math.sin(heading), r,
                  density * math.pi * r * r)
    return out[:, 0:2], out[:, 2:4], out[:, 4], out[:, 5]


def build_world(params):
    """Build the World the parameters describe, or raise ScenarioError naming the culprit."""
    box, arena = arena_walls(params)
    walls = extra_walls(params)
    explicit = explicit_balls(params, arena, walls)
    extra = random_balls(params, arena, walls, explicit)
    positions, velocities, radii, masses = (
        np.concatenate((a, b)) for a, b in zip(explicit, extra))
    return World(positions, velocities, radii, masses, walls=np.concatenate((box, walls)),
                 backend=physics_backend(params))


def physics_backend(params):
    """The `physics.backend` parameter, checked: 'numpy', or 'numba' where it is installed."""
    backend = params.get('physics.backend', DEFAULTS['physics.backend'])
    if backend not in BACKENDS:
        raise ScenarioError('physics.backend', f'expected one of {", ".join(BACKENDS)}, got '
                                               f'{backend!r}')
    if backend == 'numba' and not numba_installed():
        raise ScenarioError('physics.backend', "'numba' needs the numba package (pip install "
                                               'numba); use numpy')
    return backend


def describe(world, dt_ns):
    """One readable line about a world, for the node's start-up log."""
    n = len(world)
    if n:
        radii = f'radius {world.radii.min():.3g}-{world.radii.max():.3g} m, '
    else:
        radii = ''
    return (f'{n} balls ({radii}kinetic energy {world.kinetic_energy():.6g} J), '
            f'{len(world.walls)} walls, dt {dt_ns / 1e9:.6g} s')
