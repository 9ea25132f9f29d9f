"""Which impulse commands are accepted, and why the others are not.

An impulse names its ball in header.frame_id (the ball's entity name, 'ball_<i>' for the
balls a world starts with), carries J in N s along the world axes, and must lie in the
z = 0 plane. Every rejection has a short reason key, so the node can count rejections by
kind and warn once per kind rather than once per message.

A name is looked up, never parsed into a number: whatever a publisher puts in frame_id
(5,000 digits, control characters, megabytes) is either a name the world has or a counted
rejection.
"""
import math

from ball_world.core.limits import MAX_NAME_LENGTH

#: A non-zero header.stamp further than this from both the simulation time and the wall
#: clock is taken for a mistake (a stale or corrupt message), not an order for now.
STAMP_WINDOW_NS = 3600 * 10**9


class ImpulseRejected(ValueError):
    """An impulse that must not touch the world; `reason` is a short key for counting."""

    def __init__(self, reason, detail):
        super().__init__(detail)
        self.reason = reason


def _shown(frame_id):
    """A frame_id fit for one log line: at most 64 characters, no control characters."""
    text = frame_id[:64].encode('unicode_escape').decode('ascii')
    return text + ('...' if len(frame_id) > 64 else '')


def _check_name(frame_id):
    if not frame_id:
        raise ImpulseRejected('empty_frame_id', 'header.frame_id is empty; name the ball, '
                                                'e.g. ball_0')
    if len(frame_id) > MAX_NAME_LENGTH:
        raise ImpulseRejected('unknown_ball', f"no ball '{_shown(frame_id)}' "
                                              f'({len(frame_id):,} characters)')


def lookup_ball(frame_id, index_of):
    """Index of the ball whose entity name is frame_id; index_of maps names to indices."""
    _check_name(frame_id)
    ball = index_of.get(frame_id)
    if ball is None:
        raise ImpulseRejected('unknown_ball', f"no ball '{_shown(frame_id)}': the world has "
                                              f'{len(index_of)} balls')
    return ball


def check_impulse(frame_id, x, y, z, index_of, stamp_ns=0, sim_ns=0, wall_ns=0):
    """Return (ball, jx, jy) for a valid impulse, or raise ImpulseRejected.

    index_of maps each ball's entity name to its index in the world's arrays.
    """
    ball = lookup_ball(frame_id, index_of)
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


def velocity_after(velocities, masses, ball, jx, jy, speed_limit, energy, lightest):
    """The velocity an impulse would give; ImpulseRejected if not finite or over the limit.

    The limit keeps one command from freezing the node: substeps grow with the fastest
    ball's speed, so a ball at 1e30 m/s would take forever to step. It is taken on the
    world's energy, not only on this ball: collisions may later hand all of the energy to
    the lightest ball, which must still be steppable. energy is the world's kinetic energy
    before the impulse, lightest the smallest mass. Returns (vx, vy, energy after).
    """
    mass = float(masses[ball])  # Python floats: an overflow is inf, not a numpy warning
    old_x = float(velocities[ball, 0])
    old_y = float(velocities[ball, 1])
    vx = old_x + jx / mass
    vy = old_y + jy / mass
    after = energy + 0.5 * mass * ((vx * vx + vy * vy) - (old_x * old_x + old_y * old_y))
    reachable = math.sqrt(2.0 * max(after, 0.0) / lightest)
    if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(reachable)):
        raise ImpulseRejected('overflow', f'impulse ({jx:.3g}, {jy:.3g}) would make ball '
                                          f'{ball} velocity non-finite')
    if reachable > speed_limit:
        raise ImpulseRejected('too_fast', f'impulse ({jx:.3g}, {jy:.3g}) on ball {ball} would '
                                          f'give the world enough energy for a ball to reach '
                                          f'{reachable:.3g} m/s, over the {speed_limit:.3g} '
                                          'm/s it can step')
    return vx, vy, after
