"""What a map of a real building costs: loading it, stepping balls among its cells, scanning it.

Issue 27's figures, measured on a generated warehouse (benchmarks.warehouse: 45 m x 36 m at
3 cm, 1.8 million cells, about 25,000 boundary runs) against an open box of the same free
area holding the same balls (same count, radii, speeds and seed: the scenario's random
placement, in the map's free cells or in the box):

- load: the map's files read and decoded (ball_world.map_files, nav2_map_server's rules),
  its solid cells, the static geometry a World builds from them (boundary runs and their
  bucket index, core.static_geometry), and what the first compiled step and the first
  compiled scan add (the index dilated by the balls' reach, the free squares the lidar's
  walk skips by); wall-clock time, best of a few.
- step: one seed-mode step (numba, the default backend) in the warehouse over one in the box;
  exact mode likewise.
- scan: one 360-beam scan (0.1-12 m, no noise) from each of SCANNERS balls in the warehouse
  over the same in the box.

Ratios come from one run, timed in alternating rounds (a busy core slows both worlds alike),
in the thread's CPU time (time.thread_time), as benchmarks.lidar_speed does. Never a timed
assertion: this prints a table for docs/performance.md.

`python -m benchmarks.map_speed` (options: --balls, --scan-balls, --repeats, --keep DIR).
"""
import argparse
import math
import statistics
import sys
import tempfile
import time

from benchmarks import warehouse
import numpy as np

from ball_world.core import lidar
from ball_world.core.scenario import build_scene
from ball_world.core.solid_cells import CellQueries
from ball_world.core.static_geometry import StaticGeometry
from ball_world.core.world import Walls, World
from ball_world.map_files import load_map_file

#: Balls that scan, per world (the first ones).
SCANNERS = 20
FAN = lidar.Fan.full_turn(360, range_min=0.1, range_max=12.0)
#: The balls: the scenario's random balls, radius 0.05-0.1 m, up to 1 m/s, stepped at 100 Hz.
RADIUS = (0.05, 0.1)
SPEED = 1.0
DT = 0.01


def _parameters(count, seed, arena):
    return {'random.count': count, 'random.seed': seed, 'random.radius': list(RADIUS),
            'random.speed': SPEED, 'arena': arena, 'dt': DT}


def load(yaml_path, repeats):
    """Best wall-clock seconds of (read and decode, solid cells, static geometry, dilated
    index, free squares), and the map, its solid cells and their static geometry."""
    best = [math.inf] * 5
    lidar.lidar_kernel.free_squares(np.zeros((2, 2), dtype=np.uint8))  # compiled first
    for _ in range(repeats):
        began = time.perf_counter()
        occupancy_map = load_map_file(str(yaml_path))
        decoded = time.perf_counter()
        cells = occupancy_map.solid_cells().checked()
        solid = time.perf_counter()
        static = StaticGeometry(Walls(()), cells)
        built = time.perf_counter()
        static.dilated(RADIUS[1] + 2.0 * RADIUS[0])  # as numba_backend asks: r + skin
        dilated = time.perf_counter()
        lidar.lidar_kernel.free_squares(static.scan_grid.solid)
        squares = time.perf_counter()
        for k, seconds in enumerate((decoded - began, solid - decoded, built - solid,
                                     dilated - built, squares - dilated)):
            best[k] = min(best[k], seconds)
    return best, occupancy_map, cells, static


def worlds(occupancy_map, cells, count, seed, mode='seed'):
    """(warehouse World, box World): the same random balls placed in the map's free cells
    and in a box of the same free area."""
    params = _parameters(count, seed, [])
    scene = build_scene({**params, 'map': 'warehouse.yaml'}, occupancy_map)
    inside = scene.world
    in_map = World(inside.positions, inside.velocities, inside.radii, inside.masses,
                   mode=mode, solid_cells=cells)
    side = math.sqrt(CellQueries(cells).free_area())
    boxed = build_scene(_parameters(count, seed, [0.0, 0.0, side, side])).world
    in_box = World(boxed.positions, boxed.velocities, boxed.radii, boxed.masses,
                   walls=boxed.walls.segments, mode=mode)
    return in_map, in_box


def _cpu_seconds(call, inner):
    began = time.thread_time()
    for _ in range(inner):
        call()
    return (time.thread_time() - began) / inner


def alternate(calls, repeats, inner):
    """(median, least) CPU seconds per call of each of `calls` (name -> function), in
    alternating rounds of `inner` calls. The least is the round the other processes of a
    shared machine disturbed least (its caches, its cores)."""
    times = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            times[name].append(_cpu_seconds(call, inner))
    return {name: (statistics.median(values), min(values)) for name, values in times.items()}


#: Steps per timed round of a step: seed mode rebuilds its candidate lists every 3-4 steps
#: at 1 m/s, so a round of 5 was one rebuild more or less, and its least round compared a
#: map round with rebuilds to a box round without (ratios of 1.4 and 2.2 in one run); 20
#: steps hold several rebuilds of each world.
STEP_ROUND = 20


def steps(in_map, in_box, repeats, warm_up=20):
    """(median, least) CPU seconds per step in the warehouse and in the box."""
    for world in (in_map, in_box):
        for _ in range(warm_up):
            world.step(DT)
    medians = alternate({'map': lambda: in_map.step(DT), 'box': lambda: in_box.step(DT)},
                        repeats, STEP_ROUND)
    return medians['map'], medians['box']


def scans(in_map, in_box, repeats):
    """(median, least) CPU seconds of one scan (averaged over the SCANNERS first balls) in
    the warehouse and in the box."""
    scanner = lidar.Scanner(FAN, 'auto')

    def scan_all(world):
        grid = world.static.scan_grid
        for ball in range(min(SCANNERS, len(world))):
            scanner.distances(world.positions, world.radii, world.walls,
                              world.positions[ball], 0.3 * ball, ball, grid)

    for world in (in_map, in_box):
        scan_all(world)  # compiled, and the map's chessboard distances made, before timing
    medians = alternate({'map': lambda: scan_all(in_map), 'box': lambda: scan_all(in_box)},
                        repeats, 2)
    count = min(SCANNERS, len(in_map))
    return (tuple(value / count for value in medians['map']),
            tuple(value / count for value in medians['box']))


def report(args):
    """The markdown lines of the whole measurement."""
    lines = []
    with tempfile.TemporaryDirectory() as scratch:
        directory = args.keep or scratch
        yaml_path = warehouse.write(directory)
        seconds, occupancy_map, cells, static = load(yaml_path, args.repeats)
    rows, columns = cells.solid.shape
    lines += ['| map | cells | solid | boundary runs | index buckets | read and decode, s | '
              'solid cells, s | runs and index, s | dilated index, s | free squares, s | '
              'total, s |', '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|',
              f'| warehouse {columns} x {rows} at {warehouse.RESOLUTION} m | {rows * columns:,} | '
              f'{float(cells.solid.mean()):.1%} | {static.run_count:,} | '
              f'{static.index.columns * static.index.rows:,} ({static.index.size:.2f} m) | '
              + ' | '.join(f'{value:.3g}' for value in seconds)
              + f' | {sum(seconds):.3g} |', '']
    print('\n'.join(lines), flush=True)
    table = ['| balls | mode | warehouse, ms per step | open box, ms per step | ratio | '
             'ratio of the least |', '|---:|---|---:|---:|---:|---:|']
    for count in args.balls:
        for mode in args.modes:
            in_map, in_box = worlds(occupancy_map, cells, count, args.seed, mode)
            table.append(_row(count, mode, *steps(in_map, in_box, args.repeats)))
            print(table[-1], flush=True)
    lines += table + ['']
    table = ['| balls | warehouse, ms per scan | open box, ms per scan | ratio | '
             'ratio of the least |', '|---:|---:|---:|---:|---:|']
    for count in args.scan_balls:
        in_map, in_box = worlds(occupancy_map, cells, count, args.seed)
        for world in (in_map, in_box):
            for _ in range(10):
                world.step(DT)
        table.append(_row(count, None, *scans(in_map, in_box, args.repeats)))
        print(table[-1], flush=True)
    return lines + table


def _row(count, mode, in_map, in_box):
    """A table row: medians (ms), their ratio, and the ratio of the least rounds."""
    cells = [f'{count:,}'] + ([mode] if mode else [])
    cells += [f'{1e3 * in_map[0]:.4f}', f'{1e3 * in_box[0]:.4f}',
              f'{in_map[0] / in_box[0]:.2f}', f'{in_map[1] / in_box[1]:.2f}']
    return '| ' + ' | '.join(cells) + ' |'


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.map_speed',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('--balls', type=int, nargs='+', default=[10_000])
    parser.add_argument('--modes', nargs='+', choices=('seed', 'exact'),
                        default=['seed', 'exact'])
    parser.add_argument('--scan-balls', type=int, nargs='+', default=[1_000, 10_000])
    parser.add_argument('--repeats', type=int, default=7)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--keep', help='write the warehouse map here (else a temporary '
                                       'directory)')
    args = parser.parse_args(argv)
    print('\n'.join(['', *report(args)]))
    return 0


if __name__ == '__main__':
    sys.exit(main())
