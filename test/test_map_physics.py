"""Balls among a map's solid cells, in seed mode and exact mode (World(solid_cells=...)).

References are closed forms (a bounce off a cell's edge, off a convex corner, into a room's
corner), the definition of overlap (distance from a centre to each solid square, or past the
grid's edge, everything outside being solid), and the world without the map. The two real
nav2 maps are the package's copies (maps/), read with the package's loader.
"""
import dataclasses
import math
from pathlib import Path

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

from ball_world.core.solid_cells import SolidCells
from ball_world.core.stepping import travel_per_substep
from ball_world.core.world import World
from ball_world.map_files import load_map_file

MAPS = Path(__file__).resolve().parents[1] / 'maps'
BACKENDS = ('numpy', 'numba')


def real_map(name):
    """The solid cells of one of the package's nav2 maps (unknown counts as solid)."""
    path = MAPS / f'{name}.yaml'
    assert path.exists(), f'{path} is missing: the package ships the two nav2 maps'
    return load_map_file(str(path)).solid_cells().checked()


def penetration(positions, radii, cells):
    """Reference: for each ball, its radius minus its centre's distance to the nearest solid
    square or to the grid's edge (positive: the ball overlaps the solid region)."""
    res = cells.resolution
    k = int(math.ceil(float(radii.max()) / res)) + 1
    offsets = np.arange(-k, k + 1)
    column = np.floor((positions[:, 0] - cells.origin_x) / res).astype(int)
    row = np.floor((positions[:, 1] - cells.origin_y) / res).astype(int)
    columns = column[:, None, None] + offsets[None, None, :]
    rows = row[:, None, None] + offsets[None, :, None]
    columns, rows = np.broadcast_arrays(columns, rows)
    inside = (columns >= 0) & (rows >= 0) & (columns < cells.columns) & (rows < cells.rows)
    solid = np.ones(columns.shape, dtype=bool)
    solid[inside] = cells.solid[rows[inside], columns[inside]]
    left = cells.origin_x + columns * res
    bottom = cells.origin_y + rows * res
    x = positions[:, 0, None, None]
    y = positions[:, 1, None, None]
    dx = np.maximum(np.maximum(left - x, x - (left + res)), 0.0)
    dy = np.maximum(np.maximum(bottom - y, y - (bottom + res)), 0.0)
    depth = np.where(solid, radii[:, None, None] - np.hypot(dx, dy), -np.inf)
    edge = np.minimum.reduce([positions[:, 0] - cells.origin_x,
                              cells.origin_x + cells.columns * res - positions[:, 0],
                              positions[:, 1] - cells.origin_y,
                              cells.origin_y + cells.rows * res - positions[:, 1]])
    return np.maximum(depth.reshape(len(positions), -1).max(axis=1), radii - edge)


def pair_overlap(positions, radii):
    """Largest (R_a + R_b - distance) over pairs."""
    d = np.hypot(*(positions[:, None] - positions[None]).transpose(2, 0, 1))
    sigma = radii[:, None] + radii[None]
    np.fill_diagonal(d, np.inf)
    return float((sigma - d).max()) if len(positions) > 1 else -np.inf


def free_balls(rng, cells, count, radii, speed):
    """Balls placed at random in the free space of `cells`, overlapping nothing."""
    res = cells.resolution
    free = np.argwhere(~cells.solid)
    positions = []
    kept = []
    for pick in rng.permutation(len(free)):
        row, column = free[pick]
        point = np.array([cells.origin_x + (column + rng.uniform(0, 1)) * res,
                          cells.origin_y + (row + rng.uniform(0, 1)) * res])
        radius = radii[len(kept)]
        if penetration(point[None], np.array([radius]), cells)[0] > -1e-6:
            continue
        if any(np.hypot(*(point - q)) < radius + radii[j] + 1e-6
               for q, j in zip(positions, kept)):
            continue
        positions.append(point)
        kept.append(len(kept))
        if len(kept) == count:
            break
    positions = np.array(positions).reshape(-1, 2)
    heading = rng.uniform(0.0, 2.0 * math.pi, len(positions))
    velocities = speed * np.stack((np.cos(heading), np.sin(heading)), axis=1)
    return positions, velocities, np.array(radii[:len(positions)])


def block_map():
    """A 5 m square room (0.5 m cells, origin 0) with a solid block at x 3-4, y 1.5-3.5."""
    mask = np.zeros((10, 10), dtype=bool)
    mask[3:7, 6:8] = True
    return SolidCells(0.0, 0.0, 0.5, mask).checked()


# Closed forms ---------------------------------------------------------------------------------

def test_exact_bounce_off_a_cell_edge_at_the_contact_time():
    world = World([[1.0, 2.5]], [[3.0, 0.0]], [0.2], [1.0], mode='exact',
                  solid_cells=block_map())
    stats = world.step(1.0)
    # Contact when the centre reaches x = 3.0 - 0.2 after 0.6 s; 0.4 s back at 3 m/s.
    assert stats.ball_wall == 1
    assert world.velocities.tolist() == [[-3.0, 0.0]]
    np.testing.assert_allclose(world.positions, [[2.8 - 1.2, 2.5]], rtol=0, atol=1e-12)


def test_a_ball_listed_clear_of_a_wall_still_bounces_when_it_reaches_it():
    """The compiled step skips a ball's walls while it stands clear of them (numba_backend's
    wall_clearance): a ball that starts 0.15 m from the block, inside the lists' skin (0.4 m
    here), reaches it long before its list is searched again, so only the clearance running
    out lets the step see the contact. It must bounce on the same step, to the bit, as in the
    numpy backend, which tests every listed wall every substep."""
    runs = {}
    for backend in BACKENDS:
        world = World([[2.65, 2.5]], [[1.0, 0.0]], [0.2], [1.0], backend=backend,
                      solid_cells=block_map())
        runs[backend] = []
        for _ in range(30):
            world.step(0.01)
            runs[backend].append((world.positions.tolist(), world.velocities.tolist()))
            assert world.positions[0, 0] + 0.2 < 3.0 + travel_per_substep(0.2)
        assert world.velocities.tolist() == [[-1.0, 0.0]], backend
    assert runs['numba'] == runs['numpy']


@pytest.mark.parametrize('backend', BACKENDS)
def test_seed_bounce_off_a_cell_edge_reverses_the_normal_velocity(backend):
    world = World([[1.0, 2.5]], [[3.0, 0.0]], [0.2], [1.0], backend=backend,
                  solid_cells=block_map())
    for _ in range(60):
        world.step(1.0 / 60.0)
        assert world.positions[0, 0] + 0.2 < 3.0 + travel_per_substep(0.2)
    assert world.velocities.tolist() == [[-3.0, 0.0]]


def test_exact_bounce_off_a_convex_corner_about_the_corner_to_centre_normal():
    """The block's lower left corner (3.0, 1.5); the ball passes 0.1 m below its level, so
    its disc meets the corner point itself."""
    radius, below, speed = 0.2, 0.1, 3.0
    world = World([[1.0, 1.5 - below]], [[speed, 0.0]], [radius], [1.0], mode='exact',
                  solid_cells=block_map())
    world.step(1.0)
    gap = math.sqrt(radius ** 2 - below ** 2)
    contact = np.array([3.0 - gap, 1.5 - below])
    normal = (contact - [3.0, 1.5]) / radius
    velocity = np.array([speed, 0.0])
    after = velocity - 2.0 * velocity.dot(normal) * normal
    t_contact = (contact[0] - 1.0) / speed
    np.testing.assert_allclose(world.velocities[0], after, rtol=0, atol=1e-12)
    np.testing.assert_allclose(world.positions[0], contact + after * (1.0 - t_contact),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize('mode, backend', [('seed', 'numpy'), ('seed', 'numba'),
                                           ('exact', 'numba')])
def test_a_ball_aimed_along_the_diagonal_at_a_convex_corner_comes_straight_back(mode, backend):
    world = World([[2.0, 0.5]], [[2.0, 2.0]], [0.2], [1.0], mode=mode, backend=backend,
                  solid_cells=block_map())
    for _ in range(60):
        world.step(1.0 / 60.0)
    np.testing.assert_allclose(world.velocities[0], [-2.0, -2.0], rtol=0, atol=1e-12)
    assert penetration(world.positions, world.radii, world.solid_cells).max() < \
        (travel_per_substep(0.2) if mode == 'seed' else 1e-12)


@pytest.mark.parametrize('mode, backend', [('seed', 'numpy'), ('seed', 'numba'),
                                           ('exact', 'numba')])
def test_a_ball_into_a_room_corner_meets_both_walls(mode, backend):
    """The grid's lower left corner is a concave corner of the free region (outside solid):
    a ball along the diagonal touches both walls inside their length and comes back."""
    world = World([[1.0, 1.0]], [[-1.5, -1.5]], [0.2], [1.0], mode=mode, backend=backend,
                  solid_cells=block_map())
    stats = [world.step(1.0 / 60.0) for _ in range(60)]
    assert world.velocities.tolist() == [[1.5, 1.5]]
    assert sum(s.ball_wall for s in stats) == 2


# Invariants -----------------------------------------------------------------------------------

def random_mask(rng, rows, columns, fill):
    """Random solid cells with a few one-cell walls and pillars among them."""
    mask = rng.random((rows, columns)) < fill
    for _ in range(3):
        if rng.random() < 0.5:
            mask[int(rng.integers(0, rows)), :] = True
        else:
            mask[:, int(rng.integers(0, columns))] = True
        mask[int(rng.integers(0, rows)), int(rng.integers(0, columns))] = False  # a doorway
    return mask


def blocks_mask(rng, resolution, rows, columns, clearance):
    """Blocks of random size on a lattice and one-cell walls along its lines with wide
    doorways, every free gap at least `clearance` wide: no ball fits only part-way (a ball
    pressed into a gap narrower than its diameter is jammed in seed mode, as between two
    walls; docs/physics.md)."""
    gap = int(math.ceil(clearance / resolution)) + 1
    period = 2 * gap + 3
    mask = np.zeros((rows, columns), dtype=bool)
    for top in range(0, rows, period):
        for left in range(0, columns, period):
            if rng.random() < 0.7:
                height, width = rng.integers(1, period - 2 * gap + 1, 2)
                mask[top + gap:top + gap + height, left + gap:left + gap + width] = True
    for line in rng.choice(np.arange(period, min(rows, columns), period), 2):
        door = int(rng.integers(0, columns - gap))
        mask[line, :] = True
        mask[line, door:door + gap + 1] = False
    return mask


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), resolution=st.sampled_from([0.05, 0.1, 0.3]),
       speed=st.sampled_from([2.0, 6.0, 15.0]))
def test_seed_mode_among_cells_keeps_energy_never_lets_a_centre_in_and_both_backends_agree(
        seed, resolution, speed):
    rng = np.random.default_rng(seed)
    rows, columns = int(5.0 / resolution), int(6.0 / resolution)  # a room of 6 m x 5 m
    cells = SolidCells(-0.7, 0.3, resolution,
                       blocks_mask(rng, resolution, rows, columns, 0.31)).checked()
    radii = rng.uniform(0.05, 0.15, 30)
    positions, velocities, radii = free_balls(rng, cells, 30, radii, speed)
    masses = rng.uniform(0.5, 2.0, len(radii))
    worlds = [World(positions, velocities, radii, masses, backend=backend, solid_cells=cells)
              for backend in BACKENDS]
    energy = worlds[0].kinetic_energy()
    travel = travel_per_substep(float(radii.min()))
    walls = 0
    for _ in range(30):
        stats = [world.step(1.0 / 60.0) for world in worlds]
        assert stats[0] == stats[1] and stats[0].unresolved == 0
        walls += stats[0].ball_wall
        np.testing.assert_array_equal(worlds[0].positions, worlds[1].positions)
        np.testing.assert_array_equal(worlds[0].velocities, worlds[1].velocities)
        # No centre ever reaches a solid cell: no ball gets deeper than one substep's travel.
        assert penetration(worlds[1].positions, radii, cells).max() <= travel + 1e-9
    assert walls > 0
    assert worlds[0].kinetic_energy() == pytest.approx(energy, rel=1e-12)


def rooms(mask):
    """Label of the connected free region (4-neighbours) of each cell; -1 on solid cells."""
    labels = np.full(mask.shape, -1)
    count = 0
    for start in zip(*np.nonzero(~mask)):
        if labels[start] >= 0:
            continue
        stack = [start]
        labels[start] = count
        while stack:
            j, i = stack.pop()
            for nj, ni in ((j + 1, i), (j - 1, i), (j, i + 1), (j, i - 1)):
                if (0 <= nj < mask.shape[0] and 0 <= ni < mask.shape[1] and not mask[nj, ni]
                        and labels[nj, ni] < 0):
                    labels[nj, ni] = count
                    stack.append((nj, ni))
        count += 1
    return labels


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_no_ball_passes_a_one_cell_wall_or_a_one_cell_corner_at_the_speed_limit(seed):
    """Walls of one 5 cm cell and corners of one cell (a pillar, a wall's end) against balls
    of radius 0.1 m as fast as the world lets them be: each ball stays in its room."""
    rng = np.random.default_rng(seed)
    mask = np.zeros((40, 40), dtype=bool)
    mask[20, :] = True  # a one-cell wall across, closed
    mask[:20, 13] = True  # and one below it, also closed
    mask[30:39, 30] = True  # a free-standing wall of one cell (two convex one-cell ends)
    for _ in range(6):  # pillars of one cell
        mask[int(rng.integers(22, 38)), int(rng.integers(2, 28))] = True
    cells = SolidCells(0.0, 0.0, 0.05, mask).checked()
    labels = rooms(mask)
    radii = np.full(30, 0.1)
    positions, velocities, radii = free_balls(rng, cells, 30, radii, 1.0)
    probe = World(positions, velocities, radii, np.ones(len(radii)), solid_cells=cells)
    dt = 1.0 / 60.0
    # Every ball at the speed limit, so a step needs MAX_SUBSTEPS substeps at most.
    velocities *= 0.99 * probe.speed_limit(dt) / math.sqrt(len(radii))
    world = World(positions, velocities, radii, np.ones(len(radii)), solid_cells=cells)

    def room_of(points):
        column = np.floor(points[:, 0] / 0.05).astype(int)
        row = np.floor(points[:, 1] / 0.05).astype(int)
        return labels[row, column]

    start = room_of(world.positions)
    assert (start >= 0).all()
    for _ in range(8):
        world.step(dt)
        assert (room_of(world.positions) == start).all()


def depot_balls(mode, count=60, seed=3, speed=2.0):
    cells = real_map('depot')
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.1, 0.25, count)
    positions, velocities, radii = free_balls(rng, cells, count, radii, speed)
    masses = np.pi * radii ** 2
    return World(positions, velocities, radii, masses, mode=mode, solid_cells=cells), cells


def test_exact_mode_in_the_depot_map_keeps_energy_and_never_overlaps_a_cell():
    world, cells = depot_balls('exact', count=80)
    energy = world.kinetic_energy()
    walls = 0
    for step in range(300):
        walls += world.step(1.0 / 60.0).ball_wall
        if step % 10 == 9:
            assert penetration(world.positions, world.radii, cells).max() < 1e-9
            assert pair_overlap(world.positions, world.radii) < 1e-9
    assert walls > 100  # the balls did meet the map
    assert abs(world.kinetic_energy() - energy) <= 1e-9 * energy


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), dt=st.sampled_from([1e-3, 1.0 / 60.0, 0.2]))
def test_exact_mode_among_random_cells_keeps_energy_and_never_overlaps(seed, dt):
    rng = np.random.default_rng(seed)
    cells = SolidCells(1.3, -2.1, 0.1, random_mask(rng, 30, 30, 0.1)).checked()
    radii = rng.uniform(0.03, 0.2, 30)
    positions, velocities, radii = free_balls(rng, cells, 30, radii, 3.0)
    world = World(positions, velocities, radii, rng.uniform(0.5, 3.0, len(radii)),
                  mode='exact', solid_cells=cells)
    energy = world.kinetic_energy()
    for _ in range(25):
        world.step(dt)
        assert penetration(world.positions, world.radii, cells).max() < 1e-9
        assert pair_overlap(world.positions, world.radii) < 1e-9
    assert world.kinetic_energy() == pytest.approx(energy, rel=1e-12)


@pytest.mark.parametrize('name', ['depot', 'tb3_sandbox'])
def test_both_backends_step_the_real_maps_bit_for_bit(name):
    cells = real_map(name)
    rng = np.random.default_rng(7)
    radii = rng.uniform(0.05, 0.2, 50)
    positions, velocities, radii = free_balls(rng, cells, 50, radii, 3.0)
    worlds = [World(positions, velocities, radii, np.ones(len(radii)), backend=backend,
                    solid_cells=cells) for backend in BACKENDS]
    walls = 0
    for _ in range(90):
        stats = [world.step(1.0 / 60.0) for world in worlds]
        assert stats[0] == stats[1]
        walls += stats[0].ball_wall
    np.testing.assert_array_equal(worlds[0].positions, worlds[1].positions)
    np.testing.assert_array_equal(worlds[0].velocities, worlds[1].velocities)
    assert walls > 10


@pytest.mark.parametrize('mode', ['seed', 'exact'])
def test_a_map_no_ball_reaches_changes_nothing_and_momentum_holds(mode):
    """Balls in the middle of a large free room, for a few steps: with or without the map,
    the same trajectory to the bit (the map's runs only add far-away walls), and pair
    collisions keep the momentum."""
    rng = np.random.default_rng(11)
    mask = np.zeros((200, 200), dtype=bool)
    mask[:3, :] = mask[:, :3] = True
    cells = SolidCells(-10.0, -10.0, 0.1, mask).checked()
    positions = rng.uniform(-2.0, 2.0, (60, 2))
    keep = [k for k in range(60) if all(np.hypot(*(positions[k] - positions[j])) > 0.25
                                        for j in range(k))]
    arrays = (positions[keep], rng.normal(0.0, 1.0, (len(keep), 2)), np.full(len(keep), 0.1),
              rng.uniform(0.5, 2.0, len(keep)))
    with_map = World(*arrays, mode=mode, solid_cells=cells)
    without = World(*arrays, mode=mode)
    momentum = with_map.momentum()
    collisions = 0
    for _ in range(60):
        a = with_map.step(1.0 / 60.0)
        b = without.step(1.0 / 60.0)
        assert a == b and a.ball_wall == 0
        collisions += a.ball_ball
    assert collisions > 0
    np.testing.assert_array_equal(with_map.positions, without.positions)
    np.testing.assert_array_equal(with_map.velocities, without.velocities)
    np.testing.assert_allclose(with_map.momentum(), momentum, rtol=0, atol=1e-12)


def test_exact_mode_with_a_map_resumes_bit_for_bit_from_its_carried_state():
    world, cells = depot_balls('exact', count=40, seed=5)
    for _ in range(20):
        world.step(1.0 / 30.0)
    carried = world.carried_state()
    assert carried.kept and (carried.hit_partner[carried.hit_kind == 1] >= 0).all()
    twin = World(world.positions.copy(), world.velocities.copy(), world.radii.copy(),
                 world.masses.copy(), mode='exact', solid_cells=cells)
    twin.restore_carried_state(carried)
    for _ in range(20):
        assert world.step(1.0 / 30.0) == twin.step(1.0 / 30.0)
    np.testing.assert_array_equal(world.positions, twin.positions)
    np.testing.assert_array_equal(world.velocities, twin.velocities)


def test_a_carried_state_naming_a_run_past_the_map_is_refused():
    world, _ = depot_balls('exact', count=10, seed=6)
    world.step(0.05)
    carried = world.carried_state()
    bad = carried.hit_partner.copy()
    bad[0] = len(world.static) + 5
    kind = carried.hit_kind.copy()
    kind[0] = 1  # WALL
    forged = dataclasses.replace(carried, hit_partner=bad, hit_kind=kind)
    with pytest.raises(ValueError, match='names no wall'):
        world.restore_carried_state(forged)
