"""Gases of equal disks in a square box, the scenes the exact-mode benchmarks measure.

A jittered square lattice (each ball inside its own lattice cell, so none overlap or touch a
wall) with all speeds equal and directions uniform: the same start the issue's bench scene
uses, at any area fraction up to about 0.6.
"""
import math

import numpy as np

from ball_world.core.scenario import arena_walls
from ball_world.core.world import World


class Gas:
    """n disks of `radius` at `area_fraction` of a square box, all at `speed`."""

    def __init__(self, n, area_fraction, speed, radius=0.5, seed=1):
        self.n = n
        self.radius = radius
        self.speed = speed
        self.side = radius * math.sqrt(n * math.pi / area_fraction)
        per_row = max(1, math.ceil(math.sqrt(n)))
        spacing = self.side / per_row
        if spacing <= 2.0 * radius:
            raise ValueError(f'area fraction {area_fraction} is too dense for a lattice start')
        rng = np.random.default_rng(seed)
        cells = rng.choice(per_row * per_row, size=n, replace=False)
        centres = (np.stack((cells // per_row, cells % per_row), axis=1) + 0.5) * spacing
        free = spacing / 2.0 - radius * (1.0 + 1e-6)
        self.positions = centres + rng.uniform(-free, free, size=(n, 2))
        heading = rng.uniform(0.0, 2.0 * math.pi, size=n)
        self.velocities = speed * np.stack((np.cos(heading), np.sin(heading)), axis=1)

    def world(self, backend='numba'):
        """A fresh World of this gas in its box."""
        walls, _ = arena_walls({'arena': [0.0, 0.0, self.side, self.side]})
        return World(self.positions, self.velocities, np.full(self.n, self.radius),
                     np.ones(self.n), walls=walls, backend=backend)
