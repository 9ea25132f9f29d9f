"""The cost of one lidar scan beside one physics step, on the benchmark's scene (issue 22).

Why beside a step: a scanner rides on an agent inside a world the node steps at its rate,
so what matters is what a scan adds to a step, at every N. Both are timed in the same
process and in alternating rounds (so a busy core slows both alike), and reported with
their ratio. Times are the thread's CPU time (time.thread_time; the step and the scan
each run on one thread): on the shared machine a round's wall time also held the time the
thread waited for a core, which made tens-of-microsecond scans read 2-10x slower at random.
The scanner is the ball nearest the box's centre, with the issue's defaults: 360 beams over
a full turn, range 0.1-12 m, no noise (noise is one draw per beam).

`python -m benchmarks.lidar_speed` prints the table; `make bench` includes it.
"""
import argparse
import statistics
import sys
import time

from benchmarks.scenes import DT, OurEngine, Scene
import numpy as np

from ball_world.core import lidar
from ball_world.core.stepping import AUTO, resolve_backend

HEADER = ('| N | balls within range | physics step, ms | scan (numba), ms | scan (numpy), ms | '
          'scan / step (numba) |\n|---:|---:|---:|---:|---:|---:|')
NOTE = ('The scanner is the ball nearest the box centre (360 beams over a full turn, 0.1-12 m, '
        'no noise); the physics step is the default backend seed-mode step of the scene '
        'above (dt 1/240 s). Both timed in CPU time of the thread, in alternating rounds of '
        '5 calls in one process (the numpy reference in rounds of its own after them); the '
        'ratio is what one scan adds to one step. A node scans at '
        'agent.scan.rate_hz (10 Hz) of simulated time, so per step it adds ratio x 10 Hz / '
        '(steps per simulated second).')
FAN = lidar.Fan.full_turn(360, range_min=0.1, range_max=12.0)


def _median_seconds(call, repeats, inner):
    """Median over `repeats` rounds of the mean CPU time (this thread's) of `inner` calls."""
    samples = []
    for _ in range(repeats):
        began = time.thread_time()
        for _ in range(inner):
            call()
        samples.append((time.thread_time() - began) / inner)
    return statistics.median(samples)


def measure(n, repeats, seed=1, warmup_steps=20):
    """(balls within range, step s, numba scan s or None, numpy scan s) at N balls."""
    scene = Scene(n, seed)
    engine = OurEngine(scene, resolve_backend(AUTO))
    world = engine.world
    engine.run(warmup_steps)
    centre = np.array([scene.side / 2.0, scene.side / 2.0])
    offset = world.positions - centre
    scanner = int(np.argmin(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1]))

    scanners = {backend: lidar.Scanner(FAN, backend) for backend in ('numba', 'numpy')
                if backend == 'numpy' or lidar.lidar_kernel.available()}

    def scan(backend):
        return scanners[backend].scan(world.positions, world.radii, world.walls,
                                      world.positions[scanner], 0.0, scanner)

    gap = np.abs(world.positions - world.positions[scanner]).max(axis=1) - world.radii
    within = int(np.count_nonzero(gap <= FAN.range_max)) - 1
    backends = list(scanners)
    for backend in backends:
        scan(backend)  # compiled or loaded before timing
    times = {backend: [] for backend in backends + ['step']}
    # The step and the compiled scan alternate (a scan follows a step, as in the node, and a
    # busy core slows both alike); the numpy reference, which no node runs, is timed after
    # them: its megabytes of temporaries evict the caches and doubled the time of the
    # compiled scan that came after it.
    for _ in range(repeats):
        times['step'].append(_median_seconds(lambda: world.step(DT), 1, 5))
        if 'numba' in scanners:
            times['numba'].append(_median_seconds(lambda: scan('numba'), 1, 5))
    times['numpy'] = [_median_seconds(lambda: scan('numpy'), 1, 5) for _ in range(repeats)]
    medians = {key: statistics.median(values) for key, values in times.items()}
    return within, medians['step'], medians.get('numba'), medians['numpy']


def rows(ns, repeats, seed=1):
    """Markdown table rows, one per N."""
    lines = []
    for n in ns:
        within, step, numba_scan, numpy_scan = measure(n, repeats, seed)
        numba_ms = f'{1e3 * numba_scan:.3f}' if numba_scan is not None else '-'
        ratio = f'{numba_scan / step:.3f}' if numba_scan is not None else '-'
        lines.append(f'| {n:,} | {within:,} | {1e3 * step:.2f} | {numba_ms} | '
                     f'{1e3 * numpy_scan:.2f} | {ratio} |')
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.lidar_speed',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('--n', type=int, nargs='+', default=[1000, 10000, 100000])
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args(argv)
    print(HEADER)
    for line in rows(args.n, args.repeats):
        print(line, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
