"""Balls and a map's solid cells: no ball placed, spawned or moved onto one, ever.

The reference for "overlaps" is the closed form, brute force: the disc's centre is closer
than its radius to some solid square, with the grid surrounded by a ring of solid squares
wider than the radius (everything outside the map is solid), never core.solid_cells' own
window and summed-area table.
"""
import math
from pathlib import Path

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from ball_world.core.edits import Ball, EditRefused
from ball_world.core.parameters import DEFAULTS
from ball_world.core.scenario import build_scene, ScenarioError
from ball_world.core.solid_cells import CellQueries, SolidCells
from ball_world.map_files import load_map_file
from ball_world.simulation import build, Simulation, SpawnRequest

MAPS = Path(__file__).resolve().parents[1] / 'maps'
SANDBOX = str(MAPS / 'tb3_sandbox.yaml')
DEPOT = str(MAPS / 'depot.yaml')


def brute_overlaps(cells, x, y, radius):
    """Whether a disc overlaps a solid square of the grid padded with a solid ring."""
    ring = int(math.ceil(radius / cells.resolution)) + 2
    solid = np.pad(cells.solid, ring, constant_values=True)
    rows, columns = np.nonzero(solid)
    left = cells.origin_x + (columns - ring) * cells.resolution
    bottom = cells.origin_y + (rows - ring) * cells.resolution
    dx = np.maximum(np.maximum(left - x, x - (left + cells.resolution)), 0.0)
    dy = np.maximum(np.maximum(bottom - y, y - (bottom + cells.resolution)), 0.0)
    return bool((dx * dx + dy * dy < radius * radius).any())


SMALL = SolidCells(origin_x=-0.3, origin_y=0.2, resolution=0.1, solid=np.array([
    [0, 0, 0, 0, 0, 0, 0],
    [0, 1, 0, 0, 0, 0, 0],
    [0, 0, 0, 1, 1, 0, 0],
    [0, 0, 0, 1, 0, 0, 0],
    [0, 0, 0, 0, 0, 0, 1]], dtype=bool))


@settings(max_examples=400, deadline=None)
@given(x=st.floats(-0.6, 0.7), y=st.floats(-0.1, 1.0), radius=st.floats(0.001, 0.4))
def test_disc_overlap_is_the_closed_form(x, y, radius):
    queries = CellQueries(SMALL)
    hit = queries.first_overlap(x, y, radius)
    assert (hit is not None) == brute_overlaps(SMALL, x, y, radius)


def test_overlap_at_touching_distance_is_none_and_a_hair_closer_is_one():
    # Binary fractions, so every edge and distance below is exact: 8 x 8 cells over
    # [-0.25, 0.75] x [0.25, 1.25], one solid, (column 1, row 1): [-0.125, 0] x [0.375, 0.5].
    cells = SolidCells(origin_x=-0.25, origin_y=0.25, resolution=0.125,
                       solid=(np.arange(8)[:, None] == 1) & (np.arange(8) == 1))
    queries = CellQueries(cells)
    assert queries.first_overlap(0.125, 0.4375, 0.125) is None
    assert queries.first_overlap(np.nextafter(0.125, 0.0), 0.4375, 0.125) == ('cell', (1, 1))
    # A corner: the distance is to the corner point (0, 0.5), here 0.0625 * 5 away.
    corner = (0.0625 * 3, 0.5 + 0.0625 * 4)
    assert queries.first_overlap(*corner, 0.3125) is None
    assert queries.first_overlap(*corner, np.nextafter(0.3125, 1.0)) == ('cell', (1, 1))
    # The grid's edge (x = -0.25): outside is solid.
    assert queries.first_overlap(-0.125, 0.8125, 0.125) is None
    assert queries.first_overlap(-0.125, 0.8125, np.nextafter(0.125, 1.0)) == \
        ('outside', None)


def test_many_balls_are_checked_at_once_like_one_by_one():
    queries = CellQueries(SMALL)
    rng = np.random.default_rng(3)
    positions = np.column_stack((rng.uniform(-0.6, 0.7, 500), rng.uniform(-0.1, 1.0, 500)))
    radii = rng.uniform(0.001, 0.2, 500)
    clear = [not brute_overlaps(SMALL, x, y, r) for (x, y), r in zip(positions, radii)]
    first = clear.index(False)
    assert queries.first_overlapping_ball(positions, radii)[0] == first
    keep = np.array(clear)
    assert queries.first_overlapping_ball(positions[keep], radii[keep]) is None


def test_free_area_and_bounds_inside_an_arena():
    queries = CellQueries(SMALL)
    assert math.isclose(queries.free_area(), (35 - 5) * 0.01, rel_tol=1e-12)
    # The arena cuts cells: count the area of each free cell inside it.
    arena = (-0.25, 0.25, 0.05, 0.61)
    expected = 0.0
    for row in range(5):
        for column in range(7):
            if SMALL.solid[row, column]:
                continue
            x0, y0 = -0.3 + column * 0.1, 0.2 + row * 0.1
            width = max(0.0, min(x0 + 0.1, arena[2]) - max(x0, arena[0]))
            height = max(0.0, min(y0 + 0.1, arena[3]) - max(y0, arena[1]))
            expected += width * height
    assert math.isclose(queries.free_area(arena), expected, rel_tol=1e-9)
    assert queries.free_bounds() == pytest.approx((-0.3, 0.2, 0.4, 0.7))
    assert queries.free_bounds(arena) == pytest.approx(arena)


def map_world(path=SANDBOX, **values):
    return {**DEFAULTS, 'map': path, 'arena': [], **values}


def clear_of_map(scene):
    cells = scene.cells.cells
    world = scene.world
    return [i for i, ((x, y), r) in enumerate(zip(world.positions, world.radii))
            if brute_overlaps(cells, x, y, r)]


@pytest.mark.parametrize('path, count, arena', [(SANDBOX, 30, []),
                                                (DEPOT, 400, []),
                                                (DEPOT, 50, [3.0, 8.0, 12.0, 15.0])])
def test_random_balls_go_in_free_cells_and_the_same_seed_gives_the_same_world(
        path, count, arena):
    occupancy = load_map_file(path)
    values = map_world(path, **{'random.count': count, 'random.seed': 5, 'arena': arena})
    scene = build_scene(values, occupancy)
    assert len(scene.world) == count and clear_of_map(scene) == []
    if arena:
        xmin, ymin, xmax, ymax = arena
        x, y = scene.world.positions.T
        r = scene.world.radii
        assert ((x - r >= xmin) & (x + r <= xmax) & (y - r >= ymin) & (y + r <= ymax)).all()
    again = build_scene(values, occupancy).world
    assert np.array_equal(again.positions, scene.world.positions)
    assert np.array_equal(again.velocities, scene.world.velocities)
    other = build_scene({**values, 'random.seed': 6}, occupancy).world
    assert not np.array_equal(other.positions, scene.world.positions)


def test_too_many_random_balls_for_the_free_area_are_refused_at_once():
    occupancy = load_map_file(SANDBOX)
    # The sandbox has about 19.8 m^2 free (of a 19.2 m x 19.2 m image): balls of 0.1 m
    # radius, 0.0314 m^2 each, cover half of it at about 315.
    build_scene(map_world(**{'random.count': 200, 'random.radius': [0.1, 0.1]}), occupancy)
    with pytest.raises(ScenarioError, match="random.count.*of the map's free area"):
        build_scene(map_world(**{'random.count': 330, 'random.radius': [0.1, 0.1]}),
                    occupancy)


def explicit(x, y, radius=0.2):
    return {'balls.x': [x], 'balls.y': [y], 'balls.vx': [0.0], 'balls.vy': [0.0],
            'balls.radius': [radius], 'balls.mass': [1.0], 'random.count': 0}


def test_an_explicit_ball_on_a_solid_cell_is_refused_naming_the_ball_and_the_cell():
    occupancy = load_map_file(SANDBOX)
    with pytest.raises(ScenarioError) as refused:
        build_scene(map_world(**explicit(0.0, 0.0)), occupancy)
    text = str(refused.value)
    assert text.startswith("parameter 'balls.x': ball 0 at (0, 0) with radius 0.2 overlaps "
                           "the map's solid cell (column ")
    with pytest.raises(ScenarioError, match='overlaps the outside of the map'):
        build_scene(map_world(**explicit(-9.9, 0.0)), occupancy)
    # Unknown cells are free when told so: the same ball in the unknown part then fits.
    unknown_spot = explicit(-9.0, -9.0)
    with pytest.raises(ScenarioError, match='solid cell'):
        build_scene(map_world(**unknown_spot), occupancy)
    build_scene(map_world(**unknown_spot, **{'map.unknown_solid': False}), occupancy)


def test_a_world_naming_a_map_is_never_built_without_it():
    with pytest.raises(ScenarioError, match="parameter 'map': names a map, but none"):
        build_scene(map_world(**{'random.count': 3}), None)
    with pytest.raises(ScenarioError, match="parameter 'map': the map YAML nowhere.yaml does "
                                            'not exist'):
        build(map_world('nowhere.yaml'))


@pytest.fixture(scope='module')
def simulation():
    return Simulation(map_world(**{'random.count': 10, 'agents': ['ball_0']}))


def test_spawn_on_a_solid_cell_is_refused_and_beside_it_accepted(simulation):
    (refused,), _ = simulation.spawn([SpawnRequest('pillar', False, Ball(0.0, 0.0, 0.0, 0.0,
                                                                         0.1, 1.0))])
    assert isinstance(refused, EditRefused) and "map's solid cell" in str(refused)
    (outside,), _ = simulation.spawn([SpawnRequest('away', False, Ball(50.0, 0.0, 0.0, 0.0,
                                                                       0.1, 1.0))])
    assert isinstance(outside, EditRefused) and 'outside of the map' in str(outside)
    (name,), _ = simulation.spawn([SpawnRequest('free', False, Ball(-2.0, -0.5, 0.0, 0.0,
                                                                    0.1, 1.0))])
    assert name == 'free'


def test_set_state_onto_a_solid_cell_is_refused_and_leaves_the_ball(simulation):
    before = simulation.world.positions[0].copy()
    with pytest.raises(EditRefused, match="'ball_0' at \\(0, 0\\) with radius .* overlaps the "
                                          "map's solid cell"):
        simulation.set_state('ball_0', 0.0, 0.0, 0.0, 0.0)
    assert np.array_equal(simulation.world.positions[0], before)


@pytest.mark.parametrize('name, agents, balls', [('sandbox', 2, 14), ('depot', 20, 60)])
def test_the_worlds_to_start_from_build_with_their_robots_clear_of_the_map(name, agents,
                                                                           balls):
    import yaml
    root = MAPS.parent
    document = yaml.safe_load((root / 'worlds' / f'{name}.yaml').read_text())
    values = document['/**']['ros__parameters']
    values['map'] = str(root / values['map'])  # relative to the repository, as documented
    simulation = Simulation(values)
    assert len(simulation.world) == balls and len(simulation.agents) == agents
    assert simulation.parameters['agent.drive'] == 'diff' and not simulation.arena
    assert simulation.cells.first_overlapping_ball(simulation.world.positions,
                                                   simulation.world.radii) is None
