"""What running trackers at arm's length costs (issue 33): the same scenes scored, side by
side and alternating, as before and as now.

    python -m benchmarks.score_workers [--scenes 4] [--duration 5] [--rounds 3]

Each run is a fresh process (imports and numba caches included, as a run of the tool):
`--jobs 1` scored in the process itself (before) against one supervised worker
(user_code.workers.LocalPool, now); `--jobs 2` multiprocessing.Pool (before) against a
LocalPool of 2. Then the deadline every call of user code runs under (faulthandler's
watchdog armed and disarmed). Prints the best of each, their ratio, the machine and the load.
"""
import argparse
import faulthandler
import os
import platform
import subprocess
import sys
import tempfile
import time


def _scenes(count, duration):
    from ball_world.tools import score_bench
    scenes = score_bench.seed_scenes(range(count), duration)
    return [(i, scene, None, 0.5) for i, scene in enumerate(scenes)], \
        [scene.label for scene in scenes]


def run(way, jobs, count, duration):
    """Score the scenes one way (in a fresh process: `python -m benchmarks.score_workers
    --run WAY JOBS`)."""
    from ball_world.tools import score_bench
    from ball_world.user_code.workers import LocalPool
    work, labels = _scenes(count, duration)
    if way == 'before' and jobs == 1:
        return [score_bench.run_scene(job) for job in work]
    if way == 'before':
        import multiprocessing
        with multiprocessing.get_context('spawn').Pool(jobs) as pool:
            return list(pool.imap_unordered(score_bench.run_scene, work))
    with LocalPool(jobs, 60.0, 'the deadline') as pool:
        return [result for _, result in pool.map_unordered(score_bench.run_scene, work,
                                                           labels)]


def deadline_cost(calls=5000):
    """Seconds one arm and disarm of the per-call deadline takes."""
    with tempfile.TemporaryFile('w') as notes:
        began = time.perf_counter()
        for _ in range(calls):
            faulthandler.dump_traceback_later(60.0, exit=True, file=notes)
            faulthandler.cancel_dump_traceback_later()
        return (time.perf_counter() - began) / calls


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scenes', type=int, default=4)
    parser.add_argument('--duration', type=float, default=5.0)
    parser.add_argument('--rounds', type=int, default=3)
    parser.add_argument('--run', nargs=2, metavar=('WAY', 'JOBS'), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.run:
        run(args.run[0], int(args.run[1]), args.scenes, args.duration)
        return 0
    times = {}
    for _ in range(args.rounds):
        for jobs in (1, 2):
            for way in ('before', 'now'):
                began = time.perf_counter()
                subprocess.run([sys.executable, '-m', 'benchmarks.score_workers', '--scenes',
                                str(args.scenes), '--duration', str(args.duration), '--run',
                                way, str(jobs)], check=True)
                times.setdefault((way, jobs), []).append(time.perf_counter() - began)
    print(f'{platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
          f'{time.strftime("%Y-%m-%d")}, load {os.getloadavg()[0]:.1f}; {args.scenes} scenes '
          f'of {args.duration:g} s, best of {args.rounds}')
    for jobs in (1, 2):
        before, now = min(times[('before', jobs)]), min(times[('now', jobs)])
        print(f'--jobs {jobs}: before {before:.2f} s, now {now:.2f} s, now / before '
              f'{now / before:.2f}')
    print(f'deadline per call: {deadline_cost() * 1e6:.0f} us')
    return 0


if __name__ == '__main__':
    sys.exit(main())
