"""Exact mode: each step advances the world through every collision inside it, in time order,
each at its true time of impact. Event-driven hard disks (Alder & Wainwright; Rapaport, "The
Art of Molecular Dynamics Simulation"), compiled with numba. No ROS, no I/O.

The responses are the seed's (shared/seed/RULES.md), applied at the exact contact: a pair
along r_a - r_b at contact, a wall inside its length about its direction, an end point
about the normal from the end point to the centre. A map's solid cells are walls too: the
boundary runs of core.static_geometry, numbered after the walls, found by walking the static
index along each ball's path (exact_kernel._scan_runs). How the events are found and kept in
order is in exact_kernel.py; the impact times and responses are in exact_impacts.py.

Simultaneous events (same time to the last bit) are processed in a fixed order: ball-ball
impacts first, then ball-wall impacts, then cell crossings (bookkeeping); within a kind, by
the lower ball index, then by the partner (the other ball's index, or the wall's).

Determinism: the kernel keeps its predictions from one step to the next (rebuilding them
every step would cost more than the events themselves). Same world, same sequence of dt and
of edits between steps: bit-identical trajectories. The state is kept beside the world, not
in it, and follows edits by itself: a ball whose position or velocity differs from what the
last step left (an impulse, a set-state) is predicted again; a change in the number of
balls, a radius or a wall rebuilds everything (a World's map never changes).
`invalidate(world)` drops the state, so the next step starts from the world's arrays alone.
`carried(world)` gives the state as plain arrays and `restore(world, carried)` takes it back
(core.exact_carry), so a World rebuilt from a recording's arrays and the carried state steps
bit for bit as the original did.

Bounded work: a step processes at most `event_budget(n)` events, then raises
EventBudgetExceeded instead of going on (the balls are left where they were at that moment,
the predictions dropped). Within core.limits a step's events are otherwise unbounded only
for jammed worlds: elastic disks need infinitely many collisions in a finite time only when
they are pressed together with nowhere to go while moving (a ball exactly as wide as a
corridor, a row of touching balls between two walls); ordinary worlds need far fewer (see
EVENTS_PER_BALL).
"""
import importlib.util
import math
import weakref

import numpy as np

#: Events one step may process per ball (and at least MIN_EVENT_BUDGET in all): the same
#: bound seed mode has (core.limits.MAX_SUBSTEPS passes over every ball per step). Measured
#: needs: a gas at area fraction 0.5 moving half a radius per step, about 1.6 events per
#: ball; the node's scene (0.2, 0.48 R per step) about 0.4. Cell crossings are at most
#: 2 + (distance travelled) / (the largest diameter of the ball's radius class) per ball,
#: at most about 250 for a ball at the World's speed limit (500 smallest radii per step);
#: collisions about (distance) / (mean free path),
#: so only a dense gas with every ball at that limit, or a jammed world, reaches the budget.
EVENTS_PER_BALL = 1000
MIN_EVENT_BUDGET = 1_000_000

_states = weakref.WeakKeyDictionary()
_NO_COUNTS = np.empty(0, dtype=np.int64)


class EventBudgetExceeded(RuntimeError):
    """A step needed more events than event_budget(n): the world is jammed."""


def available():
    """True when numba is installed, so exact mode can run."""
    return importlib.util.find_spec('numba') is not None


def event_budget(n):
    """Most events one step of a world with n balls may process."""
    return max(MIN_EVENT_BUDGET, EVENTS_PER_BALL * n)


def invalidate(world):
    """Forget the predictions kept for `world`: the next step rebuilds them from its arrays."""
    _states.pop(world, None)


def carried(world):
    """What `world`'s next step takes over from its last (core.exact_carry.CarriedState):
    NOTHING_KEPT when it keeps no predictions (never stepped, dropped, or built for other
    radii or walls), so the next step builds them from the world's arrays."""
    from ball_world.core import exact_carry
    from ball_world.core import exact_kernel as kernel

    state = _states.get(world)
    static = world.static
    if state is None or not kernel.matches(state, world.radii, static.segments, static.layout):
        return exact_carry.NOTHING_KEPT
    return exact_carry.export(state, world)


def restore(world, carried):
    """Make `carried` (from carried(), maybe of another World) what `world`'s next step
    takes over, so its steps are bit for bit those of the World it came from, given the same
    arrays. Raises ValueError, naming what is wrong, for a state that is not one of this
    world's (checked fully first: it may come from a file)."""
    from ball_world.core import exact_carry

    if not carried.kept and not len(carried):
        invalidate(world)
        return
    _states[world] = exact_carry.restore(world, carried)


def step(world, dt, per_ball=None):
    """Advance `world` by dt seconds in exact mode, in place.

    Returns (ball_ball, ball_wall, events): collisions (contacts where the balls approached,
    as the seed counts them) and all events processed (collisions, stale predictions,
    cell crossings). `per_ball`, when given, is an int64 array of one entry per ball to which
    each ball's ball-ball collisions are added.
    """
    from ball_world.core import exact_kernel as kernel

    if not 0.0 <= dt < math.inf:
        raise ValueError(f'exact step: dt must be finite and >= 0, got {dt}')
    n = len(world.positions)
    if n == 0:
        return 0, 0, 0
    totals = np.zeros(3, dtype=np.int64)
    counts = per_ball if per_ball is not None else _NO_COUNTS
    budget = event_budget(n)
    arguments = (world.positions, world.velocities, world.radii, world.masses,
                 *kernel.geometry(world.static), float(dt), budget, totals, counts)
    state = _states.get(world)
    status = kernel.STALE_STATE if state is None else kernel.advance(state, *arguments)
    if status == kernel.STALE_STATE:
        state = _states[world] = _build(world, kernel)
        status = kernel.advance(state, *arguments)
    if status == kernel.NOT_FINITE:
        invalidate(world)
        raise ValueError('exact step: a ball position or velocity is not finite')
    if status == kernel.OVER_BUDGET:
        invalidate(world)
        raise EventBudgetExceeded(
            f'exact step: more than {budget} events in one step of {dt} s with {n} balls; '
            'balls are jammed (pressed between walls or each other while moving)')
    ball_ball, ball_wall, events = totals.tolist()
    return ball_ball, ball_wall, events


def _build(world, kernel):
    positions = world.positions
    velocities = world.velocities
    if not (np.isfinite(positions).all() and np.isfinite(velocities).all()):
        raise ValueError('exact step: a ball position or velocity is not finite')
    return kernel.build(positions, velocities, world.radii, *kernel.geometry(world.static))
