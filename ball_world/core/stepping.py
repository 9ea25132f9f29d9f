"""What one seed-mode step is, whichever backend computes it: stages, plan, counters.

A step of dt seconds is split into equal substeps (the plan below), and every substep runs
the same four stages, under the same names in `numpy_backend` (the reference, vectorized)
and in `numba_backend` (compiled loops):

1. `move`: every ball moves for h seconds at its velocity (`rules.advance`).
2. `find_contacts`: every ball-ball pair and ball-wall pair that is touching, in the
   canonical order: pairs (a, b) with a < b sorted by (a, b), then ball-wall contacts
   sorted by (ball, wall). The broadphase may find candidates in any order and may offer
   more than needed; the order of the contacts is a property of the world only.
3. `resolve`, in rounds: contacts are numbered pairs first, then walls, in canonical order.
   A round takes every contact that is approaching and keeps those whose balls take part in
   no lower-numbered approaching contact (so no ball is in two kept contacts, and the
   lowest-numbered approaching contact is always kept: every round makes progress). Rounds
   repeat until no touching contact is approaching, at most MAX_ROUNDS times.
4. `respond`: each kept contact gets the seed's response (`rules.pair_response`,
   `rules.reflect_off_wall`, `rules.reflect_off_end`). Kept contacts share no ball, so the
   order within a round cannot matter. numpy responds to a round's contacts at once
   (`respond_pairs`, `respond_walls`), numba to one at a time (`respond_pair`,
   `respond_wall`), from the same formulas.

If a collision makes a ball faster than the plan assumed, the rest of the step is split
again (`replan`). The same `StepStats` counters come out of both backends.

Bounded work: the plan never exceeds `limits.MAX_SUBSTEPS` substeps per step. A world whose
reachable speed (see `speed_limit`) is within the limit cannot need more; a world driven
past it by direct writes to its arrays is refused (`SubstepLimitExceeded`).
"""
import importlib.util
import math
from typing import NamedTuple

from ball_world.core.limits import MAX_SUBSTEPS

#: Largest distance a ball may travel in one substep, as a fraction of the smallest radius.
MAX_TRAVEL = 0.5
#: Cap on resolution rounds per substep; contacts left approaching after it (never seen in
#: practice) are counted as `unresolved` and resolved in a later substep.
MAX_ROUNDS = 10_000
#: The ways a World can compute the seed-mode step; both give bit-identical trajectories.
BACKENDS = ('numpy', 'numba')
#: The backend choice that means "numba when installed, numpy otherwise".
AUTO = 'auto'
#: Status codes a backend's step returns (the numba kernel cannot raise formatted errors).
STEP_DONE = 0
STEP_REFUSED = 1


class StepStats(NamedTuple):
    """What happened in one step: collisions resolved, substeps taken, rounds, leftovers.

    A NamedTuple rather than a dataclass: it is made once per step, and at small N a
    dataclass's construction alone is a tenth of a compiled step.
    """

    ball_ball: int = 0
    ball_wall: int = 0
    substeps: int = 0
    rounds: int = 0
    unresolved: int = 0
    events: int = 0  # exact mode: events processed (collisions, stale ones, cell crossings)


#: Positions of the counters in the totals array the backends fill (StepStats' field order).
BALL_BALL, BALL_WALL, SUBSTEPS, ROUNDS, UNRESOLVED = range(5)


class SubstepLimitExceeded(ValueError):
    """A step would need more than MAX_SUBSTEPS substeps."""


def numba_installed():
    """Whether the 'numba' backend can run, without importing numba (half a second)."""
    return importlib.util.find_spec('numba') is not None


def resolve_backend(name):
    """The concrete backend for a choice: 'auto' is numba where installed, else numpy."""
    if name == AUTO:
        return 'numba' if numba_installed() else 'numpy'
    if name not in BACKENDS:
        raise ValueError(f'unknown backend {name!r}; expected one of {AUTO}, '
                         f'{", ".join(BACKENDS)}')
    if name == 'numba' and not numba_installed():
        raise ValueError("backend 'numba' needs the numba package (pip install numba)")
    return name


def travel_per_substep(min_radius):
    """How far a ball may move in one substep, m."""
    return MAX_TRAVEL * min_radius


def plan_substeps(speed, duration, travel):
    """Equal substeps for `duration` so that a ball at `speed` moves at most `travel` in one.

    Returns MAX_SUBSTEPS + 1 for any plan past the limit (also for a non-finite speed), so
    that no caller ever converts a huge float to an integer.
    """
    if speed == 0.0 or travel == 0.0:
        return 1
    ratio = speed * duration / travel
    if not ratio <= MAX_SUBSTEPS:
        return MAX_SUBSTEPS + 1
    return max(1, math.ceil(ratio))


def replan(count, done, h, speed, fastest, travel):
    """The plan after `done` of `count` substeps of h, given the fastest collided ball.

    A collision that makes a ball faster than `speed` splits the rest of the step again,
    but only if the new speed would travel more than `travel` in one substep of h.
    Returns (count, done, h, speed).
    """
    if fastest > speed:
        speed = fastest
        if done < count and plan_substeps(speed, h, travel) > 1:
            rest = (count - done) * h
            count = plan_substeps(speed, rest, travel)
            h = rest / count
            done = 0
    return count, done, h, speed


def over_budget(taken, count, done):
    """Whether finishing the plan would take the step past MAX_SUBSTEPS substeps."""
    return taken + count - done > MAX_SUBSTEPS


def speed_limit(travel, dt):
    """Largest speed that keeps every step within MAX_SUBSTEPS substeps, m/s.

    Why half of MAX_SUBSTEPS * travel / dt: re-splitting after collisions rounds up once per
    split. Every substep but the last of a step lasts h = rest / ceil(s rest / travel) with
    ceil(...) >= 2, so h > travel / (2 s); with every speed s <= v, a step of dt then takes
    fewer than 2 v dt / travel + 1 substeps, which is at most MAX_SUBSTEPS when
    v <= (MAX_SUBSTEPS - 1) travel / (2 dt). Collisions alone never make any ball faster
    than the world's reachable speed, so comparing that with this limit bounds every step.
    """
    if travel == 0.0:
        return math.inf
    return (MAX_SUBSTEPS - 1) * travel / (2.0 * dt)


def reachable_speed(energy, min_mass):
    """Fastest any ball can become through collisions alone: sqrt(2 E / m_min), m/s.

    Collisions conserve kinetic energy E; a ball of mass m holding all of it moves at
    sqrt(2 E / m), and the lightest ball is the fastest such.
    """
    if energy == 0.0:
        return 0.0
    return math.sqrt(2.0 * energy / min_mass)


def refusal_possible(energy, min_mass, travel, dt):
    """Whether a step could be refused part-way, so that it must keep a copy of the state.

    By `speed_limit`'s argument, a world whose reachable speed is within the limit never
    needs more than MAX_SUBSTEPS substeps, so its steps skip the copy.
    """
    return not reachable_speed(energy, min_mass) <= speed_limit(travel, dt)
