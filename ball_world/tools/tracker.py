"""ball_world_tracker: follow the balls a laser scanner sees, from its scans and /tf alone.

This node is also a starting point for your own tracker: it is the simplest complete
multi-target tracker for a 2D lidar, and `ball_world_score` tells you how good it is (and
yours, on the same recording). Read it top to bottom. For each scan it does four things:

  1. segments the scan: consecutive beams whose end points lie close together form a
     cluster (one object seen, or a piece of wall); with the world's map (`/map`), beams
     that end on or next to a solid cell are left out first: the map says what is building;
  2. fits a circle to each cluster (centre and radius, least squares on the distances to
     the circle); a cluster is kept as a ball when the circle fits, its radius is plausible
     and the cluster stands in front of what lies beside it (a wall piece does not);
  3. puts the centres in the world frame with the scanner's pose from /tf (world ->
     <p><name>/odom -> <p><name>/base_link at the scan's stamp);
  4. updates one constant-velocity Kalman filter per track: predict every track to the
     scan's time, pair tracks and detections nearest first within a gate (greedy, the
     simplest rule: with balls further apart than the gate it agrees with the optimal
     assignment; scipy.optimize.linear_sum_assignment is the next step up), correct the
     paired tracks, start a track for each unpaired detection, and drop tracks unseen for
     `max_misses` scans.

It publishes `<name>/tracks` (visualization_msgs/MarkerArray in the world frame, one sphere
per confirmed track, marker id = track id, so RViz and ball_world_score see the ids) and
`<name>/tracks/poses` (geometry_msgs/PoseArray of the same tracks, for tools that take
poses). A track is published once it has `confirm` detections: 1 publishes every
detection at once (what scores best on ball_world's gases, where balls come and go behind
others all the time); 2 or more keeps a stray cluster from making a track, at the cost of
missing each ball on the scans it needs to be confirmed.

    ros2 run ball_world ball_world_tracker --ros-args -p agent:=ball_0

Everything above the node class is plain Python and numpy (no ROS). `ScanTracker` is the
whole tracker as one class, `update(scan, pose) -> rows (id, x, y, vx, vy)`: the node runs
it on live scans, ball_world_score on recorded ones and on simulated scenes
(`ball_world_score --seeds 0:100`), and a class of your own with the same method is scored
the same way (`--tracker my_module:MyTracker`).
"""
import math
import sys
from typing import NamedTuple

import numpy as np

PROG = 'ball_world_tracker'
PARAMETERS = """\
ROS parameters (after --ros-args; integers are taken for numbers):
  agent          entity name of the agent whose <agent>/scan to track with (default ball_0)
  frame_id       the world frame the tracks are given in (default world)
  frame_prefix   the world's frame_prefix, if it has one (default "")
  radius         [min, max] radius of a ball, m (default [0.1, 0.3], the default world's)
  gate           largest distance between a track and its detection, m (default 0.6)
  meas_stddev    error of a detected centre, m (default 0.03)
  accel_stddev   unmodelled acceleration (collisions), m/s^2 (default 8.0)
  confirm        detections before a track is published (default 1)
  max_misses     scans without a detection before a track is dropped (default 2)"""


# 1 and 2. From a scan to ball centres in the scanner's frame -------------------------------

class ScanGeometry(NamedTuple):
    """What a LaserScan says about its beams (the fields of the message of the same names)."""

    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float


class Options(NamedTuple):
    """The tracker's tuning (see PARAMETERS)."""

    radius_min: float = 0.1
    radius_max: float = 0.3
    gate: float = 0.6
    meas_stddev: float = 0.03
    accel_stddev: float = 8.0
    confirm: int = 1
    max_misses: int = 2


#: End points of neighbouring beams closer than this many beam spacings (at their range),
#: plus JUMP_FLOOR, belong to one cluster.
JUMP_SPACINGS = 1.5
JUMP_FLOOR = 0.05
#: A cluster stands in front when a beam beside it reaches this much further (or nothing).
FOREGROUND = 0.1
#: A point this close (m) to the line of the two beyond it continues their surface.
ON_LINE = 0.05
#: A run whose end points are further apart than a ball's diameter plus this (m) is no
#: ball: not fitted (a wall seen head-on makes runs of hundreds of beams).
WIDER = 0.1
#: A fit whose centre moves further than this many largest radii from its points is given
#: up (a wall: its points want a circle far larger than a ball; it would not fit anyway).
RUNAWAY = 3.0
#: A circle fits when its rms distance to the points is below this (m): a few times the
#: default noise of 0.01 m, far below the sag of a wall piece bent onto a ball's radius.
MAX_RMS = 0.03


def scan_points(ranges, scan):
    """End points (N, 2) of the beams in the scanner's frame (0, 0 for infinite ranges)."""
    ranges = np.asarray(ranges, dtype=np.float64)
    angles = scan.angle_min + np.arange(len(ranges)) * scan.angle_increment
    r = np.where(np.isfinite(ranges), ranges, 0.0)
    return np.column_stack((r * np.cos(angles), r * np.sin(angles)))


def clusters(ranges, scan):
    """Lists of beam indices: runs of consecutive valid beams whose end points are close.

    A full-turn scan wraps: its last and first beams are neighbours.
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    n = len(ranges)
    valid = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
    points = scan_points(ranges, scan)
    spacing = abs(scan.angle_increment)
    full_turn = n * spacing >= 2.0 * math.pi - 1e-9
    # joined[k]: beams k and k + 1 (the last and the first for k = n - 1) are one object.
    following = np.roll(np.arange(n), -1)
    reach = JUMP_FLOOR + JUMP_SPACINGS * spacing * np.minimum(
        np.where(valid, ranges, 0.0), np.where(valid[following], ranges[following], 0.0))
    gap = np.hypot(*(points[following] - points).T)
    joined = valid & valid[following] & (gap <= reach)
    runs = []
    current = []
    for k in np.flatnonzero(valid).tolist():
        if current and current[-1] == k - 1 and joined[k - 1]:
            current.append(k)
        else:
            if current:
                runs.append(current)
            current = [k]
    if current:
        runs.append(current)
    if full_turn and len(runs) > 1 and runs[0][0] == 0 and runs[-1][-1] == n - 1 \
            and joined[n - 1]:
        runs[0] = runs.pop() + runs[0]
    return runs


def fit_circle(points, radius_min, radius_max):
    """Centre (x, y), radius and rms residual of the circle that best fits the points.

    Least squares on the distances to the circle (Gauss-Newton, radius kept within its
    bounds: points that want a much larger circle, a wall, send the centre away and do not
    fit), started from the centroid pushed one mean radius away from the scanner (the
    visible side of a ball faces the scanner at the origin). Fewer than three points cannot
    tell the radius: it is then the mean of the bounds, and the circle has a closed form
    (three points: the circle through them, when its radius is within the bounds). Plain
    floats, not numpy: a ball shows a handful of beams, and for so few numbers the
    loop below is several times faster than array calls.
    """
    if isinstance(points, np.ndarray):
        points = points.reshape(-1, 2).tolist()
    n = len(points)
    radius = 0.5 * (radius_min + radius_max)
    mx = sum(x for x, _ in points) / n
    my = sum(y for _, y in points) / n
    norm = max(math.hypot(mx, my), 1e-12)
    away = (mx / norm, my / norm)
    if n < 3:
        return _circle_of_radius(points, radius, away)
    cx, cy = mx + radius * away[0], my + radius * away[1]
    if n == 3:  # three points: the circle through them, when its radius is plausible
        circle = _circumcircle(points)
        if circle is not None and radius_min <= circle[2] <= radius_max:
            return np.array(circle[:2]), circle[2], 0.0
    for _ in range(20):
        step = _gauss_newton_step(points, cx, cy, radius)
        if step is None:
            break
        cx, cy = cx + step[0], cy + step[1]
        radius = min(max(radius + step[2], radius_min), radius_max)
        if math.hypot(step[0], step[1]) < 1e-6:
            break
        if math.hypot(cx - mx, cy - my) > RUNAWAY * radius_max:
            break  # the centre runs off after a far larger circle: no ball, stop early
    rms = math.sqrt(sum((math.hypot(x - cx, y - cy) - radius) ** 2 for x, y in points) / n)
    return np.array([cx, cy]), radius, rms


def _circumcircle(points):
    """(cx, cy, r) of the circle through three points, None when they are in line."""
    (ax, ay), (bx, by), (cx, cy) = points
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-12:
        return None
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return ux, uy, math.hypot(ax - ux, ay - uy)


def _circle_of_radius(points, radius, away):
    """The least-squares circle of a given radius through one or two points: for two
    closer than a diameter, the circle through both whose centre lies beyond them (seen
    from the scanner); further apart, the one centred between them."""
    if len(points) == 1:
        (x, y), = points
        return np.array([x + radius * away[0], y + radius * away[1]]), radius, 0.0
    (x0, y0), (x1, y1) = points
    mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    half = 0.5 * math.hypot(x1 - x0, y1 - y0)
    if half == 0.0:
        return np.array([mx + radius * away[0], my + radius * away[1]]), radius, 0.0
    if half >= radius:
        return np.array([mx, my]), radius, half - radius
    nx, ny = -(y1 - y0) / (2.0 * half), (x1 - x0) / (2.0 * half)
    if nx * mx + ny * my < 0.0:
        nx, ny = -nx, -ny
    depth = math.sqrt(radius * radius - half * half)
    return np.array([mx + depth * nx, my + depth * ny]), radius, 0.0


def _gauss_newton_step(points, cx, cy, radius):
    """The Gauss-Newton step (dcx, dcy, dr) for the residuals d - r, from the normal
    equations (the gradient of a residual is (-ux, -uy, -1), u the unit vector from the
    centre to its point). When the radius cannot be told (a short arc: the system is
    singular) the step moves the centre alone (dr = 0); None when even that cannot be
    solved."""
    sxx = sxy = syy = sx = sy = bx = by = b = 0.0
    for x, y in points:
        ox, oy = x - cx, y - cy
        d = math.hypot(ox, oy) or 1e-12
        ux, uy = ox / d, oy / d
        r = d - radius
        sxx += ux * ux
        sxy += ux * uy
        syy += uy * uy
        sx += ux
        sy += uy
        bx += ux * r
        by += uy * r
        b += r
    n = float(len(points))
    # Cramer's rule on [[sxx, sxy, sx], [sxy, syy, sy], [sx, sy, n]] (dcx, dcy, dr) = (bx, by, b).
    minors = (syy * n - sy * sy, sxy * n - sy * sx, sxy * sy - syy * sx)
    det = sxx * minors[0] - sxy * minors[1] + sx * minors[2]
    if abs(det) > 1e-9 * n:
        dcx = (bx * minors[0] - sxy * (by * n - sy * b) + sx * (by * sy - syy * b)) / det
        dcy = (sxx * (by * n - sy * b) - bx * minors[1] + sx * (sxy * b - by * sx)) / det
        dr = (sxx * (syy * b - by * sy) - sxy * (sxy * b - by * sx)
              + bx * minors[2]) / det
        return dcx, dcy, dr
    det2 = sxx * syy - sxy * sxy
    if abs(det2) <= 1e-12 * n:
        return None
    return (bx * syy - sxy * by) / det2, (sxx * by - sxy * bx) / det2, 0.0


def detect(ranges, scan, options=Options()):
    """Centres (K, 2) of the balls seen in one scan, in the scanner's frame."""
    ranges = np.asarray(ranges, dtype=np.float64)
    valid = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
    runs = clusters(ranges, scan)
    # From here on one beam at a time: Python lists answer that far faster than arrays.
    points = scan_points(ranges, scan).tolist()
    valid = valid.tolist()
    ranges = ranges.tolist()
    used = [False] * len(ranges)
    found = []
    # Longest runs first: each may take in the beams beside it that graze the same ball.
    for run in sorted(runs, key=len, reverse=True):
        if any(used[k] for k in run):
            continue
        if math.dist(points[run[0]], points[run[-1]]) > 2.0 * options.radius_max + WIDER:
            for k in run:
                used[k] = True
            continue  # wider than any ball: a piece of wall (or balls side by side)
        run, (centre, radius, rms) = _grown(run, points, valid, used, options)
        for k in run:
            used[k] = True
        if not _in_front(ranges, points, run):
            continue  # a piece of wall, or of something behind others
        # The circle must fit, and lie behind its points (a ball shows its near side).
        if rms <= MAX_RMS and math.hypot(*centre) > sum(ranges[k] for k in run) / len(run):
            found.append(centre)
    return np.array(found).reshape(-1, 2)


def _grown(run, points, valid, used, options):
    """The run with the beams beside it that the same circle fits, and that circle.

    Beams near a ball's edge meet it almost tangentially, so their end points lie further
    from their neighbours' than the clustering allows; they belong to the ball when the
    circle through the run still fits with them.
    """
    n = len(points)
    fit = fit_circle([points[k] for k in run], options.radius_min, options.radius_max)
    for step in (-1, 1):
        for _ in range(2):
            edge = run[0] if step < 0 else run[-1]
            beside = (edge + step) % n
            if not valid[beside] or used[beside] or beside in run or math.dist(
                    points[edge], points[beside]) > 2.0 * options.radius_max:
                break
            grown = [beside] + run if step < 0 else run + [beside]
            grown_fit = fit_circle([points[k] for k in grown], options.radius_min,
                                   options.radius_max)
            if grown_fit[2] > MAX_RMS:
                break
            run, fit = grown, grown_fit
    return run, fit


def _in_front(ranges, points, run):
    """Whether the run stands in front of what lies beside it.

    A side is in front when the beam beside the run reaches FOREGROUND further (or meets
    nothing within range), and the run's edge point does not continue the surface that beam
    and the next one lie on. At least one side must be in front. A run of one or two
    points (too few for a circle to tell a ball from a wall) must also continue no surface
    on either side: a wall seen at a grazing angle breaks into single points, each with a
    farther neighbour on one side and a nearer on the other, all on one line.
    """
    n = len(ranges)
    front = False
    for edge, step in ((run[0], -1), (run[-1], 1)):
        beside = (edge + step) % n
        if beside in run:
            continue
        further = (beside + step) % n
        continues = (math.isfinite(ranges[beside]) and math.isfinite(ranges[further])
                     and further not in run
                     and _on_line(points[edge], points[beside], points[further]))
        if continues and len(run) < 3:
            return False
        behind = ranges[beside]
        if not continues and (behind == math.inf or behind > ranges[edge] + FOREGROUND):
            front = True
    return front


def _on_line(point, a, b):
    """Whether `point` lies within ON_LINE of the line through a and b."""
    abx, aby = b[0] - a[0], b[1] - a[1]
    length = math.hypot(abx, aby)
    if length == 0.0:
        return False
    return abs(abx * (point[1] - a[1]) - aby * (point[0] - a[0])) / length < ON_LINE


def to_world(points, x, y, yaw):
    """Points (K, 2) in a frame at (x, y) with heading yaw, in the world frame."""
    c, s = math.cos(yaw), math.sin(yaw)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return np.column_stack((x + c * points[:, 0] - s * points[:, 1],
                            y + s * points[:, 0] + c * points[:, 1]))


# 4. Tracking: a constant-velocity Kalman filter per track -----------------------------------

class Track:
    """One followed ball: state (x, y, vx, vy), its covariance, and its bookkeeping."""

    def __init__(self, track_id, position, time, options):
        self.id = track_id
        self.state = np.array([position[0], position[1], 0.0, 0.0])
        # Position known to the detection's error, velocity to a ball's likely speed.
        self.covariance = np.diag([options.meas_stddev ** 2] * 2 + [4.0, 4.0])
        self.time = time
        self.hits = 1
        self.misses = 0

    def predict(self, time, accel_stddev):
        """Move the estimate to `time` at constant velocity; uncertainty grows by a white
        acceleration of accel_stddev (which is what collisions look like to the filter)."""
        dt = time - self.time
        if dt <= 0.0:
            return
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        q = accel_stddev ** 2 * np.array([[dt ** 4 / 4, 0, dt ** 3 / 2, 0],
                                          [0, dt ** 4 / 4, 0, dt ** 3 / 2],
                                          [dt ** 3 / 2, 0, dt ** 2, 0],
                                          [0, dt ** 3 / 2, 0, dt ** 2]])
        self.state = f @ self.state
        self.covariance = f @ self.covariance @ f.T + q
        self.time = time

    def correct(self, position, meas_stddev):
        """The Kalman update with a measured position."""
        h = np.eye(2, 4)
        innovation = np.asarray(position) - h @ self.state
        s = h @ self.covariance @ h.T + meas_stddev ** 2 * np.eye(2)
        gain = self.covariance @ h.T @ np.linalg.inv(s)
        self.state = self.state + gain @ innovation
        self.covariance = (np.eye(4) - gain @ h) @ self.covariance
        self.hits += 1
        self.misses = 0


class Tracker:
    """Tracks from detections in the world frame, one update per scan."""

    def __init__(self, options=Options()):
        self.options = options
        self.tracks = []
        self.next_id = 0

    def update(self, time, detections):
        """Advance to `time` (s) with this scan's detections (K, 2); returns the confirmed
        tracks seen in it as rows (id, x, y, vx, vy)."""
        options = self.options
        detections = np.asarray(detections, dtype=np.float64).reshape(-1, 2)
        for track in self.tracks:
            track.predict(time, options.accel_stddev)
        pairs = associate([track.state[:2] for track in self.tracks], detections, options.gate)
        paired_tracks = set()
        paired_detections = set()
        for t, d in pairs:
            self.tracks[t].correct(detections[d], options.meas_stddev)
            paired_tracks.add(t)
            paired_detections.add(d)
        for t, track in enumerate(self.tracks):
            if t not in paired_tracks:
                track.misses += 1
        self.tracks = [track for track in self.tracks if track.misses <= options.max_misses]
        for d in range(len(detections)):
            if d not in paired_detections:
                self.tracks.append(Track(self.next_id, detections[d], time, options))
                self.next_id += 1
        return [(track.id, *track.state) for track in self.tracks
                if track.hits >= options.confirm and track.misses == 0]


class Scan(NamedTuple):
    """A laser scan as a tracker gets it: sensor_msgs/LaserScan's fields (ranges as the
    message carries them, float32), stamp in integer nanoseconds."""

    stamp_ns: int
    frame_id: str
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: np.ndarray


class MapGrid(NamedTuple):
    """A map as a tracker gets it: nav_msgs/OccupancyGrid's fields (what `/map` carries).

    data: int8 (height, width), the message's data in rows of `width`: row 0 starts at the
    origin (the grid's lower-left corner, m), 100 occupied, 0 free, -1 unknown.
    """

    resolution: float
    origin_x: float
    origin_y: float
    data: np.ndarray


#: A map cell with this value or more is solid (nav2's maps: 100; scale mode: 1..99); an
#: unknown cell (-1) is solid too, as the world makes it by default (map.unknown_solid).
SOLID_FROM = 50


#: A return this close (m) to a solid cell is the cell's: three times the lidar's default
#: noise (0.01 m), as a return on a cell's edge lands either side of it.
NEAR_MAP = 0.03


class MapMask:
    """Which points lie on or next to a solid map cell: a wall, a pillar, a shelf.

    The lidar sees a map's cells as it sees balls, and a pillar is as round as a ball: the
    map says what is building, so its points are no objects. A point counts when it lies in
    a solid cell or within `near` of one (x and y each; the lidar's return lies on the
    cell's edge, its noise either side). A ball touching a wall keeps the rest of its
    points. Points off the map are free.
    """

    def __init__(self, grid, near=NEAR_MAP):
        data = np.asarray(grid.data)
        self.solid = (data >= SOLID_FROM) | (data == -1)
        self.resolution = float(grid.resolution)
        self.origin = (float(grid.origin_x), float(grid.origin_y))
        self.near = float(near)

    def __call__(self, points):
        """Bool (K,): whether each world point (K, 2) is on or next to a solid cell."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        out = np.zeros(len(points), dtype=bool)
        for dx in (-self.near, 0.0, self.near):
            for dy in (-self.near, 0.0, self.near):
                out |= self._solid_at(points[:, 0] + dx, points[:, 1] + dy)
        return out

    def _solid_at(self, x, y):
        with np.errstate(invalid='ignore'):
            col = np.floor((x - self.origin[0]) / self.resolution)
            row = np.floor((y - self.origin[1]) / self.resolution)
        height, width = self.solid.shape
        inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
        out = np.zeros(len(x), dtype=bool)
        out[inside] = self.solid[row[inside].astype(np.intp), col[inside].astype(np.intp)]
        return out


def without_map(ranges, scan, pose, mask):
    """The ranges with every beam whose return lies on or next to a solid map cell made
    +inf (REP 117's "nothing seen"): the detector then sees no wall there, and a ball in
    front of a wall stands in front of nothing."""
    ranges = np.array(ranges, dtype=np.float64)
    hits = np.isfinite(ranges)
    on_map = mask(to_world(scan_points(ranges, scan), *pose)) & hits
    ranges[on_map] = math.inf
    return ranges


class ScanTracker:
    """The example tracker as ball_world_score runs any tracker: one `update(scan, pose)`
    per scan, pose the scanner's (x, y, yaw) in the world frame at the scan's stamp (what
    /tf gives), returning the tracks seen in that scan as rows (id, x, y, ...) in the world
    frame. A tracker of your own with this interface is scored by
    `ball_world_score --seeds 0:100 --tracker my_module:MyTracker` on many scenes; the node
    below runs this one on live scans.

    `use_map(grid)` (a MapGrid, what /map carries) gives it the world's map: returns on or
    next to solid cells are then no objects. ball_world_score calls it, before the first
    scan, on any tracker class that has it, when the world has a map.
    """

    def __init__(self, options=Options()):
        self.options = options
        self.tracker = Tracker(options)
        self.mask = None

    def use_map(self, grid):
        self.mask = None if grid is None else MapMask(grid)

    def update(self, scan, pose):
        geometry = ScanGeometry(scan.angle_min, scan.angle_increment, scan.range_min,
                                scan.range_max)
        ranges = np.asarray(scan.ranges, dtype=np.float64)
        if self.mask is not None:
            ranges = without_map(ranges, geometry, pose, self.mask)
        centres = to_world(detect(ranges, geometry, self.options), *pose)
        return self.tracker.update(scan.stamp_ns * 1e-9, centres)


def associate(predicted, detections, gate):
    """Pairs (track index, detection index), nearest first, each at most `gate` apart."""
    if len(predicted) == 0 or len(detections) == 0:
        return []
    predicted = np.asarray(predicted, dtype=np.float64).reshape(-1, 2)
    gaps = np.hypot(predicted[:, None, 0] - detections[None, :, 0],
                    predicted[:, None, 1] - detections[None, :, 1])
    order = np.argsort(gaps, axis=None, kind='stable')
    used_tracks = set()
    used_detections = set()
    pairs = []
    for flat in order:
        t, d = divmod(int(flat), gaps.shape[1])
        if gaps[t, d] > gate:
            break
        if t in used_tracks or d in used_detections:
            continue
        used_tracks.add(t)
        used_detections.add(d)
        pairs.append((t, d))
    return pairs


# 3 and the node: scans and /tf in, tracks out ----------------------------------------------

class Poses:
    """The little of a TF buffer this tracker needs: each frame's parent and transform by
    stamp (2D: x, y, yaw), kept for the last `keep` stamps, composed up to a root frame."""

    def __init__(self, keep=200):
        self.keep = keep
        self.static = {}
        self.dynamic = {}

    def add(self, parent, child, stamp, x, y, yaw, static=False):
        if static:
            self.static[child] = (parent, x, y, yaw)
            return
        history = self.dynamic.setdefault(child, {})
        history[stamp] = (parent, x, y, yaw)
        if len(history) > self.keep:
            del history[min(history)]

    def lookup(self, root, frame, stamp):
        """(x, y, yaw) of `frame` in `root` at `stamp`, or None if a link is missing."""
        x, y, yaw = 0.0, 0.0, 0.0
        for _ in range(32):
            if frame == root:
                return x, y, yaw
            link = self.dynamic.get(frame, {}).get(stamp) or self.static.get(frame)
            if link is None:
                return None
            parent, px, py, pyaw = link
            c, s = math.cos(pyaw), math.sin(pyaw)
            x, y, yaw = px + c * x - s * y, py + s * x + c * y, pyaw + yaw
            frame = parent
        return None


def yaw_of(q):
    """Heading (rotation about z) of a quaternion given as (x, y, z, w)."""
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class ParameterError(ValueError):
    """A parameter value the tracker cannot work with; the message names it."""


#: Scans kept while their transform has not arrived (the oldest is dropped past this).
WAITING_SCANS = 10


def _node_class():
    """The ROS node, made on first use so that the algorithm above imports without ROS."""
    from geometry_msgs.msg import Pose, PoseArray
    from nav_msgs.msg import OccupancyGrid
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage
    from visualization_msgs.msg import Marker, MarkerArray

    class TrackerNode(Node):
        """Scans and /tf in, tracks out (see the module's doc)."""

        def __init__(self):
            super().__init__('ball_world_tracker')
            agent = self.parameter('agent', 'ball_0')
            self.world_frame = self.parameter('frame_id', 'world')
            prefix = self.declare_parameter(
                'frame_prefix', '', ParameterDescriptor(dynamic_typing=True)).value
            radius = self.declare_parameter(
                'radius', [0.1, 0.3], ParameterDescriptor(dynamic_typing=True)).value
            if not (isinstance(radius, (list, tuple)) and len(radius) == 2
                    and 0.0 < float(radius[0]) <= float(radius[1])):
                raise ParameterError(f"parameter 'radius': expected [min, max] with "
                                     f'0 < min <= max, got {radius!r}')
            numbers = {name: self.number(name, default) for name, default in (
                ('gate', 0.6), ('meas_stddev', 0.03), ('accel_stddev', 8.0), ('confirm', 1))}
            numbers['max_misses'] = self.number('max_misses', 2, zero=True)
            self.options = Options(float(radius[0]), float(radius[1]), numbers['gate'],
                                   numbers['meas_stddev'], numbers['accel_stddev'],
                                   int(numbers['confirm']), int(numbers['max_misses']))
            self.tracker = ScanTracker(self.options)
            self.poses = Poses()
            self.waiting = []  # scans waiting for the transform at their stamp
            self.scan_frame = f'{prefix}{agent}/base_link'
            # Relative names: under -r __ns:=/sim2 these are the world's in /sim2.
            self.create_subscription(LaserScan, f'{agent}/scan', self.on_scan, 10)
            self.create_subscription(TFMessage, '/tf', self.on_tf, 100)
            self.create_subscription(
                TFMessage, '/tf_static', lambda msg: self.on_tf(msg, static=True),
                QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL))
            # The world latches its map (transient local): a tracker started late gets it.
            self.create_subscription(OccupancyGrid, 'map', self.on_map, QoSProfile(
                depth=1, reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL))
            self.markers = self.create_publisher(MarkerArray, f'{agent}/tracks', 10)
            self.pose_array = self.create_publisher(PoseArray, f'{agent}/tracks/poses', 10)
            self.Marker, self.MarkerArray, self.Pose, self.PoseArray = (
                Marker, MarkerArray, Pose, PoseArray)
            self.get_logger().info(f'tracking the balls {agent}/scan sees, in '
                                   f'{self.world_frame}')

        def on_map(self, msg):
            info = msg.info
            data = np.array(msg.data, dtype=np.int8).reshape(info.height, info.width)
            self.tracker.use_map(MapGrid(info.resolution, info.origin.position.x,
                                         info.origin.position.y, data))
            self.get_logger().info(f'using the map: {info.width} x {info.height} cells; '
                                   'returns on its solid cells are no objects')

        def on_tf(self, msg, static=False):
            for transform in msg.transforms:
                t = transform.transform
                stamp = (transform.header.stamp.sec, transform.header.stamp.nanosec)
                self.poses.add(transform.header.frame_id, transform.child_frame_id, stamp,
                               t.translation.x, t.translation.y,
                               yaw_of((t.rotation.x, t.rotation.y, t.rotation.z,
                                       t.rotation.w)), static)
            self.track_waiting()

        def on_scan(self, msg):
            # A scan and the /tf of its step come on two topics, in either order: a scan
            # waits (a few at most) for the transform at its stamp.
            self.waiting.append(msg)
            del self.waiting[:-WAITING_SCANS]
            self.track_waiting()

        def track_waiting(self):
            while self.waiting:
                msg = self.waiting[0]
                stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
                pose = self.poses.lookup(self.world_frame, msg.header.frame_id, stamp)
                if pose is None:
                    if len(self.waiting) == WAITING_SCANS:
                        self.waiting.pop(0)
                        self.get_logger().warning(
                            f'no transform {self.world_frame} -> {msg.header.frame_id} at '
                            "a scan's stamp; scan dropped", throttle_duration_sec=5.0)
                        continue
                    return
                self.waiting.pop(0)
                scan = Scan(stamp[0] * 1_000_000_000 + stamp[1], msg.header.frame_id,
                            msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max,
                            np.array(msg.ranges, dtype=np.float32))
                self.publish(msg.header.stamp, self.tracker.update(scan, pose))

        def publish(self, stamp, tracks):
            markers = self.MarkerArray()
            poses = self.PoseArray()
            poses.header.stamp = stamp
            poses.header.frame_id = self.world_frame
            clear = self.Marker()
            clear.header = poses.header  # stamped too: an empty set of tracks is a result
            clear.action = self.Marker.DELETEALL  # tracks that ended disappear
            markers.markers.append(clear)
            for track_id, x, y, _, _ in tracks:
                marker = self.Marker()
                marker.header = poses.header
                marker.ns = 'tracks'
                marker.id = int(track_id)
                marker.type = self.Marker.SPHERE
                marker.pose.position.x, marker.pose.position.y = float(x), float(y)
                marker.pose.orientation.w = 1.0
                marker.scale.x = marker.scale.y = marker.scale.z = 2.0 * self.options.radius_max
                marker.color.r, marker.color.g, marker.color.a = 1.0, 0.5, 0.6
                markers.markers.append(marker)
                pose = self.Pose()
                pose.position.x, pose.position.y = float(x), float(y)
                pose.orientation.w = 1.0
                poses.poses.append(pose)
            self.markers.publish(markers)
            self.pose_array.publish(poses)

        def parameter(self, name, default):
            value = self.declare_parameter(
                name, default, ParameterDescriptor(dynamic_typing=True)).value
            if not (isinstance(value, str) and value):
                raise ParameterError(f"parameter '{name}': expected a name, got {value!r}")
            return value

        def number(self, name, default, zero=False):
            value = self.declare_parameter(
                name, default, ParameterDescriptor(dynamic_typing=True)).value
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value < 0 or (value == 0 and not zero):
                raise ParameterError(f"parameter '{name}': expected a number "
                                     f"{'>=' if zero else '>'} 0, got {value!r}")
            return value

    return TrackerNode


class MissingMessages(Exception):
    """A message package the node needs is not installed (one line, exit 2)."""


def _make_node():
    try:
        node_class = _node_class()
    except ImportError as error:
        raise MissingMessages(f'a message package is missing: {error}') from None
    return node_class()


def main(args=None):
    from ball_world.tools import node_tool
    return node_tool.run(PROG, f'usage: {PROG} [--ros-args -p NAME:=VALUE ...]\n\n{__doc__}\n'
                         f'{PARAMETERS}', _make_node, (ParameterError, MissingMessages), args)


if __name__ == '__main__':
    sys.exit(main())
