"""The exact elastic-collision core: the World as arrays, and its step. No ROS, no I/O.

The rules are the seed's (`shared/seed/RULES.md`), applied a posteriori: balls move first,
then every pair that is touching AND approaching collides, with the seed's response.

Choices the seed leaves open, made here:

- Several contacts of one ball in one step are resolved in rounds. Each round takes a
  conflict-free set of approaching contacts (every ball in at most one of them, chosen by
  lowest contact index, so the result is deterministic) and applies the seed's pairwise
  response to each. Rounds repeat until no touching pair is approaching. Each response
  conserves momentum and kinetic energy exactly, so the whole step does too (to rounding).
- Segment walls: inside a segment the seed's wall rule applies as written; beyond an end
  point the contact normal is the direction from that end point to the ball's centre, and
  the velocity is reflected about it.
- Tunnelling: a step is split into equal substeps so that no ball moves more than
  `MAX_TRAVEL` (half) of the smallest radius in one substep. A ball that was not touching
  a wall cannot reach its far side then, and two balls close by at most half the sum of
  their radii per substep, so their centres cannot pass each other unseen. What a
  posteriori detection can still miss is a graze shallower than 1 - sqrt(15/16) (3.2%)
  of the sum of the radii, entered and left within one substep. If a collision speeds a
  ball up, the rest of the step is split again.
"""
from dataclasses import dataclass
import importlib.util
import math

import numpy as np

from ball_world.core.broadphase import dot_rows, NeighbourLists, segment_offsets, take_rows

#: Largest distance a ball may travel in one substep, as a fraction of the smallest radius.
MAX_TRAVEL = 0.5
#: The ways a World can step: 'numpy' (pure numpy, the default) or 'numba' (kernels.py).
BACKENDS = ('numpy', 'numba')
#: Substeps per step that a commanded speed may demand at most (see World.speed_limit).
SPEED_LIMIT_SUBSTEPS = 1000
#: Safety cap on resolution rounds per substep; contacts left approaching (never seen in
#: practice) are resolved at the end of the next substep, and counted.
MAX_ROUNDS = 10_000


@dataclass(frozen=True)
class StepStats:
    """What happened in one step: collisions resolved, substeps taken, lists rebuilt."""

    ball_ball: int = 0
    ball_wall: int = 0
    substeps: int = 0
    rounds: int = 0
    unresolved: int = 0


def numba_installed():
    """Whether the 'numba' backend can run, without importing numba (half a second)."""
    return importlib.util.find_spec('numba') is not None


class Walls:
    """Wall segments (M, 4) and the per-segment values every step needs."""

    def __init__(self, segments):
        segments = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        self.segments = segments
        self.starts = segments[:, 0:2].copy()
        self.ends = segments[:, 2:4].copy()
        edge = self.ends - self.starts
        self.lengths = np.sqrt(np.einsum('ij,ij->i', edge, edge))
        if np.any(self.lengths <= 0.0):
            raise ValueError('a wall segment has zero length')
        self.directions = edge / self.lengths[:, None]

    def __len__(self):
        return len(self.segments)


class World:
    """N balls (positions, velocities, radii, masses) and M wall segments, as numpy arrays.

    Ball i is row i of every array, for the life of the World: the broadphase never
    reorders them, so users can rely on indices.
    """

    def __init__(self, positions, velocities, radii, masses, walls=(), skin=None,
                 backend='numpy'):
        self.positions = np.array(positions, dtype=np.float64).reshape(-1, 2)
        self.velocities = np.array(velocities, dtype=np.float64).reshape(-1, 2)
        self.radii = np.array(radii, dtype=np.float64).reshape(-1)
        self.masses = np.array(masses, dtype=np.float64).reshape(-1)
        n = len(self.positions)
        if not (len(self.velocities) == len(self.radii) == len(self.masses) == n):
            raise ValueError('positions, velocities, radii and masses differ in length')
        if n and (np.any(self.radii <= 0.0) or np.any(self.masses <= 0.0)):
            raise ValueError('radii and masses must be positive')
        self.walls = Walls(walls)
        self.min_radius = float(self.radii.min()) if n else 0.0
        if skin is None:
            skin = float(self.radii.mean()) * 2.0 if n else 1.0
        self.neighbours = NeighbourLists(skin)
        self._scratch_best = np.empty(n, dtype=np.intp)
        if backend not in BACKENDS:
            raise ValueError(f'unknown backend {backend!r}; expected one of {BACKENDS}')
        if backend == 'numba':
            # Imported here: numba takes half a second to import, and most runs use numpy.
            from ball_world.core import numba_backend as kernels
            if not kernels.available():
                raise ValueError("backend 'numba' needs the numba package (pip install numba)")
            self._kernels = kernels
        self.backend = backend

    def __len__(self):
        return len(self.positions)

    # Invariants -------------------------------------------------------------------------

    def kinetic_energy(self):
        """Total kinetic energy, J."""
        return 0.5 * float(np.dot(self.masses, dot_rows(self.velocities, self.velocities)))

    def momentum(self):
        """Total linear momentum (px, py), kg m/s."""
        return self.masses @ self.velocities

    def speed_limit(self, dt):
        """Fastest speed an impulse may give a ball: SPEED_LIMIT_SUBSTEPS substeps per step.

        Collisions conserve energy, so speeds stay bounded by what commands put in; the
        limit keeps one absurd command from making a single step take hours.
        """
        if len(self) == 0:
            return math.inf
        return SPEED_LIMIT_SUBSTEPS * MAX_TRAVEL * self.min_radius / dt

    # Inputs -----------------------------------------------------------------------------

    def apply_impulse(self, ball, jx, jy):
        """Apply an impulse J (N s) to one ball: v += J / m."""
        mass = self.masses[ball]
        self.velocities[ball, 0] += jx / mass
        self.velocities[ball, 1] += jy / mass

    # Stepping ---------------------------------------------------------------------------

    def _max_speed(self):
        if len(self) == 0:
            return 0.0
        return math.sqrt(float(dot_rows(self.velocities, self.velocities).max()))

    def _plan(self, speed, duration):
        """Substeps needed so that no ball travels more than MAX_TRAVEL * min radius."""
        if speed == 0.0 or self.min_radius == 0.0:
            return 1
        return max(1, math.ceil(speed * duration / (MAX_TRAVEL * self.min_radius)))

    def step(self, dt):
        """Advance the world by dt seconds; return what happened as StepStats."""
        if len(self) == 0:
            return StepStats(substeps=1)
        if self.backend == 'numba':
            return StepStats(*self._kernels.step(self, dt, MAX_TRAVEL))
        totals = [0, 0, 0, 0, 0]
        speed = self._max_speed()
        count = self._plan(speed, dt)
        h = dt / count
        done = 0
        while done < count:
            new_speed = self._substep(h, speed, totals)
            done += 1
            if new_speed > speed:
                speed = new_speed
                if done < count and self._plan(speed, h) > 1:
                    # A collision sped a ball up: split what is left of the step again.
                    rest = (count - done) * h
                    count = self._plan(speed, rest)
                    h = rest / count
                    done = 0
        return StepStats(*totals)

    def _substep(self, h, speed, totals):
        """Move every ball for h seconds, then resolve every touching, approaching contact.

        Returns the largest speed of a ball that collided (0 when none did).
        """
        x = self.positions
        v = self.velocities
        x += v * h
        totals[2] += 1
        lists = self.neighbours
        lists.update(x, self.radii, self.walls, speed * h)

        pair_a, pair_b, pair_rel = self._touching_pairs(lists)
        wall_ball, wall_offset, wall_dir, wall_interior = self._touching_walls(lists)
        if len(pair_a) == 0 and len(wall_ball) == 0:
            return 0.0

        fastest = 0.0
        for _ in range(MAX_ROUNDS):
            approaching_pairs = dot_rows(
                pair_rel, take_rows(v, pair_a) - take_rows(v, pair_b)) < 0.0
            approaching_walls = dot_rows(wall_offset, take_rows(v, wall_ball)) < 0.0
            pairs = np.flatnonzero(approaching_pairs)
            walls = np.flatnonzero(approaching_walls)
            if len(pairs) == 0 and len(walls) == 0:
                break
            totals[3] += 1
            pairs, walls = self._conflict_free(pair_a, pair_b, wall_ball, pairs, walls)
            if len(pairs):
                self._collide_pairs(pair_a[pairs], pair_b[pairs], pair_rel[pairs])
                totals[0] += len(pairs)
            if len(walls):
                self._collide_walls(
                    wall_ball[walls], wall_offset[walls], wall_dir[walls], wall_interior[walls])
                totals[1] += len(walls)
            moved = take_rows(v, np.concatenate((pair_a[pairs], pair_b[pairs], wall_ball[walls])))
            fastest = max(fastest, math.sqrt(float(dot_rows(moved, moved).max())))
        else:
            totals[4] += len(pairs) + len(walls)
        return fastest

    def _touching_pairs(self, lists):
        """Candidate pairs that touch: |r_a - r_b| < R_a + R_b. Returns a, b, r_a - r_b."""
        a = lists.ball_a
        b = lists.ball_b
        rel = take_rows(self.positions, a) - take_rows(self.positions, b)
        touching = np.flatnonzero(dot_rows(rel, rel) < lists.reach2)
        return np.take(a, touching), np.take(b, touching), take_rows(rel, touching)

    def _touching_walls(self, lists):
        """Candidate ball-wall pairs that touch: |s| < R, with s the offset from the wall."""
        balls = lists.wall_ball
        offsets, interior = segment_offsets(
            take_rows(self.positions, balls), lists.wall_starts, lists.wall_directions,
            lists.wall_lengths, lists.wall_ends)
        touching = np.flatnonzero(dot_rows(offsets, offsets) < lists.wall_radius2)
        return (np.take(balls, touching), take_rows(offsets, touching),
                take_rows(lists.wall_directions, touching), np.take(interior, touching))

    def _conflict_free(self, pair_a, pair_b, wall_ball, pairs, walls):
        """Keep the contacts whose balls take part in no lower-numbered approaching contact.

        Ball-ball contacts are numbered before ball-wall contacts, each in list order. The
        lowest-numbered contact is always kept, so every round makes progress.
        """
        best = self._scratch_best
        big = np.iinfo(np.intp).max
        n_pairs = len(pairs)
        ids_pairs = np.arange(n_pairs)
        ids_walls = np.arange(n_pairs, n_pairs + len(walls))
        a = pair_a[pairs]
        b = pair_b[pairs]
        c = wall_ball[walls]
        touched = np.concatenate((a, b, c))
        best[touched] = big
        np.minimum.at(best, a, ids_pairs)
        np.minimum.at(best, b, ids_pairs)
        np.minimum.at(best, c, ids_walls)
        keep_pairs = (best[a] == ids_pairs) & (best[b] == ids_pairs)
        keep_walls = best[c] == ids_walls
        return pairs[keep_pairs], walls[keep_walls]

    def _collide_pairs(self, a, b, rel):
        """The seed's ball-ball response, for pairs that share no ball."""
        v = self.velocities
        m_a = np.take(self.masses, a)
        m_b = np.take(self.masses, b)
        v_a = take_rows(v, a)
        v_b = take_rows(v, b)
        dist2 = dot_rows(rel, rel)
        # v_a' = v_a - 2 m_b/(m_a+m_b) ((v_a-v_b).(r_a-r_b)) / |r_a-r_b|^2 (r_a-r_b)
        k_a = 2.0 * m_b / (m_a + m_b) * dot_rows(v_a - v_b, rel) / dist2
        # v_b' = v_b - 2 m_a/(m_a+m_b) ((v_b-v_a).(r_b-r_a)) / |r_b-r_a|^2 (r_b-r_a)
        k_b = 2.0 * m_a / (m_a + m_b) * dot_rows(v_b - v_a, -rel) / dist2
        v[a] = v_a - k_a[:, None] * rel
        v[b] = v_b - k_b[:, None] * -rel

    def _collide_walls(self, balls, offsets, directions, interior):
        """The seed's ball-wall response; about the end-point normal beyond a segment end."""
        v = self.velocities
        vb = take_rows(v, balls)
        # Inside the segment: v' = 2 (v.w) w - v.
        along = dot_rows(vb, directions)
        reflected = 2.0 * along[:, None] * directions - vb
        # Beyond an end point: reflect about n = s / |s|: v' = v - 2 (v.n) n.
        ends = ~interior
        if ends.any():
            s = offsets[ends]
            n = s / np.sqrt(dot_rows(s, s))[:, None]
            vn = dot_rows(vb[ends], n)
            reflected[ends] = vb[ends] - 2.0 * vn[:, None] * n
        v[balls] = reflected
