"""Candidate pairs from positions and radii: a uniform grid (cell list), plus Verlet lists.

The broadphase knows nothing of collision responses. It answers one question: which pairs
of balls, and which ball-wall pairs, can possibly be touching? It answers it in O(N):

- `grid_pairs` sorts balls by grid cell (cells at least as large as the interaction range)
  and pairs every ball with the balls of its own cell and four neighbouring cells (a half
  stencil, so each pair appears once), without a Python loop.
- `NeighbourLists` keeps those pairs, widened by a skin, for as long as no ball can have
  moved far enough to close the skin: the grid is rebuilt every few steps, not every step.
"""
import numpy as np

_EMPTY = np.empty(0, dtype=np.intp)


def grid_pairs(positions, radii, margin):
    """Return (i, j), i < j, of every pair with |x_i - x_j| < r_i + r_j + margin."""
    n = len(positions)
    if n < 2:
        return _EMPTY, _EMPTY
    cell = 2.0 * float(radii.max()) + margin
    cells = np.floor((positions - positions.min(axis=0)) / cell).astype(np.int64)
    # Column stride leaves a free row on both sides, so key +- 1 never wraps into a
    # neighbouring column.
    stride = int(cells[:, 1].max()) + 3
    keys = cells[:, 0] * stride + cells[:, 1] + 1
    order = np.argsort(keys, kind='stable')
    sorted_keys = keys[order]

    # Half stencil: the rest of the own cell, then (0,+1), (+1,-1), (+1,0), (+1,+1).
    cell_end = np.searchsorted(sorted_keys, sorted_keys, side='right')
    lows = [np.arange(1, n + 1)]
    highs = [cell_end]
    for offset in (1, stride - 1, stride, stride + 1):
        target = sorted_keys + offset
        lows.append(np.searchsorted(sorted_keys, target, side='left'))
        highs.append(np.searchsorted(sorted_keys, target, side='right'))
    low = np.concatenate(lows)
    counts = np.concatenate(highs) - low
    total = int(counts.sum())
    if total == 0:
        return _EMPTY, _EMPTY
    first = np.repeat(np.tile(np.arange(n), 5), counts)
    starts = np.cumsum(counts) - counts
    second = np.repeat(low - starts, counts) + np.arange(total)
    a = order[first]
    b = order[second]

    delta = positions[a] - positions[b]
    reach = radii[a] + radii[b] + margin
    near = np.einsum('ij,ij->i', delta, delta) < reach * reach
    a = a[near]
    b = b[near]
    return np.minimum(a, b), np.maximum(a, b)


def segment_offsets(points, starts, directions, lengths, ends):
    """Offset from the nearest point of each segment to each point, and whether it is inside.

    Inside the segment the offset is the seed's s = r - (r.w) w, perpendicular to the wall;
    beyond an end it is the vector from that end point to the point.
    """
    r = points - starts
    along = np.einsum('ij,ij->i', r, directions)
    interior = (along > 0.0) & (along < lengths)
    offsets = r - along[:, None] * directions
    before = along <= 0.0
    offsets[before] = r[before]
    after = along >= lengths
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
    # One wall at a time keeps memory at O(N) however many walls there are.
    for k in range(m):
        ball = np.arange(n)
        wall = np.full(n, k)
        offsets, _ = segment_offsets(
            positions, walls.starts[wall], walls.directions[wall], walls.lengths[wall],
            walls.ends[wall])
        reach = radii + margin
        near = np.einsum('ij,ij->i', offsets, offsets) < reach * reach
        balls_out.append(ball[near])
        walls_out.append(wall[near])
    return np.concatenate(balls_out), np.concatenate(walls_out)


class NeighbourLists:
    """Ball-ball and ball-wall candidate pairs, valid until balls may have moved skin / 2.

    A pair left out was at least r_i + r_j + skin apart when the lists were built; if no ball
    has moved more than `skin / 2` since, it is still further apart than r_i + r_j and cannot
    be touching. The World reports an upper bound of the distance moved; the lists rebuild
    themselves when it reaches half the skin.
    """

    def __init__(self, skin):
        self.skin = float(skin)
        self.moved = np.inf  # forces a build on first use
        self.ball_a = self.ball_b = _EMPTY
        self.wall_ball = self.wall_index = _EMPTY
        self.builds = 0

    def invalidate(self):
        """Forget the lists (the world changed in a way the bound does not cover)."""
        self.moved = np.inf

    def update(self, positions, radii, walls, moved):
        """Account for `moved` metres of travel; rebuild if the skin may be closed."""
        self.moved += moved
        if 2.0 * self.moved < self.skin:
            return False
        self.ball_a, self.ball_b = grid_pairs(positions, radii, self.skin)
        self.wall_ball, self.wall_index = wall_pairs(positions, radii, walls, self.skin)
        self.moved = 0.0
        self.builds += 1
        return True
