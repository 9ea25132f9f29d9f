"""python -m benchmarks.map_agents: 100 robots scanning in a warehouse, against the 10 ms step.

Issue 27's real-time case: 100 differential-drive agents (agent.drive diff), each with a
360-beam lidar at 10 Hz (0-12 m, the default noise), among 1,000 balls in the generated
warehouse (benchmarks.warehouse), stepped at 100 Hz in seed mode. This runs it through the
Simulation class the node steps (ball_world.simulation: the drive rule, the physics, odom,
/tf, bumpers, the scans and their LaserScan bytes), every agent commanded anew every 10 steps
(a controller at 10 Hz), and reports what a step costs against the 10 ms a step may take:
the mean over whole scan periods (every tenth step scans all 100 agents at once), the scan
steps and the others apart, and where a scan step's time goes (the scans themselves,
timed inside AgentScans.take). Publishing is not included (the node publishes the step's
bytes raw); `--record` adds the MCAP sink's write.

The real-time factor the node can keep is at most 10 ms over the mean step (the node's
timer catches up on a late step within pacing.MAX_LAG, so a scan step's burst is absorbed
when the mean fits). Times are the thread's CPU time (time.thread_time): on a shared machine
wall time measures the other processes; the load average goes in the report all the same.
Scans shared among threads (`--scan-threads`, scans.ScanPool; by default one per core) are
work this thread does not do: their mean step is given in wall time too, which only an idle
machine makes meaningful. Never a timed assertion.
"""
import argparse
import statistics
import sys
import tempfile
import time

from benchmarks import warehouse

from ball_world import scans as scans_module
from ball_world.simulation import Simulation

RATE_HZ = 100.0
COMMAND_EVERY = 10
#: Radii of the balls, the agents among them (m): robots of 0.1-0.2 m.
RADIUS = (0.1, 0.2)


def parameters(yaml_path, balls, agents, seed, scan_rate):
    """The run's parameters: balls placed at random in the map's free cells."""
    return {'map': str(yaml_path), 'arena': [], 'random.count': balls,
            'random.radius': list(RADIUS), 'random.speed': 1.0, 'random.seed': seed,
            'rate_hz': RATE_HZ, 'agents': [f'ball_{i}' for i in range(agents)],
            'agent.drive': 'diff', 'agent.cmd_timeout': 0.5,
            'agent.scan.samples': 360, 'agent.scan.rate_hz': scan_rate}


def command_all(simulation):
    """Every agent: forward at 0.5-1 m/s, turning one way or the other."""
    for row, name in enumerate(simulation.agents.names):
        simulation.command(name, 0.5 + 0.05 * (row % 11), 0.0, 0.6 - 0.1 * (row % 13))


class _TimedScans:
    """AgentScans.take with the CPU time it took, summed in `seconds`."""

    def __init__(self, scans):
        self.scans = scans
        self.seconds = 0.0

    def take(self, *args):
        began = time.thread_time()
        try:
            return self.scans.take(*args)
        finally:
            self.seconds += time.thread_time() - began

    def __getattr__(self, name):
        return getattr(self.scans, name)


def run(yaml_path, args, sinks=()):
    """Per-step CPU seconds, whether each step scanned, and the scans' share of each."""
    simulation = Simulation(parameters(yaml_path, args.balls, args.agents, args.seed,
                                       args.scan_rate), sinks=sinks)
    if args.no_messages:  # as the node when nobody takes them, ball_world_sim unrecorded
        simulation.agents.encode = frozenset()
    timed = _TimedScans(simulation.agents.scans)
    simulation.agents.scans = timed
    assert isinstance(timed.scans, scans_module.AgentScans)
    if args.scan_threads:
        pool = scans_module.ScanPool(args.scan_threads) if args.scan_threads > 1 else None
        timed.scans.pool = lambda: pool
    took, scanned, in_scans, wall = [], [], [], []
    for k in range(args.warm_up + args.steps):
        if k % COMMAND_EVERY == 0:
            command_all(simulation)
        timed.seconds = 0.0
        began = time.thread_time()
        clock = time.perf_counter()
        record, _ = simulation.step()
        seconds = time.thread_time() - began
        if k >= args.warm_up:
            took.append(seconds)
            wall.append(time.perf_counter() - clock)
            scanned.append(bool(record.agents and record.agents.scans))
            in_scans.append(timed.seconds)
    simulation.close()
    return took, scanned, in_scans, wall


def report(took, scanned, in_scans, wall, args, load):
    budget = 1.0 / RATE_HZ
    scan_steps = [t for t, s in zip(took, scanned) if s]
    other = [t for t, s in zip(took, scanned) if not s]
    scan_share = [q for q, s in zip(in_scans, scanned) if s]
    mean = statistics.fmean(took)
    rows = [('mean step (whole scan periods)', mean),
            ('median step without scans', statistics.median(other) if other else float('nan')),
            ('median scan step', statistics.median(scan_steps) if scan_steps else float('nan')),
            (f'  of which the {args.agents} scans', statistics.median(scan_share)
             if scan_share else float('nan')),
            ('mean step, wall time', statistics.fmean(wall))]
    threads = args.scan_threads or 'one per core'
    lines = [f'{args.agents} diff-drive agents scanning (360 beams, {args.scan_rate:g} Hz) '
             f'among {args.balls:,} balls in the warehouse, {RATE_HZ:g} Hz, {len(took)} steps, '
             f'scan threads {threads}'
             + (', no robot messages made' if args.no_messages else '')
             + f', load average {load}', '',
             '| | ms | share of the 10 ms step |', '|---|---:|---:|']
    lines += [f'| {name} | {1e3 * value:.2f} | {value / budget:.0%} |' for name, value in rows]
    lines += ['', f'real-time factor the step allows: {min(budget / mean, float("inf")):.2f} '
                  '(10 ms over the mean step; publishing not included); in wall time: '
                  f'{min(budget / statistics.fmean(wall), float("inf")):.2f}']
    return '\n'.join(lines)


def _load():
    try:
        with open('/proc/loadavg') as stream:
            return ' '.join(stream.read().split()[:3])
    except OSError:
        return 'unknown'


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.map_agents', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--balls', type=int, default=1_000)
    parser.add_argument('--agents', type=int, default=100)
    parser.add_argument('--scan-rate', type=float, default=10.0, help='scans per second')
    parser.add_argument('--steps', type=int, default=300, help='timed steps (whole periods)')
    parser.add_argument('--warm-up', type=int, default=20)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--record', action='store_true', help='add the MCAP sink')
    parser.add_argument('--scan-threads', type=int, default=0,
                        help='threads the scans of a step share (1: this one; 0: one per core)')
    parser.add_argument('--no-messages', action='store_true',
                        help="make no robot's messages (odom, ground truth, /tf, LaserScan "
                             'bytes): what a run nobody listens to or records needs')
    args = parser.parse_args(argv)
    if args.no_messages and args.record:
        parser.error('--no-messages leaves nothing to --record')
    if args.agents > args.balls:
        parser.error(f'{args.agents} agents need at least as many balls (--balls)')
    with tempfile.TemporaryDirectory() as directory:
        yaml_path = warehouse.write(directory)
        sinks = ()
        if args.record:
            from ball_world.recording.mcap_writer import McapSink
            sinks = (McapSink(f'{directory}/run.mcap'),)
        took, scanned, in_scans, wall = run(yaml_path, args, sinks)
    print(report(took, scanned, in_scans, wall, args, _load()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
