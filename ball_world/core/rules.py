"""The seed's formulas, each written once, for both backends.

Why one source: the numpy backend applies these functions to whole columns of contacts
(numpy arrays), the numba backend compiles the very same functions and applies them to one
contact at a time (floats). Both evaluate the same IEEE operations in the same order, so
they round identically and the two backends agree bit for bit. Rules for this module:

- only `+ - * /`, comparisons, `&`, `np.sqrt`, `np.minimum` and `np.maximum` (numpy ufuncs
  work element-wise on arrays and on scalars, and numba supports them on scalars);
- every product and sum written out in the order the seed writes it, with no algebraic
  shortcut in one backend that the other does not take;
- nothing here may be compiled with fastmath: contraction into fused multiply-adds or
  re-association would change the last bit.

The collision rules themselves are the seed's (`shared/seed/RULES.md`); the docstrings say
which line of it each function implements.
"""
import numpy as np


def advance(x, v, h):
    """Position after moving for h seconds at constant velocity: x + v h."""
    return x + v * h


def speed_squared(vx, vy):
    """|v|^2; the substep plan takes the square root of the largest."""
    return vx * vx + vy * vy


def reach_squared(radius_a, radius_b):
    """(R_a + R_b)^2: two balls touch when their centres are closer than R_a + R_b."""
    return (radius_a + radius_b) * (radius_a + radius_b)


def pair_touching(rx, ry, reach2):
    """Ball-ball touching: |r_a - r_b|^2 < (R_a + R_b)^2, with (rx, ry) = r_a - r_b."""
    return rx * rx + ry * ry < reach2


def pair_approaching(rx, ry, vax, vay, vbx, vby):
    """Ball-ball approaching: (r_a - r_b) . (v_a - v_b) < 0."""
    return rx * (vax - vbx) + ry * (vay - vby) < 0.0


def pair_response(vax, vay, vbx, vby, rx, ry, mass_a, mass_b):
    """The seed's ball-ball response; returns (v_a', v_b') as four components.

    v_a' = v_a - 2 m_b/(m_a+m_b) ((v_a-v_b).(r_a-r_b)) / |r_a-r_b|^2 (r_a-r_b)
    v_b' = v_b - 2 m_a/(m_a+m_b) ((v_b-v_a).(r_b-r_a)) / |r_b-r_a|^2 (r_b-r_a)
    """
    dist2 = rx * rx + ry * ry
    k_a = 2.0 * mass_b / (mass_a + mass_b) * ((vax - vbx) * rx + (vay - vby) * ry) / dist2
    k_b = 2.0 * mass_a / (mass_a + mass_b) * ((vbx - vax) * -rx + (vby - vay) * -ry) / dist2
    return vax - k_a * rx, vay - k_a * ry, vbx - k_b * -rx, vby - k_b * -ry


def wall_offset(px, py, start_x, start_y, wx, wy, length):
    """Offset s from a wall segment's nearest point to a ball centre, and whether inside.

    Along the segment (0 < r.w < length, r = centre - start) it is the seed's
    s = r - (r.w) w, perpendicular to the wall; beyond an end point it is the vector from
    that end point (start + clamp(r.w) w) to the centre.
    """
    rx = px - start_x
    ry = py - start_y
    along = rx * wx + ry * wy
    clamped = np.minimum(np.maximum(along, 0.0), length)
    return rx - clamped * wx, ry - clamped * wy, (along > 0.0) & (along < length)


def wall_touching(sx, sy, radius):
    """Ball-wall touching: |s| < R, compared squared."""
    return sx * sx + sy * sy < radius * radius


def wall_approaching(sx, sy, vx, vy):
    """Ball-wall approaching: d|s|/dt < 0, which is s . v < 0."""
    return sx * vx + sy * vy < 0.0


def reflect_off_wall(vx, vy, wx, wy):
    """The seed's ball-wall response inside a segment: v' = 2 (v.w) w - v."""
    along = vx * wx + vy * wy
    return 2.0 * along * wx - vx, 2.0 * along * wy - vy


def reflect_off_end(vx, vy, sx, sy):
    """Beyond a segment's end: reflect about n = s / |s|, v' = v - 2 (v.n) n."""
    norm = np.sqrt(sx * sx + sy * sy)
    nx = sx / norm
    ny = sy / norm
    vn = vx * nx + vy * ny
    return vx - 2.0 * vn * nx, vy - 2.0 * vn * ny
