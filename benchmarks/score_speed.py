"""How fast ball_world_score is (issue 29): a benchmark of 100 seeded 30 s scenes with the
example tracker on every core, and one 10-minute recording scored.

    python -m benchmarks.score_speed [--scenes 100] [--duration 30] [--minutes 10]

Prints a markdown section (docs/scoring.md, "Speed") with the machine, the date and the
load. The benchmark's time is wall time from the command's start to its report, spawning
the worker processes included; its CPU time is that of the workers (getrusage of the
children), so CPU / wall / processes says how busy the cores were. The recording is made
first (the node's own MCAP sink on the default world with ball_0 driving a circle), then
scored in this process like `ball_world_score FILE`, timed in its parts.
"""
import argparse
import contextlib
import datetime
import io
import json
import os
import platform
import resource
import tempfile
import time


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def bench_seeds(scenes, duration, jobs):
    from ball_world.tools import score
    before, began = _children_cpu(), time.perf_counter()
    argv = ['--seeds', f'0:{scenes}', '--duration', str(duration), '--json']
    if jobs:
        argv += ['--jobs', str(jobs)]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = score.main(argv)
    if code != 0:
        raise SystemExit(f'the benchmark failed ({code})')
    wall = time.perf_counter() - began
    report = json.loads(out.getvalue())
    return report, wall, _children_cpu() - before


def make_recording(path, minutes):
    from ball_world.recording.mcap_writer import McapSink
    from ball_world.simulation import Simulation
    parameters = {'agents': ['ball_0']}
    simulation = Simulation(parameters, sinks=[McapSink(path)])
    for _ in range(round(minutes * 60 * 60)):
        simulation.command('ball_0', 0.5, 0.0, 0.4)
        simulation.step()
    simulation.close()


def score_recording(path):
    """(report, {part: seconds}) of scoring a recording with the example tracker."""
    from ball_world.scoring import figures
    from ball_world.tools import score_frames, score_recording as recorded
    from ball_world.tools.tracker import ScanTracker
    parts = {}
    cpu = time.process_time()
    began = time.perf_counter()
    segments = recorded.read_run(path, 'ball_0')
    parts['read the recording, ground truth'] = time.perf_counter() - began
    mark = time.perf_counter()
    frames = score_frames.frames_with_tracker(segments[0].scans, ScanTracker())
    parts['example tracker'] = time.perf_counter() - mark
    mark = time.perf_counter()
    result = figures.score_tracks(frames, 0.5).figures()
    parts["metrics (don't-care, CLEAR, identity, HOTA)"] = time.perf_counter() - mark
    parts['total'] = time.perf_counter() - began
    parts['cpu'] = time.process_time() - cpu
    return result, parts, len(frames)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.score_speed',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--scenes', type=int, default=100)
    parser.add_argument('--duration', type=float, default=30.0)
    parser.add_argument('--jobs', type=int, default=0, help='0: every core')
    parser.add_argument('--minutes', type=float, default=10.0)
    parser.add_argument('--skip-seeds', action='store_true')
    args = parser.parse_args(argv)
    processor = platform.processor() or '?'
    lines = [f'Measured {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC on '
             f'{platform.machine()} with {os.cpu_count()} cores ({processor}), load average '
             f'before: {os.getloadavg()[0]:.2f}.', '']
    if not args.skip_seeds:
        report, wall, cpu = bench_seeds(args.scenes, args.duration, args.jobs)
        busy = cpu / wall / report['jobs']
        summary = report['summary']
        lines += [
            f'- `ball_world_score --seeds 0:{args.scenes} --duration {args.duration:g}`: '
            f"{wall:.1f} s wall ({wall / 60:.2f} min) on {report['jobs']} processes, "
            f'{cpu:.1f} s CPU in the workers: the cores {busy:.0%} busy; '
            f"HOTA {summary['HOTA']['mean']:.4f} +- {summary['HOTA']['ci95']:.4f}, "
            f"MOTA {summary['MOTA']['mean']:.4f} +- {summary['MOTA']['ci95']:.4f}, "
            f"IDF1 {summary['IDF1']['mean']:.4f} +- {summary['IDF1']['ci95']:.4f} "
            f'(load average after: {os.getloadavg()[0]:.2f}).']
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, 'ten_minutes.mcap')
        began = time.perf_counter()
        make_recording(path, args.minutes)
        made = time.perf_counter() - began
        size = os.path.getsize(path)
        result, parts, scans = score_recording(path)
    lines.append(
        f'- one {args.minutes:g}-minute recording ({size / 1e6:.0f} MB, {scans:,} scans; made '
        f'in {made:.0f} s) scored with the example tracker in {parts["total"]:.1f} s wall, '
        f'{parts["cpu"]:.1f} s CPU: '
        + ', '.join(f'{name} {seconds:.1f} s' for name, seconds in parts.items()
                    if name not in ('total', 'cpu'))
        + f" (HOTA {result['HOTA']:.4f}, MOTA {result['MOTA']:.4f}; load average after: "
        f'{os.getloadavg()[0]:.2f}).')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
