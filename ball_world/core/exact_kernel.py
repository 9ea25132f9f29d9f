"""Exact mode's event loop: per-ball predictions, a tournament tree, a cell list per radius class.

Each ball holds two predictions: its earliest impact (with another ball or a wall segment)
and the time it leaves its grid cell; its next event is the earlier of the two. A tournament
tree over the balls yields the earliest event of all. Processing an event moves only the
balls involved (each ball keeps its own clock) and predicts again for them; every other
prediction that named one of them as partner is recognised as stale by the partner's
collision counter when it comes up, and is then predicted again.

Balls whose radii lie within a factor CLASS_RATIO of each other form a radius class, and
each class has its own grid (one grid sized by the largest ball would put thousands of small
balls in one cell when radii differ 100-fold). A class's cells are squares at least a little
wider than its largest diameter, so touching balls of the class are always in neighbouring
cells; the smallest class's are as wide as its area per ball where its balls are spread
evenly (see _cell_width: in a dilute gas most events would otherwise be cell crossings,
which only keep the books); the other classes' cells are the smallest class's times a power
of two, so all cell edges lie on one grid of units (see _grids). A ball lives in its own
class's grid, looks for partners in the cells of every grid within reach of its cell (_span:
in its own grid, its 3 x 3 block) and for walls in its own cell. When it enters a new cell
it only looks at the strip of cells new to its reach in each grid and the new cell's walls,
keeping its stored impact for the rest. Nothing is missed: for any two balls in cells within
reach of each other (a symmetric relation), their next impact on their current paths is no
earlier than the stored impact of one of them (the one that changed course, or came into
reach, last), and balls further apart cannot touch before one of them changes cell. With
radii within CLASS_RATIO there is one grid, cell for cell the single grid exact mode had
before classes. Buckets of cells form a torus laid over the plane (one torus per grid), so
the world needs no bounds (distant cells sharing a bucket only add candidates, and a
predicted impact is exact whatever the cells). Each wall is listed in the buckets of every
cell of each grid where a ball of its class could touch it; a wall too long for that is
checked by every ball of the class.

Robustness near contact (why rounding cannot creep into overlap or loop):
- A pair or a wall collides only while approaching, and a pair that already overlaps and
  approaches collides at once, so an overlap is never left to grow.
- A ball and the partner (ball or wall) of its latest collision are not predicted against
  each other again until one of them changes course for another reason: straight paths
  that have just separated at contact cannot meet again (the distance between a point and a
  line or a convex set is convex along a straight path), so this loses nothing, and it
  removes the zero-time re-collisions rounding would otherwise cause.
- Times are relative to the step's start and never decrease: a prediction earlier than the
  current time (an overlap) is clamped to it.

State lives across steps (the lists, the predictions, the tree): at the start of each step
the kernel compares the world's positions and velocities with the values it left, and
predicts again for any ball an impulse or a set-state changed; a change of ball count,
radii or walls rebuilds everything (exact.py decides). Between two steps the state can be
taken out as plain arrays and put into another world (exact_carry.py, `restore` here).
"""
import collections
import math

import numpy as np

from ball_world.core.exact_impacts import (collide_pair, collide_wall, compile_inline,
                                           compile_kernel, INFINITY, pair_impact_time,
                                           wall_impact_time)

# Event kinds, in the order simultaneous events are processed.
PAIR = 0
WALL = 1
CROSSING = 2
NOTHING = 3

# Columns of State.balls.
CELL_X = 0
CELL_Y = 1
NEXT = 2          # next ball in the same bucket, or NO_BALL
PREVIOUS = 3      # previous ball in the same bucket, or NO_BALL
COUNTER = 4       # changes of course so far: a prediction naming this ball records it
LAST = 5          # partner of the latest collision: a ball, wall_code(k), or NO_PARTNER
HIT_KIND = 6      # the earliest impact predicted: PAIR, WALL or NOTHING
HIT_PARTNER = 7   # its partner: a ball or a wall
HIT_STAMP = 8     # the partner ball's COUNTER when predicted
EXIT = 9          # where the ball leaves its cell: 0 (+x), 1 (-x), 2 (+y), 3 (-y), NO_PARTNER
KIND = 10         # the next event: HIT_KIND, or CROSSING when leaving the cell comes first
CLASS = 11        # the ball's radius class: whose grid it lives in
COLUMNS = 12
NO_BALL = -1
NO_PARTNER = -1

# Columns of State.grids (one row per radius class, and a last row of totals).
SHIFT = 0         # the class's cells are unit * 2 ** SHIFT wide
COLUMN_MASK = 1   # its buckets tile the plane: COLUMN_MASK + 1 columns of cells,
ROW_BITS = 2      # 2 ** ROW_BITS rows (see _bucket)
BUCKETS = 3       # its first bucket in heads and wall_first (last row: all buckets)
GLOBALS = 4       # its first wall in global_walls, which all its balls check (last row: all)
REACH = 5         # REACH + b: how far (in units) grid b is searched around its cells (_span)

# Entries of State.run_layout (core.static_geometry.StaticGeometry.layout).
LAYOUT_COLUMNS = 0
LAYOUT_ROWS = 1
FIRST_RUN = 2     # the map's runs are walls FIRST_RUN .. FIRST_RUN + RUNS - 1
RUNS = 3

# Outcomes of a step.
DONE = 0
OVER_BUDGET = 1
NOT_FINITE = 2
STALE_STATE = 3

#: Cells are this much wider than the largest diameter, so rounding of a ball's position
#: against its cell's edges can never put touching balls two cells apart.
CELL_MARGIN = 1.0 + 2.0 ** -20
#: Cells wider than the diameter are kept only while a ball shares its cell with this many
#: balls or fewer on average (itself included; an even spread of one ball per cell gives 2).
MAX_CROWDING = 3.0
#: Most buckets per ball (the bucket count is a power of two).
BUCKETS_PER_BALL = 4
#: Wall entries in the buckets, per bucket, before further long walls become global.
WALL_ENTRIES_PER_BUCKET = 16
#: Relative widening of the capsule a ball's path walks through the static buckets
#: (_scan_runs), far above the rounding of its bucket coordinates.
WALK_SLACK = 1e-9
#: Largest radius over smallest within one radius class: radii from r_min * 4 ** c up to
#: (not including) r_min * 4 ** (c + 1) share class c's grid (empty classes are left out),
#: as seed mode's broadphase groups them (broadphase.LEVEL_RATIO).
CLASS_RATIO = 4.0

State = collections.namedtuple('State', (
    'unit',             # cell width of the smallest radius class's grid, m
    'grids',            # (C + 1, REACH + C) int64: each class's grid, see its column names
                        # (one array, not one per column: every array in the state costs
                        # reference counting on each call that passes it)
    'leaves',           # leaves of the tournament tree (a power of two >= balls)
    'clock',            # (N,) each ball's own time within the step, s
    'hit_time',         # (N,) each ball's earliest impact, s from the step's start
    'exit_time',        # (N,) when it leaves its cell
    'event_time',       # (N,) the earlier of the two: the key of the tree
    'balls',            # (N, COLUMNS) int64, see the column names
    'heads',            # (buckets,) first ball of each bucket
    'wall_first',       # (buckets + 1,) each bucket's walls: wall_items[first[b]:first[b+1]]
    'wall_items',
    'global_walls',     # walls every ball of a class checks (grids' GLOBALS)
    'tree',             # (2 leaves,) winner ball of each node, NO_BALL if none
    'seen_positions',   # what the kernel left in the world, to notice edits
    'seen_velocities',
    'seen_radii',
    'seen_walls',       # (W, 4) the walls' segments (the map's runs never change)
    'run_grid',         # the static index (core.static_geometry.SegmentIndex): origin x, y,
    'run_layout',       # bucket width, scale; columns, rows, first run (= W), runs (LAYOUT)
    'run_first',        # its buckets' first items, column by column
    'run_items',        # its items: walls and runs (the walk takes the runs only)
    'run_seen',         # (M,) the walk's stamp of the last walk that met each segment
    'run_stamp',        # (1,) walks so far
))


def geometry(static):
    """A World's static geometry (core.static_geometry.StaticGeometry) as build, restore and
    advance take it: every segment (the walls, then the map's runs: segments, starts, ends,
    directions, lengths) and the static index (grid, layout, first, items)."""
    index = static.index
    return (static.segments, static.starts, static.ends, static.directions, static.lengths,
            index.grid, static.layout, index.first, index.items)


@compile_inline
def wall_code(k):
    """LAST's encoding of wall k (balls are >= 0, NO_PARTNER is -1)."""
    return -2 - k


@compile_inline
def _bucket(cx, cy, column_mask, row_bits):
    """Cell (cx, cy)'s bucket: the buckets are a torus of cells laid over the plane.

    Neighbouring cells share no bucket while the torus is larger than the world (the usual
    case), and a 3 x 3 block reads three short runs of memory.
    """
    return ((cx & column_mask) << row_bits) | (cy & ((1 << row_bits) - 1))


@compile_inline
def _home(state, c, cx, cy):
    """Cell (cx, cy) of class c's grid: its bucket in heads (and in wall_first)."""
    grids = state.grids
    return grids[c, BUCKETS] + _bucket(cx, cy, grids[c, COLUMN_MASK], grids[c, ROW_BITS])


@compile_inline
def _width(state, c):
    """Class c's cell width (exact: a power of two times the unit)."""
    return state.unit * (1 << state.grids[c, SHIFT])


@compile_inline
def _span(c, shift_a, shift_b, reach):
    """Cells of grid b to search, along one axis, around cell c of grid a: [low, high].

    In units of the finest cell (unit), cell c of grid a covers [c, c + 1) * 2 ** shift_a;
    the cells of grid b that meet it widened by `reach` units on both sides are searched.
    The relation is symmetric (cell d of grid b is searched around cell c of grid a exactly
    when c is searched around d), in integers, so a pair is always found by whichever ball
    came into reach last. reach * unit exceeds the largest radius of a plus that of b, so
    balls in cells not searched cannot touch.
    """
    low = (c * (1 << shift_a) - reach) >> shift_b
    high = ((c + 1) * (1 << shift_a) + reach - 1) >> shift_b
    return low, high


@compile_inline
def _cell_of(coordinate, cell):
    return np.int64(math.floor(coordinate / cell))


@compile_inline
def _link(balls, heads, i, bucket):
    first = heads[bucket]
    balls[i, NEXT] = first
    balls[i, PREVIOUS] = NO_BALL
    if first != NO_BALL:
        balls[first, PREVIOUS] = i
    heads[bucket] = i


@compile_inline
def _unlink(balls, heads, i, bucket):
    before = balls[i, PREVIOUS]
    after = balls[i, NEXT]
    if before != NO_BALL:
        balls[before, NEXT] = after
    else:
        heads[bucket] = after
    if after != NO_BALL:
        balls[after, PREVIOUS] = before


@compile_kernel
def _place(state, i, px, py):
    """Put ball i in the cell of (px, py) of its class's grid."""
    c = state.balls[i, CLASS]
    cell = _width(state, c)
    cx = _cell_of(px, cell)
    cy = _cell_of(py, cell)
    state.balls[i, CELL_X] = cx
    state.balls[i, CELL_Y] = cy
    _link(state.balls, state.heads, i, _home(state, c, cx, cy))


@compile_inline
def _move(x, v, clock, i, t):
    """Bring ball i's position to time t along its straight path."""
    elapsed = t - clock[i]
    if elapsed != 0.0:
        x[i, 0] += v[i, 0] * elapsed
        x[i, 1] += v[i, 1] * elapsed
        clock[i] = t


@compile_inline
def _precedes(t, kind, partner, best_t, best_kind, best_partner):
    """One ball's candidates in processing order: time, then kind, then partner index."""
    if t != best_t:
        return t < best_t
    if kind != best_kind:
        return kind < best_kind
    return partner < best_partner


@compile_inline
def _scan_walls(i, now, px, py, vx, vy, bucket, balls, hit_time, wall_first, wall_items,
                global_walls, global_low, global_high, radii, starts, ends, directions,
                lengths):
    """Merge ball i's impacts with the walls of `bucket` and its class's global walls
    (global_walls[global_low:global_high]) into its hit."""
    best_t = hit_time[i]
    best_kind = balls[i, HIT_KIND]
    best_partner = balls[i, HIT_PARTNER]
    found = False
    last = balls[i, LAST]
    radius = radii[i]
    first = wall_first[bucket]
    listed = wall_first[bucket + 1] - first
    for s in range(listed + global_high - global_low):
        k = wall_items[first + s] if s < listed else global_walls[global_low + s - listed]
        if last == wall_code(k):
            continue
        t = wall_impact_time(px, py, vx, vy, radius, starts[k, 0], starts[k, 1], ends[k, 0],
                             ends[k, 1], directions[k, 0], directions[k, 1], lengths[k])
        if t < INFINITY:
            t += now
            if _precedes(t, WALL, k, best_t, best_kind, best_partner):
                best_t = t
                best_kind = WALL
                best_partner = k
                found = True
    if found:
        hit_time[i] = best_t
        balls[i, HIT_KIND] = WALL
        balls[i, HIT_PARTNER] = best_partner


@compile_inline
def _scan_balls(i, now, px, py, vx, vy, gx_low, gx_high, gy_low, gy_high, balls, hit_time,
                heads, clock, offset, column_mask, row_bits, x, v, radii):
    """Merge ball i's impacts with the balls of cells [gx_low, gx_high] x [gy_low, gy_high]
    of the grid whose buckets start at `offset`.

    A range wider than the torus visits each of its columns (rows) once: a bucket seen
    twice would only offer the same candidates again.
    """
    gx_high = min(gx_high, gx_low + column_mask)
    gy_high = min(gy_high, gy_low + (1 << row_bits) - 1)
    best_t = hit_time[i]
    best_kind = balls[i, HIT_KIND]
    best_partner = balls[i, HIT_PARTNER]
    best_stamp = 0
    found = False
    last = balls[i, LAST]
    radius = radii[i]
    for gx in range(gx_low, gx_high + 1):
        for gy in range(gy_low, gy_high + 1):
            j = heads[offset + _bucket(gx, gy, column_mask, row_bits)]
            while j != NO_BALL:
                if j != i and not (last == j and balls[j, LAST] == i):
                    qx = x[j, 0] + v[j, 0] * (now - clock[j])
                    qy = x[j, 1] + v[j, 1] * (now - clock[j])
                    t = pair_impact_time(px - qx, py - qy, vx - v[j, 0], vy - v[j, 1],
                                         radius + radii[j])
                    if t < INFINITY:
                        t += now
                        if _precedes(t, PAIR, j, best_t, best_kind, best_partner):
                            best_t = t
                            best_kind = PAIR
                            best_partner = j
                            best_stamp = balls[j, COUNTER]
                            found = True
                j = balls[j, NEXT]
    if found:
        hit_time[i] = best_t
        balls[i, HIT_KIND] = PAIR
        balls[i, HIT_PARTNER] = best_partner
        balls[i, HIT_STAMP] = best_stamp


@compile_inline
def _predict_exit(i, now, px, py, vx, vy, balls, exit_time, cell):
    """When and where ball i leaves its cell: EXIT 0 (+x), 1 (-x), 2 (+y), 3 (-y)."""
    cx = balls[i, CELL_X]
    cy = balls[i, CELL_Y]
    leave = INFINITY
    direction = NO_PARTNER
    if vx > 0.0:
        leave = ((cx + 1) * cell - px) / vx
        direction = 0
    elif vx < 0.0:
        leave = (cx * cell - px) / vx
        direction = 1
    if vy > 0.0:
        leave_y = ((cy + 1) * cell - py) / vy
        if leave_y < leave:
            leave = leave_y
            direction = 2
    elif vy < 0.0:
        leave_y = (cy * cell - py) / vy
        if leave_y < leave:
            leave = leave_y
            direction = 3
    # A position rounded just past its cell's edge leaves at once, never in the past.
    exit_time[i] = now + max(0.0, leave) if direction != NO_PARTNER else INFINITY
    balls[i, EXIT] = direction


@compile_inline
def _schedule(i, balls, hit_time, exit_time, event_time):
    """Ball i's next event: its hit, or leaving its cell if that comes strictly first."""
    if balls[i, HIT_KIND] != NOTHING and hit_time[i] <= exit_time[i]:
        event_time[i] = hit_time[i]
        balls[i, KIND] = balls[i, HIT_KIND]
    elif balls[i, EXIT] != NO_PARTNER:
        event_time[i] = exit_time[i]
        balls[i, KIND] = CROSSING
    else:
        event_time[i] = INFINITY
        balls[i, KIND] = NOTHING


@compile_inline
def _scan_runs(state, i, now, px, py, vx, vy, radius, starts, ends, directions, lengths):
    """Merge ball i's impacts with the map's runs that its disc can meet on its path from
    `now` until its next event (its cell exit or its stored hit, whichever is first): the
    static buckets that path's capsule (the path widened by the radius) covers, column by
    column, each run once.

    Why bounded by the next event: at a cell exit the ball walks again from there (_cross),
    and any hit makes it predict again (_predict, also for a stale one), so the walks cover
    its whole path piece by piece, and no walk ever crosses the map. A run is found if its
    contact point lies within the radius of the path walked, and that holds for every impact
    before the bound: what is found beyond it is exact too, and kept if earliest.
    """
    layout = state.run_layout
    if layout[RUNS] == 0 or (vx == 0.0 and vy == 0.0):
        return
    until = min(state.exit_time[i], state.hit_time[i])
    if not until < INFINITY:
        return
    duration = max(0.0, until - now)
    qx = px + vx * duration
    qy = py + vy * duration
    grid = state.run_grid
    origin_x = grid[0]
    origin_y = grid[1]
    size = grid[2]
    scale = max(grid[3], abs(px), abs(py), abs(qx), abs(qy))
    reach = radius + WALK_SLACK * (radius + scale)
    columns = layout[LAYOUT_COLUMNS]
    rows = layout[LAYOUT_ROWS]
    first_run = layout[FIRST_RUN]
    first = state.run_first
    items = state.run_items
    seen = state.run_seen
    state.run_stamp[0] += 1
    stamp = state.run_stamp[0]
    balls = state.balls
    last = balls[i, LAST]
    best_t = state.hit_time[i]
    best_kind = balls[i, HIT_KIND]
    best_partner = balls[i, HIT_PARTNER]
    found = False
    dx = qx - px
    dy = qy - py
    low_col = max(0, _bucket_of(min(px, qx) - reach, origin_x, size, columns))
    high_col = min(columns - 1, _bucket_of(max(px, qx) + reach, origin_x, size, columns))
    for col in range(low_col, high_col + 1):
        # The part of the path whose x lies within reach of the column, then its rows.
        if dx == 0.0:
            t_low = 0.0
            t_high = 1.0
        else:
            ta = (origin_x + col * size - reach - px) / dx
            tb = (origin_x + (col + 1) * size + reach - px) / dx
            t_low = min(max(min(ta, tb), 0.0), 1.0)
            t_high = min(max(max(ta, tb), 0.0), 1.0)
        ya = py + t_low * dy
        yb = py + t_high * dy
        low_row = max(0, _bucket_of(min(ya, yb) - reach, origin_y, size, rows))
        high_row = min(rows - 1, _bucket_of(max(ya, yb) + reach, origin_y, size, rows))
        if low_row > high_row:
            continue
        base = col * rows
        for s in range(first[base + low_row], first[base + high_row + 1]):
            k = items[s]
            if k < first_run or seen[k] == stamp:
                continue
            seen[k] = stamp
            if last == wall_code(k):
                continue
            t = wall_impact_time(px, py, vx, vy, radius, starts[k, 0], starts[k, 1], ends[k, 0],
                                 ends[k, 1], directions[k, 0], directions[k, 1], lengths[k])
            if t < INFINITY:
                t += now
                if _precedes(t, WALL, k, best_t, best_kind, best_partner):
                    best_t = t
                    best_kind = WALL
                    best_partner = k
                    found = True
    if found:
        state.hit_time[i] = best_t
        balls[i, HIT_KIND] = WALL
        balls[i, HIT_PARTNER] = best_partner


@compile_inline
def _bucket_of(coordinate, origin, size, count):
    """The static bucket of a coordinate along one axis, clipped to [-1, count] (so a
    coordinate far outside, or not finite, never overflows an integer)."""
    return np.int64(math.floor(min(max((coordinate - origin) / size, -1.0), float(count))))


@compile_inline
def _predict(state, i, now, x, v, radii, starts, ends, directions, lengths):
    """Ball i's earliest events from time `now` on, over every grid's cells within reach of its
    cell (in its own grid: the 3 x 3 block), and its own cell's walls (not the tree).

    Inlined, as _cross is: a call that passes the state reference-counts each of its arrays,
    which cost the gases about a tenth of their speed once the loop over grids was added.
    """
    balls = state.balls
    px = x[i, 0] + v[i, 0] * (now - state.clock[i])
    py = x[i, 1] + v[i, 1] * (now - state.clock[i])
    vx = v[i, 0]
    vy = v[i, 1]
    grids = state.grids
    a = balls[i, CLASS]
    cx = balls[i, CELL_X]
    cy = balls[i, CELL_Y]
    state.hit_time[i] = INFINITY
    balls[i, HIT_KIND] = NOTHING
    balls[i, HIT_PARTNER] = NO_PARTNER
    balls[i, HIT_STAMP] = 0
    _predict_exit(i, now, px, py, vx, vy, balls, state.exit_time, _width(state, a))
    _scan_walls(i, now, px, py, vx, vy, _home(state, a, cx, cy), balls, state.hit_time,
                state.wall_first, state.wall_items, state.global_walls, grids[a, GLOBALS],
                grids[a + 1, GLOBALS], radii, starts, ends, directions, lengths)
    for b in range(grids.shape[0] - 1):
        reach = grids[a, REACH + b]
        low_x, high_x = _span(cx, grids[a, SHIFT], grids[b, SHIFT], reach)
        low_y, high_y = _span(cy, grids[a, SHIFT], grids[b, SHIFT], reach)
        _scan_balls(i, now, px, py, vx, vy, low_x, high_x, low_y, high_y, balls,
                    state.hit_time, state.heads, state.clock, grids[b, BUCKETS],
                    grids[b, COLUMN_MASK], grids[b, ROW_BITS], x, v, radii)
    _scan_runs(state, i, now, px, py, vx, vy, radii[i], starts, ends, directions, lengths)
    _schedule(i, balls, state.hit_time, state.exit_time, state.event_time)


@compile_inline
def _cross(state, i, now, x, v, radii, starts, ends, directions, lengths):
    """Move ball i into the next cell of its grid and predict against what is new there only.

    Its stored hit was the earliest over the cells within reach of the old cell, in every
    grid; the new cell's reach differs from it by a strip on the side it moved to (in its
    own grid, three cells), which is searched with the new cell's walls (an impact already
    predicted with a ball now out of reach is still exact).
    """
    balls = state.balls
    grids = state.grids
    a = balls[i, CLASS]
    old_x = balls[i, CELL_X]
    old_y = balls[i, CELL_Y]
    _unlink(balls, state.heads, i, _home(state, a, old_x, old_y))
    direction = balls[i, EXIT]
    if direction < 2:
        balls[i, CELL_X] += 1 if direction == 0 else -1
    else:
        balls[i, CELL_Y] += 1 if direction == 2 else -1
    cx = balls[i, CELL_X]
    cy = balls[i, CELL_Y]
    _link(balls, state.heads, i, _home(state, a, cx, cy))
    px = x[i, 0] + v[i, 0] * (now - state.clock[i])
    py = x[i, 1] + v[i, 1] * (now - state.clock[i])
    vx = v[i, 0]
    vy = v[i, 1]
    _predict_exit(i, now, px, py, vx, vy, balls, state.exit_time, _width(state, a))
    _scan_walls(i, now, px, py, vx, vy, _home(state, a, cx, cy), balls, state.hit_time,
                state.wall_first, state.wall_items, state.global_walls, grids[a, GLOBALS],
                grids[a + 1, GLOBALS], radii, starts, ends, directions, lengths)
    for b in range(grids.shape[0] - 1):
        reach = grids[a, REACH + b]
        # Along the axis of the move: the cells within reach of the new cell, not the old.
        old_low, old_high = _span(old_x if direction < 2 else old_y, grids[a, SHIFT],
                                  grids[b, SHIFT], reach)
        low, high = _span(cx if direction < 2 else cy, grids[a, SHIFT], grids[b, SHIFT], reach)
        if direction == 0 or direction == 2:
            low = old_high + 1
        else:
            high = old_low - 1
        if low > high:
            continue
        # Across it: the same cells as before.
        across_low, across_high = _span(cy if direction < 2 else cx, grids[a, SHIFT],
                                        grids[b, SHIFT], reach)
        if direction < 2:
            _scan_balls(i, now, px, py, vx, vy, low, high, across_low, across_high, balls,
                        state.hit_time, state.heads, state.clock, grids[b, BUCKETS],
                        grids[b, COLUMN_MASK], grids[b, ROW_BITS], x, v, radii)
        else:
            _scan_balls(i, now, px, py, vx, vy, across_low, across_high, low, high, balls,
                        state.hit_time, state.heads, state.clock, grids[b, BUCKETS],
                        grids[b, COLUMN_MASK], grids[b, ROW_BITS], x, v, radii)
    _scan_runs(state, i, now, px, py, vx, vy, radii[i], starts, ends, directions, lengths)
    _schedule(i, balls, state.hit_time, state.exit_time, state.event_time)


@compile_inline
def _first(event_time, balls, a, b):
    """Of two balls' events (NO_BALL for none), the one processed first.

    Simultaneous events go by kind (ball-ball, ball-wall, cell crossing), then by the lower
    ball index, then by the partner (the higher ball index, or the wall index); one pair
    event predicted by both of its balls is the same event.
    """
    if a == NO_BALL:
        return b
    if b == NO_BALL:
        return a
    ta = event_time[a]
    tb = event_time[b]
    if ta != tb:
        return a if ta < tb else b
    kind = balls[a, KIND]
    if kind != balls[b, KIND]:
        return a if kind < balls[b, KIND] else b
    partner = EXIT if kind == CROSSING else HIT_PARTNER
    low_a = a
    high_a = balls[a, partner]
    low_b = b
    high_b = balls[b, partner]
    if kind == PAIR:
        low_a, high_a = min(a, high_a), max(a, high_a)
        low_b, high_b = min(b, high_b), max(b, high_b)
    if low_a != low_b:
        return a if low_a < low_b else b
    if high_a != high_b:
        return a if high_a < high_b else b
    return min(a, b)


@compile_kernel
def _update_tree(tree, leaves, event_time, balls, i):
    """Replay ball i's path to the root after its prediction changed."""
    node = (leaves + i) >> 1
    while node >= 1:
        tree[node] = _first(event_time, balls, tree[2 * node], tree[2 * node + 1])
        node >>= 1


@compile_kernel
def _build_tree(tree, leaves, event_time, balls, n):
    for i in range(leaves):
        tree[leaves + i] = i if i < n else NO_BALL
    for node in range(leaves - 1, 0, -1):
        tree[node] = _first(event_time, balls, tree[2 * node], tree[2 * node + 1])


@compile_kernel
def _wall_buckets(k, cell, column_mask, row_bits, starts, directions, lengths, seen, counts,
                  fill, items):
    """Visit each bucket a ball touching wall k can be in, once: count it, or list k in it.

    The wall is sampled every half cell from end to end; a ball touching it has its centre
    within r_max + cell / 4 < 3/4 cell of a sample, so in the 3 x 3 block of that sample's
    cell. With `items` empty the buckets are counted, else k is written at `fill`.
    """
    spacing = 0.5 * cell
    samples = int(math.ceil(lengths[k] / spacing)) + 1
    for s in range(samples):
        along = min(s * spacing, lengths[k])
        sx = _cell_of(starts[k, 0] + along * directions[k, 0], cell)
        sy = _cell_of(starts[k, 1] + along * directions[k, 1], cell)
        for gx in range(sx - 1, sx + 2):
            for gy in range(sy - 1, sy + 2):
                b = _bucket(gx, gy, column_mask, row_bits)
                if seen[b] == k:
                    continue
                seen[b] = k
                if items.shape[0] == 0:
                    counts[b] += 1
                else:
                    items[fill[b]] = k
                    fill[b] += 1


@compile_kernel
def _register_walls(cell, column_mask, row_bits, starts, directions, lengths):
    """Bucket lists of walls (first, items), and the walls too long to list (global).

    A wall is listed while it needs no more entries than there are buckets and the lists
    stay within WALL_ENTRIES_PER_BUCKET per bucket; longer walls are checked by every ball.
    """
    buckets = (column_mask + 1) << row_bits
    m = starts.shape[0]
    counts = np.zeros(buckets, dtype=np.int64)
    seen = np.full(buckets, -1, dtype=np.int64)
    listed = np.zeros(m, dtype=np.bool_)
    no_items = np.empty(0, dtype=np.int64)
    entries = 0
    for k in range(m):
        needed = 9 * (int(math.ceil(lengths[k] / (0.5 * cell))) + 1)
        if needed <= buckets and entries + needed <= WALL_ENTRIES_PER_BUCKET * buckets:
            listed[k] = True
            entries += needed
            _wall_buckets(k, cell, column_mask, row_bits, starts, directions, lengths, seen,
                          counts, counts, no_items)
    first = np.zeros(buckets + 1, dtype=np.int64)
    for b in range(buckets):
        first[b + 1] = first[b] + counts[b]
    items = np.empty(max(1, first[buckets]), dtype=np.int64)
    fill = first[:buckets].copy()
    seen[:] = -1
    for k in range(m):
        if listed[k]:
            _wall_buckets(k, cell, column_mask, row_bits, starts, directions, lengths, seen,
                          counts, fill, items)
    return first, items, np.flatnonzero(~listed).astype(np.int64)


@compile_kernel
def _extent(x):
    """The balls' bounding box: (low x, low y, width, height), taken once per build."""
    low_x = high_x = x[0, 0]
    low_y = high_y = x[0, 1]
    for i in range(x.shape[0]):
        low_x = min(low_x, x[i, 0])
        high_x = max(high_x, x[i, 0])
        low_y = min(low_y, x[i, 1])
        high_y = max(high_y, x[i, 1])
    return low_x, low_y, high_x - low_x, high_y - low_y


@compile_kernel
def _cell_width(x, extent, narrowest):
    """The cell width: the area per ball of the balls' bounding box, when wider than
    `narrowest` (a little over the largest diameter) and when the balls are spread evenly
    enough that a ball shares its cell with at most MAX_CROWDING balls on average; else
    `narrowest`.

    Why: events are collisions and cell crossings, and in a dilute gas (area fraction 0.1)
    cells one diameter wide make nine crossings of every collision; cells of one ball each
    halve the events there, while a dense gas keeps cells near one diameter. The crowding
    check keeps a cluster with a far outlier (a huge box, nearly empty) at `narrowest`.
    Measured on benchmarks.exact_speed's gases: dilute 0.43 -> 0.70 of seed mode's speed
    at 10,000 balls, dense unchanged.
    """
    n = x.shape[0]
    low_x, low_y, span_x, span_y = extent
    width = math.sqrt(span_x * span_y / n)
    if not width > narrowest:  # also a line of balls, one ball, or an overflow to inf
        return narrowest
    columns = int(span_x / width) + 1
    rows = int(span_y / width) + 1
    if columns * rows > 4 * n + 4:  # rounding at most: the box holds about n cells
        return narrowest
    counts = np.zeros(columns * rows, dtype=np.int64)
    for i in range(n):
        counts[int((x[i, 0] - low_x) / width) * rows + int((x[i, 1] - low_y) / width)] += 1
    shared = 0
    for c in range(counts.shape[0]):
        shared += counts[c] * counts[c]
    return width if shared <= MAX_CROWDING * n else narrowest


@compile_kernel
def _torus(n, extent, cell):
    """The bucket torus (column_mask, row_bits): as large as the balls' extent (_extent), in
    cells, within BUCKETS_PER_BALL buckets per ball; beyond that distant cells share buckets."""
    limit = 64
    while limit < BUCKETS_PER_BALL * n:
        limit *= 2
    # Compare extents as floats: a world far wider than the torus needs no exact count.
    wide = extent[2] / cell + 3.0
    tall = extent[3] / cell + 3.0
    columns = 1
    while columns < wide and columns < limit:
        columns *= 2
    row_bits = 0
    while (1 << row_bits) < tall and (1 << row_bits) < limit:
        row_bits += 1
    while columns * (1 << row_bits) > limit:
        if columns >= (1 << row_bits):
            columns //= 2
        else:
            row_bits -= 1
    return columns - 1, row_bits


@compile_kernel
def _classes(radii, ratio):
    """Each ball's radius class (radii from r_min * ratio ** c up to r_min * ratio ** (c + 1)),
    numbered from 0 up in increasing radius with empty classes left out, and the number of
    classes. An infinite ratio puts every ball in one class."""
    n = radii.shape[0]
    smallest = radii[0]
    for i in range(n):
        smallest = min(smallest, radii[i])
    band = np.zeros(n, dtype=np.int64)
    top = 0
    for i in range(n):
        bound = smallest * ratio
        while radii[i] >= bound:
            band[i] += 1
            bound *= ratio
        top = max(top, band[i])
    used = np.zeros(top + 1, dtype=np.bool_)
    for i in range(n):
        used[band[i]] = True
    number = np.zeros(top + 1, dtype=np.int64)
    count = 0
    for c in range(top + 1):
        if used[c]:
            number[c] = count
            count += 1
    for i in range(n):
        band[i] = number[band[i]]
    return band, count


@compile_kernel
def _grids(x, radii, classes, count):
    """Each class's grid: (unit, grids) of State, GLOBALS not yet filled in.

    The smallest class's cells are as _cell_width makes them for its balls and largest
    radius; they are the unit. Every other class's cells are a little over its largest
    diameter, rounded up to the unit times a power of two, so the cells of all grids have
    edges on the unit grid and reaches can be counted in whole units. Only the smallest class
    widens its cells: a larger class's cells set how many small cells its balls search on
    every prediction, so a few far-apart large balls with cells as wide as their area per
    ball would each search a whole grid of small ones. With one class this is the single
    grid of equal radii, cells exactly _cell_width's.
    """
    largest, members = _class_sizes(radii, classes, count)
    extents = np.empty((count, 4))
    unit = 0.0
    for c in range(count):
        own = x if count == 1 else x[np.flatnonzero(classes == c)]
        extent = _extent(own)
        extents[c, 0], extents[c, 1], extents[c, 2], extents[c, 3] = extent
        if c == 0:
            unit = _cell_width(own, extent, 2.0 * largest[c] * CELL_MARGIN)
    tori = np.zeros((count, 2), dtype=np.int64)
    for c in range(count):
        width = unit * (1 << cell_shift(unit, largest, c))
        extent = (extents[c, 0], extents[c, 1], extents[c, 2], extents[c, 3])
        tori[c, 0], tori[c, 1] = _torus(members[c], extent, width)
    return unit, _lay_out(unit, tori, largest)


@compile_kernel
def _class_sizes(radii, classes, count):
    """Each class's largest radius and number of balls."""
    largest = np.zeros(count)
    members = np.zeros(count, dtype=np.int64)
    for i in range(radii.shape[0]):
        c = classes[i]
        largest[c] = max(largest[c], radii[i])
        members[c] += 1
    return largest, members


@compile_kernel
def cell_shift(unit, largest, c):
    """Class c's cells are unit * 2 ** shift wide: the smallest class's the unit, any other's
    the unit doubled until a little over its largest diameter."""
    shift = 0
    if c > 0:
        width = unit
        narrowest = 2.0 * largest[c] * CELL_MARGIN
        while width < narrowest:
            width *= 2.0
            shift += 1
    return shift


@compile_kernel
def _lay_out(unit, tori, largest):
    """grids of State (GLOBALS not yet filled in) for the unit, each class's torus
    (column_mask, row_bits) and each class's largest radius."""
    count = largest.shape[0]
    grids = np.zeros((count + 1, REACH + count), dtype=np.int64)
    for c in range(count):
        grids[c, SHIFT] = cell_shift(unit, largest, c)
        grids[c, COLUMN_MASK] = tori[c, 0]
        grids[c, ROW_BITS] = tori[c, 1]
        grids[c + 1, BUCKETS] = grids[c, BUCKETS] + ((grids[c, COLUMN_MASK] + 1)
                                                     << grids[c, ROW_BITS])
        for b in range(count):
            units = math.ceil((largest[c] + largest[b]) * CELL_MARGIN / unit)
            grids[c, REACH + b] = max(1, int(units))
    return grids


@compile_kernel
def _class_walls(unit, grids, starts, directions, lengths):
    """The walls of every class's buckets, one after another (wall_first, wall_items), and
    all classes' global walls (fills in grids' GLOBALS): _register_walls per grid."""
    count = grids.shape[0] - 1
    firsts = []
    items = []
    globals_ = []
    listed = 0
    for c in range(count):
        first, entries, global_walls = _register_walls(
            unit * (1 << grids[c, SHIFT]), grids[c, COLUMN_MASK], grids[c, ROW_BITS], starts,
            directions, lengths)
        firsts.append(first)
        items.append(entries)
        globals_.append(global_walls)
        listed += first[first.shape[0] - 1]
        grids[c + 1, GLOBALS] = grids[c, GLOBALS] + global_walls.shape[0]
    wall_first = np.zeros(grids[count, BUCKETS] + 1, dtype=np.int64)
    wall_items = np.empty(max(1, listed), dtype=np.int64)
    global_walls = np.empty(grids[count, GLOBALS], dtype=np.int64)
    filled = 0
    for c in range(count):
        first = firsts[c]
        buckets = first.shape[0] - 1
        for b in range(buckets):
            wall_first[grids[c, BUCKETS] + b] = filled + first[b]
        wall_items[filled:filled + first[buckets]] = items[c][:first[buckets]]
        filled += first[buckets]
        global_walls[grids[c, GLOBALS]:grids[c + 1, GLOBALS]] = globals_[c]
    wall_first[grids[count, BUCKETS]] = filled
    return wall_first, wall_items, global_walls


@compile_kernel
def build(x, v, radii, segments, starts, ends, directions, lengths, run_grid, run_layout,
          run_first, run_items, class_ratio=CLASS_RATIO):
    """A fresh state for the world at the start of a step: cells, walls, predictions, tree.

    The static geometry (core.exact.geometry): every segment (the walls, then the map's
    runs) and the static index, whose layout says where the runs begin; the walls go in
    the classes' buckets as they always did, the runs are walked (_scan_runs).

    class_ratio: the radius classes' width (CLASS_RATIO); math.inf makes the single grid of
    cells one largest diameter wide (or wider) that exact mode had before radius classes,
    which the tests compare against.
    """
    n = x.shape[0]
    classes, count = _classes(radii, class_ratio)
    unit, grids = _grids(x, radii, classes, count)
    leaves = 1
    while leaves < n:
        leaves *= 2
    walls = run_layout[FIRST_RUN]
    wall_first, wall_items, global_walls = _class_walls(unit, grids, starts[:walls],
                                                        directions[:walls], lengths[:walls])
    state = State(unit, grids, leaves, np.zeros(n),
                  np.empty(n), np.empty(n), np.empty(n),
                  np.empty((n, COLUMNS), dtype=np.int64),
                  np.full(grids[count, BUCKETS], NO_BALL, np.int64),
                  wall_first, wall_items, global_walls,
                  np.full(2 * leaves, NO_BALL, np.int64), x.copy(), v.copy(), radii.copy(),
                  segments[:walls].copy(), run_grid, run_layout.copy(), run_first, run_items,
                  np.full(segments.shape[0], -1, np.int64), np.zeros(1, dtype=np.int64))
    balls = state.balls
    for i in range(n):
        balls[i, COUNTER] = 0
        balls[i, LAST] = NO_PARTNER
        balls[i, CLASS] = classes[i]
        _place(state, i, x[i, 0], x[i, 1])
    for i in range(n):
        _predict(state, i, 0.0, x, v, radii, starts, ends, directions, lengths)
    _build_tree(state.tree, state.leaves, state.event_time, balls, n)
    return state


@compile_kernel
def class_sizes(radii):
    """Each ball's radius class, and each class's largest radius and number of balls, as
    build makes them (core.exact_carry checks a carried state against these)."""
    classes, count = _classes(radii, CLASS_RATIO)
    largest, members = _class_sizes(radii, classes, count)
    return classes, largest, members


@compile_kernel
def export(state, x, v, cells, last, hit_kind, hit_partner, hit_current, exit_side,
           next_kind, edited):
    """Fill one row per ball of what exact_carry carries (the times are copied by the
    caller) in one pass; returns how many balls were edited since the last step, listed at
    the start of `edited`. Compiled: taken every step of a split recording, where numpy's
    column copies cost more than a step of a dilute gas."""
    balls = state.balls
    seen_x = state.seen_positions
    seen_v = state.seen_velocities
    count = 0
    for i in range(x.shape[0]):
        cells[i, 0] = balls[i, CELL_X]
        cells[i, 1] = balls[i, CELL_Y]
        last[i] = balls[i, LAST]
        kind = balls[i, HIT_KIND]
        partner = balls[i, HIT_PARTNER]
        hit_kind[i] = kind
        hit_partner[i] = partner
        hit_current[i] = kind == PAIR and balls[partner, COUNTER] == balls[i, HIT_STAMP]
        exit_side[i] = balls[i, EXIT]
        next_kind[i] = balls[i, KIND]
        if (x[i, 0] != seen_x[i, 0] or x[i, 1] != seen_x[i, 1] or v[i, 0] != seen_v[i, 0]
                or v[i, 1] != seen_v[i, 1]):
            edited[count] = i
            count += 1
    return count


@compile_kernel
def restore(x, v, radii, segments, starts, ends, directions, lengths, run_grid, run_layout,
            run_first, run_items, unit, tori, largest, balls, hit_time, exit_time, event_time,
            edited):
    """The state another World kept at the end of a step, carried over (core.exact_carry,
    which checked every value against this world): build's, with the cells, predictions and
    partners given instead of found. `balls` has every column but NEXT and PREVIOUS filled
    in; `edited` lists the balls changed since that step, which the next step predicts
    again (their seen position is NaN, so it differs from any).

    Balls are linked into their buckets in index order, as build links them; the order
    within a bucket never changes an outcome (_scan_balls takes the first candidate in a
    total order, whichever order they come in), so it is not carried.
    """
    n = x.shape[0]
    grids = _lay_out(unit, tori, largest)
    leaves = 1
    while leaves < n:
        leaves *= 2
    walls = run_layout[FIRST_RUN]
    wall_first, wall_items, global_walls = _class_walls(unit, grids, starts[:walls],
                                                        directions[:walls], lengths[:walls])
    seen_x = x.copy()
    for e in range(edited.shape[0]):
        seen_x[edited[e], 0] = math.nan
    state = State(unit, grids, leaves, np.zeros(n), hit_time, exit_time, event_time, balls,
                  np.full(grids[grids.shape[0] - 1, BUCKETS], NO_BALL, np.int64),
                  wall_first, wall_items, global_walls,
                  np.full(2 * leaves, NO_BALL, np.int64), seen_x, v.copy(), radii.copy(),
                  segments[:walls].copy(), run_grid, run_layout.copy(), run_first, run_items,
                  np.full(segments.shape[0], -1, np.int64), np.zeros(1, dtype=np.int64))
    for i in range(n):
        _link(balls, state.heads, i, _home(state, balls[i, CLASS], balls[i, CELL_X],
                                           balls[i, CELL_Y]))
    _build_tree(state.tree, leaves, event_time, balls, n)
    return state


@compile_kernel
def matches(state, radii, segments, run_layout):
    """Whether the state was built for these radii and walls (else it must be rebuilt).

    The walls are compared segment by segment; of the map's runs (the rest of `segments`),
    their number and the index's layout: a World's map never changes, and comparing tens of
    thousands of runs would cost a step of a small world.
    """
    seen_radii = state.seen_radii
    seen_walls = state.seen_walls
    walls = run_layout[FIRST_RUN]
    if radii.shape[0] != seen_radii.shape[0] or walls != seen_walls.shape[0]:
        return False
    for entry in range(run_layout.shape[0]):
        if run_layout[entry] != state.run_layout[entry]:
            return False
    for i in range(radii.shape[0]):
        if radii[i] != seen_radii[i]:
            return False
    for k in range(walls):
        for c in range(4):
            if segments[k, c] != seen_walls[k, c]:
                return False
    return True


@compile_kernel
def _absorb_edits(state, x, v, radii, starts, ends, directions, lengths):
    """Predict again for balls changed since the last step (impulses, set-state).

    A changed ball's counter moves on, so every prediction that named it becomes stale, and
    it forgets its latest partner (the path that separated from it is gone).
    """
    n = x.shape[0]
    balls = state.balls
    seen_x = state.seen_positions
    seen_v = state.seen_velocities
    changed = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        if (x[i, 0] != seen_x[i, 0] or x[i, 1] != seen_x[i, 1] or v[i, 0] != seen_v[i, 0]
                or v[i, 1] != seen_v[i, 1]):
            changed[count] = i
            count += 1
    for c in range(count):
        i = changed[c]
        if not (math.isfinite(x[i, 0]) and math.isfinite(x[i, 1])
                and math.isfinite(v[i, 0]) and math.isfinite(v[i, 1])):
            return NOT_FINITE
    for c in range(count):
        i = changed[c]
        _unlink(balls, state.heads, i, _home(state, balls[i, CLASS], balls[i, CELL_X],
                                             balls[i, CELL_Y]))
        _place(state, i, x[i, 0], x[i, 1])
        balls[i, COUNTER] += 1
        balls[i, LAST] = NO_PARTNER
    # Predict only once every changed ball sits in its new cell.
    for c in range(count):
        i = changed[c]
        _predict(state, i, 0.0, x, v, radii, starts, ends, directions, lengths)
        _update_tree(state.tree, state.leaves, state.event_time, balls, i)
    return DONE


@compile_kernel
def advance(state, x, v, radii, masses, segments, starts, ends, directions, lengths, run_grid,
            run_layout, run_first, run_items, dt, budget, totals, per_ball):
    """Process every event before dt in order, then bring all balls to dt.

    totals gets [ball-ball collisions, ball-wall collisions, events processed] added;
    per_ball (empty, or one entry per ball) gets each ball's ball-ball collisions added.
    Returns DONE; STALE_STATE (the state was built for other radii or walls: build a new
    one; nothing moved); NOT_FINITE (an edited ball is not finite; nothing moved); or
    OVER_BUDGET (more than `budget` events: the balls are left at the time reached).
    """
    if not matches(state, radii, segments, run_layout):
        return STALE_STATE
    status = _absorb_edits(state, x, v, radii, starts, ends, directions, lengths)
    if status != DONE:
        return status
    n = x.shape[0]
    balls = state.balls
    clock = state.clock
    tree = state.tree
    leaves = state.leaves
    event_time = state.event_time
    count_each = per_ball.shape[0] == n
    events = 0
    end = dt
    while True:
        i = tree[1]
        now = event_time[i]
        if not now < dt:
            break
        if events == budget:
            status = OVER_BUDGET
            end = now
            break
        events += 1
        kind = balls[i, KIND]
        if kind == CROSSING:
            _cross(state, i, now, x, v, radii, starts, ends, directions, lengths)
            _update_tree(tree, leaves, event_time, balls, i)
            continue
        if kind == PAIR:
            j = balls[i, HIT_PARTNER]
            if balls[j, COUNTER] == balls[i, HIT_STAMP]:
                _move(x, v, clock, i, now)
                _move(x, v, clock, j, now)
                if collide_pair(v, masses, i, j, x[i, 0] - x[j, 0], x[i, 1] - x[j, 1]):
                    totals[0] += 1
                    if count_each:
                        per_ball[i] += 1
                        per_ball[j] += 1
                balls[i, COUNTER] += 1
                balls[j, COUNTER] += 1
                balls[i, LAST] = j
                balls[j, LAST] = i
                _predict(state, j, now, x, v, radii, starts, ends, directions, lengths)
                _update_tree(tree, leaves, event_time, balls, j)
        else:
            k = balls[i, HIT_PARTNER]
            _move(x, v, clock, i, now)
            if collide_wall(v, i, x[i, 0], x[i, 1], starts[k, 0], starts[k, 1], ends[k, 0],
                            ends[k, 1], directions[k, 0], directions[k, 1], lengths[k]):
                totals[1] += 1
            balls[i, COUNTER] += 1
            balls[i, LAST] = wall_code(k)
        # After a collision, or a stale prediction (its partner changed course since).
        _predict(state, i, now, x, v, radii, starts, ends, directions, lengths)
        _update_tree(tree, leaves, event_time, balls, i)
    totals[2] += events

    # Everyone to the end time; predictions become relative to the next step's start.
    hit_time = state.hit_time
    exit_time = state.exit_time
    seen_x = state.seen_positions
    seen_v = state.seen_velocities
    for i in range(n):
        _move(x, v, clock, i, end)
        clock[i] = 0.0
        hit_time[i] -= end
        exit_time[i] -= end
        event_time[i] -= end
        seen_x[i, 0] = x[i, 0]
        seen_x[i, 1] = x[i, 1]
        seen_v[i, 0] = v[i, 0]
        seen_v[i, 1] = v[i, 1]
    _build_tree(tree, leaves, event_time, balls, n)
    return status
