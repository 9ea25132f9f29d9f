"""The example tracker (ball_world_tracker) on scans made by core.lidar, judged by CLEAR-MOT.

The pieces are checked against what the scene makes them by construction (points on a
known circle, a constant-velocity target, transforms composed by hand); the whole against
ground truth: moving balls in a box, scanned at 10 Hz with the default noise, must be
followed with a MOTA and MOTP that a tracker with a broken piece does not reach.
"""
import math

import numpy as np
import pytest

from ball_world.core import lidar
from ball_world.core.scenario import arena_walls
from ball_world.core.world import World
from ball_world.scoring.figures import score_tracks
from ball_world.scoring.frames import Frame
from ball_world.tools import tracker

FAN = lidar.Fan(-math.pi, 2.0 * math.pi / 360, 360, 0.35, 12.0, 0.01)
GEOMETRY = tracker.ScanGeometry(FAN.angle_min, FAN.angle_increment, FAN.range_min,
                                FAN.range_max)
BOX = arena_walls({'arena': [0.0, 0.0, 10.0, 10.0]})[0]


def test_clusters_split_at_jumps_and_join_across_the_wrap():
    ranges = np.full(360, 5.0)
    ranges[100:103] = 2.0  # something in front: its own run
    ranges[200] = np.inf  # a gap
    runs = tracker.clusters(ranges, GEOMETRY)
    assert [100, 101, 102] in runs
    # The rest is one run from 201 round the wrap to 99, then 103 to 199.
    assert list(range(201, 360)) + list(range(0, 100)) in runs
    assert list(range(103, 200)) in runs
    assert len(runs) == 3


def test_circle_fit_recovers_centre_and_radius():
    angles = np.linspace(2.5, 3.8, 7)  # the side of the circle facing the origin
    points = np.column_stack((4.0 + 0.25 * np.cos(angles), 1.0 + 0.25 * np.sin(angles)))
    centre, radius, rms = tracker.fit_circle(points, 0.1, 0.3)
    assert centre == pytest.approx([4.0, 1.0], abs=1e-6)
    assert radius == pytest.approx(0.25, abs=1e-6)
    assert rms < 1e-6
    # One point: the radius cannot be told, the mean of the bounds is taken, behind it.
    centre, radius, _ = tracker.fit_circle(np.array([[3.0, 4.0]]), 0.1, 0.3)
    assert radius == pytest.approx(0.2)
    assert centre == pytest.approx([3.0 * 5.2 / 5.0, 4.0 * 5.2 / 5.0], abs=1e-9)


@pytest.mark.parametrize('scanner', [(5.0, 5.0), (0.4, 0.4), (9.5, 2.0)])
def test_detect_finds_each_ball_and_no_wall(scanner):
    # Three balls well apart in the box, scanned without noise from the centre and from
    # near a corner and a side (walls at grazing angles): three detections, at the centres.
    balls = np.array([[3.0, 7.0], [7.5, 7.5], [6.0, 3.0]])
    radii = np.array([0.3, 0.2, 0.25])
    ranges = lidar.scan(balls, radii, BOX, scanner, 0.0, FAN._replace(noise_stddev=0.0))
    found = tracker.to_world(tracker.detect(ranges, GEOMETRY), *scanner, 0.0)
    assert len(found) == 3
    for centre in balls:
        assert np.min(np.hypot(*(found - centre).T)) < 0.02


def test_few_points_give_the_circle_of_the_mean_radius_through_them():
    # Two points 0.2 apart, radius 0.2 (the mean of the bounds): the centre lies beyond
    # them at sqrt(0.2^2 - 0.1^2) from their middle.
    centre, radius, rms = tracker.fit_circle([[3.0, -0.1], [3.0, 0.1]], 0.1, 0.3)
    assert radius == 0.2 and rms == 0.0
    assert centre == pytest.approx([3.0 + math.sqrt(0.03), 0.0])
    # Further apart than a diameter: centred between them, each 0.05 from the circle.
    centre, radius, rms = tracker.fit_circle([[3.0, -0.25], [3.0, 0.25]], 0.1, 0.3)
    assert centre == pytest.approx([3.0, 0.0]) and rms == pytest.approx(0.05)
    # Three points on a circle of radius 0.25: that circle.
    angles = (2.9, 3.1, 3.3)
    points = [[4.0 + 0.25 * math.cos(a), 1.0 + 0.25 * math.sin(a)] for a in angles]
    centre, radius, rms = tracker.fit_circle(points, 0.1, 0.3)
    assert centre == pytest.approx([4.0, 1.0]) and radius == pytest.approx(0.25)


def test_points_on_a_flat_surface_do_not_fit_a_ball():
    # Seven points on a line (a wall) and on a circle of radius 2: no circle of radius
    # 0.1-0.3 fits them.
    line = np.column_stack((np.full(7, 4.0), np.linspace(-0.3, 0.3, 7)))
    angles = np.linspace(2.95, 3.35, 7)
    arc = np.column_stack((6.0 + 2.0 * np.cos(angles), 2.0 * np.sin(angles)))
    for points in (line, arc):
        _, radius, rms = tracker.fit_circle(points, 0.1, 0.3)
        assert 0.1 <= radius <= 0.3 and rms > tracker.MAX_RMS


def test_the_scan_tracker_takes_a_scan_and_a_pose():
    balls = np.array([[3.0, 7.0], [7.5, 7.5]])
    radii = np.array([0.3, 0.2])
    ranges = lidar.scan(balls, radii, BOX, (5.0, 5.0), 0.5, FAN._replace(noise_stddev=0.0))
    scan = tracker.Scan(0, 'ball_0/base_link', FAN.angle_min, FAN.angle_increment,
                        FAN.range_min, FAN.range_max, ranges.astype(np.float32))
    rows = tracker.ScanTracker().update(scan, (5.0, 5.0, 0.5))
    assert sorted(row[0] for row in rows) == [0, 1]
    for centre in balls:
        assert min(math.dist(centre, row[1:3]) for row in rows) < 0.02


def pillar_map():
    """A 10 m square map of 0.05 m cells, free but for a round pillar of radius 0.25 (a
    ball's size) at (3, 7) and a 0.4 m square block at (7.5, 2.5): int8 as /map has it."""
    resolution = 0.05
    centres = (np.arange(200) + 0.5) * resolution
    x, y = np.meshgrid(centres, centres)  # row = y, column = x
    data = np.zeros((200, 200), dtype=np.int8)
    data[np.hypot(x - 3.0, y - 7.0) <= 0.25] = 100
    data[(abs(x - 7.5) <= 0.2) & (abs(y - 2.5) <= 0.2)] = 100
    return tracker.MapGrid(resolution, 0.0, 0.0, data)


def test_with_the_map_the_tracker_follows_balls_not_pillars():
    # The pillar is as round as a ball and the block's corner fits one: without the map
    # both are tracked (and the ball beside the block is lost in it); with the map, only
    # the two balls are, one of them 0.05 m from the block.
    from ball_world.core.solid_cells import SolidCells
    from ball_world.core.static_geometry import ScanGrid
    grid = pillar_map()
    cells = ScanGrid(SolidCells(0.0, 0.0, grid.resolution, grid.data == 100).checked())
    balls = np.array([[7.5, 7.5], [7.5, 2.0]])
    radii = np.array([0.2, 0.25])
    ranges = lidar.scan(balls, radii, BOX, (5.0, 5.0), 0.3, FAN._replace(noise_stddev=0.0),
                        grid=cells)
    scan = tracker.Scan(0, 'ball_0/base_link', FAN.angle_min, FAN.angle_increment,
                        FAN.range_min, FAN.range_max, ranges.astype(np.float32))
    pose = (5.0, 5.0, 0.3)
    blind = tracker.ScanTracker().update(scan, pose)
    assert min(math.dist((3.0, 7.0), row[1:3]) for row in blind) < 0.05  # the pillar
    assert min(math.dist((7.5, 2.5), row[1:3]) for row in blind) < 0.1  # the block's corner
    mapped = tracker.ScanTracker()
    mapped.use_map(grid)
    rows = mapped.update(scan, pose)
    assert len(rows) == 2
    for centre in balls:
        assert min(math.dist(centre, row[1:3]) for row in rows) < 0.02


def test_the_map_mask_takes_solid_cells_and_what_lies_near_them_not_off_the_map():
    data = np.zeros((4, 5), dtype=np.int8)
    data[1, 2] = 100  # the cell x in [0.2, 0.3), y in [0.1, 0.2) (origin 0, 0.1 m cells)
    data[3, 4] = -1  # unknown: solid, as the world makes it by default
    mask = tracker.MapMask(tracker.MapGrid(0.1, 0.0, 0.0, data), near=0.03)
    # In the cell; 0.02 left of it and 0.02 below it (within `near`); 0.02 off a corner
    # each way; 0.05 left of it (not within); the unknown cell; off the map; not a number.
    points = [(0.25, 0.15), (0.18, 0.15), (0.25, 0.08), (0.32, 0.22), (0.15, 0.15),
              (0.45, 0.35), (0.25, -0.5), (9.0, 9.0), (np.nan, 0.0)]
    assert mask(points).tolist() == [True, True, True, True, False, True, False, False,
                                     False]


def test_kalman_track_learns_a_constant_velocity():
    options = tracker.Options()
    track = tracker.Track(0, (0.0, 0.0), 0.0, options)
    for k in range(1, 30):
        t = 0.1 * k
        track.predict(t, options.accel_stddev)
        track.correct((1.5 * t, -0.5 * t), options.meas_stddev)
    assert track.state == pytest.approx([1.5 * 2.9, -0.5 * 2.9, 1.5, -0.5], abs=1e-3)


def test_association_is_nearest_first_within_the_gate():
    predicted = [(0.0, 0.0), (1.0, 0.0), (5.0, 5.0)]
    detections = np.array([[0.9, 0.0], [0.2, 0.0], [9.0, 9.0]])
    # Track 1 takes detection 0 (0.1 apart) first; track 0 then gets detection 1; track 2
    # and detection 2 are further apart than the gate.
    assert sorted(tracker.associate(predicted, detections, 0.5)) == [(0, 1), (1, 0)]


def test_poses_compose_the_transform_chain_at_the_scan_stamp():
    poses = tracker.Poses()
    poses.add('world', 'ball_0/odom', None, 0.0, 0.0, 0.0, static=True)
    poses.add('ball_0/odom', 'ball_0/base_link', (1, 0), 2.0, 3.0, math.pi / 2)
    poses.add('ball_0/odom', 'ball_0/base_link', (2, 0), 4.0, 3.0, 0.0)
    assert poses.lookup('world', 'ball_0/base_link', (1, 0)) == pytest.approx(
        (2.0, 3.0, math.pi / 2))
    assert poses.lookup('world', 'ball_0/base_link', (3, 0)) is None
    # A point 1 m ahead of the scanner at (2, 3) facing +y is (2, 4).
    assert tracker.to_world([[1.0, 0.0]], 2.0, 3.0, math.pi / 2)[0] == pytest.approx([2.0, 4.0])
    q = (0.0, 0.0, math.sin(0.35), math.cos(0.35))
    assert tracker.yaw_of(q) == pytest.approx(0.7)


def gas(seed, n=20):
    """Balls of radius 0.1-0.3 at up to 2 m/s in the 10 m box, none overlapping."""
    rng = np.random.default_rng(seed)
    positions, radii = [], []
    while len(positions) < n:
        r = rng.uniform(0.1, 0.3)
        p = rng.uniform(r + 0.01, 10.0 - r - 0.01, 2)
        if all(math.dist(p, q) > r + s + 0.01 for q, s in zip(positions, radii)):
            positions.append(p)
            radii.append(r)
    heading = rng.uniform(0.0, 2.0 * math.pi, n)
    speed = rng.uniform(0.0, 2.0, n)
    velocities = np.column_stack((speed * np.cos(heading), speed * np.sin(heading)))
    return World(positions, velocities, radii, math.pi * np.square(radii), walls=BOX,
                 backend='numpy')


def tracked_run(seed, track=None, scans=40, steps_per_scan=10, dt=0.01):
    """Frames (every ball, visible or not, and the tracks) of a scanner riding on ball 0 and
    turning at 0.3 rad/s."""
    world = gas(seed)
    scanner = lidar.Scanner(FAN, 'numpy', seed=seed, name='ball_0')
    track = track or tracker.Tracker()
    frames = []
    for scan in range(scans):
        step = scan * steps_per_scan
        t = step * dt
        yaw = 0.3 * t
        origin = world.positions[0].copy()
        ranges = scanner.scan(world.positions, world.radii, world.walls, origin, yaw, 0, step)
        found = tracker.to_world(tracker.detect(ranges, GEOMETRY), *origin, yaw)
        tracks = track.update(t, found)
        seen = lidar.seen_balls(world.positions, world.radii, world.walls, origin, yaw, FAN, 0)
        visible = np.zeros(len(world), dtype=bool)
        visible[seen] = True
        frames.append(Frame(step, tuple(range(len(world))), world.positions.copy(), visible,
                            tuple(row[0] for row in tracks),
                            np.array([row[1:3] for row in tracks]).reshape(-1, 2)))
        for _ in range(steps_per_scan):
            world.step(dt)
    return frames


@pytest.mark.parametrize('seed', [0, 1])
def test_tracks_follow_the_moving_balls(seed):
    score = score_tracks(tracked_run(seed), gate=0.5).figures()
    assert score['CLR_TP'] + score['CLR_FN'] > 300
    assert score['MOTA'] > 0.7, score
    assert score['mean_distance_m'] < 0.06, score
    assert score['HOTA'] > 0.6, score


class Forgetful(tracker.Tracker):
    """A broken tracker: it drops every track after each scan (new ids every time)."""

    def update(self, time, detections):
        tracks = super().update(time, detections)
        self.tracks = []
        return tracks


class Shifted(tracker.Tracker):
    """A broken tracker: its detections are off by 0.1 m (a wrong frame offset)."""

    def update(self, time, detections):
        return super().update(time, np.asarray(detections) + [0.1, 0.0])


def test_broken_trackers_fail_the_bounds():
    forgetful = score_tracks(tracked_run(0, Forgetful()), gate=0.5).figures()
    assert forgetful['MOTA'] < 0.3 and forgetful['AssA'] < 0.2
    shifted = score_tracks(tracked_run(0, Shifted()), gate=0.5).figures()
    assert shifted['mean_distance_m'] > 0.08


def test_tracker_command_line_help_and_bad_parameters():
    from ball_world_testing.harness import run_tool
    code, out, err = run_tool('ball_world_tracker', '--help')
    assert code == 0 and 'max_misses' in out and 'ball_world_score' in out
    code, out, err = run_tool('ball_world_tracker', '--ros-args', '-p', 'gate:=-1.0')
    assert code == 2 and err.strip().splitlines() == [
        "ball_world_tracker: parameter 'gate': expected a number > 0, got -1.0"]
    code, out, err = run_tool('ball_world_tracker', '--ros-args', '-p', 'radius:=[0.3, 0.1]')
    assert code == 2 and len(err.strip().splitlines()) == 1 and "'radius'" in err
