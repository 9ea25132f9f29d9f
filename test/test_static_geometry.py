"""A map's solid cells as walls: the boundary runs and the bucket index (core.static_geometry).

The reference for the runs is the definition, cell by cell in plain loops: every unit edge
between a solid cell (or the outside of the grid) and a free cell is boundary, exactly once;
a run is a maximal chain of such edges on one line with the solid on the same side, so its
end points are corners. The index is checked against brute-force distances.
"""
from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from ball_world.core import limits, static_geometry
from ball_world.core.solid_cells import SolidCells
from ball_world.core.static_geometry import (boundary_runs, count_boundary_runs, SegmentIndex,
                                             StaticGeometry)
from ball_world.core.world import Walls, World

ORIGIN = (-1.5, 2.25)
RESOLUTION = 0.25


def cells_of(mask, origin=ORIGIN, resolution=RESOLUTION):
    return SolidCells(origin[0], origin[1], resolution, np.array(mask, dtype=bool)).checked()


def solid_at(mask, row, column):
    """Solid, with everything outside the grid solid."""
    rows, columns = mask.shape
    return not (0 <= row < rows and 0 <= column < columns) or bool(mask[row, column])


def boundary_edges(mask):
    """Reference: each unit edge between solid and free, as (axis, line, index, solid side).

    Horizontal edge on row line j under column i: between rows j - 1 (below) and j; side
    'below' or 'above' names the solid one. Vertical likewise with columns.
    """
    rows, columns = mask.shape
    edges = set()
    for j in range(rows + 1):
        for i in range(columns):
            below, above = solid_at(mask, j - 1, i), solid_at(mask, j, i)
            if below != above:
                edges.add(('h', j, i, 'below' if below else 'above'))
    for i in range(columns + 1):
        for j in range(rows):
            left, right = solid_at(mask, j, i - 1), solid_at(mask, j, i)
            if left != right:
                edges.add(('v', i, j, 'left' if left else 'right'))
    return edges


def run_edges(runs, mask, origin=ORIGIN, resolution=RESOLUTION):
    """The unit edges each run covers, in grid units, with the solid side read off the mask."""
    covered = []
    for x1, y1, x2, y2 in runs:
        a = (np.array([x1, y1]) - origin) / resolution
        b = (np.array([x2, y2]) - origin) / resolution
        assert np.allclose(a, np.round(a)) and np.allclose(b, np.round(b))
        a = np.round(a).astype(int)
        b = np.round(b).astype(int)
        if a[1] == b[1]:
            assert a[0] < b[0]  # left to right
            j = a[1]
            sides = set()
            for i in range(a[0], b[0]):
                side = 'below' if solid_at(mask, j - 1, i) else 'above'
                sides.add(side)
                covered.append(('h', j, i, side))
            assert len(sides) == 1, 'a run has its solid side on one side only'
        else:
            assert a[0] == b[0] and a[1] < b[1]  # axis-aligned, bottom to top
            i = a[0]
            sides = set()
            for j in range(a[1], b[1]):
                side = 'left' if solid_at(mask, j, i - 1) else 'right'
                sides.add(side)
                covered.append(('v', i, j, side))
            assert len(sides) == 1
    return covered


def continues(edges, edge, step):
    """Whether the boundary edge `step` cells further along the same line, with the solid on
    the same side, exists (then a run ending here would not be maximal)."""
    axis, line, index, side = edge
    return (axis, line, index + step, side) in edges


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.floats(0.0, 1.0), st.integers(0, 2**32 - 1))
def test_runs_cover_every_boundary_edge_once_and_end_at_corners(rows, columns, fill, seed):
    mask = np.random.default_rng(seed).random((rows, columns)) < fill
    runs = boundary_runs(cells_of(mask))
    edges = boundary_edges(mask)
    covered = run_edges(runs, mask)
    assert sorted(covered) == sorted(edges)  # every edge, none twice, no interior edge
    for x1, y1, x2, y2 in runs:
        first = run_edges([(x1, y1, x2, y2)], mask)
        start, end = min(first), max(first)
        # Maximal: the same line does not go on with the same solid side at either end.
        assert not continues(edges, start, -1) and not continues(edges, end, 1)


def test_one_solid_cell_is_four_runs_around_its_square():
    mask = np.zeros((3, 3), dtype=bool)
    mask[1, 1] = True
    runs = boundary_runs(cells_of(mask, (0.0, 0.0), 1.0))
    inner = [list(run) for run in runs if 0.0 < min(run) and max(run) < 3.0]
    assert sorted(inner) == [[1.0, 1.0, 1.0, 2.0], [1.0, 1.0, 2.0, 1.0],
                             [1.0, 2.0, 2.0, 2.0], [2.0, 1.0, 2.0, 2.0]]


def test_a_free_grid_is_closed_by_the_outside():
    runs = boundary_runs(cells_of(np.zeros((2, 3), dtype=bool), (0.0, 0.0), 1.0))
    expected = [[0.0, 0.0, 0.0, 2.0], [0.0, 0.0, 3.0, 0.0], [0.0, 2.0, 3.0, 2.0],
                [3.0, 0.0, 3.0, 2.0]]
    assert sorted(map(list, runs)) == expected


def test_cells_meeting_at_a_corner_only_keep_four_runs_ending_there():
    """Checkerboard: the two solid cells touch at (1, 1) only; on each line through it the
    two edges have their solid on opposite sides, so they are separate runs ending there."""
    mask = np.array([[True, False], [False, True]])
    runs = boundary_runs(cells_of(mask, (0.0, 0.0), 1.0))
    through = [list(run) for run in runs if (run[0], run[1]) == (1.0, 1.0)
               or (run[2], run[3]) == (1.0, 1.0)]
    assert sorted(through) == [[0.0, 1.0, 1.0, 1.0], [1.0, 0.0, 1.0, 1.0],
                               [1.0, 1.0, 1.0, 2.0], [1.0, 1.0, 2.0, 1.0]]


def segment_distances(points, segments):
    """Reference: (N, M) distances from points to segments, by projection and clamping."""
    start = segments[None, :, 0:2]
    edge = segments[None, :, 2:4] - start
    rel = points[:, None, :] - start
    t = np.clip((rel * edge).sum(-1) / (edge * edge).sum(-1), 0.0, 1.0)
    return np.sqrt(((rel - t[..., None] * edge) ** 2).sum(-1))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.6), st.sampled_from([0.0, 0.05, 0.3]))
def test_near_pairs_equal_brute_force_with_walls_and_runs(seed, margin, walls_spread):
    rng = np.random.default_rng(seed)
    mask = rng.random((int(rng.integers(1, 20)), int(rng.integers(1, 20)))) < 0.3
    cells = cells_of(mask)
    starts = rng.uniform(-3.0, 4.0, (5, 2))
    walls = Walls(np.concatenate((starts, starts + rng.uniform(-2.0, 2.0, (5, 2))
                                  + walls_spread), axis=1))
    static = StaticGeometry(walls, cells)
    points = rng.uniform(-3.0, 4.0, (200, 2))
    radii = rng.uniform(0.01, 0.3, 200)
    ball, wall = static.near_pairs(points, radii, margin)
    near = segment_distances(points, static.segments) < radii[:, None] + margin
    assert list(zip(ball.tolist(), wall.tolist())) == list(zip(*map(list, np.nonzero(near))))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.01, 1.0))
def test_a_dilated_index_lists_every_segment_within_reach_in_the_own_bucket(seed, reach):
    """Seed mode's compiled search reads one bucket: it must list whatever lies within the
    dilation of any point in it, also for points outside the index's box (nearest bucket)."""
    rng = np.random.default_rng(seed)
    mask = rng.random((15, 15)) < 0.2
    static = StaticGeometry(Walls([[-1.0, -1.0, 3.0, 4.0]]), cells_of(mask))
    index = static.dilated(reach)
    assert index.reach >= reach
    ox, oy, size, _ = index.grid
    points = rng.uniform(-4.0, 8.0, (300, 2))
    column = np.clip(np.floor((points[:, 0] - ox) / size), 0, index.columns - 1).astype(int)
    row = np.clip(np.floor((points[:, 1] - oy) / size), 0, index.rows - 1).astype(int)
    distances = segment_distances(points, static.segments)
    for k in range(len(points)):
        bucket = column[k] * index.rows + row[k]
        listed = index.items[index.first[bucket]:index.first[bucket + 1]]
        assert set(np.flatnonzero(distances[k] < reach)) <= set(listed.tolist())
        assert list(listed) == sorted(set(listed.tolist()))  # once each, in wall order


def test_walls_keep_their_numbers_and_runs_come_after_them():
    walls = [[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    mask = np.zeros((4, 4), dtype=bool)
    mask[2, 2] = True
    world = World([[0.5, 0.5]], [[0.0, 0.0]], [0.1], [1.0], walls=walls,
                  solid_cells=cells_of(mask))
    static = world.static
    assert static.wall_count == 2 and static.run_count == len(static) - 2
    np.testing.assert_array_equal(static.segments[:2], world.walls.segments)
    np.testing.assert_array_equal(static.segments[2:], boundary_runs(cells_of(mask)))
    plain = World([[0.5, 0.5]], [[0.0, 0.0]], [0.1], [1.0], walls=walls)
    assert plain.static.run_count == 0
    np.testing.assert_array_equal(plain.static.segments, plain.walls.segments)


def test_a_map_beyond_the_coordinate_limit_is_refused():
    far = SolidCells(2e6, 0.0, 1.0, np.zeros((2, 2), dtype=bool))
    with pytest.raises(ValueError, match='coordinate limit'):
        World([], [], [], [], solid_cells=far)


def test_index_buckets_are_sized_by_the_geometry_not_the_balls():
    runs = boundary_runs(cells_of(np.random.default_rng(1).random((60, 60)) < 0.1))
    index = SegmentIndex(runs, RESOLUTION)
    # Within the budget of a few buckets per segment, never narrower than a few cells.
    assert index.columns * index.rows <= 4 * len(runs) + 1024
    assert index.size >= 4 * RESOLUTION


# Bounded by the segments' count (issue 33) ----------------------------------------------------

def checkerboard(rows, columns):
    return np.add.outer(np.arange(rows), np.arange(columns)) % 2 == 1


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30), st.floats(0.0, 1.0), st.integers(0, 2**32 - 1))
def test_runs_are_counted_without_making_them(rows, columns, fill, seed):
    mask = np.random.default_rng(seed).random((rows, columns)) < fill
    assert count_boundary_runs(cells_of(mask)) == len(boundary_runs(cells_of(mask)))
    board = cells_of(checkerboard(rows, columns))
    assert count_boundary_runs(board) == len(boundary_runs(board))


def index_entries(index):
    """(bucket, wall) of every entry, for comparing two indexes."""
    buckets = np.repeat(np.arange(len(index.first) - 1), np.diff(index.first))
    return list(zip(buckets.tolist(), index.items.tolist()))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 3.0))
def test_the_entries_bound_holds_for_any_segment(seed, reach):
    """Oblique walls too: the bound the bucket width is chosen by is never below what the
    index then holds, segment by segment."""
    rng = np.random.default_rng(seed)
    starts = rng.uniform(-5.0, 5.0, (40, 2))
    segments = np.concatenate((starts, starts + rng.uniform(-4.0, 4.0, (40, 2))), axis=1)
    segments[:5, 2] = segments[:5, 0]  # vertical ones
    segments[5:10, 3] = segments[5:10, 1]  # horizontal ones
    index = SegmentIndex(segments, 0.0, reach)
    keys, walls = index._bucket_entries(segments, 0)
    made = np.bincount(walls, minlength=len(segments))
    assert (made <= index.entries_bound(segments)).all()
    assert len(index.items) == len(walls)


def test_a_fine_checkerboard_with_a_wide_reach_stays_within_its_budget(monkeypatch):
    """Issue 33: a checkerboard of 5 cm cells dilated by 1 m listed every run in some 25
    buckets (gigabytes at 512 x 512). Buckets widen instead: at most ENTRIES_PER_SEGMENT
    entries a run, and every run within reach of a point still in its bucket."""
    cells = cells_of(checkerboard(64, 64), (0.0, 0.0), 0.05)
    static = StaticGeometry(Walls([]), cells)
    index = static.dilated(1.0)
    budget = static_geometry.ENTRIES_PER_SEGMENT * len(static) + static_geometry.BUCKETS_SLACK
    assert len(index.items) <= budget
    ox, oy, size, _ = index.grid
    points = np.random.default_rng(2).uniform(-0.5, 3.7, (100, 2))
    distances = segment_distances(points, static.segments)
    for k, (x, y) in enumerate(points):
        column = min(max(int(np.floor((x - ox) / size)), 0), index.columns - 1)
        row = min(max(int(np.floor((y - oy) / size)), 0), index.rows - 1)
        bucket = column * index.rows + row
        listed = index.items[index.first[bucket]:index.first[bucket + 1]]
        assert set(np.flatnonzero(distances[k] < index.reach)) <= set(listed.tolist())
    # Made a few entries at a time, the index is the same, bucket by bucket in wall order.
    monkeypatch.setattr(static_geometry, 'FILL_CHUNK', 97)
    assert index_entries(SegmentIndex(static.segments, 0.05, index.reach)) == \
        index_entries(index)


def test_a_map_of_too_many_runs_is_refused_before_its_world_is_built():
    """Counted from the grid at the real limit (a checkerboard just past MAX_MAP_RUNS): one
    line, and no runs made."""
    side = int(np.ceil(np.sqrt(limits.MAX_MAP_RUNS / 2.0))) + 2
    cells = SolidCells(0.0, 0.0, 0.05, checkerboard(side, side))
    assert count_boundary_runs(cells.checked()) > limits.MAX_MAP_RUNS
    with pytest.raises(ValueError) as refused:
        World([[1.0, 1.0]], [[0.0, 0.0]], [0.01], [1.0], solid_cells=cells)
    message = str(refused.value)
    assert f'at most {limits.MAX_MAP_RUNS:,}' in message and '\n' not in message


def test_the_world_builds_its_indexes_when_made_not_on_its_first_step():
    """A node says it started once its World is made: the compiled step's dilated index must
    exist by then, and the first step must not make another."""
    mask = np.zeros((40, 40), dtype=bool)
    mask[10:30, 20] = True
    world = World([[1.0, 1.0], [4.0, 4.0]], [[1.0, 0.0], [0.0, 1.0]], [0.1, 0.1], [1.0, 1.0],
                  backend='numba', solid_cells=cells_of(mask, (0.0, 0.0), 0.125))
    index = world.static._dilated
    assert index is not None and len(index.items) > 0 and index.reach >= 0.1 + 2 * 0.1
    world.step(0.01)
    assert world.static._dilated is index
