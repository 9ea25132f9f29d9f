"""ball_world_bench: ball_world's World (both backends) against pymunk (Chipmunk2D).

Why a tool and not a note: speed claims rot. This runs every engine in one process on the
same scene (the issue's: equal balls of radius 0.5 m at a 20% area fraction, all at 24 m/s,
dt 1/240 s, elastic, no gravity), so the numbers in docs/bench.md can be re-made on any
machine with one command. The default backend (`physics.backend: auto`) is named in the
report and compared with pymunk. Exact mode is timed beside seed mode on the gas scenes of
benchmarks.exact_speed (the same code, not a copy). Besides steps per second it measures what
the node spends per step around the physics (CDR encoding, publishing, MCAP recording), the
energy drift of each engine, and optionally: memory growth over a long recorded run, the
time from process start to the first step (numba kernels cached or not), and worst-case
worlds at the size limits of `core.limits`.

An all-pairs numpy baseline used to sit here; it was dropped: it carried a third copy of
the contact resolution, and what it showed (O(N^2) detection loses) the N sweep shows too.
"""
import argparse
import datetime
import gc
import io
import math
import os
from pathlib import Path
import platform
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks import agents as agents_speed, exact_speed, lidar_speed, step_compare
from benchmarks.scenes import (AREA_FRACTION, box_side, DT, escaped, FRAME_ID, many_walls_world,
                               MASS, OurEngine, RADIUS, radius_spread_world, Scene, SPEED)
import numpy as np

from ball_world.core import limits
from ball_world.core.alloc import MMAP_THRESHOLD_BYTES, TRIM_THRESHOLD_BYTES, tune_allocator
from ball_world.core.stepping import AUTO, resolve_backend
from ball_world.core.world import numba_installed, World
from ball_world.msgs.cdr import decode_pose_array, encode_pose_array
from ball_world.recording.files import write_file

#: Issue 11: the default backend at least this many times as fast as pymunk at every N.
TARGET_VS_PYMUNK = 2.0

OURS_NUMPY = 'ball_world (numpy)'
OURS_NUMBA = 'ball_world (numba)'
OURS = {'numpy': OURS_NUMPY, 'numba': OURS_NUMBA}
PYMUNK_TREE = 'pymunk (tree)'
PYMUNK_HASH = 'pymunk (spatial hash)'
ENGINE_CHOICES = {'ours-numba': OURS_NUMBA, 'ours-numpy': OURS_NUMPY, 'pymunk-tree': PYMUNK_TREE,
                  'pymunk-hash': PYMUNK_HASH}


# The scene ---------------------------------------------------------------------------------

# The engines -------------------------------------------------------------------------------

class PymunkEngine:
    """pymunk: static segment walls, unit-mass circles, elasticity 1, friction 0, defaults else.

    The spatial hash gets cells of one ball diameter and 10 N cells, pymunk's own advice.
    """

    def __init__(self, scene, pymunk, spatial_hash):
        self.name = PYMUNK_HASH if spatial_hash else PYMUNK_TREE
        self.side = scene.side
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        if spatial_hash:
            space.use_spatial_hash(2.0 * RADIUS, 10 * scene.n)
        s = scene.side
        corners = [(0.0, 0.0), (s, 0.0), (s, s), (0.0, s)]
        shapes = [pymunk.Segment(space.static_body, corners[k], corners[(k + 1) % 4], 0.0)
                  for k in range(4)]
        moment = pymunk.moment_for_circle(MASS, 0.0, RADIUS)
        self.bodies = []
        for position, velocity in zip(scene.positions.tolist(), scene.velocities.tolist()):
            body = pymunk.Body(MASS, moment)
            body.position = position
            body.velocity = velocity
            self.bodies.append(body)
            shapes.append(pymunk.Circle(body, RADIUS))
        for shape in shapes:
            shape.elasticity = 1.0
            shape.friction = 0.0
        space.add(*self.bodies, *shapes)
        self.space = space

    def run(self, steps):
        step = self.space.step
        for _ in range(steps):
            step(DT)

    def kinetic_energy(self):
        return math.fsum(body.kinetic_energy for body in self.bodies)

    def escaped(self):
        positions = np.array([tuple(body.position) for body in self.bodies])
        return escaped(positions, self.side)


def make_engine(name, scene, pymunk):
    if name == OURS_NUMPY:
        return OurEngine(scene, backend='numpy')
    if name == OURS_NUMBA:
        return OurEngine(scene, backend='numba')
    return PymunkEngine(scene, pymunk, spatial_hash=name == PYMUNK_HASH)


# Timing ------------------------------------------------------------------------------------

def _timed(action, *args):
    start = time.perf_counter()
    action(*args)
    return time.perf_counter() - start


def steps_per_second(engine, seconds, repeats, warmup_steps):
    """Median steps/s of `repeats` runs of about `seconds` each, after a warm-up.

    The warm-up lets the gas thermalise first: every ball starts at the same speed, and
    within about 100 steps collisions spread the speeds into a Maxwell distribution whose
    fastest balls (about 3x the start speed) decide how often neighbour lists are rebuilt,
    in every engine. It then doubles a step count until one batch takes a tenth of
    `seconds`; that batch sizes the timed runs.
    """
    engine.run(warmup_steps)
    steps = 1
    while True:
        elapsed = _timed(engine.run, steps)
        if elapsed >= seconds / 10.0 or steps >= 1 << 20:
            break
        steps *= 2
    per_run = max(1, round(seconds * steps / max(elapsed, 1e-9)))
    rates = []
    for _ in range(repeats):
        gc.collect()
        rates.append(per_run / _timed(engine.run, per_run))
    return statistics.median(rates), rates


def energy_change(engine, steps):
    """Relative kinetic energy change after `steps` steps, and the balls that left the box."""
    before = engine.kinetic_energy()
    engine.run(steps)
    return (engine.kinetic_energy() - before) / before, engine.escaped()


def _median_ms(call, repeats):
    samples = [_timed(call) for _ in range(repeats)]
    return 1e3 * statistics.median(samples)


def bench_cdr(count, repeats):
    """ball_world.msgs.cdr.encode_pose_array against PoseArray objects + serialize_message."""
    positions = Scene(count).positions
    stamp_ns = 1_234_567_890
    ours = encode_pose_array(positions, stamp_ns, FRAME_ID)
    result = {'count': count,
              'ours_ms': _median_ms(lambda: encode_pose_array(positions, stamp_ns, FRAME_ID),
                                    max(20, repeats * 10))}
    try:
        from geometry_msgs.msg import Point, Pose, PoseArray
        from rclpy.serialization import serialize_message
    except ImportError as error:
        print(f'rclpy not available ({error}): skipping the serialize_message comparison')
        return result

    def rclpy_way():
        message = PoseArray()
        message.header.frame_id = FRAME_ID
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
        message.poses = [Pose(position=Point(x=x, y=y)) for x, y in positions.tolist()]
        return serialize_message(message)

    theirs = rclpy_way()
    # Bytes may differ in alignment padding (rmw leaves stray bytes there): compare values.
    same = all(np.array_equal(u, w) if isinstance(u, np.ndarray) else u == w
               for u, w in zip(decode_pose_array(ours), decode_pose_array(theirs)))
    result.update(rclpy_ms=_median_ms(rclpy_way, repeats), same_values=same)
    return result


class _Publishers:
    """The node's three step publishers, on their own rclpy context in a random domain."""

    def __init__(self, seed):
        import rclpy
        from rclpy.context import Context
        from geometry_msgs.msg import PoseArray
        from std_msgs.msg import Float64MultiArray
        self._rclpy = rclpy
        self.context = Context()
        domain = int(np.random.default_rng(seed + os.getpid()).integers(1, 102))
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('ball_world_bench', context=self.context)
        self.publishers = [self.node.create_publisher(kind, f'/ball_world_bench/{topic}', 10)
                           for kind, topic in ((PoseArray, 'balls'), (Float64MultiArray, 'state'),
                                               (Float64MultiArray, 'stats'))]

    def publish(self, record):
        for publisher, data in zip(self.publishers,
                                   (record.balls_cdr, record.state_cdr, record.stats_cdr)):
            publisher.publish(data)

    def close(self):
        self.node.destroy_node()
        self.context.try_shutdown()


def _optional(what, make):
    """make(), or None with one printed line saying why `what` is skipped."""
    try:
        return make()
    except Exception as error:  # noqa: B902 - any failure only drops that one column
        print(f'{what} skipped: {type(error).__name__}: {error}')
        return None


def _budget_simulation(n, seed, sinks):
    from ball_world.simulation import Simulation
    side = box_side(n)
    simulation = Simulation({'arena': [0.0, 0.0, side, side], 'random.count': n,
                             'random.radius': [RADIUS, RADIUS], 'random.speed': SPEED,
                             'random.seed': seed, 'dt': DT}, sinks=sinks)
    # The scenario draws speeds in [0, random.speed]; the benchmark scene has all at SPEED.
    heading = np.random.default_rng(seed).uniform(0.0, 2.0 * math.pi, size=n)
    simulation.world.velocities[:] = SPEED * np.stack((np.cos(heading), np.sin(heading)), 1)
    return simulation


def bench_budget(n, seconds, seed, directory):
    """Median ms per step of each part of Simulation.step at N balls, plus publishing.

    Runs what Simulation.step does (no impulses), split into timed parts: the physics
    step; Simulation.record (copies, energy, pose array, state and stats CDR); publishing
    those bytes; McapSink.write_step.
    """
    sink = _optional('MCAP row', lambda: _mcap_sink(Path(directory) / f'budget-{n}.mcap'))
    publishers = _optional('publish row', lambda: _Publishers(seed))
    simulation = _budget_simulation(n, seed, [sink] if sink else [])
    simulation.sinks = []  # records are written below, timed on their own
    world = simulation.world
    parts = {'physics': [], 'encode': [], 'publish': [], 'mcap': [], 'total': []}
    try:
        deadline = None
        steps = 0
        while steps < 10 or time.perf_counter() < deadline:
            t0 = time.perf_counter()
            stats = world.step(DT)
            simulation.step_index += 1
            t1 = time.perf_counter()
            record = simulation.record(stats)
            t2 = time.perf_counter()
            if publishers:
                publishers.publish(record)
            t3 = time.perf_counter()
            if sink:
                sink.write_step(record)
            t4 = time.perf_counter()
            steps += 1
            if steps == 5:  # warm-up done: lists built, buffers allocated
                deadline = t4 + seconds
                parts = {key: [] for key in parts}
            parts['physics'].append(t1 - t0)
            parts['encode'].append(t2 - t1)
            parts['publish'].append(t3 - t2)
            parts['mcap'].append(t4 - t3)
            parts['total'].append(t4 - t0)
    finally:
        if sink:
            sink.close()
        if publishers:
            publishers.close()
    result = {key: 1e3 * statistics.median(values) for key, values in parts.items()}
    result.update(n=n, steps=len(parts['total']), publish_ok=publishers is not None,
                  mcap_ok=sink is not None, backend=world.backend)
    return result


def _mcap_sink(path):
    from ball_world.recording.mcap_writer import McapSink
    return McapSink(path)


def memory_run(minutes, n, seed):
    """Run the Simulation with an McapSink for `minutes`; resident size at start and end.

    The recording goes to the null device: flat out, 1,000 balls make about 3 GB of MCAP a
    minute, and what can leak is the process's memory (the writer's chunk and message
    indexes, scratch buffers), not the file.
    """
    import psutil
    process = psutil.Process()
    simulation = _budget_simulation(n, seed, [_mcap_sink(os.devnull)])
    for _ in range(100):  # reach steady state: lists, scratch buffers, first chunk
        simulation.step()
    start = process.memory_info().rss
    peak = start
    steps = 0
    produced = 0
    began = time.monotonic()
    last_flush = began
    while time.monotonic() - began < minutes * 60.0:
        record, _ = simulation.step()
        produced += len(record.balls_cdr) + len(record.state_cdr) + len(record.stats_cdr)
        steps += 1
        now = time.monotonic()
        if now - last_flush >= 1.0:  # what the node does (FLUSH_PERIOD)
            simulation.flush()
            last_flush = now
            peak = max(peak, process.memory_info().rss)
    end = process.memory_info().rss
    simulation.close()
    return {'n': n, 'minutes': minutes, 'steps': steps, 'start_mb': start / 2 ** 20,
            'end_mb': end / 2 ** 20, 'peak_mb': max(peak, end) / 2 ** 20,
            'growth': (end - start) / start, 'produced_mb': produced / 2 ** 20}


def default_backend_line():
    """What physics.backend: auto means on this machine."""
    if numba_installed():
        from importlib.metadata import version
        return (f'Default backend: physics.backend auto = numba (numba {version("numba")} '
                'installed); both backends give bit-identical trajectories')
    return 'Default backend: physics.backend auto = numpy (numba not installed)'


# Start-up: process start to first step -----------------------------------------------

#: What a node does before its first message, timed inside a fresh interpreter.
_FIRST_STEP = """
import time
began = time.perf_counter()
from ball_world.core.scenario import build_world, DEFAULTS
world = build_world({{'physics.backend': {backend!r}}})
world.step(1.0 / DEFAULTS['rate_hz'])
print(world.backend, time.perf_counter() - began)
"""


def _first_step_seconds(backend, cache_dir):
    """Seconds from starting a Python process to the end of the default world's first step.

    The parent times the whole child (interpreter start, imports, world, step, exit): what
    a user waits for. numba's cache goes to `cache_dir` (empty: cold; filled: warm).
    """
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    began = time.perf_counter()
    done = subprocess.run([sys.executable, '-c', _FIRST_STEP.format(backend=backend)],
                          capture_output=True, text=True, env=environment, check=True)
    total = time.perf_counter() - began
    resolved, inside = done.stdout.split()
    return resolved, total, float(inside)


def bench_startup(repeats):
    """Process start to first step of the default world: numba cold, numba warm, numpy."""
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        cases = [('auto, no kernel cache (first run ever)', AUTO)]
        cases += [('auto, kernels cached', AUTO)] * repeats
        cases += [('numpy', 'numpy')] * repeats
        for label, backend in cases:
            resolved, total, inside = _first_step_seconds(backend, cache)
            rows.append((label, resolved, total, inside))
            print(f'start-up, {label} ({resolved}): {total:.2f} s to the first step '
                  f'({inside:.2f} s after the interpreter started)', flush=True)
    merged = {}
    for label, resolved, total, inside in rows:
        merged.setdefault((label, resolved), []).append((total, inside))
    return [(label, resolved, statistics.median(t for t, _ in values),
             statistics.median(i for _, i in values), len(values))
            for (label, resolved), values in merged.items()]


# Worst cases inside the limits -------------------------------------------------------

def bench_worst_case(n, steps, seed):
    """Mean ms per step (over `steps`, rebuilds of the candidate lists included) of both
    backends on the two worst cases inside core.limits at n balls."""
    rows = []
    for label, make in (('radius ratio 100', radius_spread_world),
                        (f'{limits.MAX_WALLS:,} walls', many_walls_world)):
        arrays = make(n, np.random.default_rng(seed))
        for backend in [b for b in ('numba', 'numpy') if b == 'numpy' or numba_installed()]:
            began = time.perf_counter()
            world = World(*arrays[:4], walls=arrays[4], backend=backend)
            world.step(DT)  # builds the candidate lists (and loads the kernels)
            first = time.perf_counter() - began
            began = time.perf_counter()
            substeps = sum(world.step(DT).substeps for _ in range(steps))
            elapsed = time.perf_counter() - began
            rows.append((label, len(world), len(world.walls), backend, 1e3 * first,
                         1e3 * elapsed / steps, substeps / steps))
            print(f'worst case {label}, {len(world):,} balls, {backend}: '
                  f'{rows[-1][5]:.1f} ms per step', flush=True)
    return rows


# Report ------------------------------------------------------------------------------------

def _rate(value):
    if value is None:
        return '-'
    return f'{value:,.0f}' if value >= 100 else f'{value:.3g}'


def machine_lines(pymunk, allocator):
    cpu = platform.processor() or platform.machine()
    try:
        with open('/proc/cpuinfo') as cpuinfo:
            cpu = next((line.split(':', 1)[1].strip() for line in cpuinfo
                        if line.startswith('model name')), cpu)
    except OSError:
        pass
    try:
        nproc = len(os.sched_getaffinity(0))
    except AttributeError:
        nproc = os.cpu_count()
    engines = f'numpy {np.__version__}, '
    engines += (f'pymunk {pymunk.version} (Chipmunk {pymunk.chipmunk_version.split("-")[0]})'
                if pymunk else 'pymunk not installed')
    return [f'- Machine: {nproc} CPUs (nproc), {cpu}, {platform.system()} '
            f'{platform.release()}',
            f'- Python {platform.python_version()}, {engines}',
            f'- Allocator: {allocator}',
            f'- Date: {datetime.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")}']


def markdown(results, args, pymunk, allocator, command):
    engines = results['engines']
    ours = [name for name in engines if name in OURS.values()]
    lines = ['# ball_world benchmark', '', f'Command: `{command}`', '',
             *machine_lines(pymunk, allocator), f'- {default_backend_line()}', '',
             f'Scene: N equal balls, r = {RADIUS} m, square box of side r sqrt(N pi / '
             f'{AREA_FRACTION}) ({AREA_FRACTION:.0%} area fraction), jittered-lattice start '
             f'(the same for every engine), |v| = {SPEED:g} m/s in random directions, '
             f'dt = 1/{round(1 / DT)} s, elastic, no gravity. pymunk: static segment walls, '
             'circles of mass 1 with elasticity 1 and friction 0, default iterations (10); '
             'the spatial hash has cells of one diameter and 10 N cells.', '',
             f'## Steps per second (median of {args.repeats} runs of about {args.seconds:g} s, '
             f'after {args.warmup_steps:,} warm-up steps)',
             '', '| N | ' + ' | '.join(engines) + ''.join(f' | {name} / pymunk' for name in ours)
             + ' |', '|---:|' + '---:|' * (len(engines) + len(ours))]
    for n in args.n:
        row = results['rates'].get(n, {})
        pymunks = [row[name] for name in (PYMUNK_TREE, PYMUNK_HASH) if row.get(name)]
        ratios = [f'{row[name] / max(pymunks):.3g}' if pymunks and row.get(name) else '-'
                  for name in ours]
        lines.append(f'| {n:,} | ' + ' | '.join(_rate(row.get(name)) for name in engines)
                     + ''.join(f' | {ratio}' for ratio in ratios) + ' |')
    lines += ['', 'Ratios: against the faster pymunk index at that N, measured in the same run. '
              + default_target_line(results, args)]
    smallest = min(args.n)
    row = results['rates'].get(smallest, {})
    lines += ['', f'## Fixed per-step cost at N = {smallest:,} (median time per step)', '',
              '| engine | us per step |', '|---|---:|']
    lines += [f'| {name} | {1e6 / row[name]:,.1f} |' for name in engines if row.get(name)]
    if results.get('exact'):
        lines += ['', '## Exact mode beside seed mode (numba backend)', '',
                  exact_speed.HEADER, *results['exact'], '',
                  f'Median of {args.repeats} alternating rounds of about '
                  f'{args.seconds / 2:g} s of CPU time each (`benchmarks/exact_speed.py`: '
                  'process CPU time, so waiting for a busy core does not count), after '
                  f'{exact_warm_up(args)} untimed steps. Equal disks of r = '
                  f'{exact_speed.RADIUS} m on a jittered lattice, all at one speed; targets '
                  'from issue 14.']
    if results.get('compare'):
        lines += ['', f'## The box step against the step before the static index '
                  f'({step_compare.BEFORE})', '',
                  '| N | before (steps/s) | now (steps/s) | now / before | trajectories |',
                  '|---:|---:|---:|---:|---|',
                  *[f'| {n:,} | {old:,.1f} | {new:,.1f} | {ratio:.3f} | '
                    f'{"equal" if same else "DIFFER"} |'
                    for n, old, new, ratio, same in results['compare']], '',
                  f'Numba backend, the scene above; each package in a child process of its '
                  f'own, {args.compare_rounds} alternating rounds of {args.seconds:g} s of CPU '
                  'time, medians; trajectories: the SHA-256 of both after '
                  f'{step_compare.CHECK_STEPS} steps (`benchmarks/step_compare.py`).']
    if results.get('scan'):
        lines += ['', '## Lidar: one 360-beam scan beside one physics step (median)', '',
                  lidar_speed.HEADER, *results['scan'], '', lidar_speed.NOTE]
    for section in results.get('agents', []):
        lines += ['', section, '', agents_speed.NOTE]
    if results['energy']:
        lines += ['', '## Kinetic energy', '',
                  '| engine | N | steps | relative change | balls outside the box |',
                  '|---|---:|---:|---:|---:|']
        lines += [f'| {name} | {n:,} | {steps:,} | {change:+.2e} | {escaped} |'
                  for name, n, steps, change, escaped in results['energy']]
    if results.get('startup'):
        lines += ['', '## Process start to the first step of the default world', '',
                  '| case | backend | s to first step | of which after interpreter start | runs |',
                  '|---|---|---:|---:|---:|']
        lines += [f'| {label} | {backend} | {total:.2f} | {inside:.2f} | {runs} |'
                  for label, backend, total, inside, runs in results['startup']]
        lines += ['', 'Each run is a fresh process (build_world of the default parameters, one '
                  'step); numba keeps its compiled kernels in NUMBA_CACHE_DIR, empty for the '
                  'first row. `python -m ball_world.core.warm` fills it at set-up.']
    if results.get('worst'):
        lines += ['', '## Worst cases inside core.limits (mean ms per step)', '',
                  '| world | balls | walls | backend | first step incl. build, ms | '
                  'ms per step | substeps per step |', '|---|---:|---:|---|---:|---:|---:|']
        lines += [f'| {label} | {balls:,} | {walls:,} | {backend} | {first:,.0f} | '
                  f'{per_step:,.1f} | {substeps:.1f} |'
                  for label, balls, walls, backend, first, per_step, substeps in results['worst']]
        lines += ['', f'dt = 1/{round(1 / DT)} s. Radius ratio 100: 1% of the balls of 1 m, '
                  'the rest of 1 cm, at 1 m/s. Walls: the benchmark scene plus random segments '
                  '0.3-6% of the box side long (balls they touch removed).']
    cdr = results.get('cdr')
    if cdr:
        lines += ['', f'## CDR encoding of a {cdr["count"]:,}-pose PoseArray (median)', '',
                  '| method | ms |', '|---|---:|',
                  f'| ball_world.msgs.cdr.encode_pose_array | {cdr["ours_ms"]:.3f} |']
        if 'rclpy_ms' in cdr:
            lines += [f'| PoseArray pose by pose + rclpy serialize_message | '
                      f'{cdr["rclpy_ms"]:.1f} |', '',
                      f'Ratio: {cdr["rclpy_ms"] / cdr["ours_ms"]:,.0f}x; decoded values equal: '
                      f'{"yes" if cdr["same_values"] else "NO"}.']
    if results['budget']:
        lines += ['', '## Node per-step budget (median ms per step, default backend '
                  f'{results["budget"][0]["backend"]})', '',
                  '| N | physics | encode | publish | MCAP record | total | steps timed |',
                  '|---:|---:|---:|---:|---:|---:|---:|']
        for b in results['budget']:
            publish = f'{b["publish"]:.3f}' if b['publish_ok'] else '-'
            mcap = f'{b["mcap"]:.3f}' if b['mcap_ok'] else '-'
            lines.append(f'| {b["n"]:,} | {b["physics"]:.3f} | {b["encode"]:.3f} | {publish} | '
                         f'{mcap} | {b["total"]:.3f} | {b["steps"]} |')
        lines += ['', 'encode: Simulation.record (state copies, energy and momentum, PoseArray, '
                  'state and stats CDR); publish: rclpy publish() of those three byte strings '
                  'with no subscriber; MCAP record: McapSink.write_step (lz4) to a temporary '
                  'file; total: median of the per-step sums. The scenario places the balls '
                  '(random, non-overlapping), all at the scene speed.']
    memory = results.get('memory')
    if memory:
        lines += ['', f'## Memory: {memory["n"]:,} balls recorded to MCAP for '
                      f'{memory["minutes"]:g} min', '',
                  f'{memory["steps"]:,} steps; resident {memory["start_mb"]:.1f} MiB at start, '
                  f'{memory["end_mb"]:.1f} MiB at end (growth {memory["growth"]:+.1%}, peak '
                  f'{memory["peak_mb"]:.1f} MiB); {memory["produced_mb"]:,.0f} MiB of messages '
                  'recorded (uncompressed, to the null device).']
    return '\n'.join(lines) + '\n'


def default_target_line(results, args):
    """Whether the default backend is at least TARGET_VS_PYMUNK x pymunk at every N."""
    default = OURS[resolve_backend(AUTO)]
    ratios = {}
    for n in args.n:
        row = results['rates'].get(n, {})
        pymunks = [row[name] for name in (PYMUNK_TREE, PYMUNK_HASH) if row.get(name)]
        if pymunks and row.get(default):
            ratios[n] = row[default] / max(pymunks)
    if not ratios:
        return ''
    missed = [f'N = {n:,} ({ratio:.2f}x)' for n, ratio in ratios.items()
              if ratio < TARGET_VS_PYMUNK]
    return (f'Target (issue 11): the default backend ({default}) at least '
            f'{TARGET_VS_PYMUNK:g}x pymunk at every N: '
            + (f'missed at {", ".join(missed)}.' if missed else 'met at every N timed.'))


def plot(results, args, path):
    """steps/s against N, log-log, one line per engine, and ideal O(N) from our N=1000."""
    from matplotlib.figure import Figure
    figure = Figure(figsize=(7.5, 5.0), layout='constrained')
    axes = figure.subplots()
    for name in results['engines']:
        points = [(n, results['rates'][n][name]) for n in args.n
                  if results['rates'].get(n, {}).get(name)]
        if points:
            axes.plot(*zip(*points), marker='o', label=name)
    default = OURS[resolve_backend(AUTO)]
    ours = {n: results['rates'][n][default] for n in args.n if results['rates'][n].get(default)}
    if ours:
        anchor = min(ours, key=lambda n: abs(math.log(n / 1000)))
        ns = np.array(sorted(args.n), dtype=float)
        axes.plot(ns, ours[anchor] * anchor / ns, linestyle='--', color='grey',
                  label=f'linear scaling from {default} at N={anchor:,}')
    axes.set_xscale('log')
    axes.set_yscale('log')
    axes.set_xlabel('balls N')
    axes.set_ylabel('steps per second (median)')
    axes.set_title(f'2D elastic balls, {AREA_FRACTION:.0%} area fraction, dt = 1/{round(1 / DT)}'
                   ' s')
    axes.grid(True, which='both', alpha=0.3)
    axes.legend()
    image = io.BytesIO()
    figure.savefig(image, format='png', dpi=120)
    write_file(path, image.getvalue(), overwrite=True)


# Command line ------------------------------------------------------------------------------

def parse_args(argv):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.bench',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('--n', type=int, nargs='+', default=[100, 1000, 10000, 100000],
                        help='ball counts (default 100 1000 10000 100000)')
    parser.add_argument('--repeats', type=int, default=5, help='timed runs per engine and N')
    parser.add_argument('--seconds', type=float, default=1.0,
                        help='target length of one timed run, s (default 1)')
    parser.add_argument('--engines', nargs='+', choices=list(ENGINE_CHOICES),
                        default=list(ENGINE_CHOICES), help='engines to time (default all)')
    parser.add_argument('--warmup-steps', type=int, default=240,
                        help='untimed steps before timing each engine (default 240, 1 s)')
    parser.add_argument('--energy-steps', type=int, default=2000)
    parser.add_argument('--energy-n', type=int, default=1000,
                        help='N of the energy measurement (default 1000)')
    parser.add_argument('--energy-all', action='store_true',
                        help='measure the energy change at every N')
    parser.add_argument('--cdr-poses', type=int, default=10000)
    parser.add_argument('--budget-n', type=int, nargs='*', default=[1000, 10000],
                        help='N of the per-step budget (default 1000 10000; none to skip)')
    parser.add_argument('--exact-n', type=int, nargs='*', default=[1000, 10000],
                        help='N of the dilute and dense scenes of exact mode beside seed mode '
                             '(default 1000 10000; none to skip them)')
    parser.add_argument('--scan-n', type=int, nargs='*', default=[1000, 10000, 100000],
                        help='N of the lidar scan beside a step (default 1000 10000 100000; '
                             'none to skip)')
    parser.add_argument('--agents-n', type=int, nargs='*', default=[10000],
                        help='N of the per-step cost of 0, 10 and 100 agents (default 10000; '
                             'none to skip)')
    parser.add_argument('--compare-n', type=int, nargs='*', default=[1000, 10000, 100000],
                        help='N of the box step against the step before the static index '
                             f'({step_compare.BEFORE}, side by side: benchmarks/step_compare.py'
                             '; default 1000 10000 100000; none to skip)')
    parser.add_argument('--compare-rounds', type=int, default=7,
                        help='alternating rounds of that comparison (default 7)')
    parser.add_argument('--no-exact', action='store_true',
                        help='do not time exact mode beside seed mode')
    parser.add_argument('--no-extras', action='store_true',
                        help='time the engines only: no energy, CDR or budget sections')
    parser.add_argument('--memory-minutes', type=float, default=0.0,
                        help='also record 1,000 balls to MCAP for M minutes; report RSS growth')
    parser.add_argument('--startup', action='store_true',
                        help='also time process start to first step, numba cold and warm')
    parser.add_argument('--worst-case', action='store_true',
                        help='also time both backends on the worst worlds inside core.limits')
    parser.add_argument('--worst-case-n', type=int, default=limits.MAX_BALLS,
                        help=f'balls of the worst-case worlds (default {limits.MAX_BALLS:,})')
    parser.add_argument('--no-tune-allocator', action='store_true',
                        help="leave glibc malloc's thresholds at their defaults")
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--docs', action='store_true',
                        help='write the tables and the plot over the tracked docs/bench.md and '
                             'docs/bench.png (default: runs/, so a checkout stays clean)')
    parser.add_argument('--plot', type=Path, default=None,
                        help='write the plot to this file (default runs/bench.png)')
    parser.add_argument('--markdown', type=Path, default=None,
                        help='write the tables to this file (default runs/bench.md)')
    parser.add_argument('--quick', action='store_true',
                        help='a tiny configuration (N = 100, 300; short runs) for tests')
    args = parser.parse_args(argv)
    output = Path('docs' if args.docs else 'runs')
    args.plot = output / 'bench.png' if args.plot is None else args.plot
    args.markdown = output / 'bench.md' if args.markdown is None else args.markdown
    if args.quick:
        args.n, args.repeats, args.seconds, args.warmup_steps = [100, 300], 2, 0.05, 20
        args.energy_n, args.energy_steps, args.cdr_poses, args.budget_n = 300, 500, 1000, [300]
        args.exact_n, args.scan_n, args.agents_n = [300], [300], [300]
        args.compare_n = []  # it compiles a second package's kernels
    if (any(n < 1 for n in args.n) or args.repeats < 1 or args.seconds <= 0.0
            or args.warmup_steps < 0):
        parser.error('--n values and --repeats must be >= 1, --seconds > 0 and '
                     '--warmup-steps >= 0')
    return args


#: Agents timed per step beside the same world without them (issue 21: 100 agents).
AGENT_COUNTS = (0, 10, 100)


def exact_warm_up(args):
    """Untimed steps before exact and seed mode are timed: enough to mix the lattice start."""
    return min(args.warmup_steps, 50)


def _import_pymunk():
    try:
        import pymunk
    except ImportError:
        print('pymunk not installed: comparing without it (pip install pymunk==7.3.1)')
        return None
    return pymunk


def run_engines(args, pymunk):
    names = [ENGINE_CHOICES[key] for key in args.engines]
    if pymunk is None:
        names = [name for name in names if name not in (PYMUNK_TREE, PYMUNK_HASH)]
    if not numba_installed():
        print('numba not installed: timing the numpy backend only')
        names = [name for name in names if name != OURS_NUMBA]
    results = {'engines': names, 'rates': {}, 'energy': []}
    for n in args.n:
        scene = Scene(n, args.seed)
        row = results['rates'].setdefault(n, {})
        for name in names:
            engine = make_engine(name, scene, pymunk)
            row[name], rates = steps_per_second(engine, args.seconds, args.repeats,
                                                args.warmup_steps)
            print(f'N={n:,} {name}: {_rate(row[name])} steps/s (runs: '
                  f'{", ".join(_rate(r) for r in rates)})', flush=True)
    if not args.no_extras:
        for n in (args.n if args.energy_all else [args.energy_n]):
            scene = Scene(n, args.seed)
            for name in names:
                change, escaped = energy_change(make_engine(name, scene, pymunk),
                                                args.energy_steps)
                results['energy'].append((name, n, args.energy_steps, change, escaped))
                print(f'N={n:,} {name}: relative energy change {change:+.2e} after '
                      f'{args.energy_steps:,} steps, {escaped} outside the box', flush=True)
    return results


def main(argv=None):
    args = parse_args(argv)
    command = ' '.join(['python -m benchmarks.bench',
                        *(sys.argv[1:] if argv is None else argv)])
    if args.no_tune_allocator:
        allocator = 'glibc defaults (--no-tune-allocator)'
    elif tune_allocator():
        allocator = (f'tuned (mallopt: mmap threshold {MMAP_THRESHOLD_BYTES >> 20} MiB, trim '
                     f'threshold {TRIM_THRESHOLD_BYTES >> 20} MiB)')
    else:
        allocator = 'not tuned (not glibc, or mallopt refused)'
    pymunk = _import_pymunk()
    results = run_engines(args, pymunk)
    if args.compare_n and numba_installed():
        results['compare'] = step_compare.compare(
            args.compare_n, args.compare_rounds, args.seconds,
            out=lambda line: print(f'box step against {step_compare.BEFORE}: {line}',
                                   flush=True))
    if not args.no_exact and numba_installed():
        results['exact'] = []
        for line in exact_speed.rows(args.exact_n, args.repeats, args.seconds / 2,
                                     exact_warm_up(args)):
            print(f'exact beside seed: {line}', flush=True)
            results['exact'].append(line)
    results['scan'] = lidar_speed.rows(args.scan_n, args.repeats, args.seed)
    results['agents'] = [agents_speed.report(n, agents_speed.run(
        n, AGENT_COUNTS, 20 if args.quick else 200, args.seed)) for n in args.agents_n]
    if not args.no_extras:
        results['cdr'] = bench_cdr(args.cdr_poses, args.repeats)
        with tempfile.TemporaryDirectory() as directory:
            results['budget'] = [bench_budget(n, 2.0 * args.seconds, args.seed, directory)
                                 for n in args.budget_n]
    else:
        results['budget'] = []
    if args.startup:
        results['startup'] = bench_startup(max(1, args.repeats // 2))
    if args.worst_case:
        results['worst'] = bench_worst_case(args.worst_case_n, 20, args.seed)
    if args.memory_minutes > 0.0:
        results['memory'] = memory_run(args.memory_minutes, 1000, args.seed)
    table = markdown(results, args, pymunk, allocator, command)
    print()
    print(table, end='')
    try:
        if args.markdown:
            args.markdown.parent.mkdir(parents=True, exist_ok=True)
            write_file(args.markdown, table, overwrite=True)
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(results, args, args.plot)
    except ImportError:
        print('matplotlib not installed: no plot (pip install matplotlib)')
    except OSError as error:  # recording.files.FileRefused names its path
        print(f'ball_world_bench: {error}', file=sys.stderr)
        return 2
    else:
        print(f'plot: {args.plot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
