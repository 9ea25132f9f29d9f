"""How far each physics mode is from the true motion of hard disks, on scenes with closed forms.

Prints Markdown tables (the README's "Two modes" section quotes them):

- one ball in a 10 m box for 10 s (dt 1/60 s): distance from the unfolded-reflection path;
- a striker hitting a resting ball of equal mass at impact parameter b: error of the target's
  outgoing angle against asin(b / sigma), over 32 contact times spread through a step;
- grazes in seed mode at the substep limit: the share of contact phases a graze of a given
  depth goes unseen, with one ball moving and with both;
- a gas of 400 disks at area fractions 0.1, 0.3, 0.5: collision rate of each mode against
  exact mode on the same start, and exact mode's bulk rate against Enskog's theory.

Run: python -m benchmarks.accuracy [--quick]. Seed mode runs with both backends.
"""
import argparse
import math
import sys

from benchmarks.gas import enskog_collision_rate, Gas, Rates
import numpy as np

from ball_world.core import exact
from ball_world.core.scenario import arena_walls
from ball_world.core.world import MAX_TRAVEL, numba_installed, World

MODES = ('seed (numpy)', 'seed (numba)', 'exact')


def _seed_step(backend):
    def step(world, dt, per_ball=None):
        stats = world.step(dt)
        return stats.ball_ball, stats.ball_wall
    step.backend = backend
    return step


def _exact_step(world, dt, per_ball=None):
    ball_ball, ball_wall, _ = exact.step(world, dt, per_ball)
    return ball_ball, ball_wall


_exact_step.backend = 'numba'
STEPPERS = dict(zip(MODES, (_seed_step('numpy'), _seed_step('numba'), _exact_step)))


def _world(stepper, positions, velocities, radii, masses, walls=()):
    return World(positions, velocities, radii, masses, walls=walls, backend=stepper.backend)


def _folded(start, velocity, t, low, high):
    span = high - low
    unfolded = math.fmod(start - low + velocity * t, 2.0 * span)
    if unfolded < 0.0:
        unfolded += 2.0 * span
    return low + (unfolded if unfolded <= span else 2.0 * span - unfolded)


def _unfolded(position, hits, radius, side):
    """Distance travelled along one axis from the wall at `radius`, after `hits` reflections,
    for a ball that started moving in +axis (inverse of the folding)."""
    span = side - 2.0 * radius
    into = position - radius
    return hits * span + (into if hits % 2 == 0 else span - into)


def box_lag(speeds):
    """Rows: speed, then each mode's lag behind the analytic path after 10 s.

    The lag is measured along the unfolded path (each wall hit taken at the first overlapped
    sample shortens it), so it grows without wrapping around the box; speeds up to 100 m/s
    keep every ball to at most one hit per axis per step, so the hits can be counted.
    """
    side, radius, dt, steps, heading = 10.0, 0.5, 1.0 / 60.0, 600, 0.3
    walls, _ = arena_walls({'arena': [0.0, 0.0, side, side]})
    rows = []
    for speed in speeds:
        v = [speed * math.cos(heading), speed * math.sin(heading)]
        start = [3.0, 4.0]
        exact_travel = [start[axis] - radius + v[axis] * steps * dt for axis in (0, 1)]
        row = [f'{speed:g}']
        for mode in MODES:
            stepper = STEPPERS[mode]
            world = _world(stepper, [start], [v], [radius], [1.0], walls)
            hits = np.zeros(2, dtype=np.int64)
            for _ in range(steps):
                before = np.sign(world.velocities[0])
                stepper(world, dt)
                hits += before != np.sign(world.velocities[0])
            lag = [exact_travel[axis] - _unfolded(world.positions[0, axis], hits[axis], radius,
                                                  side) for axis in (0, 1)]
            row.append(f'{math.hypot(*lag):.2g}')
        rows.append(row)
    return ['speed (m/s)'] + [f'{mode}: lag (m)' for mode in MODES], rows


def deflection(impacts, travels, phases):
    """Rows: b/sigma, v dt/R, then each mode's mean and worst angle error and misses."""
    radius, dt = 0.5, 0.01
    sigma = 2.0 * radius
    rows = []
    for impact in impacts:
        b = impact * sigma
        along = math.sqrt(sigma * sigma - b * b)
        expected = -math.asin(impact)
        for travel in travels:
            u = travel * radius / dt
            row = [f'{impact:g}', f'{travel:g}']
            for mode in MODES:
                stepper = STEPPERS[mode]
                errors = []
                for k in range(phases):
                    t_contact = (k + 0.5) / phases * dt
                    world = _world(stepper, [[-along - u * t_contact, b], [0.0, 0.0]],
                                   [[u, 0.0], [0.0, 0.0]], [radius, radius], [1.0, 1.0])
                    for _ in range(3):
                        stepper(world, dt)
                    vx, vy = world.velocities[1]
                    if vx == 0.0 and vy == 0.0:
                        errors.append(math.nan)
                    else:
                        errors.append(abs(math.atan2(vy, vx) - expected))
                errors = np.degrees(errors)
                seen = errors[~np.isnan(errors)]
                missed = len(errors) - len(seen)
                cell = f'{seen.mean():.2g} / {seen.max():.2g}' if len(seen) else '-'
                row.append(cell + (f' ({missed} missed)' if missed else ''))
            rows.append(row)
    header = ['b / sigma', 'v dt / R'] + [f'{mode}: mean / worst error (deg)' for mode in MODES]
    return header, rows


def grazes(depths, phases):
    """Rows: depth, then the share of phases seed mode misses with one and with both moving.

    Each moving ball travels MAX_TRAVEL radii in the step's single substep (the limit).
    """
    radius = 0.5
    sigma = 2.0 * radius
    dt = 0.01
    u = MAX_TRAVEL * radius / dt * (1.0 - 1e-9)  # exactly one substep
    rows = []
    for depth in depths:
        offset = sigma * (1.0 - depth)
        half_chord = math.sqrt(sigma * sigma - offset * offset)
        row = [f'{100 * depth:g}%']
        for movers in (1, 2):
            closing = movers * u
            # Missed when no substep end falls in the approaching half of the overlap (the
            # half chord): the share of contact phases where the first sample jumps it.
            theory = max(0.0, 1.0 - half_chord / (closing * dt))
            missed = 0
            for k in range(phases):
                # Relative distance along x at the step's start, just outside first touch.
                start = half_chord + (k + 0.5) / phases * closing * dt
                share = 0.5 if movers == 2 else 0.0
                world = World([[-start * (1.0 - share), offset], [start * share, 0.0]],
                              [[closing - (movers - 1) * u, 0.0], [-(movers - 1) * u, 0.0]],
                              [radius, radius], [1.0, 1.0])
                hits = sum(world.step(dt).ball_ball for _ in range(4))
                missed += hits == 0
            row.append(f'{missed}/{phases} ({100 * theory:.0f}%)')
        rows.append(row)
    return ['graze depth (of sigma)', 'seed: missed, one ball moving (theory)',
            'seed: missed, both moving (theory)'], rows


def gas_rates(fractions, travels, collisions_per_disk, n=400):
    """Rows: area fraction, v dt/R, exact's bulk rate vs Enskog, each mode's rate vs exact."""
    radius, speed = 0.5, 1.0
    sigma = 2.0 * radius
    rows = []
    for fraction in fractions:
        omega = enskog_collision_rate(4.0 * fraction / (math.pi * sigma * sigma), sigma,
                                      0.5 * speed * speed)
        for travel in travels:
            dt = travel * radius / speed
            steps = math.ceil(collisions_per_disk / omega / dt)
            warm_up = steps // 5
            gas = Gas(n, fraction, speed, radius, seed=3)
            measured = {}
            for mode in MODES:
                stepper = STEPPERS[mode]
                world = gas.world(stepper.backend)
                rates = Rates(gas, margin=radius + 3.0 * sigma)
                per_ball = np.zeros(n, dtype=np.int64) if mode == 'exact' else None
                for k in range(steps):
                    before = world.positions.copy()
                    counted = None if per_ball is None else per_ball.copy()
                    ball_ball, ball_wall = stepper(world, dt, per_ball)
                    if k >= warm_up:
                        rates.add(dt, before, world.positions, ball_ball, ball_wall,
                                  None if per_ball is None else per_ball - counted)
                measured[mode] = rates
            reference = measured['exact']
            theory = enskog_collision_rate(reference.bulk_density(), sigma,
                                           world.kinetic_energy() / n)
            row = [f'{fraction:g}', f'{travel:g}',
                   f'{100 * (reference.bulk_collision_rate() / theory - 1):+.1f}%']
            for mode in MODES[:-1]:
                ratio = measured[mode].collision_rate() / reference.collision_rate()
                row.append(f'{100 * (ratio - 1):+.1f}%')
            rows.append(row)
    header = ['area fraction', 'v dt / R', 'exact, bulk vs Enskog'] + [
        f'{mode} vs exact (whole box)' for mode in MODES[:-1]]
    return header, rows


def table(header, rows):
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.accuracy', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--quick', action='store_true', help='fewer cases, shorter runs')
    args = parser.parse_args(argv)
    if not numba_installed():
        print('benchmarks.accuracy needs numba (exact mode and the numba backend)')
        return 1
    quick = args.quick
    sections = [
        ('One ball in a 10 m box, 10 s at dt = 1/60 s', box_lag(
            [1.0, 100.0] if quick else [1.0, 10.0, 100.0])),
        ('Deflection of a resting ball (equal masses), error against asin(b / sigma)',
         deflection([0.9] if quick else [0.5, 0.9, 0.99], [0.5] if quick else [0.1, 0.5, 2.0],
                    8 if quick else 32)),
        ('Grazes seed mode misses at the substep limit (each mover 0.5 R per substep)',
         grazes([0.03, 0.033] if quick else [0.005, 0.02, 0.03, 0.033, 0.1, 0.13, 0.135],
                16 if quick else 100)),
        ('Collision rate of a gas of 400 disks', gas_rates(
            [0.5] if quick else [0.1, 0.3, 0.5], [0.5] if quick else [0.1, 0.5],
            20 if quick else 200)),
    ]
    for title, (header, rows) in sections:
        print(f'## {title}\n\n{table(header, rows)}\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
