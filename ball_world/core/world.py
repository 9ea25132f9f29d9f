"""The World: balls and walls as numpy arrays, their edits, invariants and step. No I/O.

The rules are the seed's (`shared/seed/RULES.md`), applied a posteriori: balls move first,
then every pair that is touching AND approaching collides, with the seed's response.
`core.stepping` defines the seed-mode step once (stages, canonical contact order, rounds,
substep plan); `numpy_backend` and `numba_backend` compute it bit for bit alike.

Choices the seed leaves open, made here:

- Several contacts of one ball in one substep are resolved in rounds of conflict-free
  contacts (see `core.stepping`). Each response conserves momentum and kinetic energy
  exactly, so the whole step does too (to rounding).
- Segment walls: inside a segment the seed's wall rule applies as written; beyond an end
  point the contact normal is the direction from that end point to the ball's centre, and
  the velocity is reflected about it.
- A map's solid cells are walls too: the boundary of the solid region as merged runs of
  cell edges (core.static_geometry), whose end points are true corners, so the same two
  rules hold at a cell's edge (inside a run) and at a convex corner (its end point).
- Tunnelling: a step is split into equal substeps so that no ball moves more than
  `MAX_TRAVEL` (half) of the smallest radius in one substep. A ball that was not touching
  a wall cannot reach its far side then, and two balls close by at most half the sum of
  their radii per substep, so their centres cannot pass each other unseen. What a
  posteriori detection can still miss is a graze shallower than 1 - sqrt(3)/2 (13.4%) of
  the sum of the radii when both balls move (1 - sqrt(15)/4, 3.2%, when one is at rest):
  the pair approaches only over the first half of its overlap chord, and no substep end
  may fall in it (docs/physics.md derives it). If a collision speeds a ball up, the rest
  of the step is split again.

Modes: `mode='seed'` is the rule above; `mode='exact'` (core.exact, needs numba) moves the
balls through every collision of a step in time order, each at its true time of impact,
with the same responses.

Every World holds only what `core.limits` allows (ball count, radii, masses, coordinates,
walls): the constructor and the edit methods refuse anything else with a ValueError.
"""
import math

import numpy as np

from ball_world.core import limits
from ball_world.core.broadphase import dot_rows
from ball_world.core.static_geometry import StaticGeometry
from ball_world.core.stepping import (BACKENDS, MAX_TRAVEL, numba_installed, reachable_speed,
                                      resolve_backend, speed_limit, STEP_REFUSED, StepStats,
                                      SubstepLimitExceeded, travel_per_substep)

#: Makes a NamedTuple from a sequence of all its fields, without its __new__'s argument handling.
_make_tuple = tuple.__new__

__all__ = ['BACKENDS', 'MAX_TRAVEL', 'MODES', 'numba_installed', 'StepStats',
           'SubstepLimitExceeded', 'Walls', 'World']

#: How a World steps: the seed's a posteriori rule, or every collision at its exact time.
MODES = ('seed', 'exact')


class Walls:
    """Wall segments (M, 4) and the per-segment values every step needs.

    Refuses segments that are not finite, shorter than MIN_WALL_LENGTH (a segment whose
    end points round together has no direction) or outside COORDINATE_LIMIT.
    """

    def __init__(self, segments):
        segments = np.array(segments, dtype=np.float64).reshape(-1, 4)
        if len(segments) > limits.MAX_WALLS:
            raise ValueError(f'{len(segments)} walls; at most {limits.MAX_WALLS} are supported')
        bad = np.flatnonzero(~np.isfinite(segments).all(axis=1))
        if len(bad):
            raise ValueError(f'wall {bad[0]} has a coordinate that is not finite: '
                             f'{segments[bad[0]].tolist()}')
        _check_coordinates(segments.reshape(-1, 2), 'wall end point')
        self.segments = segments
        self.starts = segments[:, 0:2].copy()
        self.ends = segments[:, 2:4].copy()
        edge = self.ends - self.starts
        self.lengths = np.hypot(edge[:, 0], edge[:, 1])
        short = np.flatnonzero(~(self.lengths >= limits.MIN_WALL_LENGTH))
        if len(short):
            k = short[0]
            raise ValueError(f'wall {k} {segments[k].tolist()} is {self.lengths[k]:.3g} m long; '
                             f'walls must be at least {limits.MIN_WALL_LENGTH} m')
        self.directions = edge / self.lengths[:, None]
        bent = np.flatnonzero(~np.isfinite(self.directions).all(axis=1))
        if len(bent):
            raise ValueError(f'wall {bent[0]} {segments[bent[0]].tolist()} has no finite '
                             'direction')

    def __len__(self):
        return len(self.segments)


def _check_coordinates(points, what):
    """Refuse points beyond COORDINATE_LIMIT (ValueError naming the first)."""
    far = np.flatnonzero((np.abs(points) > limits.COORDINATE_LIMIT).any(axis=1))
    if len(far):
        raise ValueError(f'{what} {far[0]} at {points[far[0]].tolist()} is beyond the '
                         f'coordinate limit of {limits.COORDINATE_LIMIT:g} m')


def _check_range(values, low, high, what, unit):
    """Refuse values outside [low, high] (ValueError naming the first)."""
    bad = np.flatnonzero(~((values >= low) & (values <= high)))
    if len(bad):
        raise ValueError(f'ball {bad[0]}: {what} {values[bad[0]]:g} {unit} is outside '
                         f'[{low:g}, {high:g}] {unit}')


def _checked_balls(positions, velocities, radii, masses):
    """The four ball arrays as float64 (K, 2), (K, 2), (K,), (K,), checked against limits."""
    positions = np.array(positions, dtype=np.float64).reshape(-1, 2)
    velocities = np.array(velocities, dtype=np.float64).reshape(-1, 2)
    radii = np.array(radii, dtype=np.float64).reshape(-1)
    masses = np.array(masses, dtype=np.float64).reshape(-1)
    n = len(positions)
    if not (len(velocities) == len(radii) == len(masses) == n):
        raise ValueError(f'positions, velocities, radii and masses differ in length '
                         f'({n}, {len(velocities)}, {len(radii)}, {len(masses)})')
    for what, values in (('position', positions), ('velocity', velocities)):
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if len(bad):
            raise ValueError(f'ball {bad[0]}: {what} {values[bad[0]].tolist()} is not finite')
    _check_coordinates(positions, 'ball')
    _check_range(radii, limits.MIN_RADIUS, limits.MAX_RADIUS, 'radius', 'm')
    _check_range(masses, limits.MIN_MASS, limits.MAX_MASS, 'mass', 'kg')
    return positions, velocities, radii, masses


def _check_world(radii):
    """Refuse a whole set of balls beyond MAX_BALLS or MAX_RADIUS_RATIO."""
    if len(radii) > limits.MAX_BALLS:
        raise ValueError(f'{len(radii)} balls; at most {limits.MAX_BALLS} are supported')
    if len(radii) and radii.max() > limits.MAX_RADIUS_RATIO * radii.min():
        raise ValueError(f'radii from {radii.min():g} m to {radii.max():g} m differ by more '
                         f'than the supported ratio of {limits.MAX_RADIUS_RATIO:g}')


def _stepper(backend):
    """A fresh stepper of the (concrete) backend; numba is imported only when chosen."""
    if backend == 'numba':
        from ball_world.core.numba_backend import NumbaStepper
        return NumbaStepper()
    from ball_world.core.numpy_backend import NumpyStepper
    return NumpyStepper()


class World:
    """N balls (positions, velocities, radii, masses), M wall segments and an optional map's
    solid cells, as numpy arrays.

    Ball i is row i of every array. The step never reorders balls; only `remove_balls`
    renumbers them (the others keep their relative order). Change the balls through the
    methods below, which keep derived state (neighbour lists, grid order, smallest radius,
    scratch buffers) in step; edits replace the arrays, so hold the World, not its arrays.
    `backend` is 'numpy', 'numba' or 'auto' (numba where installed); `self.backend` is
    always the concrete one, and the choice never changes a trajectory. `mode` is one of
    MODES; 'exact' needs numba whatever the backend.

    `solid_cells` (a core.solid_cells.SolidCells, or None) makes a map's solid cells walls:
    the boundary of the solid region, in merged runs, numbered after `walls`
    (core.static_geometry builds `static`, the one index of all static geometry, once). A
    World without one steps bit for bit as it always did.
    """

    def __init__(self, positions, velocities, radii, masses, walls=(), backend='auto',
                 mode='seed', solid_cells=None):
        if mode not in MODES:
            raise ValueError(f'unknown mode {mode!r}; expected one of {", ".join(MODES)}')
        if mode == 'exact' and not numba_installed():
            raise ValueError("mode 'exact' needs the numba package (pip install numba)")
        self.mode = mode
        self.positions, self.velocities, self.radii, self.masses = _checked_balls(
            positions, velocities, radii, masses)
        _check_world(self.radii)
        self.walls = Walls(walls)
        self.solid_cells = solid_cells.checked() if solid_cells is not None else None
        self.static = StaticGeometry(self.walls, self.solid_cells)
        self.backend = resolve_backend(backend)
        self._stepper = _stepper(self.backend)
        self._edited()
        if mode == 'seed' and len(self):
            # What the first step would build from the static geometry (a map's dilated
            # index), built now: before a node says it started, not on its first step.
            self._stepper.prepare(self)

    def __len__(self):
        return len(self.positions)

    def _edited(self):
        """Recompute what depends on the set of balls; drop the stepper's derived state."""
        self.min_radius = float(self.radii.min()) if len(self) else 0.0
        self._travel = travel_per_substep(self.min_radius)
        # The step's counters in StepStats order, zeroed by the stepper.
        self._totals = np.zeros(len(StepStats._fields), dtype=np.int64)
        self._stepper.invalidate()

    # Invariants and limits --------------------------------------------------------------

    def kinetic_energy(self):
        """Total kinetic energy, J."""
        return 0.5 * float(np.dot(self.masses, dot_rows(self.velocities, self.velocities)))

    def momentum(self):
        """Total linear momentum (px, py), kg m/s."""
        return self.masses @ self.velocities

    def reachable_speed(self):
        """The largest speed any ball can ever reach through collisions alone, m/s.

        sqrt(2 E / m_min): collisions conserve the kinetic energy E and can at most hand all
        of it to the lightest ball. Only edits and impulses change it.
        """
        if len(self) == 0:
            return 0.0
        return reachable_speed(self.kinetic_energy(), float(self.masses.min()))

    def speed_limit(self, dt):
        """Largest reachable speed for which every step of dt stays within MAX_SUBSTEPS.

        Callers that change velocities (initial conditions, impulses, set states) compare
        `reachable_speed()` with this and refuse what exceeds it; then no step is refused.
        """
        return speed_limit(travel_per_substep(self.min_radius), dt)

    # Edits between steps ----------------------------------------------------------------

    def apply_impulse(self, ball, jx, jy):
        """Apply an impulse J (N s) to one ball: v += J / m."""
        mass = self.masses[ball]
        self.velocities[ball, 0] += jx / mass
        self.velocities[ball, 1] += jy / mass

    def apply_impulses(self, balls, jx, jy):
        """apply_impulse for several distinct balls at once (arrays), with the same bits."""
        masses = self.masses[balls]
        self.velocities[balls, 0] += jx / masses
        self.velocities[balls, 1] += jy / masses

    def add_balls(self, positions, velocities, radii, masses):
        """Append balls (checked against core.limits); returns their indices.

        Overlap with other balls or walls is the caller's policy, not checked here: balls
        that overlap and separate are left alone, overlapping and approaching ones collide.
        """
        positions, velocities, radii, masses = _checked_balls(positions, velocities, radii,
                                                              masses)
        all_radii = np.concatenate((self.radii, radii))
        _check_world(all_radii)
        first = len(self)
        self.positions = np.concatenate((self.positions, positions))
        self.velocities = np.concatenate((self.velocities, velocities))
        self.radii = all_radii
        self.masses = np.concatenate((self.masses, masses))
        self._edited()
        return np.arange(first, len(self))

    def remove_balls(self, balls):
        """Remove balls by index; the others keep their relative order (and shift down)."""
        balls = np.asarray(balls).reshape(-1)
        if len(balls) == 0:
            return
        if not np.issubdtype(balls.dtype, np.integer):
            raise ValueError(f'ball indices must be integers, got {balls.dtype}')
        outside = np.flatnonzero((balls < 0) | (balls >= len(self)))
        if len(outside):
            raise ValueError(f'no ball {balls[outside[0]]}: the world has {len(self)} balls')
        keep = np.ones(len(self), dtype=bool)
        keep[balls] = False
        self.positions = self.positions[keep]
        self.velocities = self.velocities[keep]
        self.radii = self.radii[keep]
        self.masses = self.masses[keep]
        self._edited()

    def set_ball_state(self, ball, position, velocity):
        """Put one ball at `position` (x, y) with `velocity` (vx, vy)."""
        if not (isinstance(ball, (int, np.integer)) and 0 <= ball < len(self)):
            raise ValueError(f'no ball {ball!r}: the world has {len(self)} balls')
        position, velocity, _, _ = _checked_balls(position, velocity, self.radii[ball],
                                                  self.masses[ball])
        self.positions[ball] = position[0]
        self.velocities[ball] = velocity[0]
        self._edited()

    # Stepping ---------------------------------------------------------------------------

    def step(self, dt):
        """Advance the world by dt seconds in its mode; return what happened as StepStats.

        Seed mode may raise SubstepLimitExceeded, exact mode core.exact.EventBudgetExceeded
        (a jammed world): both only for worlds past what their checks let in. The seed-mode
        path is written out here, with no call it does not need: at 100 balls a compiled
        step takes about 7 us, and each Python call around it is a few percent of that.
        """
        dt = float(dt)
        if not 0.0 < dt < math.inf:
            raise ValueError(f'dt must be a finite number of seconds > 0, got {dt}')
        if self.mode == 'exact':
            return self._exact_step(dt)
        if not len(self.positions):
            return StepStats(substeps=1)
        totals = self._totals
        if self._stepper.step(self, dt, self._travel, totals) == STEP_REFUSED:
            raise SubstepLimitExceeded(
                f'step of {dt:g} s refused: it would need more than {limits.MAX_SUBSTEPS} '
                f'substeps (reachable speed {self.reachable_speed():.4g} m/s, limit '
                f'{self.speed_limit(dt):.4g} m/s for a smallest radius of '
                f'{self.min_radius:g} m)')
        # The counters in StepStats order (the stepper zeroes them; `events` stays 0), made
        # into the tuple without NamedTuple's argument handling.
        return _make_tuple(StepStats, totals.tolist())

    def carried_state(self):
        """Exact mode: what the next step takes over from the last, as plain arrays
        (core.exact_carry.CarriedState; see core.exact.carried). Seed mode carries nothing
        between steps: None."""
        if self.mode != 'exact':
            return None
        from ball_world.core import exact
        return exact.carried(self)

    def restore_carried_state(self, carried):
        """Exact mode: take over `carried` (from carried_state(), maybe of another World with
        these arrays), so the steps from here are bit for bit that World's. ValueError,
        naming what is wrong, for a state that does not fit this world."""
        if self.mode != 'exact':
            raise ValueError('seed mode carries no state between steps: an exact-mode state '
                             'cannot be taken over')
        from ball_world.core import exact
        exact.restore(self, carried)

    def _exact_step(self, dt):
        """The exact-mode step (core.exact): every collision at its time of impact."""
        from ball_world.core import exact  # numba: imported only by worlds that use it
        ball_ball, ball_wall, events = exact.step(self, dt)
        return StepStats(ball_ball=ball_ball, ball_wall=ball_wall, substeps=1, events=events)
