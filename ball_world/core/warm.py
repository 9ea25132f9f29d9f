"""Compile numba's kernels ahead of time, so that no run waits ~15 s for its first step.

Why a module of its own: warming is a set-up task (scripts/setup.sh runs
`python -m ball_world.core.warm`), not physics. It steps tiny worlds through World, the path
every run takes, so exactly the specialisations runs use are compiled and cached: one in seed
mode on the numba backend, one in exact mode. numba keeps them on disk (cache=True, next to
the modules or in NUMBA_CACHE_DIR), and recompiles them itself when the sources change
(core.numba_backend.ensure_fresh_cache for the modules its kernels inline).

The kernels come in two parts because set-up should not make a newcomer wait for what the
first run does not use: `--kernels run` is what the default world steps (seed mode, without
robots: about 16 s of the 24 s a first `make run` used to wait for), `--kernels rest` the rest
(seed mode with a map, whose step is a kernel of its own since a box's became
core.numba_backend.box_step; exact mode and the lidar), which set-up compiles in the
background (scripts/setup.sh) and a run would otherwise compile on first use (the lidar's
~8 s at a robot's first scan).
"""
import argparse
import sys
import time

import numpy as np

from ball_world.core import lidar
from ball_world.core.solid_cells import SolidCells
from ball_world.core.stepping import numba_installed
from ball_world.core.world import World

#: Two balls that meet at once and a small one heading for a wall: every stage has work.
_POSITIONS = [[1.0, 1.0], [1.9, 1.0], [3.0, 3.0]]
_VELOCITIES = [[1.0, 0.0], [-1.0, 0.0], [0.0, 5.0]]
_RADII = [0.5, 0.4, 0.05]
_WALLS = [[0.0, 0.0, 10.0, 0.0], [0.0, 4.0, 4.0, 4.0], [4.0, 0.0, 4.0, 4.0]]


#: A map of 10 m x 10 m with one solid cell, away from the balls (mode 'map').
_MAP = SolidCells(0.0, 0.0, 0.25, (np.arange(1600) == 30 * 40 + 30).reshape(40, 40))
#: What each choice of --kernels compiles, and how main() names it ('map': seed mode in a
#: map).
PARTS = {'run': (('seed',), False, 'seed mode'),
         'rest': (('map', 'exact'), True, 'seed mode with a map, exact mode and the lidar'),
         'all': (('seed', 'map', 'exact'), True, 'seed mode, exact mode and the lidar')}


def warm(kernels='all'):
    """Compile (or load from numba's cache) the kernels of `kernels` (a key of PARTS);
    returns the seconds taken."""
    modes, scanner, _ = PARTS[kernels]
    began = time.perf_counter()
    for mode in modes:
        world = World(_POSITIONS, _VELOCITIES, _RADII, [1.0, 1.0, 1.0], walls=_WALLS,
                      backend='numba', mode='seed' if mode == 'map' else mode,
                      solid_cells=_MAP if mode == 'map' else None)
        for _ in range(3):
            world.step(0.1)
    if scanner:
        lidar.warm()
    return time.perf_counter() - began


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog='python -m ball_world.core.warm',
        description='Compile and cache the numba kernels, so that no run waits for them.')
    parser.add_argument('--kernels', choices=sorted(PARTS), default='all',
                        help='run: what the default world uses (seed mode); rest: exact '
                             'mode and the lidar; all (default): both')
    kernels = parser.parse_args(argv).kernels
    if not numba_installed():
        print('numba is not installed: nothing to compile (the numpy backend needs nothing)')
        return 0
    seconds = warm(kernels)
    print(f'numba kernels ({PARTS[kernels][2]}) ready in {seconds:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
