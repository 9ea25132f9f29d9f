"""The agents' lidar scans of a step: when they are due, their ranges, their LaserScan bytes.

The Simulation asks `AgentScans.take` once per recorded step. A scan is due at step 0 and
at every step whose end crosses a multiple of the scan period (1 / agent.scan.rate_hz of
simulated time, in integer nanoseconds), so the rate never depends on the wall clock. Each
agent scans from its centre along its heading at the end of the step (core.lidar, its own
ball excluded, the map's cells seen: world.static.scan_grid), stamped with that step's time
in its `<p><name>/base_link` frame, as REP 117 says: +inf for nothing within range_max,
-inf for closer than range_min. The noise is
seeded by (random.seed, the agent's name, the step), so a re-simulation draws it again.

agent.scan.range_min 0 means 0.05 m beyond each agent's own radius (a scanner on a ball
would otherwise see its own ball's surface, which the exclusion already hides, and a
range_min below it means nothing). Bytes are made here once and shared by the publisher
and the recording, like the other messages of a step.
"""
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
import os
import threading
from typing import NamedTuple

import numpy as np

from ball_world.core import lidar
from ball_world.core.noise_seed import EntropyRows
from ball_world.core.parameters import ParameterError
from ball_world.core.static_geometry import ScanGrid
from ball_world.msgs.agent_cdr import encode_laser_scan, encode_laser_scans

#: range_min beyond the agent's radius when agent.scan.range_min is 0.
CLEARANCE = 0.05


class AgentScan(NamedTuple):
    """One agent's scan of a step."""

    name: str
    frame_id: str  # <p><name>/base_link
    ranges: np.ndarray  # float64, REP 117, noise added
    fan: lidar.Fan
    cdr: bytes  # sensor_msgs/msg/LaserScan, as published on <name>/scan


class ScanTable(Sequence):
    """The scans of a step that nobody encodes (a swarm's, or scans nobody subscribes to):
    every agent's ranges as one (N, beams) table, read as AgentScans (cdr b'') made only
    when someone iterates them. Why: as step_record.TakenCommands, an object per robot a
    step cost a 10,000-robot swarm more than its scans."""

    __slots__ = ('names', 'frames', 'table', 'fans')

    def __init__(self, names, frames, table, fans):
        self.names = names
        self.frames = frames
        self.table = table  # float64 (N, beams), REP 117, noise added
        self.fans = fans  # lidar.Fan per agent (range_min follows each radius)

    def __iter__(self):
        for name, frame_id, ranges, fan in zip(self.names, self.frames, self.table, self.fans):
            yield AgentScan(name, frame_id, ranges, fan, b'')

    def __len__(self):
        return len(self.names)

    def __getitem__(self, index):
        return tuple(self)[index]


def fan_from(parameters, radius):
    """The Fan of an agent of `radius` under the agent.scan.* parameters (ParameterError
    naming the parameter that cannot make one)."""
    samples = int(parameters['agent.scan.samples'])
    angle_min = float(parameters['agent.scan.angle_min'])
    angle_max = float(parameters['agent.scan.angle_max'])
    increment = (angle_max - angle_min) / (samples - 1) if samples > 1 else 0.0
    range_max = float(parameters['agent.scan.range_max'])
    range_min = float(parameters['agent.scan.range_min']) or radius + CLEARANCE
    fan = lidar.Fan(angle_min, increment, samples, min(range_min, range_max), range_max,
                    float(parameters['agent.scan.noise_stddev']))
    if not range_max > 0.0:
        raise ParameterError('agent.scan.range_max', f'must be > 0, got {range_max:g}')
    if float(parameters['agent.scan.range_min']) > range_max:
        raise ParameterError('agent.scan.range_min', f'{range_min:g} m is beyond '
                                                     f'agent.scan.range_max {range_max:g} m')
    return fan


def scan_grid(parameters, occupancy_map):
    """The map's cells as the agents' scans walk them in a world of these parameters and
    this map (the World's `static.scan_grid`, equal cell for cell), without building the
    world; lidar.NO_MAP without a map.

    Why: whoever re-computes what a scan could see from a recording (ball_world_score) must
    let the map's cells hide balls exactly as the live scan did; building the whole world
    again (its random balls placed among the cells) only to reach its grid would double the
    cost of reading a map world's recording.
    """
    if not parameters['map']:
        return lidar.NO_MAP
    if occupancy_map is None:
        raise ValueError(f"map names {parameters['map']!r}, but no map was given")
    return ScanGrid(occupancy_map.solid_cells(parameters['map.unknown_solid']).checked())


def check(parameters):
    """Refuse agent.scan.* values that cannot make a scanner (ParameterError)."""
    if int(parameters['agent.scan.samples']) > 0:
        try:
            fan_from(parameters, 0.0).check()
        except ParameterError:
            raise
        except ValueError as error:  # Fan's own refusal, should the table's ranges allow one
            raise ParameterError('agent.scan', str(error)) from None


#: Most threads the scans of a step share (the cores this process may use, at most this).
MAX_SCAN_THREADS = 8


class ScanPool:
    """Threads that scan runs of agents at once (lidar.scan_many's `pool`), the calling
    thread and one more per other core this process may use: the compiled scan holds no
    GIL, so 1,000 robots' lidars can take both cores of a 2-core machine for the scan
    step's burst instead of one (docs/performance.md). Each thread takes the next run
    until none is left, so when the other cores are busy (other processes), the calling
    thread does most of the runs itself rather than wait. One a process (`shared`); its
    threads start when a step first has scans enough to share (lidar.agent_runs: never for
    one robot's scan), wait idle between scan steps and end with the interpreter. The
    ranges are the same bits with or without it (test_ring_scan)."""

    _shared = None
    _lock = threading.Lock()

    def __init__(self, threads):
        self.threads = threads
        self._executor = ThreadPoolExecutor(threads - 1, thread_name_prefix='ball_world_scan')

    def run(self, function, items):
        """function(item) for every item, on this thread and the pool's; returns when all
        are done (re-raising the first failure)."""
        items = iter(items)
        taking = threading.Lock()

        def work():
            while True:
                with taking:
                    item = next(items, None)
                if item is None:
                    return
                function(item)

        helpers = [self._executor.submit(work) for _ in range(self.threads - 1)]
        try:
            work()
        finally:
            for helper in helpers:  # none may still write once this returns
                helper.result()

    @classmethod
    def _forget(cls):
        """In a forked child: the parent's threads are not there, so its pool would take
        runs that no thread ever scans; the child makes its own when it needs one."""
        cls._shared = None
        cls._lock = threading.Lock()

    @classmethod
    def shared(cls):
        """The process's pool, or None on one core."""
        with cls._lock:
            if cls._shared is None:
                try:
                    cores = len(os.sched_getaffinity(0))
                except AttributeError:  # not Linux
                    cores = os.cpu_count() or 1
                threads = min(cores, MAX_SCAN_THREADS)
                cls._shared = cls(threads) if threads > 1 else False
            return cls._shared or None


if hasattr(os, 'register_at_fork'):
    os.register_at_fork(after_in_child=ScanPool._forget)


class AgentScans:
    """The scanners of a Simulation's agents, made from its parameters."""

    def __init__(self, parameters):
        self.parameters = parameters
        self.samples = int(parameters['agent.scan.samples'])
        self.period_ns = max(1, round(1e9 / float(parameters['agent.scan.rate_hz'])))
        self.seed = int(parameters['random.seed'])
        self._scanners = {}  # name -> (radius, lidar.Scanner)
        self._last = None  # [names, radii, scanners, their EntropyRows or None] of the last
        # scan: most steps reuse it
        self.pool = ScanPool.shared  # () -> lidar.scan_many's pool (None: one thread)

    def due(self, step_index, dt_ns):
        """Whether step `step_index` (ending at step_index * dt_ns) is a scan step."""
        if self.samples == 0:
            return False
        end = step_index * dt_ns
        return step_index == 0 or end // self.period_ns != (end - dt_ns) // self.period_ns

    def scanner(self, name, radius):
        """Agent `name`'s Scanner, made again when its radius changed (range_min follows it)."""
        kept = self._scanners.get(name)
        if kept is None or kept[0] != radius:
            kept = self._scanners[name] = (radius, lidar.Scanner(
                fan_from(self.parameters, radius), 'auto', self.seed, name))
        return kept[1]

    def take(self, world, names, indices, yaws, base_frames, step_index, stamp_ns, dt_ns,
             encode=True):
        """The scans of this step (a tuple of AgentScan; empty when none is due); their
        LaserScan bytes b'' unless `encode` (nobody takes them)."""
        if not self.due(step_index, dt_ns):
            return ()
        radii = world.radii[indices].tolist()
        last = self._last
        if last is not None and last[0] == names and last[1] == radii:
            scanners, entropy = last[2], last[3]
        else:
            scanners = [self.scanner(name, radius) for name, radius in zip(names, radii)]
            entropy = None  # made at the first noisy batch
            self._last = [names, radii, scanners, entropy]
        if scanners and scanners[0].backend == 'numba':
            # Every agent's scan in one compiled call (lidar.scan_many: the same ranges as
            # one scan each, bit for bit, at a fraction of the cost when the range is short
            # and the robots many: benchmarks/ring_scan.py).
            stddev = scanners[0].fan.noise_stddev
            noise = None
            if stddev > 0.0:
                if entropy is None:
                    entropy = self._last[3] = EntropyRows.of(
                        (scanner.seed, scanner.key) for scanner in scanners)
                noise = _run_noise(entropy, step_index, stddev, len(scanners))
            range_mins = [scanner.fan.range_min for scanner in scanners]
            table = lidar.scan_many(world.positions, world.radii, world.walls, indices, yaws,
                                    scanners[0].fan, range_mins, 'numba',
                                    world.static.scan_grid, self.pool(), noise)
            if not encode:
                return ScanTable(names, base_frames, table,
                                 [scanner.fan for scanner in scanners])
            # Their LaserScan bytes at once too (encode_laser_scans: each robot's bytes
            # as encode_laser_scan makes them, noise and all already in the table).
            fan = scanners[0].fan
            cdrs = encode_laser_scans(stamp_ns, base_frames, fan.angle_min, fan.angle_max,
                                      fan.angle_increment, 0.0, self.period_ns * 1e-9,
                                      range_mins, fan.range_max, table)
            return tuple(AgentScan(name, frame_id, ranges, scanner.fan, cdr)
                         for name, scanner, frame_id, ranges, cdr
                         in zip(names, scanners, base_frames, table, cdrs))
        else:
            ranges_of = (scanner.distances(world.positions, world.radii, world.walls,
                                           world.positions[index], float(yaw), int(index),
                                           world.static.scan_grid)
                         for scanner, index, yaw in zip(scanners, indices, yaws))
        scans = []
        period = self.period_ns * 1e-9
        for name, scanner, frame_id, ranges in zip(names, scanners, base_frames, ranges_of):
            fan = scanner.fan
            if fan.noise_stddev > 0.0:
                lidar.add_noise(ranges, fan.noise_stddev, scanner.noise.generator(step_index))
            cdr = encode_laser_scan(stamp_ns, frame_id, fan.angle_min, fan.angle_max,
                                    fan.angle_increment, 0.0, period, fan.range_min,
                                    fan.range_max, ranges) if encode else b''
            scans.append(AgentScan(name, frame_id, ranges, fan, cdr))
        return tuple(scans)


def _run_noise(entropy, step_index, stddev, count):
    """lidar.scan_many's `then` for `count` agents' scans at step_index: each run of agents
    noised on the thread that scanned it (core.noise_kernel: every scanner's
    default_rng([seed, key, step]) draws, bit for bit; the kernel holds no GIL either), so
    1,000 lidars' noise (4 ms a scan step) is shared by the scan pool's threads too."""
    steps = np.full(count, step_index)

    def noise(low, high, rows):
        entropy.add_noise(rows, slice(low, high), steps[low:high], stddev)
    return noise


def hit_points(scan, x, y, yaw):
    """World coordinates (K, 2) of a scan's finite ranges (for drawing it)."""
    return lidar.hit_points((x, y), yaw, scan.fan, scan.ranges)
