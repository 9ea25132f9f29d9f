"""Candidate pairs from positions and radii: a hierarchical grid, plus Verlet lists (numpy).

The broadphase knows nothing of collision responses. It answers one question: which pairs
of balls, and which ball-wall pairs, can possibly be touching? It answers it in O(N) time
and memory for every world inside `core.limits`, without a Python loop over balls:

- Radius classes (levels): balls whose radii lie within a factor LEVEL_RATIO of each other
  share a uniform grid whose cells are one largest diameter (plus the margin) wide. A
  single grid sized by the largest ball would put thousands of small balls in one cell
  when radii differ by 100x; per level, a cell holds a bounded number of balls.
- Within a level, every ball is paired with the balls of its own cell and four neighbour
  cells (a half stencil, so each pair appears once). Across levels, each ball of a smaller
  level looks at the 3 x 3 cells around it in every larger level's grid, whose cells are at
  least as wide as any reach between the two.
- Grids never have more than CELLS_PER_BALL cells per ball (plus CELLS_SLACK): when the
  balls spread far apart (no arena), cells grow instead, so keys cannot overflow and
  memory stays linear however large the coordinates.
- Walls (and a map's boundary runs) are not in these grids: `core.static_geometry` indexes
  them once per World in buckets sized by the geometry, and each ball asks the buckets its
  reach covers. Tens of thousands of segments cost what lies near the balls, not N x M
  distance tests, nor a rasterisation on every rebuild.
- `NeighbourLists` keeps the candidates, widened by a skin, for as long as no ball can have
  moved far enough to close the skin, so the grids are rebuilt every few substeps.

Candidates are returned in the canonical order (pairs sorted by (a, b) with a < b, ball-wall
pairs by (ball, wall)), so whatever filters them keeps that order. `numba_backend` builds
the same kind of grid in compiled loops; the two may offer different candidates, but both
offer every touching pair.

Speed notes (numpy 2.5, measured here): `np.take(a, i, axis=0)` gathers rows ten times
faster than `a[i]` on (N, 2) arrays, and explicit x*x + y*y beats einsum; both are used on
every hot path.
"""
import numpy as np

from ball_world.core import rules
# `widened` (by static_geometry.SLACK, far above the rounding of cell coordinates, so that
# a pair exactly at its reach is never lost to rounding) and `expand` are the static
# geometry's, shared.
from ball_world.core.static_geometry import expand as _expand, StaticGeometry, widened

_EMPTY = np.empty(0, dtype=np.intp)
#: Largest radius over smallest radius within one level of the hierarchical grid.
LEVEL_RATIO = 4.0
#: A grid has at most CELLS_PER_BALL cells per ball plus CELLS_SLACK; its cells grow past it.
CELLS_PER_BALL = 4
CELLS_SLACK = 1024
#: Empty columns and rows around each grid, so that neighbour look-ups stay in the table.
PAD = 2


def take_rows(array, index):
    """array[index] for row gathers, the fast way."""
    return np.take(array, index, axis=0)


def dot_rows(a, b):
    """Row-wise dot product of two (K, 2) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]


def radius_levels(radii):
    """Level of each ball (0 for the smallest radii) and the number of levels.

    Level k holds radii in [r_min LEVEL_RATIO^k, r_min LEVEL_RATIO^(k+1)); the thresholds
    are compared, never logarithms taken, so a larger radius never gets a smaller level.
    """
    thresholds = []
    threshold = float(radii.min()) * LEVEL_RATIO
    largest = float(radii.max())
    while threshold <= largest:
        thresholds.append(threshold)
        threshold *= LEVEL_RATIO
    return np.searchsorted(np.array(thresholds), radii, side='right'), len(thresholds) + 1


def grid_shape(extent_x, extent_y, cell, count):
    """(cell, columns, rows) of a grid over the extent: cells at least `cell` wide, doubled
    until the grid has at most CELLS_PER_BALL * count + CELLS_SLACK cells."""
    if not (np.isfinite(extent_x) and np.isfinite(extent_y)):
        raise ValueError('ball positions span a non-finite extent; cannot grid them')
    budget = CELLS_PER_BALL * count + CELLS_SLACK
    while (extent_x / cell + 1.0) * (extent_y / cell + 1.0) > budget:
        cell *= 2.0
    return cell, int(extent_x / cell) + 1, int(extent_y / cell) + 1


class LevelGrid:
    """One level's uniform grid: its balls sorted by cell, and a dense table of cell starts.

    Cell (i, j) of the grid has key (i + PAD) * stride + (j + PAD); the balls in it are
    balls[starts[key]:starts[key + 1]].
    """

    def __init__(self, positions, members, cell, scale, previous=None):
        points = take_rows(positions, members)
        self.origin = points.min(axis=0)
        extent = points.max(axis=0) - self.origin
        self.cell, self.nx, self.ny = grid_shape(extent[0], extent[1], cell, len(members))
        self.scale = scale
        self.stride = self.ny + 2 * PAD
        fx, fy = self.coordinates(points)
        cx = np.minimum(fx.astype(np.intp), self.nx - 1)
        cy = np.minimum(fy.astype(np.intp), self.ny - 1)
        keys = (cx + PAD) * self.stride + (cy + PAD)
        if previous is not None and len(previous.order) == len(members):
            # Balls move little between builds: the previous order is nearly sorted.
            self.order = np.take(previous.order,
                                 np.argsort(np.take(keys, previous.order), kind='stable'))
        else:
            self.order = np.argsort(keys, kind='stable')
        self.balls = np.take(members, self.order)
        self.keys = np.take(keys, self.order)
        size = (self.nx + 2 * PAD) * self.stride
        self.starts = np.zeros(size + 1, dtype=np.intp)
        np.cumsum(np.bincount(self.keys, minlength=size), out=self.starts[1:])

    def coordinates(self, points):
        """Cell coordinates of points as floats (points outside the grid fall outside)."""
        return ((points[:, 0] - self.origin[0]) / self.cell,
                (points[:, 1] - self.origin[1]) / self.cell)

    def own_pairs(self):
        """Pairs of this level's balls in the same or neighbouring cells (half stencil)."""
        n = len(self.balls)
        keys = self.keys
        stride = self.stride
        # The rest of the own cell, then (0, +1), (+1, -1), (+1, 0), (+1, +1).
        lows = [np.arange(1, n + 1)] + [np.take(self.starts, keys + k)
                                        for k in (1, stride - 1, stride, stride + 1)]
        highs = [np.take(self.starts, keys + k) for k in (1, 2, stride, stride + 1, stride + 2)]
        first, second = _expand(np.tile(np.arange(n), 5), np.concatenate(lows),
                                np.concatenate(highs))
        return np.take(self.balls, first), np.take(self.balls, second)

    def pairs_with(self, positions, queries):
        """Pairs (query ball, ball of this grid) in the 3 x 3 cells around each query.

        For queries from a smaller level: this grid's cells are at least as wide as the
        reach between any of its balls and a smaller ball, so 3 x 3 cells hold them all.
        """
        fx, fy = self.coordinates(take_rows(positions, queries))
        near = np.flatnonzero((fx >= -1.0) & (fx < self.nx + 1.0)
                              & (fy >= -1.0) & (fy < self.ny + 1.0))
        if len(near) == 0:
            return _EMPTY, _EMPTY
        cx = np.floor(np.take(fx, near)).astype(np.intp)
        cy = np.floor(np.take(fy, near)).astype(np.intp)
        centre = (cx + PAD) * self.stride + (cy + PAD)
        keys = np.concatenate([centre + dx * self.stride + dy
                               for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
        first, second = _expand(np.tile(np.take(queries, near), 9),
                                np.take(self.starts, keys), np.take(self.starts, keys + 1))
        return first, np.take(self.balls, second)


class HierarchicalGrid:
    """The balls in one grid per radius level, built for one margin; see the module doc."""

    def __init__(self, positions, radii, margin, previous=None):
        self.positions = positions
        self.radii = radii
        self.margin = float(margin)
        self.scale = float(np.abs(positions).max()) if len(positions) else 0.0
        if previous is not None:
            self.members = previous.members
        else:
            level, count = radius_levels(radii)
            by_level = np.argsort(level, kind='stable')
            bounds = np.searchsorted(np.take(level, by_level), np.arange(count + 1))
            self.members = [by_level[bounds[k]:bounds[k + 1]] for k in range(count)
                            if bounds[k + 1] > bounds[k]]
        self.largest = [float(np.take(radii, members).max()) for members in self.members]
        self.levels = [
            LevelGrid(positions, members,
                      widened(2.0 * largest + self.margin, self.scale), self.scale,
                      previous.levels[k] if previous is not None else None)
            for k, (members, largest) in enumerate(zip(self.members, self.largest))]

    def pairs(self):
        """Ball pairs with |x_a - x_b| < r_a + r_b + margin, a < b, sorted by (a, b)."""
        firsts = []
        seconds = []
        for k, grid in enumerate(self.levels):
            first, second = grid.own_pairs()
            firsts.append(first)
            seconds.append(second)
            for larger in self.levels[k + 1:]:
                first, second = larger.pairs_with(self.positions, grid.balls)
                firsts.append(first)
                seconds.append(second)
        if not firsts:
            return _EMPTY, _EMPTY
        first = np.concatenate(firsts)
        second = np.concatenate(seconds)
        delta = take_rows(self.positions, first) - take_rows(self.positions, second)
        reach = np.take(self.radii, first) + np.take(self.radii, second) + self.margin
        near = np.flatnonzero(dot_rows(delta, delta) < reach * reach)
        first = np.take(first, near)
        second = np.take(second, near)
        a = np.minimum(first, second)
        b = np.maximum(first, second)
        order = np.argsort(a * len(self.positions) + b)
        return np.take(a, order), np.take(b, order)


def grid_pairs(positions, radii, margin, previous=None):
    """Pairs (a, b), a < b, sorted, with |x_a - x_b| < r_a + r_b + margin, in O(N).

    Returns (a, b, grid); passing the grid back as `previous` after the balls moved a
    little makes the next sort nearly free.
    """
    if len(positions) < 2:
        return _EMPTY, _EMPTY, None
    grid = HierarchicalGrid(positions, radii, margin, previous)
    return (*grid.pairs(), grid)


def wall_pairs(positions, radii, walls, margin):
    """(ball, wall) index arrays, sorted, of every ball within r + margin of a wall (a
    core.world.Walls): the static geometry's bucket index of those walls, asked once."""
    if len(positions) == 0 or len(walls) == 0:
        return _EMPTY, _EMPTY
    return StaticGeometry(walls).near_pairs(positions, radii, margin)


class NeighbourLists:
    """Ball-ball and ball-wall candidate pairs, valid until balls may have moved skin / 2.

    A pair left out was at least r_i + r_j + skin apart when the lists were built; if no ball
    has moved more than `skin / 2` since, it is still further apart than r_i + r_j and cannot
    be touching (a wall does not move, so a ball-wall pair keeps half the skin spare). The
    stepper reports an upper bound of the distance moved; the lists rebuild themselves when
    it reaches half the skin. Per-pair constants (reach squared, the wall's geometry) are
    gathered once per build, not once per substep. The lists stay in canonical order.
    """

    def __init__(self, skin):
        self.skin = float(skin)
        self.moved = np.inf  # forces a build on first use
        self.builds = 0
        self._grid = None

    def update(self, positions, radii, static, moved):
        """Account for `moved` metres of travel; rebuild if the skin may be closed.

        `static` is the World's core.static_geometry.StaticGeometry (walls and map runs).
        """
        self.moved += moved
        if 2.0 * self.moved < self.skin:
            return False
        grid = HierarchicalGrid(positions, radii, self.skin, self._grid)
        self._grid = grid
        self.ball_a, self.ball_b = grid.pairs()
        self.reach2 = rules.reach_squared(np.take(radii, self.ball_a),
                                          np.take(radii, self.ball_b))
        self.wall_ball, wall = static.near_pairs(positions, radii, self.skin)
        self.wall_index = wall
        self.wall_radius = np.take(radii, self.wall_ball)
        self.wall_start = take_rows(static.starts, wall)
        self.wall_direction = take_rows(static.directions, wall)
        self.wall_length = np.take(static.lengths, wall)
        self.moved = 0.0
        self.builds += 1
        return True
