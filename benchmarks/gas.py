"""Gases of equal disks in a square box, the scenes the exact-mode benchmarks measure, and
the kinetic theory their collision rates are held against.

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

    def bulk(self, positions, margin):
        """Which balls are at least `margin` (centre to wall) inside the box."""
        return ((positions > margin) & (positions < self.side - margin)).all(axis=1)

    def world(self, backend='numba'):
        """A fresh World of this gas in its box."""
        walls, _ = arena_walls({'arena': [0.0, 0.0, self.side, self.side]})
        return World(self.positions, self.velocities, np.full(self.n, self.radius),
                     np.ones(self.n), walls=walls, backend=backend)


def henderson_z(eta):
    """Henderson's equation of state of the hard-disk fluid: Z = P / (n kT) at area fraction
    eta."""
    return (1.0 + eta * eta / 8.0) / (1.0 - eta) ** 2


def enskog_collision_rate(n, sigma, kt_over_m):
    """Collisions per disk per second in an equilibrium hard-disk fluid (2D Enskog).

    A disk meets every disk whose centre passes within sigma of its own: relative to it, the
    centres in a strip of width 2 sigma swept at the relative speed g, 2 n sigma |g| per
    second in a dilute gas; in a dense one the density at contact is n g(sigma), the contact
    value of the pair distribution. For 2D Maxwellian velocities the relative velocity is
    Maxwellian with the reduced mass m / 2, so <|g|> = sqrt(pi kT / m):

        omega = 2 n sigma g(sigma) sqrt(pi kT / m).

    g(sigma) comes from the 2D virial equation of state Z = 1 + 2 eta g(sigma), with
    eta = n pi sigma^2 / 4 and Henderson's Z: g(sigma) = (1 - 7 eta / 16) / (1 - eta)^2.
    """
    eta = n * math.pi * sigma * sigma / 4.0
    contact = (henderson_z(eta) - 1.0) / (2.0 * eta)
    return 2.0 * n * sigma * contact * math.sqrt(math.pi * kt_over_m)


class Rates:
    """Collision rates of a gas run, with the ball-ball rate also taken where the gas is bulk.

    Walls change the density within a few diameters of them, so the bulk rate counts, per
    disk, the collisions of disks at least `margin` from every wall at both ends of a step,
    and the bulk density is the mean number of centres in that inner square over its area.
    """

    def __init__(self, gas, margin):
        self.gas = gas
        self.margin = margin
        self.time = 0.0
        self.ball_ball = 0
        self.ball_wall = 0
        self.bulk_collisions = 0
        self.bulk_disk_time = 0.0
        self.bulk_count = 0
        self.samples = 0

    def add(self, dt, before, after, ball_ball, ball_wall, per_ball_step=None):
        """One step of dt: positions before and after, its counts and per-ball collisions."""
        self.time += dt
        self.ball_ball += ball_ball
        self.ball_wall += ball_wall
        inside = self.gas.bulk(after, self.margin)
        self.bulk_count += int(inside.sum())
        self.samples += 1
        if per_ball_step is not None:
            both = inside & self.gas.bulk(before, self.margin)
            self.bulk_collisions += int(per_ball_step[both].sum())
            self.bulk_disk_time += int(both.sum()) * dt

    def collision_rate(self):
        """Ball-ball collisions per disk per second, whole box."""
        return 2.0 * self.ball_ball / self.gas.n / self.time

    def bulk_density(self):
        return self.bulk_count / self.samples / (self.gas.side - 2.0 * self.margin) ** 2

    def bulk_collision_rate(self):
        """Collisions per disk per second in the bulk (needs per-ball counts)."""
        return self.bulk_collisions / self.bulk_disk_time

    def wall_rate(self):
        return self.ball_wall / self.time
