"""python -m benchmarks.ring_scan: a swarm's short-range ring, all agents in one call.

Issue 35's scanner for swarms: N robots (every ball a robot, radius 0.1-0.2 m, a tenth of
the floor covered) in a box with a few walls inside, each with a 16-beam ring of 2 m. Timed
side by side in one run: every robot's scan as one compiled call (core.lidar.scan_many:
the balls sorted into cells, each ring tests only the balls around it) against one
Scanner.distances per robot (what AgentScans.take did before), which tests every ball for
every robot. Both give the same ranges bit for bit (checked here too). CPU time of this
thread (time.thread_time), the median of `--repeat` rounds; the load average goes in the
report. Never a timed assertion.
"""
import argparse
import math
import statistics
import time

import numpy as np

from ball_world.core import lidar

FAN = lidar.Fan.full_turn(16, 0.0, 2.0)


def world(count, seed=1):
    rng = np.random.default_rng(seed)
    side = math.sqrt(count * math.pi * 0.15 ** 2 / 0.1)
    positions = rng.uniform(0.0, side, (count, 2))
    radii = rng.uniform(0.1, 0.2, count)
    walls = np.array([[0.0, 0.0, side, 0.0], [side, 0.0, side, side], [side, side, 0.0, side],
                      [0.0, side, 0.0, 0.0], [0.3 * side, 0.2 * side, 0.3 * side, 0.8 * side],
                      [0.6 * side, 0.5 * side, 0.9 * side, 0.5 * side]])
    yaws = rng.uniform(-math.pi, math.pi, count)
    return positions, radii, walls, yaws


def batched(positions, radii, walls, yaws):
    agents = np.arange(len(positions))
    return lidar.scan_many(positions, radii, walls, agents, yaws, FAN, radii + 0.05, 'numba')


def one_by_one(positions, radii, walls, yaws):
    scanners = {}
    out = np.empty((len(positions), FAN.samples))
    for ball, (yaw, radius) in enumerate(zip(yaws.tolist(), radii.tolist())):
        scanner = scanners.get(radius)
        if scanner is None:
            scanner = scanners[radius] = lidar.Scanner(FAN._replace(range_min=radius + 0.05),
                                                       'numba')
        out[ball] = scanner.distances(positions, radii, walls, positions[ball], yaw, ball)
    return out


def timed(function, args, repeat):
    took = []
    for _ in range(repeat):
        began = time.thread_time()
        result = function(*args)
        took.append(time.thread_time() - began)
    return statistics.median(took), result


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.ring_scan', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--robots', type=int, nargs='+', default=[1_000, 10_000])
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args(argv)
    lidar.warm()
    batched(*world(10))  # compiled before timing
    print(f'16-beam 2 m rings, load average {" ".join(open("/proc/loadavg").read().split()[:3])}')
    print('| robots | one call, ms | per robot, us | one scanner per robot, ms | per robot, us '
          '| ratio |')
    print('|---:|---:|---:|---:|---:|---:|')
    for count in args.robots:
        scene = world(count)
        fast, a = timed(batched, scene, args.repeat)
        slow, b = timed(one_by_one, scene, max(1, args.repeat // 2))
        assert a.tobytes() == b.tobytes(), 'the batch must be the single scans, bit for bit'
        print(f'| {count:,} | {1e3 * fast:.1f} | {1e6 * fast / count:.2f} | {1e3 * slow:.1f} | '
              f'{1e6 * slow / count:.2f} | {slow / fast:.1f} |', flush=True)


if __name__ == '__main__':
    main()
