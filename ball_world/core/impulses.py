"""Which impulse commands are accepted, and why the others are not.

An impulse names its ball in header.frame_id ('ball_<i>'), carries J in N s along the
world axes, and must lie in the z = 0 plane. Every rejection has a short reason key, so
the node can count rejections by kind and warn once per kind rather than once per message.
"""
import math
import re

_BALL_FRAME = re.compile(r'ball_(0|[1-9][0-9]*)')

#: A non-zero header.stamp further than this from both the simulation time and the wall
#: clock is taken for a mistake (a stale or corrupt message), not an order for now.
STAMP_WINDOW_NS = 3600 * 10**9


class ImpulseRejected(ValueError):
    """An impulse that must not touch the world; `reason` is a short key for counting."""

    def __init__(self, reason, detail):
        super().__init__(detail)
        self.reason = reason


def parse_ball(frame_id, ball_count):
    """Ball index named by a frame_id such as 'ball_3'."""
    if not frame_id:
        raise ImpulseRejected('empty_frame_id', 'header.frame_id is empty; name the ball, '
                                                'e.g. ball_0')
    match = _BALL_FRAME.fullmatch(frame_id)
    if match is None:
        raise ImpulseRejected('malformed_frame_id', f"header.frame_id '{frame_id[:64]}' is not "
                                                    'ball_<index>')
    ball = int(match.group(1))
    if ball >= ball_count:
        raise ImpulseRejected('unknown_ball', f"no ball '{frame_id}': the world has "
                                              f'{ball_count} balls')
    return ball


def check_impulse(frame_id, x, y, z, ball_count, stamp_ns=0, sim_ns=0, wall_ns=0):
    """Return (ball, jx, jy) for a valid impulse, or raise ImpulseRejected."""
    ball = parse_ball(frame_id, ball_count)
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ImpulseRejected('non_finite', f'impulse ({x}, {y}, {z}) on {frame_id} is not '
                                            'finite')
    if z != 0.0:
        raise ImpulseRejected('nonzero_z', f'impulse on {frame_id} has z = {z}; the world is '
                                           'the z = 0 plane')
    if stamp_ns != 0 and min(abs(stamp_ns - sim_ns), abs(stamp_ns - wall_ns)) > STAMP_WINDOW_NS:
        raise ImpulseRejected('stamp_out_of_range', f'impulse on {frame_id} is stamped '
                                                    f'{stamp_ns / 1e9:.3f} s, more than an hour '
                                                    'from both simulation and wall time')
    return ball, float(x), float(y)


def velocity_after(velocities, masses, ball, jx, jy, speed_limit):
    """The velocity an impulse would give; ImpulseRejected if not finite or over the limit.

    The limit keeps one command from freezing the node: substeps grow with the fastest
    ball's speed, so a ball at 1e30 m/s would take forever to step.
    """
    mass = float(masses[ball])  # Python floats: an overflow is inf, not a numpy warning
    vx = float(velocities[ball, 0]) + jx / mass
    vy = float(velocities[ball, 1]) + jy / mass
    speed = math.hypot(vx, vy)
    if not math.isfinite(speed):
        raise ImpulseRejected('overflow', f'impulse ({jx}, {jy}) would make ball {ball} '
                                          'velocity non-finite')
    if speed > speed_limit:
        raise ImpulseRejected('too_fast', f'impulse ({jx}, {jy}) would send ball {ball} at '
                                          f'{speed:.3g} m/s, over the {speed_limit:.3g} m/s '
                                          'this world can step in real time')
    return vx, vy
