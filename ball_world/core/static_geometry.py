"""Everything that does not move: the arena, the walls and a map's solid cells, as one index.

Why one module: seed mode, exact mode and the lidar ask the same questions of static
geometry (which walls can a ball touch, which can it hit along its path, where does a beam
first meet a wall), and a map of a real building has tens of thousands of boundary edges.
Walls used to be rasterised into the balls' grid on every rebuild of the candidate lists,
and exact mode lists them in buckets sized by the ball count (too-long walls checked by
every ball): with a map's runs both would cost O(runs) or more per step. Here the static
geometry is indexed once per World, in a grid sized by the geometry, and every question
costs what lies near the ball or the beam, whatever the size of the map. (Exact mode keeps
the World's own walls in its buckets, as before maps, so a world without a map steps bit
for bit as it did; only the map's runs are walked through this index.)

A map's solid cells become walls as the boundary of the solid region, in merged runs
(`boundary_runs`): every edge between a solid cell (or the outside of the grid, solid too)
and a free cell, merged with its collinear neighbours whose solid side is the same. So a
run's end points are always true corners of the solid region: convex ones (the corner of a
block, where the seed's end-point rule applies: the normal from the corner to the ball's
centre), concave ones (inside a room's corner, where a ball touches two runs inside their
length) or the point where two solid cells meet diagonally only (a checkerboard; the two
runs on each line through it have opposite solid sides, so they are never merged, and the
point is a convex corner of both cells). Edges between two solid cells are no geometry.

Walls are numbered: the World's `walls` first (the arena's four, then the `walls`
parameter's), then the map's runs (horizontal runs by row line and start, then vertical runs
by column line and start). A world without a map keeps its walls' numbers, so the canonical
contact order of seed mode and the tie order of exact mode are the ones it always had.

The index (`SegmentIndex`) is a uniform grid of square buckets over the geometry's bounding
box, in compressed rows (CSR): the walls listed in bucket (column c, row r) are
items[first[c * rows + r]:first[c * rows + r + 1]], in increasing wall order. Buckets of one
column are consecutive, so a box of buckets is one contiguous run of items per column. A
segment is listed in every bucket it passes through (widened by a hair, SLACK), so any
region a query covers finds every segment that enters it. What is built from a map is
bounded by its runs' count, itself bounded (limits.MAX_MAP_RUNS, counted from the grid before
anything is built: count_boundary_runs): an index holds at most ENTRIES_PER_SEGMENT entries
a segment, its buckets widening when a fine map and a wide reach would list more (issue 33:
a dilated checkerboard took gigabytes). No I/O, no ROS.
"""
import math

import numpy as np

from ball_world.core import limits, rules

_EMPTY = np.empty(0, dtype=np.int64)
#: Relative widening of bucket ranges, far above the rounding of bucket coordinates, so a
#: segment exactly on a bucket's edge is listed on both sides and a query on the edge finds
#: it (as broadphase.SLACK).
SLACK = 1e-9
#: Buckets are at least this many map cells wide: a bucket narrower than a few cells would
#: list a long run in more buckets than it saves tests.
MIN_BUCKET_CELLS = 4.0
#: Dilations of StaticGeometry.dilated are REACH_STEP (m) times a power of REACH_GROWTH.
REACH_STEP = 2.0 ** -20
REACH_GROWTH = 1.05
#: Most buckets per segment (plus BUCKETS_SLACK); buckets grow past it.
BUCKETS_PER_SEGMENT = 4
BUCKETS_SLACK = 1024
#: Most entries (a segment listed in a bucket) per segment, plus BUCKETS_SLACK; buckets grow
#: past it. A dilated index lists a short segment in every bucket within reach of it: with
#: buckets half the reach wide that is 25 or more, and a checkerboard of a million cells
#: took gigabytes (issue 33). Bounded so, an index costs at most this many items a segment
#: however fine the map or wide the reach; a wider bucket costs a search more tests (the
#: warehouse of benchmarks.map_speed, at its balls' reach, needs 15: unchanged).
ENTRIES_PER_SEGMENT = 16
#: Entries made at a time while filling an index: its temporaries stay this small (about
#: 100 bytes an entry) whatever the index's size.
FILL_CHUNK = 1 << 20


def expand(owners, low, high):
    """For each owner k and each i in [low[k], high[k]): the pair (owner, i), as two arrays
    (broadphase's _expand: `repeat` and `cumsum`, no Python loop)."""
    counts = np.maximum(high - low, 0)
    total = int(counts.sum())
    if total == 0:
        return _EMPTY, _EMPTY
    first = np.repeat(owners, counts)
    offsets = np.cumsum(counts) - counts
    second = np.repeat(low - offsets, counts) + np.arange(total)
    return first, second


def widened(length, scale):
    """`length` plus SLACK of itself and of the coordinates' magnitude `scale`."""
    return length + SLACK * (length + scale)


# A map's solid cells as merged boundary runs -------------------------------------------------

def _runs(kinds):
    """Maximal runs of equal non-zero values along the last axis of `kinds` (2D int8, whose
    first and last columns are 0): (line, first, end) arrays, end exclusive, in row-major
    order."""
    width = kinds.shape[1]
    flat = kinds.reshape(-1)
    before = np.empty_like(flat)
    before[0] = 0
    before[1:] = flat[:-1]
    after = np.empty_like(flat)
    after[-1] = 0
    after[:-1] = flat[1:]
    starts = np.flatnonzero((flat != 0) & (flat != before))
    ends = np.flatnonzero((flat != 0) & (flat != after)) + 1
    line = starts // width
    return line, starts - line * width, ends - line * width


def _edge_kinds(cells):
    """The grid's edges between a solid and a free cell, as two int8 arrays whose runs along
    the last axis are boundary_runs': horizontal edges, then vertical ones (transposed)."""
    solid = cells.solid
    rows, columns = solid.shape
    # A ring of solid cells around the grid: everything outside it is solid.
    padded = np.ones((rows + 2, columns + 2), dtype=bool)
    padded[1:-1, 1:-1] = solid
    # Horizontal edges on row line j (0..rows), between padded rows j and j + 1: 1 where the
    # solid side is below, 2 where it is above. Padded columns 0 and columns + 1 are solid
    # on both sides, so runs never continue from one line to the next.
    below = padded[:-1, :]
    above = padded[1:, :]
    yield (below & ~above).astype(np.int8) + 2 * (above & ~below).astype(np.int8)
    # Vertical edges on column line i (0..columns), between padded columns i and i + 1,
    # transposed so that runs go along the last axis.
    left = padded[:, :-1]
    right = padded[:, 1:]
    yield np.ascontiguousarray(
        ((left & ~right).astype(np.int8) + 2 * (right & ~left).astype(np.int8)).T)


def count_boundary_runs(cells):
    """How many runs boundary_runs would make of `cells` (checked), without making them: a
    few passes over the grid's bytes, so a map can be refused (limits.MAX_MAP_RUNS) before
    anything its size decides is built."""
    total = 0
    for kinds in _edge_kinds(cells):
        flat = kinds.reshape(-1)
        total += int(np.count_nonzero(flat[0] != 0))
        total += int(np.count_nonzero((flat[1:] != 0) & (flat[1:] != flat[:-1])))
    return total


def check_run_count(cells):
    """ValueError (one line) when `cells` have more boundary runs than limits.MAX_MAP_RUNS."""
    count = count_boundary_runs(cells)
    if count > limits.MAX_MAP_RUNS:
        raise ValueError(f'the map has {count:,} boundary runs (edges between solid and free '
                         f'cells, merged along each grid line); a world takes at most '
                         f'{limits.MAX_MAP_RUNS:,} (speckle or a fine pattern of cells makes '
                         'many: clean the map, or coarsen its resolution)')
    return count


def boundary_runs(cells):
    """The boundary of a map's solid cells (core.solid_cells.SolidCells, checked) as merged
    axis-aligned runs: (K, 4) segments x1, y1, x2, y2, horizontal runs first (by row line,
    then x), left to right, then vertical runs (by column line, then y), bottom to top.

    Vertex (i, j) of the grid is at (origin_x + i resolution, origin_y + j resolution), the
    same expression the lidar's grid walk uses for cell edges, so both see the same lines.
    """
    horizontal_kinds, vertical_kinds = _edge_kinds(cells)
    line, first, end = _runs(horizontal_kinds)
    del horizontal_kinds
    y = cells.origin_y + line.astype(np.float64) * cells.resolution
    horizontal = np.stack((cells.origin_x + (first - 1).astype(np.float64) * cells.resolution,
                           y,
                           cells.origin_x + (end - 1).astype(np.float64) * cells.resolution,
                           y), axis=1)
    line, first, end = _runs(vertical_kinds)
    x = cells.origin_x + line.astype(np.float64) * cells.resolution
    vertical = np.stack((x, cells.origin_y + (first - 1).astype(np.float64) * cells.resolution,
                         x, cells.origin_y + (end - 1).astype(np.float64) * cells.resolution),
                        axis=1)
    return np.concatenate((horizontal, vertical)).reshape(-1, 4)


# The bucket index -----------------------------------------------------------------------------

def _cell_ranges(low, high, origin, size, count, slack):
    """First and last bucket (arrays) of intervals [low, high] widened by `slack`, clipped to
    [0, count - 1] (first > last where an interval misses the grid)."""
    first = np.floor(np.clip((low - slack - origin) / size, -1.0, float(count)))
    last = np.floor(np.clip((high + slack - origin) / size, -1.0, float(count)))
    return (np.maximum(first.astype(np.int64), 0),
            np.minimum(last.astype(np.int64), count - 1))


def bucket_size(extent_x, extent_y, count, resolution, reach=0.0):
    """The buckets' width for `count` segments spanning the extent (m): as many buckets as
    BUCKETS_PER_SEGMENT per segment (plus BUCKETS_SLACK) allow over the extent, at least
    MIN_BUCKET_CELLS map cells (resolution 0 without a map) and at least half of `reach`
    (an index dilated by it, see SegmentIndex: a bucket then lists what lies within a square
    of twice its width around it), widened by a tenth at a time until the budget holds."""
    budget = BUCKETS_PER_SEGMENT * count + BUCKETS_SLACK
    area = max(extent_x, 0.0) * max(extent_y, 0.0)
    size = max(math.sqrt(area / budget), MIN_BUCKET_CELLS * resolution, 0.5 * reach,
               1e-6 * max(extent_x, extent_y, 1.0))
    while (extent_x / size + 1.0) * (extent_y / size + 1.0) > budget:
        size *= 1.1
    return size


class SegmentIndex:
    """Segments (M, 4) in a uniform grid of buckets (see the module docstring).

    With `reach` > 0 each segment is listed in every bucket within `reach` of it (a dilated
    index): a point's own bucket then lists every segment within `reach` of the point, so a
    ball asks one bucket, not a box of them (seed mode's compiled search, see
    StaticGeometry.dilated). `grid` holds (origin_x, origin_y, bucket width, largest
    |coordinate|) and `shape` (columns, rows), as the compiled kernels take them.

    Its size is bounded by the segments' count, not by what they span or the reach: buckets
    widen until the entries (a segment listed in a bucket) are at most ENTRIES_PER_SEGMENT
    per segment (plus BUCKETS_SLACK), counted by an upper bound (entries_bound) before any
    is made, and the entries are made FILL_CHUNK at a time.
    """

    def __init__(self, segments, resolution=0.0, reach=0.0):
        segments = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        count = len(segments)
        if count:
            low = np.minimum(segments[:, 0:2], segments[:, 2:4]).min(axis=0)
            high = np.maximum(segments[:, 0:2], segments[:, 2:4]).max(axis=0)
            scale = float(np.abs(segments).max())
        else:
            low = high = np.zeros(2)
            scale = 0.0
        size = bucket_size(float(high[0] - low[0]), float(high[1] - low[1]), count, resolution,
                           reach)
        self.reach = float(reach)
        budget = ENTRIES_PER_SEGMENT * count + BUCKETS_SLACK
        while True:
            self.columns = int((high[0] - low[0]) / size) + 1
            self.rows = int((high[1] - low[1]) / size) + 1
            self.grid = np.array([low[0], low[1], size, scale])
            bound = self.entries_bound(segments)
            total = int(bound.sum())
            if total <= budget:
                break
            # Entries of short segments fall as the square of the width: close in fast,
            # then by tenths.
            size *= min(max(1.1, math.sqrt(total / budget) / 1.1), 4.0)
        self.shape = np.array([self.columns, self.rows], dtype=np.int64)
        self.first, self.items = self._fill(segments, bound)

    @property
    def size(self):
        """A bucket's width, m."""
        return float(self.grid[2])

    def entries_bound(self, segments):
        """For each segment, at least as many entries as _fill makes of it: its columns
        times the rows one column's slice of it can span (exact for axis-aligned segments),
        without making them."""
        ox, oy, size, scale = self.grid
        slack = widened(self.reach, max(size, scale))
        dx = np.abs(segments[:, 2] - segments[:, 0])
        dy = np.abs(segments[:, 3] - segments[:, 1])
        first_col, last_col = _cell_ranges(np.minimum(segments[:, 0], segments[:, 2]),
                                           np.maximum(segments[:, 0], segments[:, 2]), ox,
                                           size, self.columns, slack)
        first_row, last_row = _cell_ranges(np.minimum(segments[:, 1], segments[:, 3]),
                                           np.maximum(segments[:, 1], segments[:, 3]), oy,
                                           size, self.rows, slack)
        columns = np.maximum(last_col - first_col + 1, 0)
        rows = np.maximum(last_row - first_row + 1, 0)
        # A column's slice spans at most dy/dx times its widened width, plus slack each side.
        with np.errstate(divide='ignore', invalid='ignore'):
            span = np.where(dx > 0.0, dy / np.where(dx > 0.0, dx, 1.0), np.inf) \
                * (size + 2.0 * slack) + 2.0 * slack
        per_column = np.minimum(rows, np.floor(np.minimum(span / size, float(self.rows)))
                                .astype(np.int64) + 2)
        return columns * per_column

    def _fill(self, segments, bound):
        """(first, items): each segment listed in the buckets it passes within `reach` of
        (_bucket_entries), in compressed rows, each bucket's in wall order. Made a chunk of
        segments at a time (about FILL_CHUNK entries by `bound`), placed by a counting sort:
        the temporaries stay small however large the index (a checkerboard's took
        gigabytes, issue 33)."""
        buckets = self.columns * self.rows
        narrow = np.int32 if max(buckets, len(segments)) < 2 ** 31 else np.int64
        chunks = []
        counts = np.zeros(buckets, dtype=np.int64)
        ends = np.searchsorted(np.cumsum(bound),
                               np.arange(FILL_CHUNK, int(bound.sum()), FILL_CHUNK),
                               side='right')
        begin = 0
        for end in [*ends.tolist(), len(segments)]:
            end = max(end, begin + 1)
            if begin >= len(segments):
                break
            keys, items = self._bucket_entries(segments[begin:end], begin)
            counts += np.bincount(keys, minlength=buckets)
            chunks.append((keys.astype(narrow), items.astype(narrow)))
            begin = end
        first = np.zeros(buckets + 1, dtype=np.int64)
        np.cumsum(counts, out=first[1:])
        items = np.empty(int(first[-1]), dtype=np.int64)
        fill = first[:-1].copy()
        for keys, walls in chunks:
            # Entries come segment by segment, and chunks in segment order: a stable sort
            # of each chunk keeps every bucket's walls in increasing order.
            order = np.argsort(keys, kind='stable')
            ordered = np.take(keys, order)
            # Each entry's rank among its bucket's in this chunk: its place less its group's.
            place = np.arange(len(ordered))
            group = np.ones(len(ordered), dtype=bool)
            group[1:] = ordered[1:] != ordered[:-1]
            rank = place - np.maximum.accumulate(np.where(group, place, 0))
            items[np.take(fill, ordered) + rank] = np.take(walls, order)
            fill += np.bincount(keys, minlength=buckets)
        return first, items

    def _bucket_entries(self, segments, offset):
        """(bucket key, wall number) of each bucket within `reach` of each segment (walls
        numbered from `offset`), segment by segment: column by column (the part of the
        segment whose x lies within reach of a column's gives rows, widened by reach).
        Conservative: it may list a bucket slightly out of reach, never miss one within it."""
        ox, oy, size, scale = self.grid
        slack = widened(self.reach, max(size, scale))
        x0 = segments[:, 0]
        y0 = segments[:, 1]
        x1 = segments[:, 2]
        y1 = segments[:, 3]
        first_col, last_col = _cell_ranges(np.minimum(x0, x1), np.maximum(x0, x1), ox, size,
                                           self.columns, slack)
        wall, col = expand(np.arange(len(segments)), first_col, last_col + 1)
        x0 = np.take(x0, wall)
        y0 = np.take(y0, wall)
        dx = np.take(x1, wall) - x0
        dy = np.take(y1, wall) - y0
        left = ox + col * size - slack - x0
        right = ox + (col + 1) * size + slack - x0
        vertical = dx == 0.0
        safe_dx = np.where(vertical, 1.0, dx)
        ta = left / safe_dx
        tb = right / safe_dx
        t_low = np.where(vertical, 0.0, np.clip(np.minimum(ta, tb), 0.0, 1.0))
        t_high = np.where(vertical, 1.0, np.clip(np.maximum(ta, tb), 0.0, 1.0))
        ya = y0 + t_low * dy
        yb = y0 + t_high * dy
        first_row, last_row = _cell_ranges(np.minimum(ya, yb), np.maximum(ya, yb), oy, size,
                                           self.rows, slack)
        entry, row = expand(np.arange(len(wall)), first_row, last_row + 1)
        keys = np.take(col, entry) * self.rows + row
        return keys, np.take(wall, entry) + offset

    def near_pairs(self, positions, radii, margin, starts, directions, lengths):
        """(ball, segment) with the ball's centre closer than r + margin to the segment, in
        canonical order (by ball, then segment), vectorised: each ball's box of buckets,
        one contiguous run of items per column, then the exact distance test."""
        if len(positions) == 0 or len(self.items) == 0:
            return _EMPTY, _EMPTY
        ox, oy, size, scale = self.grid
        reach = widened(radii + margin, max(scale, float(np.abs(positions).max())))
        x = positions[:, 0]
        y = positions[:, 1]
        col0, col1 = _cell_ranges(x - reach, x + reach, ox, size, self.columns, 0.0)
        row0, row1 = _cell_ranges(y - reach, y + reach, oy, size, self.rows, 0.0)
        ball, col = expand(np.arange(len(positions)), col0, col1 + 1)
        base = col * self.rows
        low = np.take(self.first, base + np.take(row0, ball))
        high = np.take(self.first, base + np.take(row1, ball) + 1)
        entry, item = expand(np.arange(len(ball)), low, high)
        ball = np.take(ball, entry)
        wall = np.take(self.items, item)
        points = np.take(positions, ball, axis=0)
        sx, sy, _ = rules.wall_offset(points[:, 0], points[:, 1],
                                      np.take(starts[:, 0], wall), np.take(starts[:, 1], wall),
                                      np.take(directions[:, 0], wall),
                                      np.take(directions[:, 1], wall), np.take(lengths, wall))
        near = np.take(radii, ball) + margin
        keep = np.flatnonzero(sx * sx + sy * sy < near * near)
        # A segment listed in several buckets of the box is found once per bucket.
        keys = np.unique(np.take(ball, keep) * max(1, len(starts)) + np.take(wall, keep))
        return keys // max(1, len(starts)), keys % max(1, len(starts))


# The whole static geometry of a World ---------------------------------------------------------

class StaticGeometry:
    """The World's walls and its map's boundary runs as one list of segments (walls first),
    their per-segment values (as core.world.Walls has them), the bucket index, and the map's
    cells for the lidar.

    Built once per World: nothing static changes while it lives (edits move balls only).
    """

    def __init__(self, walls, cells=None):
        self.wall_count = len(walls)
        self.cells = cells
        if cells is None:
            runs = np.empty((0, 4))
        else:
            check_run_count(cells)
            runs = boundary_runs(cells)
            far = np.abs(runs) > limits.COORDINATE_LIMIT
            if far.any():
                raise ValueError(f'the map reaches {float(np.abs(runs).max()):g} m from the '
                                 f'origin, beyond the coordinate limit of '
                                 f'{limits.COORDINATE_LIMIT:g} m')
        self.run_count = len(runs)
        self.segments = np.concatenate((walls.segments, runs)).reshape(-1, 4)
        edge = runs[:, 2:4] - runs[:, 0:2]
        run_lengths = np.hypot(edge[:, 0], edge[:, 1])
        self.starts = np.concatenate((walls.starts, runs[:, 0:2])).reshape(-1, 2)
        self.ends = np.concatenate((walls.ends, runs[:, 2:4])).reshape(-1, 2)
        self.lengths = np.concatenate((walls.lengths, run_lengths))
        self.directions = np.concatenate((walls.directions,
                                          edge / np.maximum(run_lengths, 1e-300)[:, None]))
        self.resolution = cells.resolution if cells is not None else 0.0
        self.index = SegmentIndex(self.segments, self.resolution)
        self._dilated = None
        #: columns and rows of the index, the first run's wall number, the number of runs
        #: (as exact mode's kernel takes them: exact_kernel's LAYOUT_COLUMNS ... RUNS)
        self.layout = np.array([self.index.columns, self.index.rows, self.wall_count,
                                self.run_count], dtype=np.int64)
        self._scan_grid = None

    def __len__(self):
        return len(self.segments)

    def near_pairs(self, positions, radii, margin):
        """(ball, wall) index arrays, in canonical order, of every ball whose centre is
        closer than its radius plus `margin` to a wall or run."""
        return self.index.near_pairs(positions, radii, margin, self.starts, self.directions,
                                     self.lengths)

    def dilated(self, reach):
        """The segments in an index dilated by at least `reach` (SegmentIndex), kept for the
        next caller: the dilation is rounded up to REACH_STEP times a power of REACH_GROWTH,
        so that
        spawning or removing balls (which moves the reach a ball needs: its radius plus the
        candidate lists' skin) rarely makes a new one."""
        dilation = REACH_STEP
        while dilation < reach:
            dilation *= REACH_GROWTH
        if self._dilated is None or self._dilated.reach != dilation:
            self._dilated = SegmentIndex(self.segments, self.resolution, dilation)
        return self._dilated

    @property
    def scan_grid(self):
        """The map's cells as the lidar walks them (ScanGrid), made on first use."""
        if self._scan_grid is None:
            self._scan_grid = ScanGrid(self.cells)
        return self._scan_grid


class ScanGrid:
    """A map's solid cells as a beam walks them (core.lidar): one byte a cell (1 solid), in
    OccupancyGrid's layout, and `frame` (origin x, origin y, resolution). `skips` (the
    largest free squares at each cell, one per quadrant of directions) is made by the
    compiled scan the first time it walks the grid (core.lidar_kernel.free_squares), so a
    World that never scans, or scans with the numpy reference, never pays for it.

    Without a map: a grid of no cells, which a scan never walks.
    """

    def __init__(self, cells=None):
        self.skips = None
        if cells is None:
            self.solid = np.zeros((0, 0), dtype=np.uint8)
            self.frame = np.array([0.0, 0.0, 1.0])
            return
        self.solid = np.ascontiguousarray(cells.solid, dtype=np.uint8)
        self.frame = np.array([cells.origin_x, cells.origin_y, cells.resolution])

    @property
    def empty(self):
        """Whether there is no map to walk."""
        return self.solid.size == 0
