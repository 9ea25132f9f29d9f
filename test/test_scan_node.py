"""<name>/scan through real processes: the node publishes each agent's LaserScan as REP 117 and
the message definition say, and ball_world_tracker, in a process of its own, turns the
scans and /tf into tracks of the balls the agent sees.

The ranges are checked against the closed form of the scene (a box and one ball), at
float32, the type LaserScan declares.
"""
import math

from ball_world_testing.harness import executable, finish, node_command
import numpy as np
import pytest
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray

#: ball_0 (the agent, r 0.3) at (3, 4) in the box [0, 10] x [0, 8]; ball_1 (r 0.5) at
#: (7, 4), straight ahead of it; both at rest. 50 Hz steps, scans at 10 Hz, no noise.
WORLD = ('rate_hz:=50.0', 'markers.rate_hz:=0.0', 'random.count:=0', 'arena:=[0, 0, 10, 8]',
         'balls.x:=[3.0, 7.0]', 'balls.y:=[4.0, 4.0]', 'balls.vx:=[0.0, 0.0]',
         'balls.vy:=[0.0, 0.0]', 'balls.radius:=[0.3, 0.5]', 'balls.mass:=[1.0, 1.0]',
         'agents:=[ball_0]', 'agent.scan.noise_stddev:=0.0', 'frame_prefix:=w1/')
DT_NS = 20_000_000


def expected_ranges():
    """From (3, 4): ball_1's near side along the beams that meet it, else the box's walls."""
    angles = -math.pi + np.arange(360) * (2.0 * math.pi / 360)
    out = []
    for a in angles:
        c, s = math.cos(a), math.sin(a)
        best = min(d for d in ((7.0 / c if c > 0 else math.inf),
                               (-3.0 / c if c < 0 else math.inf),
                               (4.0 / s if s > 0 else math.inf),
                               (-4.0 / s if s < 0 else math.inf)))
        along = 4.0 * c  # ball_1 is 4 m ahead along +x
        across = 4.0 * s
        if along > 0 and abs(across) <= 0.5:
            best = min(best, along - math.sqrt(0.25 - across * across))
        out.append(best)
    return np.array(out, dtype=np.float32)


def test_scans_are_published_stamped_framed_and_exact(probe, processes):
    process = processes.start(node_command(*WORLD))
    scans = probe.listen(LaserScan, 'ball_0/scan')
    probe.spin_until(lambda: len(scans) >= 3, 'three scans', process=process)
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in scans]
    # Every fifth step of 20 ms (10 Hz of simulated time), stamped with its step's time.
    assert all(stamp % (5 * DT_NS) == 0 for stamp in stamps)
    assert all(b - a == 5 * DT_NS for a, b in zip(stamps, stamps[1:]))
    message = scans[-1]
    assert message.header.frame_id == 'w1/ball_0/base_link'
    assert message.angle_min == pytest.approx(-math.pi)
    assert message.angle_increment == pytest.approx(2.0 * math.pi / 360)
    assert message.range_min == pytest.approx(0.35) and message.range_max == 12.0
    assert message.scan_time == pytest.approx(0.1)
    assert len(message.ranges) == 360 and len(message.intensities) == 0
    assert np.array_equal(np.array(message.ranges, dtype=np.float32), expected_ranges())
    process.send_signal(2)
    code, _, err = finish(process)
    assert code == 0 and 'Traceback' not in err


def test_the_tracker_node_tracks_the_ball_it_sees(probe, processes):
    world = processes.start(node_command(*WORLD))
    # ball_1's radius, 0.5 m, is beyond the tracker's default range of radii (the default
    # world's, 0.1-0.3 m): it is told.
    tracker = processes.start([executable('ball_world_tracker'), '--ros-args', '-p',
                               'agent:=ball_0', '-p', 'frame_prefix:=w1/', '-p',
                               'radius:=[0.2, 0.6]'])
    tracks = probe.listen(MarkerArray, 'ball_0/tracks')

    def tracked():
        return [m for array in tracks for m in array.markers if m.action == m.ADD]
    probe.spin_until(lambda: len(tracked()) >= 3, 'tracks of ball_1', process=tracker)
    for marker in tracked():
        assert marker.header.frame_id == 'world'
        assert (marker.pose.position.x, marker.pose.position.y) == pytest.approx(
            (7.0, 4.0), abs=0.02)
    assert len({marker.id for marker in tracked()}) == 1  # one ball, one track, one id
    for process in (tracker, world):
        process.send_signal(2)
        code, _, err = finish(process)
        assert code == 0 and 'Traceback' not in err, err
