"""python -m benchmarks.robots_recording: what recording 1,000 robots with topics costs a step.

Issue 35's node run (`benchmarks.soak rtf --balls 1000 --agents 1000 --speed 1 --odom-rate
10`) without ROS: the same world stepped by a Simulation, every robot commanded every 10th
step (10 Hz at 100 Hz stepping, as soak's Commander does, with the bytes a cmd_vel
subscription hands over), `agent.odom.rate_hz` 10, scanners off. Timed side by side in one
run: the steps alone, then the same steps with an McapSink written inline, its write_step
timed apart (in the node it runs on the writer thread, but holds the GIL as long). The
messages a step records are counted. Wall time of this process, for `--steps` steps; the
load average goes in the report. Never a timed assertion. `--profile` prints the sink's
cProfile instead.

`--thread` writes on a writer thread as the node does (recording.writer_thread.BackgroundSink)
and times the steps until the sink is closed: how much the writer, sharing the GIL, slows the
stepping thread.

`--against TREE` runs this benchmark of another source tree (an older commit: `git archive
<commit> | tar -x -C TREE`) and this tree's alternately, `--repeats` times each, each in a
process of its own with the same Python, and prints their lines. `--agents 0` records a plain
world of balls (the 1,000- and 10,000-ball worlds of `make bench`'s MCAP row).
"""
import argparse
import cProfile
import math
import os
from pathlib import Path
import pstats
import subprocess
import sys
import tempfile
import time

from ball_world.msgs.twist_cdr import encode_twist
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.writer_thread import BackgroundSink
from ball_world.simulation import Simulation


def parameters(balls, agents):
    """soak.rtf_parameters' world: balls of 0.5 m at 20% of a box, 100 Hz, the first
    `agents` of them robots with topics, odometry at 10 Hz."""
    side = round(0.5 * math.sqrt(balls * math.pi / 0.2), 3)
    return {'random.count': balls, 'random.radius': [0.5, 0.5], 'random.speed': 1.0,
            'arena': [0.0, 0.0, side, side], 'dt': 0.01, 'rate_hz': 100.0,
            'agents': [f'ball_{i}' for i in range(agents)], 'agent.scan.samples': 0,
            'agent.odom.rate_hz': 10.0}


class TimedSink:
    """An McapSink whose write_step is timed."""

    def __init__(self, sink):
        self.sink = sink
        self.spent = 0.0

    def start_segment(self, world, info):
        self.sink.start_segment(world, info)

    def write_step(self, record):
        began = time.perf_counter()
        self.sink.write_step(record)
        self.spent += time.perf_counter() - began

    def flush(self):
        self.sink.flush()

    def close(self):
        self.sink.close()


def run(args, sink=None, until_closed=False):
    """Seconds for args.steps steps (commands included), the sink's flushed once a second;
    until_closed: and until the sink is closed (a writer thread done with its queue)."""
    simulation = Simulation(parameters(args.balls, args.agents),
                            sinks=[sink] if sink is not None else [])
    command = encode_twist(1.0, 0.0, 0.5)
    names = simulation.agents.names
    began = time.perf_counter()
    for k in range(args.steps):
        if k % 10 == 0:
            for name in names:
                simulation.command(name, 1.0, 0.0, 0.5, command)
        simulation.step()
        if k % 100 == 99:
            simulation.flush()
    spent = time.perf_counter() - began
    simulation.close()
    return time.perf_counter() - began if until_closed else spent


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--balls', type=int, default=1000)
    parser.add_argument('--agents', type=int, default=1000)
    parser.add_argument('--steps', type=int, default=300)
    parser.add_argument('--profile', action='store_true')
    parser.add_argument('--against', metavar='TREE',
                        help='another source tree whose McapSink is timed alternately')
    parser.add_argument('--repeats', type=int, default=1)
    parser.add_argument('--thread', action='store_true',
                        help='write on a writer thread, as the node does')
    args = parser.parse_args(argv)
    if args.against:
        return compare(args)
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, 'robots.mcap')
        if args.profile:
            sink = McapSink(path)
            profile = cProfile.Profile()
            original = sink.write_step

            def profiled(record):
                profile.runcall(original, record)

            sink.write_step = profiled
            run(args, sink)
            pstats.Stats(profile).sort_stats('cumulative').print_stats(20)
            return 0
        alone = run(args)
        if args.thread:
            threaded = run(args, BackgroundSink(McapSink(path)), until_closed=True)
            print(f'{args.balls:,} balls, {args.agents:,} robots with topics, {args.steps} '
                  f'steps: the steps alone {1e3 * alone / args.steps:.2f} ms a step; with an '
                  f'McapSink on its writer thread {1e3 * threaded / args.steps:.2f} ms; load '
                  f'average {os.getloadavg()[0]:.1f}')
            return 0
        timed = TimedSink(McapSink(path))
        recorded = run(args, timed)
        messages = sum(timed.sink.summary().topics[t].message_count
                       for t in timed.sink.summary().topics)
        size = os.path.getsize(path) / 2 ** 20
    steps = args.steps
    print(f'{args.balls:,} balls, {args.agents:,} robots with topics commanded every 10th '
          f'step, odometry every 10th, {steps} steps: the steps alone '
          f'{1e3 * alone / steps:.2f} ms a step; with an McapSink inline '
          f'{1e3 * recorded / steps:.2f} ms, its write_step {1e3 * timed.spent / steps:.2f} ms '
          f'({messages / (steps + 1):.0f} messages a step, {size:.1f} MB); load average '
          f'{os.getloadavg()[0]:.1f}')
    return 0


def compare(args):
    """This benchmark of this tree and of args.against, alternately, a process each run."""
    trees = {'this tree': Path(__file__).resolve().parents[1], args.against: args.against}
    command = [sys.executable, '-m', 'benchmarks.robots_recording', '--balls',
               str(args.balls), '--agents', str(args.agents), '--steps', str(args.steps),
               *(['--thread'] if args.thread else [])]
    for _ in range(args.repeats):
        for name, tree in trees.items():
            done = subprocess.run(command, cwd=tree, capture_output=True, text=True)
            lines = (done.stdout or done.stderr).strip().splitlines() or ['(no output)']
            print(f'{name}: {lines[-1]}', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
