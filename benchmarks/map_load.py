"""How long a map takes to load: the loader alone, and the node from its start to its first step.

    .venv/bin/python -m benchmarks.map_load [--repeat 5]

The maps: the two real ones shipped in maps/ (TurtleBot3 sandbox, 147,456 cells; depot,
185,428 cells), a warehouse at 3 cm made here, 2048 x 1024 = 2,097,152 cells (a PGM of
walls, shelves and unknown border, like a SLAM map), and issue 27's warehouse
(benchmarks.warehouse, 1500 x 1200 at 3 cm, the one benchmarks.map_speed measures), last also
with the real-time case of benchmarks.map_agents (1,000 balls, 100 diff-drive agents scanning
360 beams: its first step scans, so it includes the lidar's free squares). The loader's time
is read_map_files + load_map (decode, cells) and the world's CellQueries, the median of
--repeat runs; the
node's is the wall time of `ball_world -p max_steps:=1` (process start to its first step and
exit) with the map and without, so their difference is what the map costs a start (on a
loaded machine that difference drowns in the start's noise); the world's build in this process
(a Simulation: files read, decoded, cells, placement, the World's static geometry, /map
encoded) is what the node does between its start and its first step.

`--worst` measures the worst maps inside the limits instead (issue 33): a checkerboard of 5 cm
cells with exactly limits.MAX_MAP_RUNS boundary runs (1024 x 1024: every cell its own block),
the largest map (4096 x 4096) with 2% speckle (a raw SLAM map), and a checkerboard two rows
and columns larger, which must be refused in one line. For each: the world's build in this
process (CPU seconds and the growth of this process's peak RSS) and the node from start to
first step with 1,000 random balls (wall seconds, and the largest peak RSS of the children so
far), after the node without a map for comparison.
"""
import argparse
import os
from pathlib import Path
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks import warehouse as generated
import numpy as np

from ball_world.core import limits
from ball_world.core.parameters import DEFAULTS
from ball_world.core.solid_cells import CellQueries
from ball_world.map_files import load_map_file
from ball_world.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]


def warehouse(folder, columns=2048, rows=1024):
    """A 3 cm warehouse map of walls, aisles of shelves and an unknown border."""
    pixels = np.full((rows, columns), 254, dtype=np.uint8)
    pixels[:8, :] = pixels[-8:, :] = 205
    pixels[:, :8] = pixels[:, -8:] = 205
    pixels[8:12, 8:-8] = pixels[-12:-8, 8:-8] = 0
    pixels[8:-8, 8:12] = pixels[8:-8, -12:-8] = 0
    for x in range(120, columns - 120, 90):  # shelves: 0.9 m deep, aisles of 1.8 m
        pixels[100:rows - 100, x:x + 30] = 0
    rng = np.random.default_rng(0)
    pixels[rng.random((rows, columns)) < 0.002] = 0  # clutter, as SLAM leaves it
    (folder / 'warehouse.pgm').write_bytes(f'P5\n{columns} {rows}\n255\n'.encode()
                                           + pixels.tobytes())
    (folder / 'warehouse.yaml').write_text('image: warehouse.pgm\nmode: trinary\n'
                                           'resolution: 0.03\norigin: [-5.0, -5.0, 0]\n'
                                           'negate: 0\noccupied_thresh: 0.65\n'
                                           'free_thresh: 0.25\n')
    return folder / 'warehouse.yaml'


def loader_seconds(path, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        occupancy = load_map_file(str(path))
        CellQueries(occupancy.solid_cells())
        times.append(time.perf_counter() - start)
    return statistics.median(times), occupancy


def build_seconds(repeat, **values):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        Simulation({**DEFAULTS, 'random.count': 20, **values})
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def node_seconds(repeat, *parameters):
    node = Path(sys.prefix) / 'bin' / 'ball_world'
    times = []
    for _ in range(repeat):
        command = [str(node), '--ros-args', '-p', 'max_steps:=1', '-p', 'rate_hz:=0.0',
                   '-p', 'dt:=0.01', '-p', 'markers.rate_hz:=0.0']
        for parameter in parameters:
            command += ['-p', parameter]
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def write_pgm(folder, name, pixels, resolution=0.05):
    """A trinary map of `pixels` (0 occupied, 254 free), its YAML's path."""
    rows, columns = pixels.shape
    (folder / f'{name}.pgm').write_bytes(f'P5\n{columns} {rows}\n255\n'.encode()
                                         + pixels.astype(np.uint8).tobytes())
    (folder / f'{name}.yaml').write_text(f'image: {name}.pgm\nmode: trinary\n'
                                         f'resolution: {resolution}\norigin: [0.0, 0.0, 0]\n'
                                         'negate: 0\noccupied_thresh: 0.65\n'
                                         'free_thresh: 0.25\n')
    return folder / f'{name}.yaml'


def worst_maps(folder):
    """(label, YAML path, refused) of the worst maps inside the limits, and one past them."""
    # Each interior grid line of an n x n checkerboard has n runs, each border line n / 2
    # (the outside is solid): 2 (n - 1) n + 2 n runs, exactly the limit at n = 1024.
    side = 1024
    assert 2 * side * side == limits.MAX_MAP_RUNS
    board = np.add.outer(np.arange(side), np.arange(side)) % 2 * 254
    speckle = np.where(np.random.default_rng(0).random((4096, 4096)) < 0.02, 0, 254)
    past = np.add.outer(np.arange(side + 2), np.arange(side + 2)) % 2 * 254
    return [(f'checkerboard {side} x {side}', write_pgm(folder, 'board', board), False),
            ('4096 x 4096, 2% speckle', write_pgm(folder, 'speckle', speckle), False),
            (f'checkerboard {side + 2} x {side + 2}', write_pgm(folder, 'past', past), True)]


def worst(folder):
    """The --worst table's lines."""
    balls = ['random.count:=1000', 'random.radius:=[0.02, 0.02]', 'random.seed:=1',
             'dt:=0.01']
    node = Path(sys.prefix) / 'bin' / 'ball_world'
    start = time.perf_counter()
    subprocess.run([str(node), '--ros-args', '-p', 'max_steps:=1', '-p', 'rate_hz:=0.0', '-p',
                    'markers.rate_hz:=0.0', *[part for value in balls for part in ('-p', value)]],
                   check=True, capture_output=True)
    print(f'no map: node start to first step {time.perf_counter() - start:.1f} s; peak RSS '
          f'{resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6:.2f} GB', flush=True)
    for label, path, refused in worst_maps(folder):
        values = {'map': str(path), 'arena': [], 'random.count': 1000,
                  'random.radius': [0.02, 0.02], 'random.seed': 1, 'dt': 0.01}
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        start = time.process_time()
        try:
            Simulation({**DEFAULTS, **values})
            built = f'world built in {time.process_time() - start:.2f} s CPU'
        except ValueError as error:
            built = f'refused: {error}'
        grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1e6
        command = [str(node), '--ros-args', '-p', 'max_steps:=1', '-p', 'rate_hz:=0.0', '-p',
                   'markers.rate_hz:=0.0', '-p', f'map:={path}', '-p', 'arena:=[]']
        for parameter in balls:
            command += ['-p', parameter]
        start = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6
        outcome = 'exit 0' if done.returncode == 0 else \
            f'exit {done.returncode}: {done.stderr.strip().splitlines()[-1]}'
        print(f'{label}: {built} (peak RSS +{grown:.2f} GB); node start to first step '
              f'{seconds:.1f} s, {outcome}; largest child peak RSS so far {peak:.2f} GB',
              flush=True)
        assert refused == (done.returncode != 0)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='benchmarks.map_load', description=__doc__)
    parser.add_argument('--repeat', type=int, default=5)
    parser.add_argument('--worst', action='store_true',
                        help='the worst maps inside the limits (see above) instead')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if args.worst:
        with tempfile.TemporaryDirectory() as folder:
            worst(Path(folder))
        return
    with tempfile.TemporaryDirectory() as folder:
        maps = [ROOT / 'maps' / 'tb3_sandbox.yaml', ROOT / 'maps' / 'depot.yaml',
                warehouse(Path(folder)), generated.write(Path(folder) / 'generated')]
        baseline = node_seconds(args.repeat, 'random.count:=20')
        built = build_seconds(args.repeat)
        print(f'without a map: world built in {built * 1e3:.0f} ms; node start to first step '
              f'{baseline:.2f} s')
        for path in maps:
            seconds, occupancy = loader_seconds(path, args.repeat)
            built = build_seconds(args.repeat, map=str(path), arena=[])
            started = node_seconds(args.repeat, f'map:={path}', 'arena:=[]',
                                   'random.count:=20')
            print(f'{path.name}: {occupancy.width} x {occupancy.height} = '
                  f'{occupancy.width * occupancy.height:,} cells; loader {seconds * 1e3:.0f} ms;'
                  f' world built in {built * 1e3:.0f} ms; node start to first step '
                  f'{started:.2f} s ({started - baseline:+.2f} s)')
        robots = ['random.count:=1000', 'random.radius:=[0.1, 0.2]', 'agent.drive:=diff',
                  'agents:=[' + ', '.join(f'ball_{i}' for i in range(100)) + ']']
        started = node_seconds(args.repeat, f'map:={maps[-1]}', 'arena:=[]', *robots)
        print(f'{maps[-1].name} with 1,000 balls and 100 agents scanning: node start to first '
              f'step {started:.2f} s ({started - baseline:+.2f} s)')


if __name__ == '__main__':
    main()
