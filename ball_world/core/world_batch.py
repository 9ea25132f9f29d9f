"""K seed-mode Worlds of the same balls' sizes and static geometry, stepped in one call.

Why: a learner's vectorized environment steps many small worlds (envs.arenas: 64 worlds of
13 balls, 6 physics steps an environment step). A 13-ball map world's compiled step takes
about 1.3 us, but calling it through World.step costs about 7 us: the Python around it and
numba's dispatch of its 25 arguments. One call for all K worlds (numba_backend.worlds_step)
pays that once.

Each world keeps its own World (edits, checks, reads) whose positions and velocities become
rows of the batch's arrays (`bind`); the batch keeps each world's candidate lists as its
World's own stepper would, row by row, and calls the very kernel World.step calls, so every
world steps bit for bit as it would alone (test/test_world_batch.py). While bound, a world
is stepped only through the batch (its own stepper's lists would not follow the moves): bind
it again after any edit.

numba only, seed mode only (`WorldBatch.supports`); callers step the Worlds one by one
otherwise.
"""
import numpy as np

from ball_world.core.stepping import STEP_REFUSED


def supports(world):
    """Whether a World can be stepped by a WorldBatch (seed mode, the numba backend)."""
    return world.mode == 'seed' and world.backend == 'numba'


class WorldBatch:
    """The Worlds `worlds` (equal radii, masses and static geometry) stepped together."""

    def __init__(self, worlds):
        from ball_world.core import numba_backend
        self._kernel = numba_backend.worlds_step
        self._fresh = numba_backend.FRESH
        self._counts = (numba_backend.PAIRS, numba_backend.NEAR_WALLS)
        self.worlds = list(worlds)
        first = self.worlds[0]
        if not all(supports(world) for world in self.worlds):
            raise ValueError('a WorldBatch steps seed-mode worlds of the numba backend only')
        count, balls = len(self.worlds), len(first)
        if balls == 0:
            raise ValueError('a WorldBatch needs worlds with balls')
        self.radii = first.radii.copy()
        self.masses = first.masses.copy()
        self.positions = np.zeros((count, balls, 2))
        self.velocities = np.zeros((count, balls, 2))
        self._shared = None  # what every world's step shares (from its stepper's prepare)
        self._checked = [None] * count  # each world's shared part last found equal to it
        self._pair_rows = np.empty((count, 4 * balls, 2), dtype=np.int64)
        self._wall_rows = np.empty((count, balls, 2), dtype=np.int64)
        self._lists = np.zeros((count, 3), dtype=np.int64)
        self._anchor = np.empty((count, balls, 2))
        self._wall_anchor = np.empty((count, balls, 2))
        self._wall_first = np.zeros((count, balls + 1), dtype=np.int64)
        self._wall_clear = np.zeros((count, balls))
        self._order = np.empty((count, balls), dtype=np.int64)
        self._best = np.empty((count, balls), dtype=np.int64)
        self._totals = np.zeros((count, len(first._totals)), dtype=np.int64)
        self._status = np.zeros(count, dtype=np.int64)
        for index in range(count):
            self.bind(index)

    def bind(self, index):
        """Take world `index` (just made or edited) into the batch: its positions and
        velocities become views of the batch's rows, its candidate lists start anew, as its
        stepper's after an edit."""
        world = self.worlds[index]
        if not (len(world) == len(self.radii) and np.array_equal(world.radii, self.radii)
                and np.array_equal(world.masses, self.masses)):
            raise ValueError(f'world {index} has other balls than the batch: bind worlds '
                             'of the same radii and masses')
        world._stepper.prepare(world)
        shared = self._shared_of(world)
        if self._shared is None:
            self._shared = shared
        elif not _same(shared, self._checked[index]) and not _same(shared, self._shared):
            raise ValueError(f'world {index} has other static geometry (or needs another '
                             'index reach) than the batch')
        # A World keeps its index between edits: comparing it by identity next time spares
        # comparing a large map's index by value at every reset.
        self._checked[index] = shared
        self.positions[index] = world.positions
        self.velocities[index] = world.velocities
        world.positions = self.positions[index]
        world.velocities = self.velocities[index]
        self._lists[index] = 0
        self._wall_first[index] = 0
        self._wall_clear[index] = 0.0
        self._order[index] = np.arange(len(self.radii))
        self._best[index] = -1

    @staticmethod
    def _shared_of(world):
        """(min_mass, travel, walls, wall_scale, index grid, shape, first, items, members,
        level starts, level largest, skin, direct) of a prepared World's stepper."""
        (min_mass, walls, index_grid, index_shape, index_first, index_items, members,
         level_starts, largest, skin, *_, direct, wall_scale) = world._stepper._prepared
        return (min_mass, world._travel, walls, wall_scale, index_grid, index_shape,
                index_first, index_items, members, level_starts, largest, skin, direct)

    def step(self, indices, dt):
        """Step the worlds `indices` (int64 array) by dt seconds each, as World.step would
        (SubstepLimitExceeded's case, a refused step, is a ValueError here: callers bind
        only worlds whose speeds they bound)."""
        (min_mass, travel, walls, wall_scale, index_grid, index_shape, index_first,
         index_items, members, level_starts, largest, skin, direct) = self._shared
        status = self._status
        self._kernel(indices, self.positions, self.velocities, self.radii, self.masses,
                     min_mass, float(dt), travel, walls, wall_scale, index_grid, index_shape,
                     index_first, index_items, members, level_starts, largest, skin, direct,
                     self._pair_rows, self._wall_rows, self._lists, self._anchor,
                     self._wall_anchor, self._wall_first, self._wall_clear, self._order,
                     self._best, self._totals, status)
        stepped = status[indices]
        if (stepped == STEP_REFUSED).any():
            raise ValueError(f'a step of {dt:g} s was refused in world '
                             f'{int(indices[np.argmax(stepped == STEP_REFUSED)])}: its balls '
                             'are faster than the batch can step')
        if not self._lists[indices, self._fresh].all():
            self._grow()

    def _grow(self):
        """Room for lists that outgrew their rows, as NumbaStepper._grow makes it (twice what
        was asked); the other worlds' lists are kept, the outgrown ones rebuild next step."""
        pairs, near_walls = self._counts
        rows = (max(2 * int(self._lists[:, pairs].max()), self._pair_rows.shape[1]),
                max(2 * int(self._lists[:, near_walls].max()), self._wall_rows.shape[1]))
        for name, size in zip(('_pair_rows', '_wall_rows'), rows):
            old = getattr(self, name)
            if size > old.shape[1]:
                grown = np.empty((old.shape[0], size, 2), dtype=np.int64)
                grown[:, :old.shape[1]] = old
                setattr(self, name, grown)


def _same(first, second):
    """Whether two _shared_of tuples are equal, arrays by identity or else by value (False
    when `second` is None)."""
    if second is None:
        return False
    return all(a is b or (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b)
               for a, b in zip(first, second))
