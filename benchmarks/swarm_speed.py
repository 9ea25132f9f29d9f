"""python -m benchmarks.swarm_speed: a swarm and its controller, against real time, without ROS.

Issue 35's ARGoS case: N differential-drive robots (default 10,000), each with a ring of 16
beams reaching 2 m (ARGoS's proximity ring, Stage's sonar ring), stepped at 10 Hz among
walls (the arena's four and a lattice of 10 m walls inside it) and driven by
`ball_world.controllers.wander:Wander` at 10 Hz, with `agent.topics: none`. It runs exactly
what `ball_world_sim --params-file FILE --controller ...` runs: the Simulation, the
controller in its supervised worker (user_code.controller.ControllerProcess: the
observation pickled there and the commands back, checked) and, with --record, the MCAP the
node would write. It reports steps per second and the real-time factor (simulated seconds
per wall second), and the share of a step the controller's round trip took.

Scan noise: ARGoS's proximity sensors have none unless asked; the node's lidar has 1 cm by
default, seeded per robot and step (core.noise_seed): --noise 0.01 measures it. All robots'
noise is drawn in one compiled call (core.noise_kernel); --per-scan-noise runs each size
again, in the same process, the way it was drawn before: a reseeded Generator per robot per
scan (about 7 us each), the same numbers.
Wall time on a shared 2-core machine: the load average is printed with the figures; never a
timed assertion.
"""
import argparse
import contextlib
import math
import os
import tempfile
import time

import numpy as np

from ball_world.core import lidar
from ball_world.core.noise_seed import EntropyRows, NoiseSeeds
from ball_world.simulation import Simulation
from ball_world.user_code.controller import ControllerProcess

WANDER = 'ball_world.controllers.wander:Wander'
#: Area per robot, m^2 (about ARGoS's foot-bot arena density of its 10,000-robot run).
AREA_PER_ROBOT = 6.0
#: Spacing of the lattice of inner walls, m, and their length.
WALL_SPACING = 20.0
WALL_LENGTH = 10.0


def parameters(robots, noise, seed=0):
    """The swarm's world: a square arena of AREA_PER_ROBOT m^2 a robot, a lattice of walls."""
    side = math.ceil(math.sqrt(robots * AREA_PER_ROBOT) / WALL_SPACING) * WALL_SPACING
    walls = []
    for row in range(1, int(side // WALL_SPACING)):
        for column in range(1, int(side // WALL_SPACING)):
            x, y = column * WALL_SPACING, row * WALL_SPACING
            if (row + column) % 2:
                walls += [x - WALL_LENGTH / 2, y, x + WALL_LENGTH / 2, y]
            else:
                walls += [x, y - WALL_LENGTH / 2, x, y + WALL_LENGTH / 2]
    return {'arena': [0.0, 0.0, side, side], 'walls': walls, 'rate_hz': 10.0,
            'random.count': robots, 'random.radius': [0.1, 0.1], 'random.speed': 0.0,
            'random.seed': seed, 'agents': [f'ball_{i}' for i in range(robots)],
            'agent.topics': 'none', 'agent.drive': 'diff', 'agent.max_speed': 0.5,
            'agent.scan.samples': 16, 'agent.scan.range_max': 2.0,
            'agent.scan.angle_min': -math.pi, 'agent.scan.angle_max': math.pi * 7 / 8,
            'agent.scan.noise_stddev': noise, 'agent.scan.rate_hz': 10.0,
            'controller': WANDER, 'controller.rate_hz': 10.0}


#: per_scan_noise's generators: (id of an EntropyRows, row) -> NoiseSeeds.
_PER_SCAN = {}


@contextlib.contextmanager
def per_scan_noise():
    """While open, EntropyRows noise their rows as the callers did before core.noise_kernel
    (the same numbers): each row's scan through core.lidar.add_noise with its scanner's
    reseeded Generator (core.noise_seed.NoiseSeeds, one kept per row, as each Scanner kept
    one). Rows must be set while it is open (it may be opened again: they are kept). For
    timing the two side by side."""
    kept = _PER_SCAN
    batched_set, batched_noise = EntropyRows.set, EntropyRows.add_noise

    def set_row(rows, row, seed, key):
        batched_set(rows, row, seed, key)
        kept[id(rows), row] = NoiseSeeds(seed, key)

    def add_noise(rows, ranges, which, steps, stddev):
        which = np.arange(len(rows.lengths))[which].tolist()
        steps = np.broadcast_to(steps, len(which)).tolist()
        for out, row, step in zip(ranges, which, steps):
            lidar.add_noise(out, stddev, kept[id(rows), row].generator(step))
        return ranges

    EntropyRows.set, EntropyRows.add_noise = set_row, add_noise
    try:
        yield
    finally:
        EntropyRows.set, EntropyRows.add_noise = batched_set, batched_noise


def noise_alone(robots, noise, rounds=7, beams=16):
    """Milliseconds of CPU time (median of `rounds`, alternating) to noise one step's scans
    of `robots` robots: (in one call, scan by scan) on the same table of ranges."""
    table = np.full((robots, beams), 1.0)
    pairs = [(0, lidar.name_key(f'ball_{robot}')) for robot in range(robots)]
    times = {False: [], True: []}
    for step in range(rounds):
        for per_scan in (False, True):
            with per_scan_noise() if per_scan else contextlib.nullcontext():
                rows = EntropyRows.of(pairs)
                began = time.thread_time()
                rows.add_noise(table, slice(None), np.full(robots, step), noise)
                times[per_scan].append(time.thread_time() - began)
    return tuple(1e3 * sorted(times[path])[rounds // 2] for path in (False, True))


class _Timed:
    """The controller with the wall time of its round trips summed."""

    def __init__(self, controller):
        self.controller = controller
        self.seconds = 0.0

    def act(self, observation):
        began = time.perf_counter()
        try:
            return self.controller.act(observation)
        finally:
            self.seconds += time.perf_counter() - began


def run(robots, steps, warm_up, noise, record, per_scan=False):
    values = parameters(robots, noise)
    with ControllerProcess(WANDER) as process, tempfile.TemporaryDirectory() as folder, \
            (per_scan_noise() if per_scan else contextlib.nullcontext()):
        controller = _Timed(process)
        sinks = []
        if record:
            from ball_world.recording.mcap_writer import McapSink
            sinks.append(McapSink(os.path.join(folder, 'swarm.mcap')))
        simulation = Simulation(values, sinks, controller=controller)
        for _ in range(warm_up):
            simulation.step()
        controller.seconds = 0.0
        began = time.perf_counter()
        for _ in range(steps):
            simulation.step()
        elapsed = time.perf_counter() - began
        simulation.close()
    simulated = steps * simulation.dt_ns * 1e-9
    return {'robots': robots, 'steps': steps, 'seconds': elapsed,
            'steps_per_s': steps / elapsed, 'rtf': simulated / elapsed,
            'controller_share': controller.seconds / elapsed,
            'walls': len(values['walls']) // 4 + 4, 'side': values['arena'][2]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--robots', type=int, nargs='+', default=[10_000])
    parser.add_argument('--steps', type=int, default=300)
    parser.add_argument('--warm-up', type=int, default=20)
    parser.add_argument('--noise', type=float, default=0.0,
                        help='scan noise stddev, m (default 0, as ARGoS)')
    parser.add_argument('--record', action='store_true', help='record the MCAP too')
    parser.add_argument('--per-scan-noise', action='store_true',
                        help='run each size again with the noise drawn scan by scan, as '
                             'before core.noise_kernel (needs --noise)')
    args = parser.parse_args(argv)
    paths = [False, True] if args.per_scan_noise and args.noise > 0.0 else [False]
    print(f'load average {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    print('| robots | arena m | walls | steps | noise drawn | steps/s | real-time factor | '
          'controller share |')
    print('|---:|---:|---:|---:|---|---:|---:|---:|')
    for robots in args.robots:
        for per_scan in paths:
            result = run(robots, args.steps, args.warm_up, args.noise, args.record, per_scan)
            drawn = ('-' if args.noise <= 0.0 else 'scan by scan' if per_scan
                     else 'one call')
            print(f"| {robots:,} | {result['side']:g} | {result['walls']} | {args.steps} | "
                  f"{drawn} | {result['steps_per_s']:.1f} | {result['rtf']:.2f} | "
                  f"{result['controller_share']:.0%} |", flush=True)
    if len(paths) > 1:
        for robots in args.robots:
            batched, each = noise_alone(robots, args.noise)
            print(f'the noise of one step of {robots:,} scans alone (CPU): {batched:.2f} ms in '
                  f'one call, {each:.1f} ms scan by scan ({each / batched:.0f}x)')
    print(f'16-beam 2 m ring at 10 Hz, scan noise {args.noise:g} m, wander at 10 Hz, 10 Hz '
          f"steps{', recording MCAP' if args.record else ''}; load average "
          f'{" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
