"""Candidate pairs from positions and radii: a uniform grid (cell list), plus Verlet lists.

The broadphase knows nothing of collision responses. It answers one question: which pairs
of balls, and which ball-wall pairs, can possibly be touching? It answers it in O(N):

- `grid_pairs` sorts balls by grid cell (cells at least as large as the interaction range)
  and pairs every ball with the balls of its own cell and four neighbouring cells (a half
  stencil, so each pair appears once), without a Python loop.
- `NeighbourLists` keeps those pairs, widened by a skin, for as long as no ball can have
  moved far enough to close the skin: the grid is rebuilt every few steps, not every step.

Speed notes (numpy 2.5, measured here): `np.take(a, i, axis=0)` gathers rows ten times
faster than `a[i]` on (N, 2) arrays, and explicit x*x + y*y beats einsum; both are used on
every hot path.
"""
import numpy as np

_EMPTY = np.empty(0, dtype=np.intp)
#: Use a dense cell table (O(1) look-ups) while it has at most this many cells per ball.
_DENSE_CELLS_PER_BALL = 8


def take_rows(array, index):
    """array[index] for row gathers, the fast way."""
    return np.take(array, index, axis=0)


def dot_rows(a, b):
    """Row-wise dot product of two (K, 2) arrays."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]


def _cell_ranges(sorted_keys, offsets):
    """For each ball and each key offset: [low, high) of the balls in that neighbour cell."""
    top = int(sorted_keys[-1]) + max(offsets) + 2
    if top <= _DENSE_CELLS_PER_BALL * len(sorted_keys) + 1024:
        # starts[k]: first ball (in sorted order) whose key is >= k.
        starts = np.zeros(top + 1, dtype=np.intp)
        np.cumsum(np.bincount(sorted_keys, minlength=top), out=starts[1:])
        return ([np.take(starts, sorted_keys + offset) for offset in offsets],
                [np.take(starts, sorted_keys + offset + 1) for offset in offsets])
    lows = [np.searchsorted(sorted_keys, sorted_keys + offset, side='left')
            for offset in offsets]
    highs = [np.searchsorted(sorted_keys, sorted_keys + offset, side='right')
             for offset in offsets]
    return lows, highs


def grid_pairs(positions, radii, margin, previous_order=None):
    """Pairs (i, j) with |x_i - x_j| < r_i + r_j + margin, and the cell order of the balls.

    Passing the order returned last time makes the sort nearly free: balls move little
    between builds, so the keys arrive almost sorted.
    """
    n = len(positions)
    if n < 2:
        return _EMPTY, _EMPTY, None
    cell = 2.0 * float(radii.max()) + margin
    cells = np.floor((positions - positions.min(axis=0)) / cell).astype(np.intp)
    # Column stride leaves a free row on both sides, so key +- 1 never wraps into a
    # neighbouring column.
    stride = int(cells[:, 1].max()) + 3
    keys = cells[:, 0] * stride + cells[:, 1] + 1
    if previous_order is not None and len(previous_order) == n:
        order = np.take(previous_order,
                        np.argsort(np.take(keys, previous_order), kind='stable'))
    else:
        order = np.argsort(keys, kind='stable')
    sorted_keys = np.take(keys, order)

    # Half stencil: the rest of the own cell, then (0,+1), (+1,-1), (+1,0), (+1,+1).
    lows, highs = _cell_ranges(sorted_keys, (0, 1, stride - 1, stride, stride + 1))
    lows[0] = np.arange(1, n + 1)
    low = np.concatenate(lows)
    counts = np.concatenate(highs) - low
    total = int(counts.sum())
    if total == 0:
        return _EMPTY, _EMPTY, order
    first = np.repeat(np.tile(np.arange(n), 5), counts)
    starts = np.cumsum(counts) - counts
    second = np.repeat(low - starts, counts) + np.arange(total)
    a = np.take(order, first)
    b = np.take(order, second)

    delta = take_rows(positions, a) - take_rows(positions, b)
    reach = np.take(radii, a) + np.take(radii, b) + margin
    near = dot_rows(delta, delta) < reach * reach
    a = a[near]
    b = b[near]
    return np.minimum(a, b), np.maximum(a, b), order


def segment_offsets(points, starts, directions, lengths, ends):
    """Offset from the nearest point of each segment to each point, and whether it is inside.

    Inside the segment the offset is the seed's s = r - (r.w) w, perpendicular to the wall;
    beyond an end it is the vector from that end point to the point.
    """
    r = points - starts
    along = dot_rows(r, directions)
    interior = (along > 0.0) & (along < lengths)
    offsets = r - along[:, None] * directions
    before = along <= 0.0
    if before.any():
        offsets[before] = r[before]
    after = along >= lengths
    if after.any():
        offsets[after] = points[after] - ends[after]
    return offsets, interior


def wall_pairs(positions, radii, walls, margin):
    """Return (ball, wall) index arrays of every ball within r + margin of a wall segment."""
    n = len(positions)
    m = len(walls.starts)
    if n == 0 or m == 0:
        return _EMPTY, _EMPTY
    balls_out = []
    walls_out = []
    reach = radii + margin
    reach2 = (reach * reach)[:, None]
    # Blocks of walls keep memory near 4 million distances however many walls there are.
    block = max(1, 4_000_000 // n)
    for first in range(0, m, block):
        sl = slice(first, first + block)
        rx = positions[:, 0:1] - walls.starts[None, sl, 0]
        ry = positions[:, 1:2] - walls.starts[None, sl, 1]
        along = np.clip(rx * walls.directions[None, sl, 0] + ry * walls.directions[None, sl, 1],
                        0.0, walls.lengths[None, sl])
        dx = rx - along * walls.directions[None, sl, 0]
        dy = ry - along * walls.directions[None, sl, 1]
        ball, wall = np.nonzero(dx * dx + dy * dy < reach2)
        balls_out.append(ball)
        walls_out.append(wall + first)
    return np.concatenate(balls_out), np.concatenate(walls_out)


class NeighbourLists:
    """Ball-ball and ball-wall candidate pairs, valid until balls may have moved skin / 2.

    A pair left out was at least r_i + r_j + skin apart when the lists were built; if no ball
    has moved more than `skin / 2` since, it is still further apart than r_i + r_j and cannot
    be touching. The World reports an upper bound of the distance moved; the lists rebuild
    themselves when it reaches half the skin. Per-pair constants (reach squared, the wall's
    geometry) are gathered once per build, not once per substep.
    """

    def __init__(self, skin):
        self.skin = float(skin)
        self.moved = np.inf  # forces a build on first use
        self.builds = 0
        self._order = None
        self.ball_a = self.ball_b = _EMPTY
        self.reach2 = np.empty(0)
        self.wall_ball = self.wall_index = _EMPTY

    def update(self, positions, radii, walls, moved):
        """Account for `moved` metres of travel; rebuild if the skin may be closed."""
        self.moved += moved
        if 2.0 * self.moved < self.skin:
            return False
        self.ball_a, self.ball_b, self._order = grid_pairs(
            positions, radii, self.skin, self._order)
        reach = np.take(radii, self.ball_a) + np.take(radii, self.ball_b)
        self.reach2 = reach * reach
        self.wall_ball, self.wall_index = wall_pairs(positions, radii, walls, self.skin)
        wall = self.wall_index
        self.wall_starts = take_rows(walls.starts, wall)
        self.wall_ends = take_rows(walls.ends, wall)
        self.wall_directions = take_rows(walls.directions, wall)
        self.wall_lengths = np.take(walls.lengths, wall)
        self.wall_radius2 = np.square(np.take(radii, self.wall_ball))
        self.moved = 0.0
        self.builds += 1
        return True
