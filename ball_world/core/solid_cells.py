"""A map's solid cells as the physics sees them: squares on a grid, and everything outside it.

Why a type of its own: the map loader (nav2_map_server's rules, core.occupancy_map) decides
which cells are solid; the static geometry (the walls' index, seed and exact mode, the lidar)
only needs where the squares are. This is what passes between them, with no file, no YAML and
no ROS in it, so tests can make one from a few lines of numpy.

Layout, as nav_msgs/OccupancyGrid lays out its data: cell (row j, column i) is the square
[origin_x + i resolution, origin_x + (i + 1) resolution) x [origin_y + j resolution, ...);
row 0 is the map's bottom row (the image's last), columns grow with x. Every point outside the
grid counts as solid: a map is closed where nobody looked.
"""
import math
from typing import NamedTuple

import numpy as np


class SolidCells(NamedTuple):
    """Which cells of a map are solid (bool (rows, columns), row 0 at origin_y), and where."""

    origin_x: float  # m, world x of the lower-left corner of cell (0, 0)
    origin_y: float  # m, world y of that corner
    resolution: float  # m, the side of a cell
    solid: np.ndarray  # bool (rows, columns)

    @property
    def rows(self):
        return self.solid.shape[0]

    @property
    def columns(self):
        return self.solid.shape[1]

    @property
    def bounds(self):
        """(xmin, ymin, xmax, ymax) of the grid, m."""
        return (self.origin_x, self.origin_y,
                self.origin_x + self.columns * self.resolution,
                self.origin_y + self.rows * self.resolution)

    def checked(self):
        """The same cells with `solid` a C-contiguous bool array, or ValueError saying why not."""
        values = (self.origin_x, self.origin_y, self.resolution)
        if not all(math.isfinite(value) for value in values):
            raise ValueError(f'map origin and resolution must be finite, got {values}')
        if not self.resolution > 0.0:
            raise ValueError(f'map resolution must be > 0 m, got {self.resolution}')
        solid = np.ascontiguousarray(self.solid, dtype=bool)
        if solid.ndim != 2 or solid.shape[0] < 1 or solid.shape[1] < 1:
            raise ValueError(f'map cells must be a non-empty 2D grid, got shape {solid.shape}')
        return self._replace(origin_x=float(self.origin_x), origin_y=float(self.origin_y),
                             resolution=float(self.resolution), solid=solid)


class CellQueries:
    """What placing balls asks of a map's solid cells: overlaps, free bounds and free area.

    Built once per world (O(cells)): a summed-area table of the solid cells answers "is
    anything solid near this disc?" in O(1), so only discs beside a wall pay for the exact
    test, distance from the centre to each nearby solid square (or to the grid's outside)
    < radius, the physics' notion of overlap. Placing 100,000 balls or checking a spawn costs
    microseconds per ball, whatever the map's size.
    """

    def __init__(self, cells):
        self.cells = cells.checked()
        solid = self.cells.solid
        table = np.zeros((solid.shape[0] + 1, solid.shape[1] + 1), dtype=np.int32)
        np.cumsum(solid, axis=0, dtype=np.int32, out=table[1:, 1:])
        np.cumsum(table[1:, 1:], axis=1, dtype=np.int32, out=table[1:, 1:])
        self._table = table

    def _window(self, x, y, radius):
        """Rows and columns (clipped, half-open) of every cell a disc could reach, and
        whether it reaches outside the grid."""
        cells = self.cells
        res = cells.resolution
        xmin, ymin, xmax, ymax = cells.bounds
        # Distance to each edge first, then compared, as for the squares: x - radius would
        # round away a hair of overlap.
        outside = x - xmin < radius or xmax - x < radius or y - ymin < radius \
            or ymax - y < radius
        # One cell more on each side: rounding in the divisions cannot hide one.
        c0 = max(0, math.floor((x - radius - cells.origin_x) / res) - 1)
        c1 = min(cells.columns, math.floor((x + radius - cells.origin_x) / res) + 2)
        r0 = max(0, math.floor((y - radius - cells.origin_y) / res) - 1)
        r1 = min(cells.rows, math.floor((y + radius - cells.origin_y) / res) + 2)
        return r0, max(r0, r1), c0, max(c0, c1), outside

    def _solid_count(self, r0, r1, c0, c1):
        table = self._table
        return int(table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0])

    def first_overlap(self, x, y, radius):
        """What a disc overlaps: None, ('outside', None) or ('cell', (column, row)).

        Overlap is distance < radius: to the nearest point of a solid square, or a disc
        reaching past the grid's edge (everything outside is solid). Of several cells, the
        one with the lowest row, then column, is named.
        """
        r0, r1, c0, c1, outside = self._window(x, y, radius)
        if outside:
            return 'outside', None
        if r0 >= r1 or c0 >= c1 or not self._solid_count(r0, r1, c0, c1):
            return None
        rows, columns = np.nonzero(self.cells.solid[r0:r1, c0:c1])
        rows = rows + r0
        columns = columns + c0
        cells = self.cells
        left = cells.origin_x + columns * cells.resolution
        right = cells.origin_x + (columns + 1) * cells.resolution
        bottom = cells.origin_y + rows * cells.resolution
        top = cells.origin_y + (rows + 1) * cells.resolution
        dx = np.maximum(np.maximum(left - x, x - right), 0.0)
        dy = np.maximum(np.maximum(bottom - y, y - top), 0.0)
        hits = np.flatnonzero(dx * dx + dy * dy < radius * radius)
        if not len(hits):
            return None
        return 'cell', (int(columns[hits[0]]), int(rows[hits[0]]))

    def first_overlapping_ball(self, positions, radii):
        """(ball index, what first_overlap says) of the first overlapping disc, or None.

        Vectorised over the balls: the summed-area table clears every disc away from walls
        at once; only the others are tested one by one.
        """
        count = len(positions)
        if not count:
            return None
        cells = self.cells
        res = cells.resolution
        x, y = positions[:, 0], positions[:, 1]
        xmin, ymin, xmax, ymax = cells.bounds
        outside = (x - xmin < radii) | (xmax - x < radii) | (y - ymin < radii) \
            | (ymax - y < radii)
        c0 = np.clip(np.floor((x - radii - cells.origin_x) / res) - 1, 0, cells.columns)
        c1 = np.clip(np.floor((x + radii - cells.origin_x) / res) + 2, 0, cells.columns)
        r0 = np.clip(np.floor((y - radii - cells.origin_y) / res) - 1, 0, cells.rows)
        r1 = np.clip(np.floor((y + radii - cells.origin_y) / res) + 2, 0, cells.rows)
        c0, c1, r0, r1 = (np.nan_to_num(v).astype(np.int64) for v in (c0, c1, r0, r1))
        c1 = np.maximum(c0, c1)
        r1 = np.maximum(r0, r1)
        table = self._table
        near = table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0] > 0
        for index in np.flatnonzero(outside | near).tolist():
            hit = self.first_overlap(float(x[index]), float(y[index]), float(radii[index]))
            if hit is not None:
                return index, hit
        return None

    def free(self, arena=None):
        """Flat indices (row * columns + column) of the free cells, those overlapping
        `arena` (xmin, ymin, xmax, ymax) with some area when one is given."""
        free = ~self.cells.solid
        if arena:
            free = free & self._inside(arena)
        return np.flatnonzero(free.reshape(-1))

    def _inside(self, arena):
        """Cells overlapping the arena with positive area: bool (rows, columns)."""
        x_low, x_high, y_low, y_high = self._overlaps(arena)
        return np.outer((y_high - y_low) > 0.0, (x_high - x_low) > 0.0)

    def _overlaps(self, arena):
        cells = self.cells
        xs = cells.origin_x + np.arange(cells.columns + 1) * cells.resolution
        ys = cells.origin_y + np.arange(cells.rows + 1) * cells.resolution
        xmin, ymin, xmax, ymax = arena
        return (np.maximum(xs[:-1], xmin), np.minimum(xs[1:], xmax),
                np.maximum(ys[:-1], ymin), np.minimum(ys[1:], ymax))

    def free_area(self, arena=None):
        """m^2 of free cells (inside `arena`, if given, counting only the part inside)."""
        cells = self.cells
        free = ~cells.solid
        if not arena:
            return float(np.count_nonzero(free)) * cells.resolution * cells.resolution
        x_low, x_high, y_low, y_high = self._overlaps(arena)
        widths = np.maximum(x_high - x_low, 0.0)
        heights = np.maximum(y_high - y_low, 0.0)
        return float(heights @ free.astype(np.float64) @ widths)

    def free_bounds(self, arena=None):
        """(xmin, ymin, xmax, ymax) of the free cells (inside `arena`), or None if none."""
        indices = self.free(arena)
        if not len(indices):
            return None
        cells = self.cells
        rows, columns = np.divmod(indices, cells.columns)
        bounds = (cells.origin_x + columns.min() * cells.resolution,
                  cells.origin_y + rows.min() * cells.resolution,
                  cells.origin_x + (columns.max() + 1) * cells.resolution,
                  cells.origin_y + (rows.max() + 1) * cells.resolution)
        if arena:
            bounds = (max(bounds[0], arena[0]), max(bounds[1], arena[1]),
                      min(bounds[2], arena[2]), min(bounds[3], arena[3]))
        return bounds

    def describe(self, hit):
        """The words a refusal uses for what first_overlap found."""
        kind, where = hit
        cells = self.cells
        if kind == 'outside':
            xmin, ymin, xmax, ymax = cells.bounds
            return (f'the outside of the map (it spans x {xmin:g} to {xmax:g}, y {ymin:g} to '
                    f'{ymax:g} m)')
        column, row = where
        x = cells.origin_x + column * cells.resolution
        y = cells.origin_y + row * cells.resolution
        return (f"the map's solid cell (column {column}, row {row}), the square from "
                f'({x:.6g}, {y:.6g}) to ({x + cells.resolution:.6g}, '
                f'{y + cells.resolution:.6g}) m')
