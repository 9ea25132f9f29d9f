"""The benchmark's scenes and its own engine, shared by bench.py and its sections.

Why a module of its own: bench.py reports what its sections (agents, exact_speed,
lidar_speed) measure, and the sections build their worlds from the same scenes; each
importing the other was an import circle. Now bench.py and every section import this,
and nothing here imports them.

The issue's scene: equal balls of radius 0.5 m at a 20% area fraction, all at 24 m/s, dt 1/240
s, elastic, no gravity; and the two worst cases inside core.limits.
"""
import math

import numpy as np

from ball_world.core import limits
from ball_world.core.broadphase import grid_pairs, wall_pairs
from ball_world.core.scenario import arena_walls
from ball_world.core.world import Walls, World

RADIUS = 0.5
AREA_FRACTION = 0.2
SPEED = 24.0
DT = 1.0 / 240.0
MASS = 1.0
FRAME_ID = 'world'


class Scene:
    """The issue's start state: N balls on a jittered lattice in a square box, all at SPEED."""

    def __init__(self, n, seed=1):
        self.n = n
        self.side = box_side(n)
        per_row = max(1, math.ceil(math.sqrt(n)))
        spacing = self.side / per_row
        rng = np.random.default_rng(seed)
        cells = rng.choice(per_row * per_row, size=n, replace=False)
        centres = (np.stack((cells // per_row, cells % per_row), axis=1) + 0.5) * spacing
        # Each ball stays inside its own lattice cell, so no two overlap and none leaves the
        # box; the spacing is at least 2.8 r for any N, leaving room to jitter.
        free = max(0.0, spacing / 2.0 - RADIUS * (1.0 + 1e-6))
        self.positions = centres + rng.uniform(-free, free, size=(n, 2))
        heading = rng.uniform(0.0, 2.0 * math.pi, size=n)
        self.velocities = SPEED * np.stack((np.cos(heading), np.sin(heading)), axis=1)


def box_side(n):
    """Side of the square box that N balls fill to AREA_FRACTION."""
    return RADIUS * math.sqrt(n * math.pi / AREA_FRACTION)


def escaped(positions, side):
    """Balls whose centre is outside the box."""
    return int(np.count_nonzero(((positions < 0.0) | (positions > side)).any(axis=1)))


# The engine ----------------------------------------------------------------------------------

class OurEngine:
    """ball_world's World, exactly as the node steps it (pure numpy, or the numba kernels)."""

    def __init__(self, scene, backend):
        walls, _ = arena_walls({'arena': [0.0, 0.0, scene.side, scene.side]})
        self.side = scene.side
        self.world = World(scene.positions, scene.velocities, np.full(scene.n, RADIUS),
                           np.full(scene.n, MASS), walls=walls, backend=backend)

    def run(self, steps):
        step = self.world.step
        for _ in range(steps):
            step(DT)

    def kinetic_energy(self):
        return self.world.kinetic_energy()

    def escaped(self):
        return escaped(self.world.positions, self.side)


# Worst cases inside the limits -------------------------------------------------------

def box(side):
    return [[0.0, 0.0, side, 0.0], [side, 0.0, side, side], [side, side, 0.0, side],
            [0.0, side, 0.0, 0.0]]


def radius_spread_world(n, rng):
    """n balls whose radii differ by MAX_RADIUS_RATIO: 1% of 1 m, the rest of 1 cm.

    The large balls sit on a jittered lattice filling 20% of the box; the small ones on a
    finer lattice between them (those touching a large ball are left out). All at 1 m/s.
    """
    large_count = max(1, n // 100)
    small_radius = 1.0 / limits.MAX_RADIUS_RATIO
    per_row = math.ceil(math.sqrt(large_count))
    spacing = math.sqrt(math.pi / AREA_FRACTION)
    side = per_row * spacing
    lattice = np.stack(np.divmod(np.arange(large_count), per_row), axis=1)
    large = (lattice + 0.5) * spacing + rng.uniform(-0.3, 0.3, (large_count, 2))
    columns = math.ceil(math.sqrt((n - large_count) * 1.5))
    fine = np.stack(np.divmod(np.arange(columns * columns), columns), axis=1)
    small = (fine + 0.5) * (side / columns)
    positions = np.concatenate((large, small))
    radii = np.concatenate((np.ones(large_count), np.full(len(small), small_radius)))
    a, b, _ = grid_pairs(positions, radii, 0.0)
    keep = np.setdiff1d(np.arange(len(positions)), b[a < large_count])[:n]
    heading = rng.uniform(0.0, 2.0 * math.pi, len(keep))
    return (positions[keep], np.stack((np.cos(heading), np.sin(heading)), axis=1),
            radii[keep], np.ones(len(keep)), box(side))


def many_walls_world(n, rng):
    """The benchmark scene of n balls plus MAX_WALLS - 4 random segments 0.3-6% of the box
    side long (2-40 m at 100,000 balls); balls the segments touch are left out."""
    scene = Scene(n, 1)
    count = limits.MAX_WALLS - 4
    starts = rng.uniform(0.0, scene.side, (count, 2))
    heading = rng.uniform(0.0, 2.0 * math.pi, count)
    length = rng.uniform(0.003, 0.064, count)[:, None] * scene.side
    ends = np.clip(starts + np.stack((np.cos(heading), np.sin(heading)), axis=1) * length,
                   0.0, scene.side)
    walls = np.concatenate((box(scene.side), np.concatenate((starts, ends), axis=1)))
    radii = np.full(n, RADIUS)
    touched, _ = wall_pairs(scene.positions, radii, Walls(walls), 0.0)
    keep = np.setdiff1d(np.arange(n), touched)
    return scene.positions[keep], scene.velocities[keep], radii[keep], np.ones(len(keep)), walls
