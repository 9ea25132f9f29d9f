"""The compiled backend: the seed-mode step (`core.stepping`) as numba loops, bit for bit.

Why it exists: a numpy step pays 1-2 us per numpy call and needs about a hundred calls per
substep, so below a few thousand balls that fixed cost dominates. Compiled loops have no
such floor. What it computes is exactly the numpy backend's: the same stages under the same
names (`move`, `find_contacts`, `resolve`, `respond_pair`, `respond_wall`), the formulas
compiled from the same source (`core.rules`), the same plan and re-split (`core.stepping`),
the same canonical contact order and the same rounds, with no fastmath (no fused
multiply-adds, no re-association). Its trajectories are therefore bit-identical to the
numpy backend's, and a recording made with one re-simulates exactly with the other.

Only the broadphase is this file's own: the same hierarchical grid and Verlet lists as
`broadphase`, built in compiled loops, their candidates put in canonical order by a counting
sort. Candidate lists may differ from the numpy backend's; the touching contacts may not.

Compiled kernels are cached on disk (numba's cache=True, next to this file or in the
user's cache directory). numba only notices changes to this file, not to the modules its
kernels inline (`rules`, `stepping`, `broadphase`, `limits`), so `ensure_fresh_cache`
compares a fingerprint of those with the one the cached kernels were built with, and
rebuilds them if they differ. `python -m ball_world.core.warm` compiles and caches everything
once (a set-up step), so no run pays the compilation.

numba is in requirements/base.txt; without it the numpy backend still works, and
`available()` says whether this one can.
"""
import hashlib

import numpy as np

from ball_world.core import broadphase, limits, rules, static_geometry, stepping
from ball_world.core.broadphase import (CELLS_PER_BALL, CELLS_SLACK, grid_shape, LEVEL_RATIO,
                                        PAD)
from ball_world.core.rules import (advance, pair_approaching, pair_response, pair_touching,
                                   reach_squared, reflect_off_end, reflect_off_wall,
                                   speed_squared, wall_approaching, wall_offset, wall_touching)
from ball_world.core.static_geometry import SLACK, widened
from ball_world.core.stepping import (BALL_BALL, BALL_WALL, MAX_ROUNDS, over_budget,
                                      plan_substeps, reachable_speed, refusal_possible, replan,
                                      ROUNDS, speed_limit, STEP_DONE, STEP_REFUSED, SUBSTEPS,
                                      UNRESOLVED)

try:
    from numba import njit
    from numba.extending import register_jitable
except ImportError:  # the numpy backend needs nothing more
    njit = None

#: Skin of the candidate lists in smallest radii (see numpy_backend.SKIN_RADII).
SKIN_RADII = 2.0
#: Lists are rebuilt a millionth before the skin could close: rounding never decides.
LISTS_MARGIN = 1.0 - 1e-6
#: A ball's wall list is searched again, when some ball's must be, once that ball has moved
#: this part of the skin (see refresh_walls).
REFRESH_PART = 0.75
#: Absolute slack of wall_clearance per metre of coordinates: a million times the rounding
#: of an offset, so a ball find_contacts skips can never be touching by the formula.
CLEARANCE_SLACK = 1e-9
#: Entries of seed_step's `lists`: rows of candidate pairs and of ball-wall pairs in the
#: buffers (or rows needed, when they outgrew them), and whether the buffers hold them.
PAIRS, NEAR_WALLS, FRESH = range(3)
#: A world with no map and at most this many walls finds its ball-wall candidates as the
#: step did before the static index (commit 6c90059): each wall rasterised into the balls'
#: grids when the pair lists are built, one lifetime for both lists, no per-ball wall
#: anchors. The static index's search (a dilated bucket per ball, wall lists of their own
#: lifetime, skipped while clear) pays for a map's runs; a plain box paid for it too, 11-16%
#: of its step (issue 33). Both find every wall within reach: the contacts, and so the
#: trajectories, are the same.
DIRECT_WALLS = 64
#: Columns of the packed wall array the kernels take.
WALL_COLUMNS = ('start_x', 'start_y', 'end_x', 'end_y', 'w_x', 'w_y', 'length')


def available():
    """True when numba is installed, so World(backend='numba') can run."""
    return njit is not None


_KERNELS = []


def _compile(function):
    """njit with an on-disk cache, no fastmath, numpy's division semantics (inf, not raise)."""
    if njit is None:
        return function
    kernel = njit(cache=True, nogil=True, error_model='numpy')(function)
    _KERNELS.append(kernel)
    return kernel


def _hash_code(digest, code):
    """Feed a code object's bytecode, names and constants (nested code too) to `digest`."""
    digest.update(code.co_code + repr(code.co_names).encode())
    for constant in code.co_consts:
        if hasattr(constant, 'co_code'):
            _hash_code(digest, constant)
        elif isinstance(constant, frozenset):  # its repr's order varies with hash seeds
            digest.update(repr(sorted(map(repr, constant))).encode())
        else:
            digest.update(repr(constant).encode())


def _fingerprint():
    """A number that changes whenever code or constants the kernels inline change."""
    digest = hashlib.sha256()
    for module in (rules, stepping, broadphase, static_geometry):
        for name, value in sorted(vars(module).items()):
            if getattr(value, '__module__', None) == module.__name__ and hasattr(
                    value, '__code__'):
                digest.update(name.encode())
                _hash_code(digest, value.__code__)
    constants = (limits.MAX_SUBSTEPS, MAX_ROUNDS, LEVEL_RATIO, CELLS_PER_BALL, CELLS_SLACK,
                 PAD, SLACK, STEP_DONE, STEP_REFUSED)
    digest.update(repr(constants).encode())
    return int.from_bytes(digest.digest()[:7], 'big')


FINGERPRINT = _fingerprint()

# The shared formulas and plan ---------------------------------------------------------

#: Plain functions of `rules`, `stepping` and `broadphase` that the kernels call. numba
#: compiles them where they are called (also from one another), with the kernels' options.
SHARED = (advance, speed_squared, reach_squared, pair_touching, pair_approaching,
          pair_response, wall_offset, wall_touching, wall_approaching, reflect_off_wall,
          reflect_off_end, plan_substeps, replan, over_budget, reachable_speed, speed_limit,
          refusal_possible, grid_shape, widened)

if njit is not None:
    for _function in SHARED:
        register_jitable(error_model='numpy')(_function)


@_compile
def built_against():
    """The FINGERPRINT these kernels were compiled with (frozen into the cached code)."""
    return FINGERPRINT


# Stage 1 ------------------------------------------------------------------------------

@_compile
def move(x, v, h):
    """Every ball moves for h seconds."""
    for i in range(x.shape[0]):
        x[i, 0] = advance(x[i, 0], v[i, 0], h)
        x[i, 1] = advance(x[i, 1], v[i, 1], h)


# Stage 2: candidates from the hierarchical grid, then the touching contacts ------------

@_compile
def build_grids(x, members, level_starts, level_largest, margin):
    """Counting sort of each level's balls into its own grid, cells 2 r_max + margin wide.

    Returns (origin, cell, shape, starts, cell_balls, cell_keys, scale): level k's balls in
    cell order are cell_balls[level_starts[k]:level_starts[k + 1]]; shape[k] holds columns,
    rows, the key stride and where its table begins in `starts`; the balls of cell `key`
    are cell_balls[starts[base + key]:starts[base + key + 1]].
    """
    levels = level_largest.shape[0]
    n = members.shape[0]
    low = np.empty((levels, 2))
    extent = np.empty((levels, 2))
    scale = 0.0
    for k in range(levels):
        first = members[level_starts[k]]
        min_x = max_x = x[first, 0]
        min_y = max_y = x[first, 1]
        for p in range(level_starts[k] + 1, level_starts[k + 1]):
            i = members[p]
            min_x = min(min_x, x[i, 0])
            max_x = max(max_x, x[i, 0])
            min_y = min(min_y, x[i, 1])
            max_y = max(max_y, x[i, 1])
        low[k, 0] = min_x
        low[k, 1] = min_y
        extent[k, 0] = max_x - min_x
        extent[k, 1] = max_y - min_y
        scale = max(scale, abs(min_x), abs(max_x), abs(min_y), abs(max_y))
    cell = np.empty(levels)
    shape = np.empty((levels, 4), dtype=np.int64)
    table = 0
    for k in range(levels):
        size, nx, ny = grid_shape(extent[k, 0], extent[k, 1],
                                  widened(2.0 * level_largest[k] + margin, scale),
                                  level_starts[k + 1] - level_starts[k])
        cell[k] = size
        stride = ny + 2 * PAD
        shape[k, 0] = nx
        shape[k, 1] = ny
        shape[k, 2] = stride
        shape[k, 3] = table
        table += (nx + 2 * PAD) * stride + 1
    starts = np.zeros(table, dtype=np.int64)
    keys = np.empty(n, dtype=np.int64)
    for k in range(levels):
        nx, ny, stride, base = shape[k, 0], shape[k, 1], shape[k, 2], shape[k, 3]
        for p in range(level_starts[k], level_starts[k + 1]):
            i = members[p]
            cx = min(int((x[i, 0] - low[k, 0]) / cell[k]), nx - 1)
            cy = min(int((x[i, 1] - low[k, 1]) / cell[k]), ny - 1)
            keys[p] = (cx + PAD) * stride + cy + PAD
            starts[base + keys[p]] += 1
        # Inclusive prefix sums from the level's first slot, then a backward fill that
        # leaves starts[base + key] at the first ball of each cell.
        size = (nx + 2 * PAD) * stride
        running = level_starts[k]
        for key in range(size):
            running += starts[base + key]
            starts[base + key] = running
        starts[base + size] = level_starts[k + 1]
    cell_balls = np.empty(n, dtype=np.int64)
    cell_keys = np.empty(n, dtype=np.int64)
    for k in range(levels):
        base = shape[k, 3]
        for p in range(level_starts[k + 1] - 1, level_starts[k] - 1, -1):
            key = keys[p]
            starts[base + key] -= 1
            cell_balls[starts[base + key]] = members[p]
            cell_keys[starts[base + key]] = key
    return low, cell, shape, starts, cell_balls, cell_keys, scale


@_compile
def _doubled(found):
    """`found` (K, 2) copied into twice the room."""
    bigger = np.empty((2 * found.shape[0], 2), dtype=found.dtype)
    bigger[:found.shape[0]] = found
    return bigger


@_compile
def _near(x, radii, i, j, margin):
    """Whether balls i and j are closer than r_i + r_j + margin."""
    dx = x[i, 0] - x[j, 0]
    dy = x[i, 1] - x[j, 1]
    reach = radii[i] + radii[j] + margin
    return dx * dx + dy * dy < reach * reach


@_compile
def _candidate_pairs(x, radii, margin, level_starts, low, cell, shape, starts, cell_balls,
                     cell_keys):
    """Pairs (a < b) closer than r_a + r_b + margin, unsorted: half stencil within a level,
    3 x 3 cells of every larger level around each ball."""
    found = np.empty((2 * x.shape[0] + 16, 2), dtype=np.int64)
    count = 0
    levels = cell.shape[0]
    for k in range(levels):
        stride = shape[k, 2]
        base = shape[k, 3]
        for p in range(level_starts[k], level_starts[k + 1]):
            i = cell_balls[p]
            key = cell_keys[p]
            for s in range(p + 1, starts[base + key + 1]):
                j = cell_balls[s]
                if _near(x, radii, i, j, margin):
                    if count == found.shape[0]:
                        found = _doubled(found)
                    found[count, 0] = min(i, j)
                    found[count, 1] = max(i, j)
                    count += 1
            for offset in (1, stride - 1, stride, stride + 1):
                other = base + key + offset
                for s in range(starts[other], starts[other + 1]):
                    j = cell_balls[s]
                    if _near(x, radii, i, j, margin):
                        if count == found.shape[0]:
                            found = _doubled(found)
                        found[count, 0] = min(i, j)
                        found[count, 1] = max(i, j)
                        count += 1
        for larger in range(k + 1, levels):
            nx, ny, stride, base = shape[larger, 0], shape[larger, 1], shape[larger, 2], \
                shape[larger, 3]
            for p in range(level_starts[k], level_starts[k + 1]):
                i = cell_balls[p]
                fx = (x[i, 0] - low[larger, 0]) / cell[larger]
                fy = (x[i, 1] - low[larger, 1]) / cell[larger]
                if not (fx >= -1.0 and fx < nx + 1.0 and fy >= -1.0 and fy < ny + 1.0):
                    continue
                centre = (int(np.floor(fx)) + PAD) * stride + int(np.floor(fy)) + PAD
                for dx in range(-1, 2):
                    for dy in range(-1, 2):
                        other = base + centre + dx * stride + dy
                        for s in range(starts[other], starts[other + 1]):
                            j = cell_balls[s]
                            if _near(x, radii, i, j, margin):
                                if count == found.shape[0]:
                                    found = _doubled(found)
                                found[count, 0] = min(i, j)
                                found[count, 1] = max(i, j)
                                count += 1
    return found[:count]


@_compile
def _cell_range(low, high, reach, origin, cell, cells):
    """First and last cell index within reach of [low, high], clipped to the grid."""
    first = int(np.floor(min(max((low - reach - origin) / cell, -1.0), float(cells))))
    last = int(np.floor(min(max((high + reach - origin) / cell, -1.0), float(cells))))
    return max(first, 0), min(last, cells - 1)


@_compile
def _walls_into(found, x, radii, margin, walls, index_grid, index_shape, index_first,
                index_items, cell_balls):
    """_candidate_walls' search, written into `found` (at least one row) while it has room;
    returns how many pairs there are (more than its rows: call again with that many). A
    fixed buffer, not one grown inside the loop (reassigning the array there doubled the
    search's time), and no branch on the distance test (each pair is written, and kept by
    counting it: a fifth of a map's search was mispredicted branches; measured).
    """
    count = 0
    origin_x = index_grid[0]
    origin_y = index_grid[1]
    size = index_grid[2]
    columns = index_shape[0]
    rows = index_shape[1]
    last = found.shape[0] - 1
    for p in range(cell_balls.shape[0]):
        i = cell_balls[p]
        col, _ = _cell_range(x[i, 0], x[i, 0], 0.0, origin_x, size, columns)
        row, _ = _cell_range(x[i, 1], x[i, 1], 0.0, origin_y, size, rows)
        bucket = min(col, columns - 1) * rows + min(row, rows - 1)
        reach_i = radii[i] + margin
        reach2 = reach_i * reach_i
        for s in range(index_first[bucket], index_first[bucket + 1]):
            w = index_items[s]
            sx, sy, _ = wall_offset(x[i, 0], x[i, 1], walls[w, 0], walls[w, 1], walls[w, 4],
                                    walls[w, 5], walls[w, 6])
            slot = min(count, last)
            found[slot, 0] = i
            found[slot, 1] = w
            count += np.int64(sx * sx + sy * sy < reach2)
    return count


@_compile
def _candidate_walls(x, radii, margin, walls, index_grid, index_shape, index_first,
                     index_items, cell_balls):
    """(ball, wall) with the ball closer than r + margin to the segment, unsorted, for the
    balls `cell_balls` lists: each reads its own bucket of the static index dilated by at
    least the largest r + margin (core.static_geometry.StaticGeometry.dilated), which lists
    each wall within that reach of the bucket once. A ball outside the index's box reads the
    nearest bucket, which lists every wall within reach of it too (moving a point into the
    box brings it no further from any point inside). Balls are taken in the order of their
    grid cells (`cell_balls`), so neighbours read neighbouring buckets: in index order most
    reads were cache misses, which nearly doubled the search of a map's runs (measured).
    """
    found = np.empty((2 * x.shape[0] + 64, 2), dtype=np.int64)
    if index_items.shape[0] == 0:
        return found[:0]
    count = _walls_into(found, x, radii, margin, walls, index_grid, index_shape, index_first,
                        index_items, cell_balls)
    if count >= found.shape[0]:  # its last row may hold a pair that was not kept
        found = np.empty((count + 1, 2), dtype=np.int64)
        _walls_into(found, x, radii, margin, walls, index_grid, index_shape, index_first,
                    index_items, cell_balls)
    return found[:count]


@_compile
def _canonical(found, rows):
    """Rows (first, second) sorted by first, then second: the canonical order.

    A counting sort on `first` (values below `rows`), then an insertion sort of each run
    of equal firsts, which holds a handful of rows: O(len(found) + rows), no comparison
    sort of the whole list.
    """
    count = found.shape[0]
    starts = np.zeros(rows + 1, dtype=np.int64)
    for c in range(count):
        starts[found[c, 0] + 1] += 1
    for r in range(rows):
        starts[r + 1] += starts[r]
    fill = starts[:-1].copy()
    ordered = np.empty_like(found)
    for c in range(count):
        slot = fill[found[c, 0]]
        ordered[slot, 0] = found[c, 0]
        ordered[slot, 1] = found[c, 1]
        fill[found[c, 0]] += 1
    for r in range(rows):
        for i in range(starts[r] + 1, starts[r + 1]):
            second = ordered[i, 1]
            j = i - 1
            while j >= starts[r] and ordered[j, 1] > second:
                ordered[j + 1, 1] = ordered[j, 1]
                j -= 1
            ordered[j + 1, 1] = second
    return ordered


@_compile
def build_pairs(x, radii, margin, members, level_starts, level_largest, order):
    """Candidate pairs within `margin` of touching, in canonical order; `order` gets the
    balls in the order of their grid cells (for refresh_walls)."""
    low, cell, shape, starts, cell_balls, cell_keys, scale = build_grids(
        x, members, level_starts, level_largest, margin)
    order[:] = cell_balls
    pairs = _candidate_pairs(x, radii, margin, level_starts, low, cell, shape, starts,
                             cell_balls, cell_keys)
    return _canonical(pairs, x.shape[0])


@_compile
def _rasterised_walls(x, radii, margin, walls, wall_scale, level_starts, level_largest, low,
                      cell, shape, starts, cell_balls, scale):
    """(ball, wall) with the ball closer than r + margin to the segment, unsorted: each
    wall rasterised, column by column, into the cells of each level within reach of it (the
    balls' own grids, build_grids'), so only balls beside a wall are tested."""
    found = np.empty((64, 2), dtype=np.int64)
    count = 0
    for k in range(cell.shape[0]):
        nx, ny, stride, base = shape[k, 0], shape[k, 1], shape[k, 2], shape[k, 3]
        reach = widened(level_largest[k] + margin, max(scale, wall_scale))
        size = cell[k]
        for w in range(walls.shape[0]):
            x0, y0, x1, y1 = walls[w, 0], walls[w, 1], walls[w, 2], walls[w, 3]
            first_col, last_col = _cell_range(min(x0, x1), max(x0, x1), reach, low[k, 0], size,
                                              nx)
            dx = x1 - x0
            dy = y1 - y0
            for col in range(first_col, last_col + 1):
                left = low[k, 0] + col * size - reach - x0
                right = low[k, 0] + (col + 1) * size + reach - x0
                if dx == 0.0:
                    t_low = 0.0
                    t_high = 1.0
                else:
                    t_low = min(max(min(left / dx, right / dx), 0.0), 1.0)
                    t_high = min(max(max(left / dx, right / dx), 0.0), 1.0)
                ya = y0 + t_low * dy
                yb = y0 + t_high * dy
                first_row, last_row = _cell_range(min(ya, yb), max(ya, yb), reach, low[k, 1],
                                                  size, ny)
                for row in range(first_row, last_row + 1):
                    key = base + (col + PAD) * stride + row + PAD
                    for s in range(starts[key], starts[key + 1]):
                        i = cell_balls[s]
                        sx, sy, _ = wall_offset(x[i, 0], x[i, 1], walls[w, 0], walls[w, 1],
                                                walls[w, 4], walls[w, 5], walls[w, 6])
                        reach_i = radii[i] + margin
                        if sx * sx + sy * sy < reach_i * reach_i:
                            if count == found.shape[0]:
                                found = _doubled(found)
                            found[count, 0] = i
                            found[count, 1] = w
                            count += 1
    return found[:count]


@_compile
def build_direct(x, radii, walls, wall_scale, margin, members, level_starts, level_largest,
                 order, wall_first):
    """build_pairs' pairs and the ball-wall pairs within `margin` of touching, from the same
    grids, both in canonical order (DIRECT_WALLS: a world without a map); `wall_first` gets
    where each ball's ball-wall pairs begin (as refresh_walls keeps it)."""
    low, cell, shape, starts, cell_balls, cell_keys, scale = build_grids(
        x, members, level_starts, level_largest, margin)
    order[:] = cell_balls
    pairs = _candidate_pairs(x, radii, margin, level_starts, low, cell, shape, starts,
                             cell_balls, cell_keys)
    near_walls = _canonical(_rasterised_walls(x, radii, margin, walls, wall_scale,
                                              level_starts, level_largest, low, cell, shape,
                                              starts, cell_balls, scale), x.shape[0])
    row = 0
    for i in range(x.shape[0]):
        wall_first[i] = row
        while row < near_walls.shape[0] and near_walls[row, 0] == i:
            row += 1
    wall_first[x.shape[0]] = row
    return _canonical(pairs, x.shape[0]), near_walls


@_compile
def wall_clearance(x, radii, walls, rows, i):
    """How far ball i may move from where it is before it could touch any wall of its list
    `rows` ((ball, wall) rows): its smallest gap to them, shrunk by LISTS_MARGIN and by far
    more than the rounding of the offsets (CLEARANCE_SLACK of the coordinates); 0 or less
    when it may touch one already, +inf without walls. The distance to a fixed segment
    changes by at most the distance moved, so find_contacts may skip the ball's walls
    while it has moved less: a third of a step in a map was testing walls that balls
    stood well clear of (measured)."""
    gap2 = np.inf
    for c in range(rows.shape[0]):
        w = rows[c, 1]
        sx, sy, _ = wall_offset(x[i, 0], x[i, 1], walls[w, 0], walls[w, 1], walls[w, 4],
                                walls[w, 5], walls[w, 6])
        gap2 = min(gap2, sx * sx + sy * sy)
    if gap2 == np.inf:
        return np.inf
    slack = CLEARANCE_SLACK * (1.0 + abs(x[i, 0]) + abs(x[i, 1]) + radii[i])
    return LISTS_MARGIN * (np.sqrt(gap2) - radii[i]) - slack


@_compile
def refresh_walls(x, radii, walls, index_grid, index_shape, index_first, index_items, margin,
                  order, wall_anchor, near_walls, wall_first, wall_clear, everyone):
    """The ball-wall pairs within `margin` of touching, in canonical order, with the lists of
    the balls that moved REFRESH_PART of the margin or more since theirs were made searched
    again (all balls when `everyone`), the others kept: a ball's list stays valid until that
    ball alone has moved the whole margin (a wall does not move), so slow balls keep theirs
    while the fastest set the pace. (Three quarters, not a half: at 10,000 balls in a map,
    where a search costs the runs near the ball, a third as many balls searched per call,
    twice the calls, a step 12% cheaper; measured.) Returns the new pairs; updates
    `wall_anchor` (where each ball's list was made), `wall_first` (ball i's pairs are rows
    wall_first[i] to wall_first[i + 1]) and `wall_clear` (wall_clearance) in place. Balls
    are searched in `order` (build_pairs')."""
    n = x.shape[0]
    half = REFRESH_PART * margin
    again = np.zeros(n, dtype=np.bool_)
    count = 0
    for i in range(n):
        dx = x[i, 0] - wall_anchor[i, 0]
        dy = x[i, 1] - wall_anchor[i, 1]
        if everyone or not dx * dx + dy * dy < half * half:
            again[i] = True
            count += 1
    searched = np.empty(count, dtype=np.int64)
    count = 0
    for p in range(n):
        if again[order[p]]:
            searched[count] = order[p]
            count += 1
    found = _canonical(_candidate_walls(x, radii, margin, walls, index_grid, index_shape,
                                        index_first, index_items, searched), n)
    kept = 0
    for i in range(n):
        if not again[i]:
            kept += wall_first[i + 1] - wall_first[i]
    merged = np.empty((kept + found.shape[0], 2), dtype=np.int64)
    row = 0
    new = 0
    for i in range(n):
        start = row
        if again[i]:
            while new < found.shape[0] and found[new, 0] == i:
                merged[row, 0] = i
                merged[row, 1] = found[new, 1]
                row += 1
                new += 1
            wall_anchor[i, 0] = x[i, 0]
            wall_anchor[i, 1] = x[i, 1]
            wall_clear[i] = wall_clearance(x, radii, walls, merged[start:row], i)
        else:
            for old in range(wall_first[i], wall_first[i + 1]):
                merged[row, 0] = i
                merged[row, 1] = near_walls[old, 1]
                row += 1
        wall_first[i] = start
    wall_first[n] = row
    return merged


@_compile
def find_contacts(x, radii, walls, candidates, near_walls, wall_anchor, wall_first,
                  wall_clear):
    """The touching contacts among the candidates, in their (canonical) order.

    Ball i's walls (rows wall_first[i] to wall_first[i + 1] of near_walls) are not tested
    while it lies less than wall_clear[i] from wall_anchor[i] (refresh_walls): none of them
    can touch it. Returns pairs (P, 2) with a < b, rel (P, 2) = r_a - r_b, wall contacts
    (W, 2) as (ball, wall), offsets (W, 2) and interior (W,).
    """
    touching = np.empty(candidates.shape[0], dtype=np.bool_)
    count = 0
    for c in range(candidates.shape[0]):
        a = candidates[c, 0]
        b = candidates[c, 1]
        touching[c] = pair_touching(x[a, 0] - x[b, 0], x[a, 1] - x[b, 1],
                                    reach_squared(radii[a], radii[b]))
        count += touching[c]
    pairs = np.empty((count, 2), dtype=np.int64)
    rel = np.empty((count, 2))
    count = 0
    for c in range(candidates.shape[0]):
        if touching[c]:
            a = candidates[c, 0]
            b = candidates[c, 1]
            pairs[count, 0] = a
            pairs[count, 1] = b
            rel[count, 0] = x[a, 0] - x[b, 0]
            rel[count, 1] = x[a, 1] - x[b, 1]
            count += 1
    inside = np.zeros(near_walls.shape[0], dtype=np.bool_)
    count = 0
    c = 0
    while c < near_walls.shape[0]:
        i = near_walls[c, 0]
        end = wall_first[i + 1]
        dx = x[i, 0] - wall_anchor[i, 0]
        dy = x[i, 1] - wall_anchor[i, 1]
        clear = wall_clear[i]
        if clear > 0.0 and dx * dx + dy * dy < clear * clear:
            c = end
            continue
        for c in range(c, end):
            w = near_walls[c, 1]
            sx, sy, _ = wall_offset(x[i, 0], x[i, 1], walls[w, 0], walls[w, 1], walls[w, 4],
                                    walls[w, 5], walls[w, 6])
            inside[c] = wall_touching(sx, sy, radii[i])
            count += inside[c]
        c = end
    contacts = np.empty((count, 2), dtype=np.int64)
    offsets = np.empty((count, 2))
    interior = np.empty(count, dtype=np.bool_)
    count = 0
    for c in range(near_walls.shape[0]):
        if inside[c]:
            i = near_walls[c, 0]
            w = near_walls[c, 1]
            contacts[count, 0] = i
            contacts[count, 1] = w
            offsets[count, 0], offsets[count, 1], interior[count] = wall_offset(
                x[i, 0], x[i, 1], walls[w, 0], walls[w, 1], walls[w, 4], walls[w, 5],
                walls[w, 6])
            count += 1
    return pairs, rel, contacts, offsets, interior


# Stages 3 and 4 -----------------------------------------------------------------------

@_compile
def respond_pair(v, masses, a, b, rx, ry):
    """The seed's ball-ball response for one pair; returns the larger |v|^2 after it."""
    v[a, 0], v[a, 1], v[b, 0], v[b, 1] = pair_response(
        v[a, 0], v[a, 1], v[b, 0], v[b, 1], rx, ry, masses[a], masses[b])
    return max(speed_squared(v[a, 0], v[a, 1]), speed_squared(v[b, 0], v[b, 1]))


@_compile
def respond_wall(v, i, walls, w, sx, sy, inside):
    """Reflect ball i off wall w (or off its end point); returns |v|^2 after it."""
    if inside:
        v[i, 0], v[i, 1] = reflect_off_wall(v[i, 0], v[i, 1], walls[w, 4], walls[w, 5])
    else:
        v[i, 0], v[i, 1] = reflect_off_end(v[i, 0], v[i, 1], sx, sy)
    return speed_squared(v[i, 0], v[i, 1])


@_compile
def resolve(v, masses, walls, pairs, rel, contacts, offsets, interior, best, totals):
    """Rounds of conflict-free approaching contacts, numbered pairs first, then walls.

    `best` (one entry per ball, -1 between calls) holds the lowest approaching contact of
    each ball in the current round. Returns the largest speed right after a response.
    """
    n_pairs = pairs.shape[0]
    n_walls = contacts.shape[0]
    if n_pairs == 0 and n_walls == 0:
        return 0.0
    flags = np.empty(n_pairs + n_walls, dtype=np.bool_)
    fastest2 = 0.0
    for round_index in range(MAX_ROUNDS + 1):
        approaching = 0
        for c in range(n_pairs):
            a = pairs[c, 0]
            b = pairs[c, 1]
            flags[c] = pair_approaching(rel[c, 0], rel[c, 1], v[a, 0], v[a, 1], v[b, 0], v[b, 1])
            if flags[c]:
                approaching += 1
                if best[a] < 0:
                    best[a] = c
                if best[b] < 0:
                    best[b] = c
        for c in range(n_walls):
            i = contacts[c, 0]
            flags[n_pairs + c] = wall_approaching(offsets[c, 0], offsets[c, 1], v[i, 0], v[i, 1])
            if flags[n_pairs + c]:
                approaching += 1
                if best[i] < 0:
                    best[i] = n_pairs + c
        if approaching == 0:
            break
        last = round_index == MAX_ROUNDS
        if last:
            totals[UNRESOLVED] += approaching
        else:
            totals[ROUNDS] += 1
        for c in range(n_pairs):
            if flags[c]:
                a = pairs[c, 0]
                b = pairs[c, 1]
                if not last and best[a] == c and best[b] == c:
                    fastest2 = max(fastest2, respond_pair(v, masses, a, b, rel[c, 0], rel[c, 1]))
                    totals[BALL_BALL] += 1
        for c in range(n_walls):
            if flags[n_pairs + c]:
                i = contacts[c, 0]
                if not last and best[i] == n_pairs + c:
                    fastest2 = max(fastest2, respond_wall(v, i, walls, contacts[c, 1],
                                                          offsets[c, 0], offsets[c, 1],
                                                          interior[c]))
                    totals[BALL_WALL] += 1
        for c in range(n_pairs):
            if flags[c]:
                best[pairs[c, 0]] = -1
                best[pairs[c, 1]] = -1
        for c in range(n_walls):
            if flags[n_pairs + c]:
                best[contacts[c, 0]] = -1
        if last:
            break
    return np.sqrt(fastest2)


# The step -----------------------------------------------------------------------------

@_compile
def speed_and_energy(v, masses):
    """Speed of the fastest ball (m/s) and the kinetic energy (J), in one pass."""
    fastest2 = 0.0
    energy = 0.0
    for i in range(v.shape[0]):
        speed2 = speed_squared(v[i, 0], v[i, 1])
        fastest2 = max(fastest2, speed2)
        energy += masses[i] * speed2
    return np.sqrt(fastest2), 0.5 * energy


@_compile
def lists_stale(x, anchor, wall_anchor, skin):
    """Whether the pair lists (built with the balls at `anchor`) and the ball-wall lists
    (built at `wall_anchor`) may have had their skin closed: (pairs, walls).

    A pair left out was r_a + r_b + skin apart; it can touch only once the two largest
    displacements since then add up to the skin. A ball-wall pair left out needs its ball
    alone to move the whole skin (a wall does not move), so the ball-wall lists, which cost
    a map's runs, last about twice as long and are kept apart. Tighter than the numpy
    backend's bound (speed times time), so rebuilds are rarer.
    """
    first = 0.0
    second = 0.0
    wall = 0.0
    for i in range(x.shape[0]):
        dx = x[i, 0] - anchor[i, 0]
        dy = x[i, 1] - anchor[i, 1]
        moved2 = dx * dx + dy * dy
        if moved2 > second:
            if moved2 > first:
                second = first
                first = moved2
            else:
                second = moved2
        dx = x[i, 0] - wall_anchor[i, 0]
        dy = x[i, 1] - wall_anchor[i, 1]
        wall = max(wall, dx * dx + dy * dy)
    limit = LISTS_MARGIN * skin
    return not np.sqrt(first) + np.sqrt(second) < limit, not np.sqrt(wall) < limit


@_compile
def seed_step(x, v, radii, masses, min_mass, dt, travel, walls, index_grid, index_shape,
              index_first, index_items, members, level_starts, level_largest, skin,
              pair_rows, wall_rows, lists, anchor, wall_anchor, wall_first, wall_clear,
              order, best, totals):
    """One seed-mode step, planned and split exactly as numpy_backend.NumpyStepper.step.

    The candidates are Verlet lists with `skin`, built with the balls at `anchor` (pairs)
    and, ball by ball, at `wall_anchor` (ball-wall pairs, see lists_stale and
    refresh_walls, which keeps `wall_first`), kept between steps in the caller's buffers:
    pairs in pair_rows[:lists[PAIRS]], ball-wall pairs in wall_rows[:lists[NEAR_WALLS]],
    valid while lists[FRESH] is 1. They are rebuilt whenever the balls may have closed the
    skin. Buffers, not returned arrays: returning
    arrays to Python costs about 0.5 us a call, a tenth of a whole step at 100 balls. Lists
    that outgrow a buffer are used for the rest of the step, then dropped (FRESH 0) with the
    rows they need in lists[PAIRS] and lists[NEAR_WALLS], for the caller to grow the
    buffers. Counts into `totals` (zeroed first). Returns STEP_DONE, or STEP_REFUSED having
    put positions and velocities back as they were.

    `walls` packs every static segment (walls, then map runs: pack_walls), and index_* is
    their bucket index dilated by at least the largest radius plus the skin
    (core.static_geometry.StaticGeometry.dilated).
    """
    totals[:] = 0
    speed, energy = speed_and_energy(v, masses)
    count = plan_substeps(speed, dt, travel)
    if over_budget(0, count, 0):
        return STEP_REFUSED
    keep = refusal_possible(energy, min_mass, travel, dt)
    saved_x = x.copy() if keep else x[:0]
    saved_v = v.copy() if keep else v[:0]
    fresh = lists[FRESH] == 1
    candidates = pair_rows[:lists[PAIRS]]
    near_walls = wall_rows[:lists[NEAR_WALLS]]
    rebuilt = False
    h = dt / count
    done = 0
    while done < count:
        move(x, v, h)
        pairs_stale = walls_stale = not fresh
        if fresh:
            pairs_stale, walls_stale = lists_stale(x, anchor, wall_anchor, skin)
        if pairs_stale:
            candidates = build_pairs(x, radii, skin, members, level_starts, level_largest,
                                     order)
            anchor[:] = x
            rebuilt = True
        if walls_stale:
            near_walls = refresh_walls(x, radii, walls, index_grid, index_shape, index_first,
                                       index_items, skin, order, wall_anchor, near_walls,
                                       wall_first, wall_clear, not fresh)
            rebuilt = True
        fresh = True
        pairs, rel, contacts, offsets, interior = find_contacts(
            x, radii, walls, candidates, near_walls, wall_anchor, wall_first, wall_clear)
        fastest = resolve(v, masses, walls, pairs, rel, contacts, offsets, interior, best,
                          totals)
        done += 1
        totals[SUBSTEPS] += 1
        count, done, h, speed = replan(count, done, h, speed, fastest, travel)
        if over_budget(totals[SUBSTEPS], count, done):
            x[:] = saved_x  # kept: this is reachable only when refusal_possible
            v[:] = saved_v
            lists[FRESH] = 0
            return STEP_REFUSED
    if rebuilt:
        lists[PAIRS] = candidates.shape[0]
        lists[NEAR_WALLS] = near_walls.shape[0]
        fits = (candidates.shape[0] <= pair_rows.shape[0]
                and near_walls.shape[0] <= wall_rows.shape[0])
        if fits:
            pair_rows[:candidates.shape[0]] = candidates
            wall_rows[:near_walls.shape[0]] = near_walls
        lists[FRESH] = 1 if fits else 0
    return STEP_DONE


@_compile
def pairs_stale(x, anchor, skin):
    """Whether two balls may have closed the skin since the lists were built at `anchor`
    (lists_stale's first answer, for box_step: its ball-wall lists live as long)."""
    first = 0.0
    second = 0.0
    for i in range(x.shape[0]):
        dx = x[i, 0] - anchor[i, 0]
        dy = x[i, 1] - anchor[i, 1]
        moved2 = dx * dx + dy * dy
        if moved2 > second:
            if moved2 > first:
                second = first
                first = moved2
            else:
                second = moved2
    return not np.sqrt(first) + np.sqrt(second) < LISTS_MARGIN * skin


@_compile
def box_step(x, v, radii, masses, min_mass, dt, travel, walls, wall_scale, members,
             level_starts, level_largest, skin, pair_rows, wall_rows, lists, anchor,
             wall_first, wall_clear, order, best, totals):
    """seed_step for a world without a map and with at most DIRECT_WALLS walls (reaching
    `wall_scale` m from the origin): the same plan, stages and rounds, but its ball-wall
    lists are build_direct's, made with the pair lists from the same grids and rebuilt with
    them, as the step was before the static index (issue 33: the index's search, its wall
    lists' own lifetime and their per-ball anchors cost a box 11-16% of its step). A kernel
    of its own, not a flag in seed_step: the flag's branches cost a map's step 13%
    (measured), as the compiled step's inlining changed. `wall_clear` stays 0: no ball's
    walls are skipped. Same buffers and returns as seed_step; find the same contacts in the
    same order (tested against seed_step and the numpy backend).
    """
    totals[:] = 0
    speed, energy = speed_and_energy(v, masses)
    count = plan_substeps(speed, dt, travel)
    if over_budget(0, count, 0):
        return STEP_REFUSED
    keep = refusal_possible(energy, min_mass, travel, dt)
    saved_x = x.copy() if keep else x[:0]
    saved_v = v.copy() if keep else v[:0]
    fresh = lists[FRESH] == 1
    candidates = pair_rows[:lists[PAIRS]]
    near_walls = wall_rows[:lists[NEAR_WALLS]]
    rebuilt = False
    h = dt / count
    done = 0
    while done < count:
        move(x, v, h)
        if not fresh or pairs_stale(x, anchor, skin):
            candidates, near_walls = build_direct(x, radii, walls, wall_scale, skin, members,
                                                  level_starts, level_largest, order,
                                                  wall_first)
            anchor[:] = x
            rebuilt = True
            fresh = True
        pairs, rel, contacts, offsets, interior = find_contacts(
            x, radii, walls, candidates, near_walls, anchor, wall_first, wall_clear)
        fastest = resolve(v, masses, walls, pairs, rel, contacts, offsets, interior, best,
                          totals)
        done += 1
        totals[SUBSTEPS] += 1
        count, done, h, speed = replan(count, done, h, speed, fastest, travel)
        if over_budget(totals[SUBSTEPS], count, done):
            x[:] = saved_x  # kept: this is reachable only when refusal_possible
            v[:] = saved_v
            lists[FRESH] = 0
            return STEP_REFUSED
    if rebuilt:
        lists[PAIRS] = candidates.shape[0]
        lists[NEAR_WALLS] = near_walls.shape[0]
        fits = (candidates.shape[0] <= pair_rows.shape[0]
                and near_walls.shape[0] <= wall_rows.shape[0])
        if fits:
            pair_rows[:candidates.shape[0]] = candidates
            wall_rows[:near_walls.shape[0]] = near_walls
        lists[FRESH] = 1 if fits else 0
    return STEP_DONE


@_compile
def worlds_step(worlds, x, v, radii, masses, min_mass, dt, travel, walls, wall_scale,
                index_grid, index_shape, index_first, index_items, members, level_starts,
                level_largest, skin, direct, pair_rows, wall_rows, lists, anchor, wall_anchor,
                wall_first, wall_clear, order, best, totals, status):
    """seed_step (box_step when `direct`) of each world k in `worlds`, on x[k], v[k] and its
    own buffers (row k of every per-world array), into status[k]: K worlds of the same balls'
    sizes and static geometry in one call (core.world_batch.WorldBatch). Each world's step is
    the very kernel its World.step calls, so the same bits; what one call saves is K - 1
    dispatches of 25 arguments (about 3 us each, twice a 13-ball map world's step)."""
    for slot in range(worlds.shape[0]):
        k = worlds[slot]
        if direct:
            status[k] = box_step(x[k], v[k], radii, masses, min_mass, dt, travel, walls,
                                 wall_scale, members, level_starts, level_largest, skin,
                                 pair_rows[k], wall_rows[k], lists[k], anchor[k],
                                 wall_first[k], wall_clear[k], order[k], best[k], totals[k])
        else:
            status[k] = seed_step(x[k], v[k], radii, masses, min_mass, dt, travel, walls,
                                  index_grid, index_shape, index_first, index_items, members,
                                  level_starts, level_largest, skin, pair_rows[k],
                                  wall_rows[k], lists[k], anchor[k], wall_anchor[k],
                                  wall_first[k], wall_clear[k], order[k], best[k], totals[k])


def ensure_fresh_cache():
    """Rebuild the cached kernels if they were compiled against other shared code.

    Returns True when they had to be rebuilt. Uses numba's cache object of each kernel
    (`_cache`, stable across numba releases) because numba offers no public flush.
    """
    if built_against() == FINGERPRINT:
        return False
    for kernel in _KERNELS:
        kernel._cache.flush()
    built_against.recompile()
    return True


def pack_walls(static):
    """Every static segment (a core.static_geometry.StaticGeometry: walls, then map runs) as
    one (M, 7) array in WALL_COLUMNS order."""
    packed = np.column_stack((static.starts, static.ends, static.directions, static.lengths))
    return np.ascontiguousarray(packed, dtype=np.float64).reshape(-1, 7)


def radius_classes(radii):
    """(members, level_starts, level_largest): ball indices grouped by radius level."""
    level, count = broadphase.radius_levels(radii)
    members = np.argsort(level, kind='stable').astype(np.int64)
    starts = np.searchsorted(np.take(level, members), np.arange(count + 1)).astype(np.int64)
    used = np.flatnonzero(np.diff(starts) > 0)
    level_starts = np.append(np.take(starts, used), starts[-1]).astype(np.int64)
    largest = np.array([float(np.take(radii, members[level_starts[k]:level_starts[k + 1]]).max())
                        for k in range(len(used))])
    return members, level_starts, largest


class NumbaStepper:
    """Steps a World with the compiled stages; holds what depends only on radii and walls,
    and the candidate lists between steps (in buffers that grow as seed_step asks)."""

    def __init__(self):
        ensure_fresh_cache()
        self._walls = None  # the packed static segments: they never change
        self.invalidate()

    def invalidate(self):
        """Forget everything derived from the balls (after the World was edited)."""
        self._prepared = None

    def prepare(self, world):
        """Build what the next step needs of the World's balls and static geometry (the
        index dilated by their reach, the buffers), if it is not built: the World does this
        when it is made, so a map's index is built before the node says it started, not on
        the first step (issue 33)."""
        if self._prepared is not None:
            return
        static = world.static
        n = len(world)
        skin = SKIN_RADII * world.min_radius
        direct = static.run_count == 0 and len(static) <= DIRECT_WALLS
        if direct:  # the index is not read (seed_step)
            index = static.index
        else:
            # The largest reach a ball-wall candidate needs, widened as the search widens it.
            index = static.dilated(widened(float(world.radii.max()) + skin, float(
                max(static.index.grid[3], np.abs(world.positions).max()))))
        if self._walls is None:
            self._walls = pack_walls(static)
        self._prepared = (float(world.masses.min()), self._walls, index.grid, index.shape,
                          index.first, index.items, *radius_classes(world.radii), skin,
                          np.empty((4 * n, 2), dtype=np.int64),
                          np.empty((n, 2), dtype=np.int64), np.zeros(3, dtype=np.int64),
                          np.empty((n, 2)), np.empty((n, 2)),
                          np.zeros(n + 1, dtype=np.int64), np.zeros(n),
                          np.arange(n, dtype=np.int64), np.full(n, -1, np.int64), direct,
                          float(static.index.grid[3]))

    def step(self, world, dt, travel, totals):
        """One seed-mode step; counts into `totals` (zeroed first); STEP_DONE or STEP_REFUSED."""
        if self._prepared is None:
            self.prepare(world)
        (min_mass, walls, index_grid, index_shape, index_first, index_items, members,
         level_starts, largest, skin, pair_rows, wall_rows, lists, anchor, wall_anchor,
         wall_first, wall_clear, order, best, direct, wall_scale) = self._prepared
        if direct:
            status = box_step(world.positions, world.velocities, world.radii, world.masses,
                              min_mass, dt, travel, walls, wall_scale, members, level_starts,
                              largest, skin, pair_rows, wall_rows, lists, anchor, wall_first,
                              wall_clear, order, best, totals)
        else:
            status = seed_step(world.positions, world.velocities, world.radii, world.masses,
                               min_mass, dt, travel, walls, index_grid, index_shape,
                               index_first, index_items, members, level_starts, largest, skin,
                               pair_rows, wall_rows, lists, anchor, wall_anchor, wall_first,
                               wall_clear, order, best, totals)
        if not lists[FRESH] and status == STEP_DONE:
            self._grow(pair_rows, wall_rows, lists)
        return status

    @property
    def buffers(self):
        """(pair_rows, wall_rows, lists) of seed_step, once a step has made them."""
        return self._prepared[10:13]

    def _grow(self, pair_rows, wall_rows, lists):
        """Buffers for lists that outgrew them, with room to spare; the next step rebuilds."""
        rows = [max(2 * int(lists[PAIRS]), len(pair_rows)),
                max(2 * int(lists[NEAR_WALLS]), len(wall_rows))]
        head = self._prepared[:10]
        tail = self._prepared[12:]
        self._prepared = (*head, np.empty((rows[0], 2), dtype=np.int64),
                          np.empty((rows[1], 2), dtype=np.int64), *tail)
