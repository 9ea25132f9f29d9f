"""A warehouse as a SLAM toolbox would save it: a nav2 map (YAML + PGM) made from a seed.

Why generated: the issue's speed figures are for a building a user would bring (1-2 million
cells at 3 cm, tens of thousands of boundary edges), and no such map may be copied in. This
draws one deterministically (numpy's PCG64 from `seed`): outer walls with doorways, building
columns, rows of pallet racks (posts and beams seen from the side, their inside unknown), an
office block of small rooms (one never entered: unknown), then what a real scan leaves behind
(ragged wall faces, speckle of stray hits in the aisles, unknown shadows behind racks, unknown
outside the building). Cell values are those map_saver writes in trinary mode: 0 occupied,
254 free, 205 unknown; the image's first row is the map's top.

`python -m benchmarks.warehouse DIR` writes DIR/warehouse.yaml and DIR/warehouse.pgm.
"""
import argparse
from pathlib import Path
import sys

import numpy as np

OCCUPIED = 0
FREE = 254
UNKNOWN = 205
#: m per cell, as many SLAM maps of large buildings use.
RESOLUTION = 0.03
#: Free cells per speck of stray hits (see warehouse()).
SPECKLE = 4000
#: Cells: 45 m x 36 m at 3 cm, 1.8 million cells.
COLUMNS = 1500
ROWS = 1200


def _box(grid, x0, y0, x1, y1, value):
    """Fill cells [x0, x1) x [y0, y1) (map coordinates: column, row from the bottom)."""
    grid[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = value


def _wall(grid, x0, y0, x1, y1, thickness):
    """An axis-aligned wall from (x0, y0) to (x1, y1) (cells), `thickness` cells thick."""
    half = thickness // 2
    if y0 == y1:
        _box(grid, min(x0, x1), y0 - half, max(x0, x1), y0 - half + thickness, OCCUPIED)
    else:
        _box(grid, x0 - half, min(y0, y1), x0 - half + thickness, max(y0, y1), OCCUPIED)


def _rack(grid, rng, x0, y0, length, depth):
    """A double-deep pallet rack seen by a 2D lidar at beam height: posts every 1.35 m on
    both long faces joined by beams with gaps, its inside unknown (never seen)."""
    _box(grid, x0, y0, x0 + length, y0 + depth, UNKNOWN)
    for y in (y0, y0 + depth - 2):
        _box(grid, x0, y, x0 + length, y + 2, OCCUPIED)
        # Gaps in the beams, where pallets stand back: short runs on each face.
        for gap in rng.integers(x0 + 5, x0 + length - 10, size=length // 60):
            _box(grid, gap, y, gap + int(rng.integers(3, 9)), y + 2, UNKNOWN)
    for x in range(x0, x0 + length, 45):
        _box(grid, x, y0 - 1, x + 3, y0 + 2, OCCUPIED)
        _box(grid, x, y0 + depth - 2, x + 3, y0 + depth + 1, OCCUPIED)
    _box(grid, x0, y0, x0 + 3, y0 + depth, OCCUPIED)
    _box(grid, x0 + length - 3, y0, x0 + length, y0 + depth, OCCUPIED)


def _ragged(grid, rng, probability):
    """SLAM blur on wall faces: free cells beside an occupied one turn occupied (a hit a
    little short) or unknown, at random, so straight faces become many short runs."""
    occupied = grid == OCCUPIED
    beside = np.zeros_like(occupied)
    beside[1:, :] |= occupied[:-1, :]
    beside[:-1, :] |= occupied[1:, :]
    beside[:, 1:] |= occupied[:, :-1]
    beside[:, :-1] |= occupied[:, 1:]
    face = beside & (grid == FREE)
    draw = rng.random(grid.shape)
    grid[face & (draw < probability)] = OCCUPIED
    grid[face & (draw >= probability) & (draw < 1.3 * probability)] = UNKNOWN


def warehouse(seed=7, columns=COLUMNS, rows=ROWS):
    """The map's cells (uint8 (rows, columns), row 0 at the bottom) in map_saver's values."""
    rng = np.random.default_rng(seed)
    grid = np.full((rows, columns), UNKNOWN, dtype=np.uint8)
    # The building: free inside, an unknown yard around it.
    left, bottom, right, top = 40, 40, columns - 40, rows - 40
    _box(grid, left, bottom, right, top, FREE)
    for x0, y0, x1, y1 in ((left, bottom, right, bottom), (left, top, right, top),
                           (left, bottom, left, top), (right, bottom, right, top)):
        _wall(grid, x0, y0, x1, y1, 8)
    # Doorways in the outer walls (dock doors and a door), seen through: unknown outside.
    for x in range(left + 150, right - 200, 260):
        _box(grid, x, bottom - 5, x + 100, bottom + 5, FREE)
    _box(grid, right - 5, top - 300, right + 5, top - 250, FREE)
    # Building columns every 10 m.
    for x in range(left + 330, right - 100, 333):
        for y in range(bottom + 330, top - 100, 333):
            _box(grid, x - 5, y - 5, x + 5, y + 5, OCCUPIED)
    # Pallet racks: rows 1.2 m deep, 15 m long, aisles 3 m wide; on the right, racks across
    # (drawn on the transposed grid, a view).
    for y in range(bottom + 110, top - 300, 140):
        for x in (left + 100, left + 620):
            _rack(grid, rng, x, y, 500, 40)
    for x in range(left + 1150, right - 60, 140):
        _rack(grid.T, rng, bottom + 110, x, 560, 40)
    # The office block: small rooms with doors, one never entered.
    ox0, oy0, ox1, oy1 = right - 330, top - 240, right, top
    _wall(grid, ox0, oy0, ox1, oy0, 5)
    _wall(grid, ox0, oy0, ox0, oy1, 5)
    for x in range(ox0 + 110, ox1, 110):
        _wall(grid, x, oy0, x, oy1, 5)
    for k, x in enumerate(range(ox0, ox1 - 20, 110)):
        if k == 1:
            _box(grid, x + 4, oy0 + 4, x + 108, oy1 - 4, UNKNOWN)  # the locked room
        else:
            _box(grid, x + 30, oy0 - 3, x + 65, oy0 + 3, FREE)  # its door
    # Unknown shadows behind the racks nearest the walls (no beam reached them).
    _box(grid, left + 4, bottom + 120, left + 100, bottom + 180, UNKNOWN)
    _box(grid, right - 120, bottom + 300, right - 4, bottom + 360, UNKNOWN)
    _ragged(grid, rng, 0.2)
    # Stray hits in the aisles (dust, people, a forklift that moved) and unseen specks: one
    # per SPECKLE free cells, 0.28 per m^2, twice what nav2's depot map (a real SLAM map at
    # 5 cm) has, 0.14 isolated occupied cells per m^2 of free space.
    free = np.flatnonzero(grid.reshape(-1) == FREE)
    speckle = rng.choice(free, size=len(free) // SPECKLE, replace=False)
    grid.reshape(-1)[speckle[: len(speckle) * 3 // 4]] = OCCUPIED
    grid.reshape(-1)[speckle[len(speckle) * 3 // 4:]] = UNKNOWN
    return grid


def write(directory, seed=7, name='warehouse'):
    """Write `name`.yaml and `name`.pgm into `directory`; returns the YAML's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    grid = warehouse(seed)
    rows, columns = grid.shape
    image = directory / f'{name}.pgm'
    # PGM's first row is the map's top: nav2_map_server reads the image upside down.
    image.write_bytes(f'P5\n{columns} {rows}\n255\n'.encode() + grid[::-1].tobytes())
    origin = (-0.5 * columns * RESOLUTION, -0.5 * rows * RESOLUTION)
    yaml_path = directory / f'{name}.yaml'
    yaml_path.write_text(f'image: {name}.pgm\nmode: trinary\nresolution: {RESOLUTION}\n'
                         f'origin: [{origin[0]}, {origin[1]}, 0]\nnegate: 0\n'
                         'occupied_thresh: 0.65\nfree_thresh: 0.196\n')
    return yaml_path


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.warehouse',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('directory', type=Path)
    parser.add_argument('--seed', type=int, default=7)
    args = parser.parse_args(argv)
    print(write(args.directory, args.seed))
    return 0


if __name__ == '__main__':
    sys.exit(main())
