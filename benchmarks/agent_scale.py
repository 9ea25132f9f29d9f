"""python -m benchmarks.agent_scale: how long the node takes to start, step and stop with
many agents, in a process of its own as a user runs it.

For each count: the node with that many agents (no scanners, every agent with its cmd_vel
subscription and its odom, ground_truth and bumper publishers), in a box where they cover a
tenth of the floor, at 50 Hz. Reported: seconds from launch to its start-up line, steps per
second over `--seconds` of running (from its progress line), and seconds from SIGINT to its
exit. Run it with ROS_DOMAIN_ID of your own; the machine's load goes in the report.
"""
import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time

import yaml

PROGRESS = re.compile(r'step [0-9]+: ([0-9.]+) steps/s')


def parameters(count):
    side = max(20.0, (count * 3.14 * 0.0625 / 0.1) ** 0.5)
    return {'ball_world': {'ros__parameters': {
        'rate_hz': 50.0, 'markers.rate_hz': 0.0, 'random.count': count,
        'random.radius': [0.2, 0.3], 'arena': [0.0, 0.0, side, side],
        'agents': [f'ball_{i}' for i in range(count)], 'agent.scan.samples': 0}}}


def measure(node, count, seconds):
    """(start s, steps/s or None, stop s or None) of one run."""
    with tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False) as stream:
        yaml.safe_dump(parameters(count), stream)
    lines = []
    started = threading.Event()
    begin = time.monotonic()
    process = subprocess.Popen([node, '--ros-args', '--params-file', stream.name],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def read():
        for line in process.stderr:
            lines.append(line)
            if 'world:' in line:
                started.set()
    threading.Thread(target=read, daemon=True).start()
    try:
        if not started.wait(600.0):
            return None, None, None
        start = time.monotonic() - begin
        time.sleep(seconds)
        rates = []
        deadline = time.monotonic() + 60.0
        while not rates and time.monotonic() < deadline:  # a progress line comes every 10 s
            rates = [float(m.group(1)) for m in map(PROGRESS.search, lines) if m]
            time.sleep(0.2)
        stop_at = time.monotonic()
        process.send_signal(signal.SIGINT)
        try:
            process.wait(300.0)
            stop = time.monotonic() - stop_at
        except subprocess.TimeoutExpired:
            stop = None
        return start, (rates[-1] if rates else None), stop
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        os.unlink(stream.name)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.agent_scale',
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--agents', type=int, nargs='+', default=[10, 100, 300, 1000])
    parser.add_argument('--seconds', type=float, default=12.0)
    parser.add_argument('--node', default=os.path.join(os.path.dirname(sys.executable),
                                                       'ball_world'))
    args = parser.parse_args(argv)
    print(f'load before: {os.getloadavg()[0]:.1f}')
    print('| agents | start s | steps/s at 50 Hz | SIGINT to exit s |')
    print('|---:|---:|---:|---:|')
    for count in args.agents:
        start, rate, stop = measure(args.node, count, args.seconds)
        shown = [f'{value:.1f}' if value is not None else 'none' for value in
                 (start, rate, stop)]
        print(f'| {count} | ' + ' | '.join(shown) + ' |', flush=True)
    print(f'load after: {os.getloadavg()[0]:.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
