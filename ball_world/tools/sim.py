"""Run the default world without ROS: the core alone, for a quick look and for profiling."""
import argparse
import sys
import time

from ball_world.core.scenario import (build_world, DEFAULTS, describe, ScenarioError,
                                      step_duration_ns)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--steps', type=int, default=600, help='steps to run (default 600)')
    args = parser.parse_args(argv)
    try:
        world = build_world(DEFAULTS)
        dt_ns = step_duration_ns(DEFAULTS)
    except ScenarioError as error:
        print(f'ball_world: {error}', file=sys.stderr)
        return 2
    print(describe(world, dt_ns))
    energy = world.kinetic_energy()
    collisions = 0
    start = time.perf_counter()
    for _ in range(args.steps):
        stats = world.step(dt_ns * 1e-9)
        collisions += stats.ball_ball + stats.ball_wall
    elapsed = time.perf_counter() - start
    drift = (world.kinetic_energy() - energy) / energy if energy else 0.0
    print(f'{args.steps} steps in {elapsed:.3f} s ({args.steps / elapsed:.0f} steps/s), '
          f'{collisions} collisions, relative energy drift {drift:.2e}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
