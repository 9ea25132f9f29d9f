"""The scan's closed forms, written once, and the compiled scan that bins the balls by beam.

Why one source: `core.lidar`'s numpy reference applies `circle_terms` and `segment_terms` to
whole (beam, object) arrays, and `scan_sectors` below compiles the very same functions and
applies them to one beam and one object at a time. Both evaluate the same IEEE operations in
the same order (no fastmath, so no fused multiply-adds), and a minimum does not depend on
the order it is taken in, so the two give the same ranges to the last bit although they look
at different candidates. The rules of `core.rules` hold here too: only `+ - * /`,
comparisons, `&`, `np.sqrt`, `np.minimum` and `np.maximum` in the shared formulas.

Why it is fast: the beams' sectors are a polar grid around the scanner, one cell per beam,
and each object goes only into the cells it can be seen in. A scan only sees what lies
within range_max, so one pass over the balls gathers those whose disks come within
range_max of the scanner, without a branch (`within`, _near_balls). A ball at distance d of
radius r subtends asin(r / d) either side of its bearing, at most atan(r / sqrt(d^2 - r^2))
and pi / 2, so it is tested against the few beams of that sector; a wall against the beams
between its ends' bearings, when it comes within range_max. Nothing is built per scan (no
grid to sort the balls into, no walk of its cells): at 1,000 balls a scan costs half of
what the square grid walk it replaced did (docs/performance.md).

Sectors are widened by SECTOR_SLACK on each side, far above the error of the cheap `bearing`
(BEARING_ERROR), the rounding of a beam's direction and the TANGENT band, so a beam that
the closed forms say hits an object is always among those tested. Where a sector is
ill-conditioned (a scanner on a wall's line, or at a wall's end) the wall is tested against
every beam, as the reference does.
"""
import math

import numpy as np

try:
    from numba import njit
    from numba.extending import register_jitable
except ImportError:  # core.lidar's numpy reference needs nothing more
    njit = None

#: A beam within this part of its distance of a circle's tangent is that tangent (see
#: circle_terms): a hundred times the rounding of a beam's direction. Worst case, a range
#: then differs from its beam's own closed form by sqrt(2 r TANGENT (distance + r)), 0.5 um
#: at r = 1 m and 12 m.
TANGENT = 1e-14
#: A beam passing a wall segment's end by less than this part of the wall's length hits it:
#: a beam aimed into the corner of two walls must not slip between them through rounding.
GRAZE = 1e-12
#: Radians added on each side of an object's sector (see the module's docstring).
SECTOR_SLACK = 1e-4
#: Largest error of `bearing` against atan2, rad (test_lidar checks it on a dense sample).
BEARING_ERROR = 2e-6
#: atan(a) ~ a (c0 + c1 a^2 + ... + c5 a^10) on [0, 1]: fitted by least squares on Chebyshev
#: nodes for this module (max error 1.8e-6 rad); it only chooses beams, never a range.
ATAN_COEFFICIENTS = (0.9999798340122587, -0.3326554827323513, 0.19367031614042238,
                     -0.11665111632321898, 0.052823487849912906, -0.011770499896159683)
#: A wall whose line passes within this part of the scanner's distance to its ends (or whose
#: nearer end is within this part of its length) is tested against every beam.
WALL_DEGENERATE = 1e-6
#: Beams closer than this (rad) are one direction to the scan: each object meets all of them.
MIN_INCREMENT = 1e-12
#: A ball or wall further than range_max times (1 + this) cannot be hit within range_max.
REACH_SLACK = 1e-6
#: A scan among this many balls or fewer tests them one by one (_ball), as it always did:
#: for so few, gathering them first (_near_balls: another pass, allocations) saves nothing
#: (measured, docs/performance.md).
FEW_BALLS = 32
#: A ball's window of at most this many beams is tested in a plain loop (_ball_window).
SHORT_SPAN = 8
#: Side (cells) of free_squares' tiles: 8 x 8 bytes, one cache line.
TILE = 8
#: Largest square (cells a side) free_squares keeps: a beam crosses at most 255 cells in one
#: step (7.6 m at 3 cm).
SKIP_CAP = 255


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


def grid_line(origin, index, resolution):
    """Where line `index` of a map's grid lies along one axis: origin + index * resolution,
    the expression core.static_geometry.boundary_runs places the runs with."""
    return origin + index * resolution


def crossing(origin, index, resolution, p, inverse):
    """The beam parameter (distance along a unit direction, m) where a beam from p along d
    (one axis of each) crosses grid line `index`: (line - p) / d, as (line - p) * (1 / d)
    with `inverse` = 1 / d (a walk computes a crossing per step: a product costs a
    fraction of a division; within an ulp of the quotient, far below float32's)."""
    return (grid_line(origin, index, resolution) - p) * inverse


def start_cell(p, origin, resolution):
    """The map cell (along one axis) a scanner at p is in, such that its lines bracket p as
    grid_line computes them: line c <= p < line c + 1 (floor, then mended where rounding of
    the division disagrees with the lines), so every crossing ahead lies at t >= 0."""
    c = np.floor((p - origin) / resolution)
    c = c - (grid_line(origin, c, resolution) > p)
    return c + (grid_line(origin, c + 1.0, resolution) <= p)


def rep117(distance, range_min, range_max):
    """A distance as REP 117's range: -inf below range_min, +inf beyond range_max."""
    if distance < range_min:
        return -np.inf
    if distance > range_max:
        return np.inf
    return distance


def bearing(y, x):
    """atan2(y, x) within BEARING_ERROR, in [-pi, pi]: an odd polynomial on the octant, a
    few multiplies where atan2 costs a library call per ball. Chooses beams, never a range."""
    ax = abs(x)
    ay = abs(y)
    big = max(ax, ay)
    if big == 0.0:
        return 0.0
    a = min(ax, ay) / big
    s = a * a
    c0, c1, c2, c3, c4, c5 = ATAN_COEFFICIENTS
    angle = a * (c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5)))))
    if ay > ax:
        angle = 0.5 * math.pi - angle
    if x < 0.0:
        angle = math.pi - angle
    if y < 0.0:
        angle = -angle
    return angle


def fan_window(direction, half, origin, sign, per_radian):
    """Where the sector of bearings direction -+ (half + SECTOR_SLACK) (rad, world frame)
    lies along a fan whose beam k points at origin + sign * k / per_radian (origin: the
    heading plus angle_min; sign that of the increment; per_radian: beams per radian):
    (low, high) in beams from beam 0, with low + half-width in [0, one turn). Beam k can
    point into the sector only if k lies in [low, high] shifted by a whole number of turns
    (2 pi per_radian beams each; `fan_span` clips one shift to the fan). Multiplications,
    not divisions: the slack dwarfs their rounding."""
    offset = sign * (direction - origin)
    offset -= 2.0 * math.pi * math.floor(offset * (0.5 / math.pi))
    return ((offset - half - SECTOR_SLACK) * per_radian,
            (offset + half + SECTOR_SLACK) * per_radian)


def fan_span(low, high, shift, samples):
    """Beams [first, last) of [low, high] + shift (in beams) that the fan has; first >= last
    for none."""
    first = int(math.ceil(min(max(low + shift, 0.0), float(samples))))
    last = int(math.floor(min(max(high + shift, -1.0), float(samples - 1)))) + 1
    return first, last


def ball_beams(px, py, ux, uy, cx, cy, radius, first, last, best):
    """Beams first..last-1 against one ball the scanner is outside of: the nearer hit kept."""
    # Views from 0 and a branch-free minimum: a loop the compiler vectorises (twice as fast
    # as indexing first..last with an `if`, measured).
    dx = ux[first:last]
    dy = uy[first:last]
    out = best[first:last]
    for k in range(last - first):
        near, ahead, _ = circle_terms(px, py, dx[k], dy[k], cx, cy, radius)
        out[k] = min(out[k], near if ahead else np.inf)


def wall_beams(px, py, ux, uy, ax, ay, bx, by, first, last, best):
    """Beams first..last-1 against one wall: the nearer hit kept."""
    dx = ux[first:last]
    dy = uy[first:last]
    out = best[first:last]
    for k in range(last - first):  # as ball_beams
        t, hit = segment_terms(px, py, dx[k], dy[k], ax, ay, bx, by)
        out[k] = min(out[k], t if hit else np.inf)


def _compile(function):
    """njit with an on-disk cache, no fastmath, numpy's division semantics (inf, not raise)."""
    if njit is None:
        return function
    return njit(cache=True, nogil=True, error_model='numpy')(function)


if njit is not None:
    for _function in (circle_terms, segment_terms, rotate, grid_line, crossing, start_cell,
                      rep117, bearing, fan_window, fan_span, ball_beams, wall_beams):
        register_jitable(error_model='numpy')(_function)


@_compile
def free_squares(solid):
    """For each cell and each quadrant of directions, the side (in cells, capped at
    SKIP_CAP) of the largest square of free cells inside the grid that has the cell at its
    corner and extends that way (quadrant q = 2 (y grows) + 1 (x grows)); 0 on solid cells.

    A beam in cell (i, j) going into quadrant q stays inside that square until it crosses
    its far side along x or y (it only moves away from the cell's other two sides), so it
    crosses the square in one step (walk_beams). The largest-square recurrence, run from
    the quadrant's far corner: side = 1 + min(of the three neighbours ahead), outside = 0.

    Laid out for the walk's memory reads: one plane per quadrant (a beam reads only its
    own), each in tiles of TILE x TILE cells, so the beams of a scan, a few cells apart
    where they pass, share cache lines (row-major and interleaved layouts made a scan of a
    large map about twice as slow, measured). Cell (i, j) is stored at (i + 1, j + 1)
    (`_address`) behind a border of solid cells, one wide: a walk never goes more than one
    cell outside the grid (it stops at the first solid cell), so it reads without bounds
    tests; cells of the last tiles beyond the grid are 0 too (outside is solid).
    """
    rows = solid.shape[0]
    columns = solid.shape[1]
    sides = np.zeros((rows, columns), dtype=np.uint8)
    out = np.zeros((4, (rows + 2 + TILE - 1) // TILE, (columns + 2 + TILE - 1) // TILE, TILE,
                    TILE), dtype=np.uint8)
    for q in range(4):
        sx = 1 if q & 1 else -1
        sy = 1 if q & 2 else -1
        for jj in range(rows):
            j = rows - 1 - jj if sy > 0 else jj
            for ii in range(columns):
                i = columns - 1 - ii if sx > 0 else ii
                if solid[j, i]:
                    sides[j, i] = 0
                    continue
                side = 0
                if 0 <= i + sx < columns and 0 <= j + sy < rows:
                    side = min(sides[j, i + sx], sides[j + sy, i], sides[j + sy, i + sx])
                sides[j, i] = min(side + 1, SKIP_CAP)
        for j in range(rows):
            for i in range(columns):
                out[q, (j + 1) // TILE, (i + 1) // TILE, (j + 1) % TILE, (i + 1) % TILE] = (
                    sides[j, i])
    return out


@_compile
def _address(plane, tiles, i, j):
    """Where free_squares' side at cell (column i, row j >= -1) lies in its flat array: the
    quadrant's plane starts at `plane`; `tiles` tiles a row of tiles."""
    column = i + 1
    row = j + 1
    return plane + ((((row // TILE) * tiles + column // TILE) * TILE + row % TILE) * TILE
                    + column % TILE)


@_compile
def _settle(t, c, far, step, origin, resolution, p, inverse):
    """Along one axis, the beam's cell just before t, between cell c and cell `far` (every
    line crossed before t taken, one by one, as the cell by cell walk takes them), and the
    crossing of its next line: walk_beams' rare exact path."""
    ahead = 1 if step > 0 else 0
    cell = c
    t_next = crossing(origin, cell + ahead, resolution, p, inverse)
    while t_next < t and cell != far:
        cell += step
        t_next = crossing(origin, cell + ahead, resolution, p, inverse)
    return cell, t_next


@_compile
def _plane(ix, iy, planes):
    """Where the plane of free_squares a beam reads starts, from the inverses of its
    direction's components (0 along an axis): quadrant 2 (y grows) + 1 (x grows); a beam
    along an axis uses the quadrant of x (or y) growing, whose square holds its column or
    row all the same."""
    return (2 * np.int64(iy > 0.0) + np.int64(ix >= 0.0)) * planes


@_compile
def _rare(flags, t, c, r, side, i, j, ix, iy, flat, plane, tiles, px, py, origin_x, origin_y,
          resolution, reached):
    """walk_beams' rare cases for a beam that left the square of `side` at cell (c, r) at
    t into cell (i, j), whose value was `reached`: a guess the comparisons rejected (flag 4)
    settled line by line, and a step through a vertex (flag 2), which stops at the two
    cells beside it too. Returns (the value of the cell entered, 0 for a stop; the cell)."""
    sx = np.int64(ix > 0.0) - np.int64(ix < 0.0)
    sy = np.int64(iy > 0.0) - np.int64(iy < 0.0)
    if flags & 4:
        i, next_x = _settle(t, c, c + sx * (side - 1), sx, origin_x, resolution, px, ix)
        j, next_y = _settle(t, r, r + sy * (side - 1), sy, origin_y, resolution, py, iy)
        step_x = sx != 0 and next_x == t
        step_y = sy != 0 and next_y == t
        flags = 2 if step_x and step_y else 0
        i += sx if step_x else 0
        j += sy if step_y else 0
        reached = flat[_address(plane, tiles, i, j)]
    if flags & 2 and (flat[_address(plane, tiles, i - sx, j)] == 0
                      or flat[_address(plane, tiles, i, j - sy)] == 0):
        reached = 0
    return reached, i, j


@_compile
def walk_beams(px, py, ux, uy, reach, out, skips, rows, columns, frame):
    """out[k] = the smaller of out[k] and the distance along beam k (from p along the unit
    vector (ux[k], uy[k])) to where it first enters a solid cell of the map (or leaves the
    grid: outside is solid), if that is at most min(out[k], reach); 0 for every beam when p
    itself is in a solid cell.

    The result is the cell by cell walk's (Amanatides and Woo, core.lidar.first_solid):
    each crossing computed afresh from its line (`crossing`), never accumulated, so a
    distance is the closed form of the entered cell's edge; where a beam crosses a line of
    each axis at the same parameter it passes through a vertex, touching three cells, and
    is stopped if any of them is solid. `skips` (free_squares) lets a beam cross the square
    of free cells ahead of its cell in one round, then step one cell on.

    Why rounds over all the beams, not one beam at a time: a beam's steps form a chain, each
    waiting for the last (its memory read, then its crossings), and a beam walked alone
    branches unpredictably (which side it leaves a square by, when it stops). Here each
    round takes every live beam one square on in a loop without branches that the compiler
    vectorises (the beams are independent), then reads the cells they reach in another and
    drops the beams that stopped: on the 1.8 M-cell warehouse a scan's walk costs a third
    of the walk one beam at a time (docs/performance.md). Where a beam leaves a square, the
    cell it reached along the other axis is guessed from its position and confirmed by the
    very comparisons of crossings the cell by cell walk makes; the rare guess they reject
    is settled line by line (_settle), so every result is the walk's, bit for bit.
    """
    samples = ux.shape[0]
    origin_x = frame[0]
    origin_y = frame[1]
    resolution = frame[2]
    ci0 = np.int64(start_cell(px, origin_x, resolution))
    cj0 = np.int64(start_cell(py, origin_y, resolution))
    flat = skips.reshape(-1)
    tiles = np.int64(skips.shape[2])
    planes = np.int64(skips.shape[1]) * tiles * TILE * TILE
    if (ci0 < 0 or cj0 < 0 or ci0 >= columns or cj0 >= rows
            or flat[_address(0, tiles, ci0, cj0)] == 0):
        for k in range(samples):
            out[k] = min(out[k], 0.0)
        return
    per_cell = 1.0 / resolution
    start_x = (px - origin_x) * per_cell
    start_y = (py - origin_y) * per_cell
    # The live beams' state, packed at the front (slot a holds beam `beam[a]`).
    ints = np.empty((7, samples), dtype=np.int64)
    floats = np.empty((6, samples))
    beam = ints[0]
    ci = ints[1]
    cj = ints[2]
    side = ints[3]
    ni = ints[4]
    nj = ints[5]
    at = ints[6]
    rate_x = floats[0]  # cells per metre along the beam
    rate_y = floats[1]
    ixs = floats[2]
    iys = floats[3]
    bound = floats[4]
    ts = floats[5]
    live = 0
    for k in range(samples):
        dx = ux[k]
        dy = uy[k]
        if dx == 0.0 and dy == 0.0:
            continue  # no direction: crosses no line, meets no cell (as the reference)
        beam[live] = k
        rate_x[live] = dx * per_cell
        rate_y[live] = dy * per_cell
        ixs[live] = 1.0 / dx if dx != 0.0 else 0.0
        iys[live] = 1.0 / dy if dy != 0.0 else 0.0
        bound[live] = min(out[k], reach)
        ci[live] = ci0
        cj[live] = cj0
        side[live] = flat[_address(_plane(ixs[live], iys[live], planes), tiles, ci0, cj0)]
        live += 1
    while live > 0:
        # Every live beam across its square and one cell on: the cell it enters (ni, nj)
        # at ts, and in `at` its address, with flags (1: beyond the bound, 2: through a
        # vertex, 4: the guess rejected) in the bits above.
        for a in range(live):
            ix = ixs[a]
            iy = iys[a]
            sx = np.int64(ix > 0.0) - np.int64(ix < 0.0)
            sy = np.int64(iy > 0.0) - np.int64(iy < 0.0)
            ahead_x = np.int64(ix > 0.0)
            ahead_y = np.int64(iy > 0.0)
            c = ci[a]
            r = cj[a]
            # (selects, not products with sx and sy: a vector multiply of 64-bit integers
            # is slow)
            span = side[a] - 1
            far_x = c + span if ix > 0.0 else (c - span if ix < 0.0 else c)
            far_y = r + span if iy > 0.0 else (r - span if iy < 0.0 else r)
            # Where the beam leaves the square: the first of its far lines it crosses.
            t_x = crossing(origin_x, far_x + ahead_x, resolution, px, ix) if sx != 0 else np.inf
            t_y = crossing(origin_y, far_y + ahead_y, resolution, py, iy) if sy != 0 else np.inf
            t = min(t_x, t_y)
            # The cell it is in just before t along each axis: the far one along the axis
            # it leaves by, else a guess from its position, kept in the square.
            gx = np.int64(math.floor(start_x + t * rate_x[a]))
            gy = np.int64(math.floor(start_y + t * rate_y[a]))
            gx = far_x if t_x <= t_y else min(max(gx, min(c, far_x)), max(c, far_x))
            gy = far_y if t_y <= t_x else min(max(gy, min(r, far_y)), max(r, far_y))
            # A cell is the right one when its next line is crossed at t or later and the
            # line into it (unless it is where the beam was) before t: the walk's own
            # comparisons.
            next_x = crossing(origin_x, gx + ahead_x, resolution, px, ix) if sx != 0 else np.inf
            next_y = crossing(origin_y, gy + ahead_y, resolution, py, iy) if sy != 0 else np.inf
            into_x = crossing(origin_x, gx + ahead_x - sx, resolution, px, ix)
            into_y = crossing(origin_y, gy + ahead_y - sy, resolution, py, iy)
            wrong = (((sx != 0) & ((next_x < t) | ((gx != c) & (not into_x < t))))
                     | ((sy != 0) & ((next_y < t) | ((gy != r) & (not into_y < t)))))
            step_x = next_x == t
            step_y = next_y == t
            i = gx + (sx if step_x else 0)
            j = gy + (sy if step_y else 0)
            ni[a] = i
            nj[a] = j
            ts[a] = t
            flags = (np.int64(not t <= bound[a]) | (np.int64(step_x & step_y) << 1)
                     | (np.int64(wrong) << 2))
            at[a] = (_address(_plane(ix, iy, planes), tiles, i, j) << 3) | flags
        # The cells reached: a beam stops in a solid one (or one beyond its bound).
        kept = 0
        for a in range(live):
            flags = at[a] & 7
            if flags & 1:
                continue
            t = ts[a]
            ix = ixs[a]
            iy = iys[a]
            i = ni[a]
            j = nj[a]
            reached = flat[at[a] >> 3]
            if flags & 6:
                # Rare: through a vertex, or a guess to settle.
                reached, i, j = _rare(flags, t, ci[a], cj[a], side[a], i, j, ix, iy, flat,
                                      _plane(ix, iy, planes), tiles, px, py, origin_x,
                                      origin_y, resolution, reached)
            if reached == 0:
                k = beam[a]
                out[k] = min(out[k], t)
                continue
            beam[kept] = beam[a]
            ci[kept] = i
            cj[kept] = j
            side[kept] = reached
            rate_x[kept] = rate_x[a]
            rate_y[kept] = rate_y[a]
            ixs[kept] = ix
            iys[kept] = iy
            bound[kept] = bound[a]
            kept += 1
        live = kept


@_compile
def _wall_sector(px, py, ax, ay, bx, by, reach):
    """(centre, half) of the bearings (world frame) a wall can be hit in; half >= pi when it
    must be tested against every beam, and (0, -1) when it lies beyond reach."""
    qx = ax - px
    qy = ay - py
    ex = bx - ax
    ey = by - ay
    length2 = ex * ex + ey * ey
    if length2 == 0.0:  # never hit (segment_terms' denominator is 0)
        return 0.0, -1.0
    along = min(max(-(qx * ex + qy * ey) / length2, 0.0), 1.0)
    nx = qx + along * ex
    ny = qy + along * ey
    near_a = math.sqrt(qx * qx + qy * qy)
    near_b = math.sqrt((qx + ex) * (qx + ex) + (qy + ey) * (qy + ey))
    cross = qx * ey - qy * ex
    length = math.sqrt(length2)
    if (abs(cross) <= WALL_DEGENERATE * length * max(near_a, near_b)
            or min(near_a, near_b) <= WALL_DEGENERATE * length):
        return 0.0, math.pi
    if math.sqrt(nx * nx + ny * ny) > reach * (1.0 + REACH_SLACK):
        return 0.0, -1.0
    width = bearing(abs(cross), qx * (qx + ex) + qy * (qy + ey))
    if cross >= 0.0:
        start = bearing(qy, qx)
    else:
        start = bearing(qy + ey, qx + ex)
    return start + 0.5 * width, 0.5 * width


def _fan(cos_yaw, sin_yaw, bx, by, angle_min, increment, ux, uy, out):
    """A scan's beams in the world frame (ux, uy), out[:] = +inf, and how sectors are found
    along the fan: (every, origin, sign, per_radian, turn) as scan_sectors uses them."""
    for k in range(bx.shape[0]):
        ux[k], uy[k] = rotate(cos_yaw, sin_yaw, bx[k], by[k])
        out[k] = np.inf
    heading = math.atan2(sin_yaw, cos_yaw)
    # Beams per turn of the circle: a sector is looked for on the turns the fan spans. A fan
    # of (nearly) one direction has every beam tested against everything.
    every = not abs(increment) >= MIN_INCREMENT
    per_radian = 1.0 / max(abs(increment), MIN_INCREMENT)
    turn = 2.0 * math.pi * per_radian
    sign = 1.0 if increment > 0.0 else -1.0
    return every, heading + angle_min, sign, per_radian, turn


def _ball(px, py, ux, uy, cx, cy, radius, reach, every, origin, sign, per_radian, turn, out):
    """One ball against the beams it can meet (its sector of the fan): the nearer hits kept
    in out; every range 0 from inside it."""
    samples = ux.shape[0]
    mx = cx - px
    my = cy - py
    if abs(mx) > reach + radius or abs(my) > reach + radius:  # (the cheapest test first)
        return
    d2 = mx * mx + my * my
    # Nothing on a ball whose disk lies beyond reach is nearer than reach (+inf anyway).
    limit = (reach + radius) * (1.0 + REACH_SLACK)
    if d2 > limit * limit:
        return
    if d2 <= radius * radius:  # circle_terms' `inside`: every range 0
        for k in range(samples):
            out[k] = 0.0
        return
    # The ball subtends asin(r / d) either side of its bearing: at most its tangent, and
    # at most pi / 2 (a beam meets a ball it is outside of only going towards it).
    half = min(radius / math.sqrt(d2 - radius * radius), 0.5 * math.pi)
    if every:
        ball_beams(px, py, ux, uy, cx, cy, radius, 0, samples, out)
        return
    low, high = fan_window(bearing(my, mx), half, origin, sign, per_radian)
    shift = -turn if high >= turn else 0.0
    while low + shift <= samples - 1:
        first, last = fan_span(low, high, shift, samples)
        ball_beams(px, py, ux, uy, cx, cy, radius, first, last, out)
        shift += turn


def _ball_window(px, py, ux, uy, cx, cy, radius, low, high, turn, out):
    """One ball against the beams of its window (fan_window's low, high) on each turn of
    the fan, as _ball's last loop: the nearer hits kept in out."""
    samples = ux.shape[0]
    shift = -turn if high >= turn else 0.0
    while low + shift <= samples - 1:
        first, last = fan_span(low, high, shift, samples)
        if last - first <= SHORT_SPAN:
            # A few beams (most balls of a long-range scan): a plain loop, which
            # ball_beams' vectorised one, with its set-up, is slower on (measured).
            for k in range(first, last):
                near, ahead, _ = circle_terms(px, py, ux[k], uy[k], cx, cy, radius)
                out[k] = min(out[k], near if ahead else np.inf)
        else:
            ball_beams(px, py, ux, uy, cx, cy, radius, first, last, out)
        shift += turn


def within(mx, my, radius, reach):
    """Whether a ball at offset (mx, my) from the scanner passes both of _ball's reach
    tests, as one boolean without branches (a ball of NaN coordinates, which _ball passes
    but tests against no beam, is left out)."""
    limit = (reach + radius) * (1.0 + REACH_SLACK)
    return ((abs(mx) <= reach + radius) & (abs(my) <= reach + radius)
            & (mx * mx + my * my <= limit * limit))


def _near_balls(px, py, ux, uy, positions, radii, near, count, reach, every, origin, sign,
                per_radian, turn, lows, highs, out):
    """The balls near[:count] (each `within` reach) against their sectors, as _ball
    each: the same beams tested, the same closed forms, the same ranges.

    Why apart from _ball: a long-range scan in a crowd tests hundreds of balls, and tested
    one by one, each a branch on its distance that a random crowd makes unpredictable and
    a chain of a square root, a division and a bearing, a ball cost ~100 ns. Here the
    balls within reach were gathered without a branch (scan_agents), their windows are
    computed in one loop whose iterations overlap, then their beams tested: the balls'
    part of 1,000 robots' 12 m scans among 1,000 balls in the warehouse 2.6x faster, a
    scan 1.3-1.5x (docs/performance.md)."""
    inside = False
    for n in range(count):
        ball = near[n]
        radius = radii[ball]
        mx = positions[ball, 0] - px
        my = positions[ball, 1] - py
        d2 = mx * mx + my * my
        inside |= d2 <= radius * radius
        half = min(radius / math.sqrt(d2 - radius * radius), 0.5 * math.pi)
        lows[n], highs[n] = fan_window(bearing(my, mx), half, origin, sign, per_radian)
    if inside or every:  # (rare: _ball's own cases)
        for n in range(count):
            ball = near[n]
            _ball(px, py, ux, uy, positions[ball, 0], positions[ball, 1], radii[ball], reach,
                  every, origin, sign, per_radian, turn, out)
        return
    for n in range(count):
        ball = near[n]
        _ball_window(px, py, ux, uy, positions[ball, 0], positions[ball, 1], radii[ball],
                     lows[n], highs[n], turn, out)


def _walls_and_cells(walls, solid, skips, frame, px, py, ux, uy, range_min, reach, every,
                     origin, sign, per_radian, turn, out):
    """The walls against their sectors of the fan, then the map's cells up to each beam's
    nearest hit (walk_beams), then REP 117's limits: what ends every scan."""
    samples = ux.shape[0]
    for j in range(walls.shape[0]):
        ax = walls[j, 0]
        ay = walls[j, 1]
        bx_ = walls[j, 2]
        by_ = walls[j, 3]
        centre, half = _wall_sector(px, py, ax, ay, bx_, by_, reach)
        if half < 0.0:
            continue
        if half >= math.pi or every:
            wall_beams(px, py, ux, uy, ax, ay, bx_, by_, 0, samples, out)
            continue
        low, high = fan_window(centre, half, origin, sign, per_radian)
        shift = -turn if high >= turn else 0.0
        while low + shift <= samples - 1:
            first, last = fan_span(low, high, shift, samples)
            wall_beams(px, py, ux, uy, ax, ay, bx_, by_, first, last, out)
            shift += turn
    if solid.shape[0] > 0:
        walk_beams(px, py, ux, uy, reach, out, skips, solid.shape[0], solid.shape[1], frame)
    for k in range(samples):
        out[k] = rep117(out[k], range_min, reach)


if njit is not None:
    for _function in (_fan, _ball, _ball_window, within, _near_balls, _walls_and_cells):
        register_jitable(error_model='numpy')(_function)


@_compile
def _gathered_balls(px, py, ux, uy, positions, radii, exclude, reach, every, origin, sign,
                    per_radian, turn, out):
    """Every ball but `exclude` against its sector, as _ball each: gathered as scan_agents
    gathers them, then _near_balls."""
    near = np.empty(positions.shape[0], dtype=np.int64)
    count = 0
    for i in range(positions.shape[0]):
        near[count] = i
        count += np.int64(within(positions[i, 0] - px, positions[i, 1] - py, radii[i], reach)
                          & (i != exclude))
    windows = np.empty((2, count))
    _near_balls(px, py, ux, uy, positions, radii, near, count, reach, every, origin, sign,
                per_radian, turn, windows[0], windows[1], out)


@_compile
def scan_sectors(positions, radii, walls, solid, skips, frame, px, py, cos_yaw, sin_yaw, bx,
                 by, angle_min, increment, exclude, range_min, reach, out):
    """out[k]: distance along beam k from (px, py) to the first ball, wall or map cell it
    meets, as REP 117 has it: +inf when that is further than `reach` (range_max) or there
    is none, -inf when it is closer than range_min.

    The map: `solid` (one byte a cell, OccupancyGrid's layout; empty without a map), its
    `skips` (free_squares) and `frame` (origin x, origin y, resolution); each beam
    walks it up to its nearest ball or wall hit (walk_beams).

    Beam k's direction is the body direction (bx[k], by[k]), at angle_min + k * increment,
    turned by the heading whose cos and sin are given (`rotate`). Ball `exclude` (the
    scanner's own, or -1) is not seen. Walls are rows x1, y1, x2, y2.
    """
    samples = bx.shape[0]
    ux = np.empty(samples)
    uy = np.empty(samples)
    every, origin, sign, per_radian, turn = _fan(cos_yaw, sin_yaw, bx, by, angle_min,
                                                 increment, ux, uy, out)
    if positions.shape[0] <= FEW_BALLS:
        for i in range(positions.shape[0]):
            if i != exclude:
                _ball(px, py, ux, uy, positions[i, 0], positions[i, 1], radii[i], reach, every,
                      origin, sign, per_radian, turn, out)
    else:
        _gathered_balls(px, py, ux, uy, positions, radii, exclude, reach, every, origin, sign,
                        per_radian, turn, out)
    _walls_and_cells(walls, solid, skips, frame, px, py, ux, uy, range_min, reach, every,
                     origin, sign, per_radian, turn, out)


@_compile
def scan_agents(positions, radii, walls, solid, skips, frame, cell_first, cell_balls,
                grid, agents, cos_yaws, sin_yaws, bx, by, angle_min, increment, range_mins,
                reach, out):
    """scan_sectors for many scanners at once, each at the centre of its own ball: out[a]
    is the scan of the ball agents[a] (excluded from its own scan) with the heading of
    cos_yaws[a], sin_yaws[a] and range_min range_mins[a], equal bit for bit to
    scan_sectors' (each range is the least of the same closed forms).

    Why: a short-range ring (8-24 beams, 1-2 m) on each of 10,000 robots must not test
    every ball for every robot. The balls come sorted into square cells of side grid[2] >=
    reach + the largest radius, from (grid[0], grid[1]), grid[3] x grid[4] cells
    (ball_cells): cell c holds cell_balls[cell_first[c]:cell_first[c + 1]], and a ball that
    can meet a beam within reach lies in the scanner's cell or one of its eight neighbours
    (_ball's first test).
    """
    samples = bx.shape[0]
    few = positions.shape[0] <= FEW_BALLS
    balls = 0 if few else positions.shape[0]
    # Few allocations a call (a call of one robot's scan pays them each time): the beams'
    # directions and the gathered balls' windows in one, the gathered balls in another.
    work = np.empty(2 * samples + 2 * balls)
    ux = work[:samples]
    uy = work[samples:2 * samples]
    lows = work[2 * samples:2 * samples + balls]
    highs = work[2 * samples + balls:]
    near = np.empty(balls, dtype=np.int64)
    x0 = grid[0]
    y0 = grid[1]
    side = grid[2]
    columns = int(grid[3])
    rows = int(grid[4])
    for a in range(agents.shape[0]):
        own = agents[a]
        px = positions[own, 0]
        py = positions[own, 1]
        row = out[a]
        every, origin, sign, per_radian, turn = _fan(cos_yaws[a], sin_yaws[a], bx, by,
                                                     angle_min, increment, ux, uy, row)
        ci = min(max(int(math.floor((px - x0) / side)), 0), columns - 1)
        cj = min(max(int(math.floor((py - y0) / side)), 0), rows - 1)
        # The balls within reach, gathered without a branch (each slot written, kept when
        # the count moves past it): most fail, at random. (A few balls, one by one.)
        count = 0
        for i in range(max(ci - 1, 0), min(ci + 2, columns)):
            for j in range(max(cj - 1, 0), min(cj + 2, rows)):
                cell = i * rows + j
                if few:
                    for slot in range(cell_first[cell], cell_first[cell + 1]):
                        ball = cell_balls[slot]
                        if ball != own:
                            _ball(px, py, ux, uy, positions[ball, 0], positions[ball, 1],
                                  radii[ball], reach, every, origin, sign, per_radian, turn,
                                  row)
                    continue
                for slot in range(cell_first[cell], cell_first[cell + 1]):
                    ball = cell_balls[slot]
                    near[count] = ball
                    count += np.int64(within(positions[ball, 0] - px, positions[ball, 1] - py,
                                             radii[ball], reach) & (ball != own))
        _near_balls(px, py, ux, uy, positions, radii, near, count, reach, every, origin, sign,
                    per_radian, turn, lows, highs, row)
        _walls_and_cells(walls, solid, skips, frame, px, py, ux, uy, range_mins[a], reach,
                         every, origin, sign, per_radian, turn, row)


def warm():
    """Compile (or load from numba's cache) the scan kernel with a tiny scene."""
    out = np.empty(2)
    solid = np.zeros((4, 5), dtype=np.uint8)
    solid[1, 3] = 1
    scan_sectors(np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([0.3, 0.4]),
                 np.array([[3.0, -1.0, 3.0, 1.0]]), solid, free_squares(solid),
                 np.array([-1.0, -1.0, 0.5]), 0.0, 0.0, 1.0, 0.0, np.array([1.0, 0.0]),
                 np.array([0.0, 1.0]), 0.0, 0.5 * math.pi, 0, 0.1, 5.0, out)
    many = np.empty((1, 2))
    scan_agents(np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([0.3, 0.4]),
                np.array([[3.0, -1.0, 3.0, 1.0]]), solid, free_squares(solid),
                np.array([-1.0, -1.0, 0.5]), np.array([0, 2]), np.array([0, 1]),
                np.array([0.0, 0.0, 5.4, 1.0, 1.0]), np.array([0]), np.array([1.0]),
                np.array([0.0]), np.array([1.0, 0.0]), np.array([0.0, 1.0]), 0.0,
                0.5 * math.pi, np.array([0.1]), 5.0, many)
    return out
