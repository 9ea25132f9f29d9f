"""The scan's closed forms, written once, and the compiled walk of each beam through a grid.

Why one source: `core.lidar`'s numpy reference applies `circle_terms` and `segment_terms` to
whole (beam, object) arrays, and `scan_grid` below compiles the very same functions and
applies them to one beam and one object at a time. Both evaluate the same IEEE operations in
the same order (no fastmath, so no fused multiply-adds), and a minimum does not depend on
the order it is taken in, so the two give the same ranges to the last bit although they look
at different candidates. The rules of `core.rules` hold here too: only `+ - * /`,
comparisons, `&`, `np.sqrt`, `np.minimum` and `np.maximum` in the shared formulas.

The grid (why it is fast): a scan only sees what lies within range_max of the scanner, so
`scan_grid` keeps the balls whose disks meet the square of half-width range_max around it
(one pass over the balls, four comparisons each) and puts each into every cell of a uniform
grid over that square that its bounding box touches; walls go into the cells their segment
crosses, column by column (as `broadphase.LevelGrid.wall_cells` does). Each beam then walks
the cells it crosses in order of distance (Amanatides and Woo's DDA, "A Fast Voxel
Traversal Algorithm", 1987) and stops at the first cell it leaves after a hit: nothing in a
later cell can be nearer. A 360-beam scan thus tests the objects along its beams, not all N.

Objects go into the cells they touch widened by SLACK, far above the rounding of the walk's
boundary distances: a hit point within rounding of a cell boundary is in both cells' lists,
so the early stop can never skip a nearer hit.
"""
import math

import numpy as np

try:
    from numba import njit
    from numba.extending import register_jitable
except ImportError:  # core.lidar's numpy reference needs nothing more
    njit = None

#: Relative widening of what goes into a cell, of the cell width plus the coordinates' scale.
SLACK = 1e-9
#: A beam within this part of its distance of a circle's tangent is that tangent (see
#: circle_terms): a hundred times the rounding of a beam's direction. Worst case, a range
#: then differs from its beam's own closed form by sqrt(2 r TANGENT (distance + r)), 0.5 um
#: at r = 1 m and 12 m.
TANGENT = 1e-14
#: A beam passing a wall segment's end by less than this part of the wall's length hits it:
#: a beam aimed into the corner of two walls must not slip between them through rounding.
GRAZE = 1e-12
#: Most cells along one side of a scan's grid (so at most this squared cells in all).
MAX_CELLS_PER_SIDE = 256


def available():
    """True when numba is installed, so the compiled scan can run."""
    return njit is not None


def circle_terms(px, py, dx, dy, cx, cy, radius):
    """Where a beam from p along the unit vector d meets the circle (c, radius).

    Returns (near, ahead, inside). With m = c - p, the beam's line passes at distance
    |m x d| from the centre and meets the circle where t = m.d -+ sqrt(r^2 - (m x d)^2),
    with r^2 - (m x d)^2 written (r - m x d)(r + m x d), exact near a tangent.

    Tangents: near one, the range is infinitely sensitive to the beam's direction (a beam
    entering the circle by d metres stops sqrt(2 r d) short of the tangent point), and a
    direction made of a rounded cos and sin is off by ~1e-16 rad: an exact tangent would come
    out 2e-8 m short, or as a miss. So a beam within TANGENT of the distance (either side)
    of a tangent counts as that tangent and hits at m.d; every other beam gets the closed
    form as written. `near` is the first crossing (clamped at 0), `ahead` says the line meets
    the circle in front of p, `inside` that p lies in the circle (range 0).
    """
    mx = cx - px
    my = cy - py
    along = mx * dx + my * dy
    across = mx * dy - my * dx
    gap = (radius - across) * (radius + across)
    band = 2.0 * radius * TANGENT * (np.abs(along) + radius)
    near = np.maximum(along - np.sqrt(np.maximum(gap, 0.0)) * (gap > band), 0.0)
    return near, (gap >= -band) & (along > 0.0), mx * mx + my * my <= radius * radius


def segment_terms(px, py, dx, dy, ax, ay, bx, by):
    """Where a beam from p along d meets the wall segment a-b: (t, hit).

    Solves p + t d = a + u (b - a) by Cramer's rule: with q = a - p and e = b - a,
    t = (q x e) / (d x e) and u = (q x d) / (d x e). A hit needs t >= 0 and 0 <= u <= 1.
    A beam parallel to the wall (d x e = 0) does not hit it: a wall has no thickness, and a
    beam running exactly along one is a set of measure zero that its neighbours bracket.
    u may pass the ends by GRAZE: a beam into the corner where two walls meet must not
    slip between them through the rounding of u.
    """
    ex = bx - ax
    ey = by - ay
    qx = ax - px
    qy = ay - py
    denom = dx * ey - dy * ex
    t = (qx * ey - qy * ex) / denom
    u = (qx * dy - qy * dx) / denom
    return t, (denom != 0.0) & (t >= 0.0) & (u >= -GRAZE) & (u <= 1.0 + GRAZE)


def rotate(cos_yaw, sin_yaw, bx, by):
    """A body-frame direction (bx, by) in the world frame, for a heading of that cos and sin."""
    return cos_yaw * bx - sin_yaw * by, sin_yaw * bx + cos_yaw * by


def rep117(distance, range_min, range_max):
    """A distance as REP 117's range: -inf below range_min, +inf beyond range_max."""
    if distance < range_min:
        return -np.inf
    if distance > range_max:
        return np.inf
    return distance


def grid_side(count, mean_radius, reach):
    """Cells along one side of a scan's grid over the square of half-width `reach`.

    About four cells per ball kept, but cells no narrower than a mean radius (so a ball
    lands in a few cells, not dozens), and at most MAX_CELLS_PER_SIDE per side. Measured on
    the benchmark's gas (benchmarks/lidar_speed.py): one cell per ball, or cells of a
    diameter, cost 1.5x as much per scan; sixteen per ball 2x.
    """
    side = 2.0 * reach
    width = max(side / math.sqrt(4.0 * count + 1.0), mean_radius)
    return int(min(max(side / width, 1.0), float(MAX_CELLS_PER_SIDE)))


def cell_span(low, high, origin, width, cells):
    """First and last cell (ints) of one axis that the interval [low, high] touches, clipped
    to the grid; first > last when the interval lies outside it."""
    first = math.floor(min(max((low - origin) / width, -1.0), float(cells)))
    last = math.floor(min(max((high - origin) / width, -1.0), float(cells)))
    return max(first, 0), min(last, cells - 1)


def wall_rows(ax, ay, bx, by, column, gx, gy, width, cells, slack):
    """Rows of the cells in `column` that the segment a-b crosses (widened by slack)."""
    ex = bx - ax
    ey = by - ay
    left = gx + column * width - slack
    right = gx + (column + 1) * width + slack
    low = 0.0
    high = 1.0
    if ex != 0.0:
        ta = (left - ax) / ex
        tb = (right - ax) / ex
        low = min(max(min(ta, tb), 0.0), 1.0)
        high = min(max(max(ta, tb), 0.0), 1.0)
    ya = ay + low * ey
    yb = ay + high * ey
    return cell_span(min(ya, yb) - slack, max(ya, yb) + slack, gy, width, cells)


def _compile(function):
    """njit with an on-disk cache, no fastmath, numpy's division semantics (inf, not raise)."""
    if njit is None:
        return function
    return njit(cache=True, nogil=True, error_model='numpy')(function)


if njit is not None:
    for _function in (circle_terms, segment_terms, rotate, rep117, grid_side, cell_span,
                      wall_rows):
        register_jitable(error_model='numpy')(_function)


@_compile
def _fill_walls(walls, gx, gy, width, cells, slack, starts, items, fill):
    """Count (fill False) or list (fill True) each wall in the cells it crosses.

    Counting adds to starts[cell + 1]; listing writes at starts[cell] and advances it.
    """
    for j in range(walls.shape[0]):
        ax = walls[j, 0]
        ay = walls[j, 1]
        bx = walls[j, 2]
        by = walls[j, 3]
        first, last = cell_span(min(ax, bx) - slack, max(ax, bx) + slack, gx, width, cells)
        for column in range(first, last + 1):
            low, high = wall_rows(ax, ay, bx, by, column, gx, gy, width, cells, slack)
            for row in range(low, high + 1):
                cell = column * cells + row
                if fill:
                    items[starts[cell]] = j
                    starts[cell] += 1
                else:
                    starts[cell + 1] += 1


@_compile
def _fill_balls(x, y, r, gx, gy, width, cells, slack, starts, items, fill):
    """Count or list each ball (by its row in x, y, r) in the cells its bounding box touches,
    as _fill_walls does."""
    for k in range(x.shape[0]):
        reach = r[k] + slack
        first_x, last_x = cell_span(x[k] - reach, x[k] + reach, gx, width, cells)
        first_y, last_y = cell_span(y[k] - reach, y[k] + reach, gy, width, cells)
        for column in range(first_x, last_x + 1):
            for row in range(first_y, last_y + 1):
                cell = column * cells + row
                if fill:
                    items[starts[cell]] = k
                    starts[cell] += 1
                else:
                    starts[cell + 1] += 1


@_compile
def scan_grid(positions, radii, walls, px, py, cos_yaw, sin_yaw, bx, by, exclude, range_min,
              reach, out):
    """out[k]: distance along beam k from (px, py) to the first ball or wall it meets, as
    REP 117 has it: +inf when that is further than `reach` (range_max) or there is none,
    -inf when it is closer than range_min.

    Beam k's direction is the body direction (bx[k], by[k]) turned by the heading whose cos
    and sin are given (`rotate`). Ball `exclude` (the scanner's own, or -1) is not seen.
    Walls are rows x1, y1, x2, y2.
    """
    n = positions.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    r = np.empty(n)
    count = 0
    for i in range(n):
        radius = radii[i]
        if (i != exclude and abs(positions[i, 0] - px) <= reach + radius
                and abs(positions[i, 1] - py) <= reach + radius):
            x[count] = positions[i, 0]
            y[count] = positions[i, 1]
            r[count] = radius
            count += 1
    x = x[:count]
    y = y[:count]
    r = r[:count]
    radius_sum = 0.0
    for k in range(count):
        radius_sum += r[k]
    cells = grid_side(count, radius_sum / max(count, 1), reach)
    width = 2.0 * reach / cells
    gx = px - reach
    gy = py - reach
    slack = SLACK * (width + abs(px) + abs(py) + reach)
    ball_starts = np.zeros(cells * cells + 1, dtype=np.int64)
    wall_starts = np.zeros(cells * cells + 1, dtype=np.int64)
    _fill_balls(x, y, r, gx, gy, width, cells, slack, ball_starts, ball_starts, False)
    _fill_walls(walls, gx, gy, width, cells, slack, wall_starts, wall_starts, False)
    for cell in range(cells * cells):
        ball_starts[cell + 1] += ball_starts[cell]
        wall_starts[cell + 1] += wall_starts[cell]
    ball_items = np.empty(ball_starts[-1], dtype=np.int64)
    wall_items = np.empty(wall_starts[-1], dtype=np.int64)
    # The fill passes advance each start to the next cell's; shifted back afterwards.
    _fill_balls(x, y, r, gx, gy, width, cells, slack, ball_starts, ball_items, True)
    _fill_walls(walls, gx, gy, width, cells, slack, wall_starts, wall_items, True)
    for cell in range(cells * cells, 0, -1):
        ball_starts[cell] = ball_starts[cell - 1]
        wall_starts[cell] = wall_starts[cell - 1]
    ball_starts[0] = 0
    wall_starts[0] = 0
    # The last beam that tested each ball: a ball in several cells of a beam is tested once.
    tested = np.full(count, -1, dtype=np.int64)
    home_x = min(max(int(math.floor((px - gx) / width)), 0), cells - 1)
    home_y = min(max(int(math.floor((py - gy) / width)), 0), cells - 1)
    for k in range(bx.shape[0]):
        ux, uy = rotate(cos_yaw, sin_yaw, bx[k], by[k])
        ix = home_x
        iy = home_y
        step_x, next_x, delta_x = _axis(ux, px, gx, ix, width)
        step_y, next_y, delta_y = _axis(uy, py, gy, iy, width)
        best = np.inf
        while True:
            cell = ix * cells + iy
            for e in range(ball_starts[cell], ball_starts[cell + 1]):
                i = ball_items[e]
                if tested[i] == k:
                    continue
                tested[i] = k
                near, ahead, inside = circle_terms(px, py, ux, uy, x[i], y[i], r[i])
                if inside:
                    best = 0.0
                elif ahead and near < best:
                    best = near
            for e in range(wall_starts[cell], wall_starts[cell + 1]):
                j = wall_items[e]
                t, hit = segment_terms(px, py, ux, uy, walls[j, 0], walls[j, 1], walls[j, 2],
                                       walls[j, 3])
                if hit and t < best:
                    best = t
            leave = min(next_x, next_y)
            if best < leave or leave > reach:
                break
            if next_x < next_y:
                ix += step_x
                next_x += delta_x
            else:
                iy += step_y
                next_y += delta_y
            if ix < 0 or ix >= cells or iy < 0 or iy >= cells:
                break
        out[k] = rep117(best, range_min, reach)


@_compile
def _axis(u, p, origin, index, width):
    """The DDA along one axis: (step, distance to the first boundary, distance per cell)."""
    if u > 0.0:
        return 1, (origin + (index + 1) * width - p) / u, width / u
    if u < 0.0:
        return -1, (origin + index * width - p) / u, -width / u
    return 0, np.inf, np.inf


def warm():
    """Compile (or load from numba's cache) the scan kernel with a tiny scene."""
    out = np.empty(2)
    scan_grid(np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([0.3, 0.4]),
              np.array([[3.0, -1.0, 3.0, 1.0]]), 0.0, 0.0, 1.0, 0.0, np.array([1.0, 0.0]),
              np.array([0.0, 1.0]), 0, 0.1, 5.0, out)
    return out
