"""The vectorised MarkerArray bytes decode, through rclpy, to the markers RViz should get."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from visualization_msgs.msg import Marker, MarkerArray

from ball_world.msgs.markers import ball_colour, MarkerBuilder

BOX = np.array([[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 10.0]])


@pytest.mark.parametrize('n', [0, 1, 7, 300])
@pytest.mark.parametrize('frame_id', ['world', 'map', 'a', 'odom_frame_long_name'])
@pytest.mark.parametrize('walls', [BOX, np.empty((0, 4))])
def test_marker_bytes_decode_to_one_sphere_per_ball_and_the_walls(n, frame_id, walls):
    rng = np.random.default_rng(n)
    radii = rng.uniform(0.1, 0.5, n)
    positions = rng.uniform(-5, 5, (n, 2))
    builder = MarkerBuilder()
    builder.reset(radii, walls, frame_id)
    stamp_ns = 12 * 10**9 + 345
    msg = deserialize_message(builder.build(positions, stamp_ns), MarkerArray)
    spheres = [m for m in msg.markers if m.ns == 'balls']
    assert len(msg.markers) == n + (1 if len(walls) else 0)
    for i, marker in enumerate(spheres):
        assert (marker.id, marker.type, marker.action) == (i, Marker.SPHERE, Marker.ADD)
        assert marker.header.frame_id == frame_id
        assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (12, 345)
        assert [marker.pose.position.x, marker.pose.position.y, marker.pose.position.z] == [
            positions[i, 0], positions[i, 1], 0.0]
        assert marker.pose.orientation.w == 1.0
        assert [marker.scale.x, marker.scale.y, marker.scale.z] == [2 * radii[i]] * 3
        expected = np.float32(ball_colour(i))
        assert [marker.color.r, marker.color.g, marker.color.b] == expected.tolist()
        assert marker.color.a == 1.0
    if len(walls):
        line = msg.markers[-1]
        assert (line.ns, line.type) == ('walls', Marker.LINE_LIST)
        assert line.header.frame_id == frame_id
        assert [(p.x, p.y) for p in line.points] == [(0, 0), (10, 0), (10, 0), (10, 10)]
    # Moving the balls rewrites only their positions.
    moved = positions + 1.0
    again = deserialize_message(builder.build(moved, stamp_ns + 1), MarkerArray)
    assert [m.pose.position.x for m in again.markers if m.ns == 'balls'] == moved[:, 0].tolist()
    assert all(m.header.stamp.nanosec == 346 for m in again.markers)
