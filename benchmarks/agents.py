"""python -m benchmarks.agents: what agents cost a step, beside the same world without them.

The issue's speed case is 100 agents in a 10,000-ball world at 100 Hz with cmd_vel, odom
and /tf, recording MCAP. This times Simulation.step (the drive rule, its impulses, the
physics, the odom and /tf bytes) plus the MCAP sink's write of the step, for each number of
agents, in one process and interleaved step by step, so the machine's load falls on every
row alike; the report is each row's median ms per step and its ratio to the row without
agents. Every agent is commanded to drive forward while turning, so each step applies a
drive impulse to every agent (the costly case), and takes a new command every 10 steps
(a controller at 10 Hz). Publishing is not included: the node publishes the same bytes raw.
"""
import argparse
import statistics
import sys
import tempfile
import time

from benchmarks.scenes import box_side, RADIUS

from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation

RATE_HZ = 100.0
COMMAND_EVERY = 10
NOTE = ('Median ms of Simulation.step (the drive rule, its impulses, the physics, odom, /tf '
        'and scan bytes) plus the MCAP write of the step, the rows interleaved step by step in '
        'one process; every agent commanded anew every 10 steps (`benchmarks/agents.py`). '
        'Publishing is not included: the node publishes the same bytes raw.')


def world(n, agents, seed, path):
    """n balls (radii 0.25-0.5 m) in the benchmark's box for n, the first `agents` agents."""
    side = box_side(n)
    simulation = Simulation({'arena': [0.0, 0.0, side, side], 'random.count': n,
                             'random.radius': [RADIUS / 2, RADIUS], 'random.speed': 1.0,
                             'random.seed': seed, 'rate_hz': RATE_HZ,
                             'agents': [f'ball_{i}' for i in range(agents)],
                             'agent.cmd_timeout': 0.5}, sinks=[McapSink(path)])
    return simulation


def command_all(simulation):
    for row, name in enumerate(simulation.agents.names):
        simulation.command(name, 1.0, 0.1 * (row % 3), 0.5 - 0.1 * (row % 11))


def run(n, counts, steps, seed):
    """{agents: median ms per step} over `steps` interleaved steps."""
    times = {count: [] for count in counts}
    with tempfile.TemporaryDirectory() as directory:
        simulations = {count: world(n, count, seed, f'{directory}/{count}.mcap')
                       for count in counts}
        for k in range(steps + 10):
            for count, simulation in simulations.items():
                if k % COMMAND_EVERY == 0:
                    command_all(simulation)
                start = time.perf_counter()
                simulation.step()
                if k >= 10:  # the first steps warm caches and compiled kernels
                    times[count].append(time.perf_counter() - start)
        for simulation in simulations.values():
            simulation.close()
    return {count: 1e3 * statistics.median(values) for count, values in times.items()}


def report(n, medians):
    base = medians[min(medians)]
    lines = [f'## Agents at {n:,} balls, {RATE_HZ:g} Hz, recording MCAP',
             '', '| agents | ms per step | x the step without agents | share of a 10 ms step |',
             '|---:|---:|---:|---:|']
    for count, value in sorted(medians.items()):
        lines.append(f'| {count} | {value:.3f} | {value / base:.2f} | '
                     f'{value / (1e3 / RATE_HZ):.0%} |')
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.agents', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--n', type=int, default=10_000, help='balls (default 10,000)')
    parser.add_argument('--agents', type=int, nargs='+', default=[0, 10, 100],
                        help='numbers of agents to time (default 0 10 100)')
    parser.add_argument('--steps', type=int, default=200, help='timed steps per row')
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args(argv)
    counts = sorted(set([0, *args.agents]))
    if max(counts) > args.n:
        parser.error(f'{max(counts)} agents need at least as many balls (--n {args.n})')
    print(report(args.n, run(args.n, counts, args.steps, args.seed)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
