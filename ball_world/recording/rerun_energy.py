"""Where the kinetic energy plot's changes come from: the robots' drives, and the rest.

Collisions keep kinetic energy (to rounding, in both physics modes), so in a world without
robots the energy plot is a flat line unless something pushes. A robot's drive (its
cmd_vel turned into an impulse every step it accelerates or brakes, core.agents) puts
energy in and takes it out: with robots the total swings by tens of percent, and a plot of
the total alone looked like a broken simulator. So a view of a world with agents plots the
total beside what the drives did and what the rest did (pushes, edits; collisions 0).

The work of an impulse J on a ball of mass m moving at v is m/2 (|v + J/m|^2 - |v|^2):
the impulses of a step are applied, in the record's order, to the velocities of the
record before it (nothing changes velocities between two steps but impulses and edits).
A step with edits (a ball spawned, deleted or set) is all the rest's: its indices and
velocities are not the previous record's.
"""
import numpy as np


class EnergyAccount:
    """Energy put in since step 0 of a segment: (by the drives, by the rest), J."""

    def __init__(self):
        self.clear()

    def clear(self):
        self.drives = 0.0
        self.rest = 0.0
        self._velocities = None
        self._energy = None

    def add(self, record, masses):
        """Take a record (in order; step 0 starts the count) with the balls' masses in pose
        order; returns (drives, rest) since step 0."""
        energy = float(record.kinetic_energy)
        if self._energy is None or record.step == 0:
            self.drives = self.rest = 0.0
        else:
            driven = 0.0
            if not record.edits and record.impulses:
                velocities = self._velocities
                changed = {}
                for impulse in record.impulses:
                    if not getattr(impulse, 'drive', False):
                        continue
                    ball = impulse.ball
                    mass = float(masses[ball])
                    vx, vy = changed.get(ball, velocities[ball])
                    nx, ny = vx + impulse.jx / mass, vy + impulse.jy / mass
                    driven += 0.5 * mass * ((nx * nx + ny * ny) - (vx * vx + vy * vy))
                    changed[ball] = (nx, ny)
            self.drives += driven
            self.rest += (energy - self._energy) - driven
        self._velocities = np.asarray(record.velocities, dtype=np.float64)
        self._energy = energy
        return self.drives, self.rest
