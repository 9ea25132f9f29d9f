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
