"""Where an episode starts: the robots' starts, headings and goals, and the random balls.

Everything is drawn from the episode's generator (the one `reset(seed=...)` seeds), in a
fixed order, so a seed gives one layout on every machine with the same numpy:

1. the episode's noise seed (the lidar's, as a ball_world run's `random.seed`);
2. for each robot in turn: its start, clear of the map's cells, the walls, the file's fixed
   balls and the robots before it by CLEARANCE; its heading, uniform in [-pi, pi); its goal,
   clear of cells and walls by the robot's radius and CLEARANCE, and at least
   MIN_GOAL_DISTANCE from its start;
3. each random ball in turn: its position, clear of everything placed before it by
   CLEARANCE (a map's cells by its radius alone, as the scenario places them); then its
   velocity, of uniform direction and a speed uniform in [0, random.speed].

Points are drawn as the scenario draws random balls: a free cell uniformly (a map), then a
point uniformly inside it, or uniformly in the arena box.
"""
import math

import numpy as np

from ball_world.core.scenario import clear_of_walls

#: Gap between things placed at the start of an episode, m: nothing starts touching.
CLEARANCE = 0.05
#: A goal lies at least this far from its robot's start, m.
MIN_GOAL_DISTANCE = 1.0
#: Draws per thing placed before the layout is refused as too full.
TRIES = 10_000


class LayoutError(ValueError):
    """The world has no room for what an episode places (one line)."""


class EpisodeLayout:
    """Draws episodes' layouts in one world (an envs.world_file.EnvWorld's scene)."""

    def __init__(self, scene, arena, fixed, random_radii, random_speed, robot_radius):
        self.cells = scene.cells
        self.walls = scene.world.walls.segments
        self.arena = list(arena) if arena else None
        self.free = self.cells.free(self.arena) if self.cells is not None else None
        if self.free is not None and not len(self.free):
            raise LayoutError('the map has no free cell to place robots and goals in')
        self.fixed = fixed  # (positions, velocities, radii, masses)
        self.random_radii = random_radii
        self.random_speed = random_speed
        self.robot_radius = robot_radius

    def bounds(self):
        """(xmin, ymin, xmax, ymax) of where robots can be: the free cells (inside the
        arena), or the arena."""
        if self.cells is not None:
            return self.cells.free_bounds(self.arena)
        return tuple(self.arena)

    def _point(self, rng, radius):
        """A point drawn uniformly over the free cells, or the arena box less `radius`."""
        if self.free is not None:
            cells = self.cells.cells
            row, column = divmod(int(self.free[rng.integers(len(self.free))]), cells.columns)
            return (cells.origin_x + (column + rng.random()) * cells.resolution,
                    cells.origin_y + (row + rng.random()) * cells.resolution)
        xmin, ymin, xmax, ymax = self.arena
        return (rng.uniform(xmin + radius, max(xmin + radius, xmax - radius)),
                rng.uniform(ymin + radius, max(ymin + radius, ymax - radius)))

    def _static_clear(self, x, y, radius):
        """No overlap with the arena's outside, the map's cells or the walls."""
        if self.arena is not None:
            xmin, ymin, xmax, ymax = self.arena
            if not (xmin + radius <= x <= xmax - radius and ymin + radius <= y <= ymax - radius):
                return False
        if self.cells is not None and self.cells.first_overlap(x, y, radius) is not None:
            return False
        return not len(self.walls) or clear_of_walls(x, y, radius, self.walls)

    @staticmethod
    def _discs_clear(x, y, radius, discs, count):
        """No overlap (with CLEARANCE) with the first `count` rows of discs (x, y, r)."""
        if not count:
            return True
        placed = discs[:count]
        reach = placed[:, 2] + radius + CLEARANCE
        dx = placed[:, 0] - x
        dy = placed[:, 1] - y
        return bool(np.all(dx * dx + dy * dy >= reach * reach))

    def _place(self, rng, radius, static_radius, discs, count, what):
        for _ in range(TRIES):
            x, y = self._point(rng, radius)
            if self._static_clear(x, y, static_radius) and self._discs_clear(x, y, radius, discs,
                                                                             count):
                return x, y
        raise LayoutError(f'could not place {what} in {TRIES:,} tries: the world is too full '
                          'for the episode (fewer robots or balls, or a larger world)')

    def _goal(self, rng, start):
        radius = self.robot_radius
        for _ in range(TRIES):
            x, y = self._point(rng, radius)
            if (math.hypot(x - start[0], y - start[1]) >= MIN_GOAL_DISTANCE
                    and self._static_clear(x, y, radius + CLEARANCE)):
                return x, y
        raise LayoutError(f'could not place a goal {MIN_GOAL_DISTANCE:g} m from a robot in '
                          f'{TRIES:,} tries: the world is too small for the episode')

    def draw(self, rng, robots):
        """One episode's layout: (noise seed, robot starts (R, 2), headings (R,), goals
        (R, 2), ball positions (B, 2), ball velocities (B, 2)), balls being the file's
        fixed ones then the random ones (their radii and masses are the world's)."""
        noise_seed = int(rng.integers(2 ** 31))
        fixed_positions, fixed_velocities, fixed_radii, _ = self.fixed
        total = robots + len(fixed_radii) + len(self.random_radii)
        discs = np.empty((total, 3))
        count = len(fixed_radii)
        discs[:count, 0:2] = fixed_positions
        discs[:count, 2] = fixed_radii
        starts = np.empty((robots, 2))
        yaws = np.empty(robots)
        goals = np.empty((robots, 2))
        radius = self.robot_radius
        for robot in range(robots):
            starts[robot] = self._place(rng, radius, radius + CLEARANCE, discs, count,
                                        f'robot {robot}')
            discs[count] = (*starts[robot], radius)
            count += 1
            yaws[robot] = rng.uniform(-math.pi, math.pi)
            goals[robot] = self._goal(rng, starts[robot])
        balls = len(self.random_radii)
        positions = np.empty((balls, 2))
        velocities = np.empty((balls, 2))
        for ball, r in enumerate(self.random_radii.tolist()):
            positions[ball] = self._place(rng, r, r, discs, count, f'random ball {ball}')
            discs[count] = (*positions[ball], r)
            count += 1
            heading = rng.uniform(0.0, 2.0 * math.pi)
            speed = rng.uniform(0.0, self.random_speed)
            velocities[ball] = speed * math.cos(heading), speed * math.sin(heading)
        return (noise_seed, starts, yaws, goals,
                np.concatenate((fixed_positions, positions)),
                np.concatenate((fixed_velocities, velocities)))
