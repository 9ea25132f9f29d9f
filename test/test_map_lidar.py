"""The lidar among a map's solid cells: every beam against an independent grid traversal.

The reference below does not walk cell by cell as core.lidar does: it lists every crossing
of the beam with every grid line up to range_max (x = origin_x + i resolution, and y), sorts
them, and looks up the cell around the midpoint between consecutive crossings; the first
solid one (everything outside the grid is solid) ends the beam at the crossing before it.
Ranges are compared as float32, as a LaserScan carries them.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from ball_world.core import lidar
from ball_world.core.solid_cells import SolidCells
from ball_world.core.static_geometry import ScanGrid
from ball_world.core.world import World
from ball_world.map_files import load_map_file

MAPS = Path(__file__).resolve().parents[1] / 'maps'
BACKENDS = ('numpy', 'numba')


def real_map(name):
    path = MAPS / f'{name}.yaml'
    assert path.exists(), f'{path} is missing: the package ships the two nav2 maps'
    return load_map_file(str(path)).solid_cells().checked()


def traversal(cells, origin, angle, range_max):
    """Reference: distance along the beam to the first solid cell (or the grid's edge),
    +inf if none within range_max, 0 from inside a solid cell."""
    px, py = origin
    dx, dy = math.cos(angle), math.sin(angle)
    res = cells.resolution

    def solid(x, y):
        column = math.floor((x - cells.origin_x) / res)
        row = math.floor((y - cells.origin_y) / res)
        return not (0 <= row < cells.rows and 0 <= column < cells.columns) \
            or bool(cells.solid[row, column])

    if solid(px, py):
        return 0.0
    reach = range_max + 2 * res
    crossings = []
    for p, d, origin_line in ((px, dx, cells.origin_x), (py, dy, cells.origin_y)):
        if abs(d) < 1e-15:
            continue
        low = math.floor((min(p, p + d * reach) - origin_line) / res)
        high = math.ceil((max(p, p + d * reach) - origin_line) / res)
        lines = origin_line + np.arange(low, high + 1) * res
        t = (lines - p) / d
        crossings.extend(t[(t > 0.0) & (t <= reach)].tolist())
    crossings = sorted(crossings) + [reach]
    for before, after in zip(crossings, crossings[1:]):
        middle = 0.5 * (before + after)
        if solid(px + middle * dx, py + middle * dy):
            return before if before <= range_max else math.inf
    return math.inf


def rep117(distance, range_min, range_max):
    return -math.inf if distance < range_min else (math.inf if distance > range_max
                                                   else distance)


def free_point(rng, cells, clearance):
    """A point in a free cell at least `clearance` from any solid cell's square."""
    free = np.argwhere(~cells.solid)
    res = cells.resolution
    while True:
        row, column = free[rng.integers(len(free))]
        x = cells.origin_x + (column + rng.uniform(0.05, 0.95)) * res
        y = cells.origin_y + (row + rng.uniform(0.05, 0.95)) * res
        k = int(math.ceil(clearance / res)) + 1
        window = np.ones((2 * k + 1, 2 * k + 1), dtype=bool)
        r0, c0 = row - k, column - k
        for j in range(2 * k + 1):
            for i in range(2 * k + 1):
                if 0 <= r0 + j < cells.rows and 0 <= c0 + i < cells.columns:
                    window[j, i] = cells.solid[r0 + j, c0 + i]
        rows, columns = np.nonzero(window)
        left = cells.origin_x + (columns + c0) * res
        bottom = cells.origin_y + (rows + r0) * res
        dxs = np.maximum(np.maximum(left - x, x - left - res), 0.0)
        dys = np.maximum(np.maximum(bottom - y, y - bottom - res), 0.0)
        if not len(rows) or np.hypot(dxs, dys).min() >= clearance:
            return np.array([x, y])


def check_scans(cells, rng, scanners, fan, balls=None):
    """Noise-free scans from random free points: every beam equals the reference traversal
    (or the nearer ball), as float32, in both backends, which agree to the bit."""
    grid = ScanGrid(cells)
    positions = np.empty((0, 2)) if balls is None else balls[0]
    radii = np.empty(0) if balls is None else balls[1]
    hits = 0
    for _ in range(scanners):
        origin = free_point(rng, cells, 0.02)
        yaw = rng.uniform(-math.pi, math.pi)
        scans = [lidar.distances(positions, radii, np.empty((0, 4)), origin, yaw, fan,
                                 backend=backend, grid=grid) for backend in BACKENDS]
        np.testing.assert_array_equal(scans[0], scans[1])
        for k, measured in enumerate(scans[1]):
            angle = yaw + fan.angle_min + k * fan.angle_increment
            expected = traversal(cells, origin, angle, fan.range_max)
            if balls is not None:
                expected = min(expected, nearest_ball(origin, angle, positions, radii))
            expected = rep117(expected, fan.range_min, fan.range_max)
            assert np.float32(measured) == np.float32(expected), (origin, yaw, k)
            hits += math.isfinite(expected)
    assert hits > 0


def nearest_ball(origin, angle, positions, radii):
    """Reference ray-circle distance (the scanner outside every ball)."""
    d = np.array([math.cos(angle), math.sin(angle)])
    m = positions - origin
    along = m @ d
    across2 = (m * m).sum(1) - along * along
    inside = radii * radii - across2
    t = along - np.sqrt(np.maximum(inside, 0.0))
    t = np.where((inside >= 0.0) & (along > 0.0), t, np.inf)
    return float(t.min()) if len(t) else math.inf


@pytest.mark.parametrize('seed', range(4))
def test_random_cells_every_beam_equals_an_independent_traversal(seed):
    rng = np.random.default_rng(seed)
    rows, columns = rng.integers(5, 60, 2)
    mask = rng.random((rows, columns)) < rng.uniform(0.02, 0.3)
    cells = SolidCells(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.choice([0.03, 0.05, 0.2]),
                       mask).checked()
    check_scans(cells, rng, 4, lidar.Fan.full_turn(360, 0.0, 12.0))


@pytest.mark.parametrize('name', ['depot', 'tb3_sandbox'])
def test_real_maps_every_beam_equals_an_independent_traversal(name):
    check_scans(real_map(name), np.random.default_rng(3), 5,
                lidar.Fan.full_turn(360, 0.12, 8.0))


def test_beams_stop_at_the_nearer_of_a_ball_and_a_cell():
    cells = real_map('depot')
    rng = np.random.default_rng(5)
    positions = np.array([free_point(rng, cells, 0.3) for _ in range(40)])
    check_scans(cells, rng, 4, lidar.Fan(-1.0, 0.01, 200, 0.0, 10.0),
                balls=(positions, np.full(40, 0.2)))


@pytest.mark.parametrize('backend', BACKENDS)
def test_a_beam_through_a_vertex_of_cells_meeting_diagonally_is_stopped(backend):
    """Two solid cells touch at (2, 2) only; a beam at 45 degrees through that vertex passes
    no free gap (the cells meet there), so it stops at the vertex."""
    mask = np.zeros((6, 6), dtype=bool)
    mask[2, 1] = mask[1, 2] = True  # row 2 col 1 and row 1 col 2: they meet at (2, 2)
    grid = ScanGrid(SolidCells(0.0, 0.0, 1.0, mask).checked())
    fan = lidar.Fan(0.0, 1.0, 1, 0.0, 10.0)
    ranges = lidar.distances(np.empty((0, 2)), np.empty(0), np.empty((0, 4)), (3.5, 3.5),
                             -0.75 * math.pi, fan, backend=backend, grid=grid)
    assert ranges[0] == pytest.approx(1.5 * math.sqrt(2.0), rel=1e-12)


@pytest.mark.parametrize('backend', BACKENDS)
def test_inside_a_solid_cell_every_range_is_zero_and_below_range_min(backend):
    mask = np.ones((3, 3), dtype=bool)
    grid = ScanGrid(SolidCells(0.0, 0.0, 1.0, mask).checked())
    fan = lidar.Fan.full_turn(8, 0.0, 5.0)
    ranges = lidar.distances(np.empty((0, 2)), np.empty(0), np.empty((0, 4)), (1.5, 1.5),
                             0.0, fan, backend=backend, grid=grid)
    assert ranges.tolist() == [0.0] * 8
    fan = lidar.Fan.full_turn(8, 0.1, 5.0)
    assert (lidar.distances(np.empty((0, 2)), np.empty(0), np.empty((0, 4)), (1.5, 1.5), 0.0,
                            fan, backend=backend, grid=grid) == -np.inf).all()


def test_a_wall_of_cells_hides_the_balls_behind_it_from_the_ground_truth():
    mask = np.zeros((20, 20), dtype=bool)
    mask[:, 10] = True  # a wall at x 1.0-1.1
    cells = SolidCells(0.0, 0.0, 0.1, mask).checked()
    world = World([[0.5, 1.0], [1.6, 1.0], [0.5, 1.6]], np.zeros((3, 2)), [0.1, 0.1, 0.1],
                  [1.0, 1.0, 1.0], solid_cells=cells)
    fan = lidar.Fan.full_turn(360, 0.15, 5.0)
    seen = lidar.seen_balls(world.positions, world.radii, world.walls, world.positions[0], 0.0,
                            fan, 0, world.static.scan_grid)
    assert seen.tolist() == [2]  # ball 1 lies behind the wall
    assert lidar.seen_balls(world.positions, world.radii, world.walls, world.positions[0], 0.0,
                            fan, 0).tolist() == [1, 2]


def test_a_scan_without_a_map_is_unchanged_by_the_empty_grid():
    rng = np.random.default_rng(9)
    positions = rng.uniform(0, 10, (50, 2))
    radii = rng.uniform(0.1, 0.3, 50)
    walls = np.array([[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 10.0]])
    fan = lidar.Fan.full_turn(360)
    for backend in BACKENDS:
        plain = lidar.distances(positions, radii, walls, positions[0], 0.4, fan, 0, backend)
        world = World(positions, np.zeros((50, 2)), radii, np.ones(50), walls=walls)
        gridded = lidar.distances(positions, radii, walls, positions[0], 0.4, fan, 0, backend,
                                  world.static.scan_grid)
        np.testing.assert_array_equal(plain, gridded)


def lattice_beams(rng, count):
    """Unit directions that make the walk's rare cases common: along the axes (a component
    exactly 0), equal components (every step through a vertex), rational slopes (vertices
    now and then) in every quadrant, and random ones; and no direction at all (meets
    nothing)."""
    directions = [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0), (0.0, 0.0)]
    half = math.sqrt(0.5)
    directions += [(sx * half, sy * half) for sx in (1, -1) for sy in (1, -1)]
    for a, b in ((1, 2), (2, 1), (1, 3), (3, 1), (2, 3), (3, 2), (1, 5), (4, 1)):
        norm = math.hypot(a, b)
        directions += [(sx * a / norm, sy * b / norm) for sx in (1, -1) for sy in (1, -1)]
    angles = rng.uniform(-math.pi, math.pi, count - len(directions))
    directions += list(zip(np.cos(angles), np.sin(angles)))
    return np.array(directions)


@pytest.mark.parametrize('seed', range(8))
def test_the_compiled_walk_equals_the_cell_by_cell_walk_to_the_bit(seed):
    """lidar_kernel.walk_beams (rounds of beams, a free square crossed at once, the cell
    reached along the other axis guessed, then confirmed or walked line by line) against
    core.lidar.first_solid, the numpy walk of one cell a round: random grids, scanners on
    cell corners, on cell edges, inside cells, in solid cells and outside the grid, beams
    through vertices and along the axes, random bounds (the nearer hit a beam already has)
    and reach."""
    if not lidar.lidar_kernel.available():
        pytest.skip('numba is not installed')
    rng = np.random.default_rng(seed)
    rows, columns = rng.integers(3, 70, 2)
    mask = rng.random((rows, columns)) < rng.uniform(0.0, 0.25)
    # Rectangles of free cells (large squares to cross) with solid rims, as in a building.
    for _ in range(3):
        r0, c0 = rng.integers(0, rows), rng.integers(0, columns)
        mask[r0:r0 + rng.integers(2, 30), c0:c0 + rng.integers(2, 30)] = False
    resolution = float(rng.choice([0.03, 0.05, 0.1, 0.25, 1.0]))
    cells = SolidCells(float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)), resolution,
                       mask).checked()
    grid = ScanGrid(cells)
    skips = lidar.lidar_kernel.free_squares(grid.solid)
    directions = lattice_beams(rng, 120)
    starts = 0
    for _ in range(30):
        # On a cell corner (through vertices on the diagonals), an edge, or anywhere; now
        # and then outside the grid.
        column = rng.integers(-2, columns + 2)
        row = rng.integers(-2, rows + 2)
        fx, fy = rng.choice([0.0, 0.5, rng.uniform()], 2)
        px = cells.origin_x + (column + fx) * resolution
        py = cells.origin_y + (row + fy) * resolution
        reach = float(rng.choice([rng.uniform(0, 1.5), 1.5]) * max(rows, columns) * resolution)
        nearer = np.where(rng.random(len(directions)) < 0.3,
                          rng.uniform(0, reach, len(directions)), np.inf)
        dx = np.ascontiguousarray(directions[:, 0])
        dy = np.ascontiguousarray(directions[:, 1])
        out = nearer.copy()
        lidar.lidar_kernel.walk_beams(px, py, dx, dy, reach, out, skips, rows, columns,
                                      grid.frame)
        walked = lidar.first_solid(px, py, dx, dy, np.minimum(nearer, reach), grid)
        expected = np.minimum(nearer, walked)
        np.testing.assert_array_equal(out, expected, err_msg=f'scanner at {px}, {py}')
        starts += np.isfinite(walked).sum() > 0
    assert starts > 0


def test_a_world_whose_agents_scan_a_map_has_its_free_squares_before_the_first_scan():
    # Issue 33: what is built from input is built with the world, before the node's start
    # line, not by the first step's scans; a world that never scans a map makes none.
    from ball_world.simulation import build
    world = {'map': str(MAPS / 'tb3_sandbox.yaml'), 'arena': [], 'random.count': 3,
             'physics.backend': 'numba'}
    scanning = build({**world, 'agents': ['ball_0']}).world.static.scan_grid
    assert scanning.skips is not None
    expected = lidar.lidar_kernel.free_squares(scanning.solid)
    assert scanning.skips.tobytes() == expected.tobytes()
    assert build(world).world.static.scan_grid.skips is None  # no agents
    assert build({**world, 'agents': ['ball_0'], 'agent.scan.samples': 0}
                 ).world.static.scan_grid.skips is None  # no scanners
