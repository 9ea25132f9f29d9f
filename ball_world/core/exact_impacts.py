"""Exact mode's geometry: when two disks, or a disk and a wall segment, first touch, and what
the seed's elastic response does at that contact. Pure functions of numbers, compiled.

Why these formulas, and why they cannot loop or miss:

- A pair closes only while approaching, (r_a - r_b).(v_a - v_b) < 0 (the seed's second
  condition). Its impact time is the smaller root of |r + dv t| = R_a + R_b, written as
  gap / (-b + sqrt(b^2 - |dv|^2 gap)) with gap = |r|^2 - sigma^2, which has no cancellation
  for grazes and is never negative while the disks are apart. A graze of any depth has a
  real root (discriminant >= 0, a tangency included): nothing is missed however shallow.
- Disks that already overlap (from rounding, or built that way) and approach collide at once
  (time 0); overlapping disks that separate get no event, so they come apart instead of
  sticking.
- A wall segment is reached first either inside its length (the distance to its line reaches
  R while the contact point lies between the end points) or at an end point (a pair with a
  still point). The earliest of those three candidates is exactly the first time the
  distance to the segment reaches R, because that distance is the smallest of the three.
"""
import math

from numba import njit

INFINITY = math.inf


def compile_kernel(function):
    """numba's nopython compilation, cached on disk so a node starts without recompiling."""
    return njit(cache=True, nogil=True)(function)


def compile_inline(function):
    """compile_kernel, and inlined into its callers by numba (small helpers on hot paths: a
    call that passes arrays costs more than such a helper's work)."""
    return njit(cache=True, nogil=True, inline='always')(function)


@compile_kernel
def pair_impact_time(rx, ry, dvx, dvy, sigma):
    """Time until |r + dv t| = sigma, for r = r_a - r_b and dv = v_a - v_b; inf if never.

    0 when the disks already overlap and approach: the response is due now.
    """
    b = rx * dvx + ry * dvy
    if b >= 0.0:
        return INFINITY
    gap = rx * rx + ry * ry - sigma * sigma
    if gap <= 0.0:
        return 0.0
    discriminant = b * b - (dvx * dvx + dvy * dvy) * gap
    if discriminant < 0.0:
        return INFINITY
    return gap / (math.sqrt(discriminant) - b)


@compile_kernel
def wall_impact_time(px, py, vx, vy, radius, ax, ay, bx, by, wx, wy, length):
    """Time until a disk at p moving at v first touches the segment from a to b; inf if never.

    w is the segment's unit direction and `length` its length.
    """
    rx = px - ax
    ry = py - ay
    # Signed distance of the centre from the wall's line, along the normal n = (-w_y, w_x).
    across = wx * ry - wy * rx
    closing = wx * vy - wy * vx
    interior = INFINITY
    if across > 0.0 and closing < 0.0:
        interior = max(0.0, (across - radius) / -closing)
    elif across < 0.0 and closing > 0.0:
        interior = max(0.0, (-across - radius) / closing)
    best = INFINITY
    if interior < INFINITY:
        along = (rx + vx * interior) * wx + (ry + vy * interior) * wy
        if 0.0 < along < length:
            best = interior
    best = min(best, pair_impact_time(rx, ry, vx, vy, radius))
    return min(best, pair_impact_time(px - bx, py - by, vx, vy, radius))


@compile_kernel
def collide_pair(v, masses, a, b, rx, ry):
    """The seed's ball-ball response at contact normal r = r_a - r_b; False if not approaching.

    A contact reached by rounding with the disks no longer approaching (a graze of zero
    depth) is not a collision under the seed's rule: the velocities are left alone.
    """
    dvx = v[a, 0] - v[b, 0]
    dvy = v[a, 1] - v[b, 1]
    if dvx * rx + dvy * ry >= 0.0:
        return False
    dist2 = rx * rx + ry * ry
    ma = masses[a]
    mb = masses[b]
    # v_a' = v_a - 2 m_b/(m_a+m_b) ((v_a-v_b).(r_a-r_b)) / |r_a-r_b|^2 (r_a-r_b)
    k_a = 2.0 * mb / (ma + mb) * (dvx * rx + dvy * ry) / dist2
    # v_b' = v_b - 2 m_a/(m_a+m_b) ((v_b-v_a).(r_b-r_a)) / |r_b-r_a|^2 (r_b-r_a)
    k_b = 2.0 * ma / (ma + mb) * ((-dvx) * (-rx) + (-dvy) * (-ry)) / dist2
    v[a, 0] = v[a, 0] - k_a * rx
    v[a, 1] = v[a, 1] - k_a * ry
    v[b, 0] = v[b, 0] - k_b * -rx
    v[b, 1] = v[b, 1] - k_b * -ry
    return True


@compile_kernel
def collide_wall(v, i, px, py, ax, ay, bx, by, wx, wy, length):
    """The seed's ball-wall response for a disk touching the segment; False if not approaching.

    Inside the segment v' = 2 (v.w) w - v; beyond an end point the velocity is reflected
    about the normal n from that end point to the centre: v' = v - 2 (v.n) n.
    """
    vx = v[i, 0]
    vy = v[i, 1]
    rx = px - ax
    ry = py - ay
    along = rx * wx + ry * wy
    if 0.0 < along < length:
        sx = rx - along * wx
        sy = ry - along * wy
        if sx * vx + sy * vy >= 0.0:
            return False
        parallel = vx * wx + vy * wy
        v[i, 0] = 2.0 * parallel * wx - vx
        v[i, 1] = 2.0 * parallel * wy - vy
        return True
    if along <= 0.0:
        sx = rx
        sy = ry
    else:
        sx = px - bx
        sy = py - by
    if sx * vx + sy * vy >= 0.0:
        return False
    norm = math.sqrt(sx * sx + sy * sy)
    nx = sx / norm
    ny = sy / norm
    normal = vx * nx + vy * ny
    v[i, 0] = vx - 2.0 * normal * nx
    v[i, 1] = vy - 2.0 * normal * ny
    return True
