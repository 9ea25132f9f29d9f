"""RViz markers: a sphere per ball (scale = diameter) and the walls as one line list.

Why bytes and not Marker objects: rclpy needs about 0.2 s to convert a MarkerArray of 10,000
spheres, which would cost a 100 Hz world twenty steps. Every sphere of a world has the same
layout (same namespace, frame and empty strings), so its CDR block is the same but for a
few numbers. The builder has rclpy serialize a two-sphere template once per world, finds
where id, stamp, position, scale and colour sit in a sphere's block (sentinel values), and
then writes N blocks with numpy. The walls marker is serialized once and appended; the
array is published on a transient-local topic, so a late RViz still gets the walls.
"""
import colorsys

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

#: Line width of the walls, m.
WALL_WIDTH = 0.05
_COUNT = 4  # offset of the markers sequence length: right after the encapsulation header


def ball_colour(index):
    """A stable, well-spread colour per ball index (golden-ratio hues): (r, g, b) in 0..1."""
    hue = (index * 0.618033988749895) % 1.0
    return colorsys.hsv_to_rgb(hue, 0.65, 0.95)


def ball_colours(count):
    """ball_colour for balls 0..count-1, as a (count, 3) array."""
    return np.array([ball_colour(i) for i in range(count)]).reshape(-1, 3)


def _stamp(stamp_ns):
    sec, nanosec = divmod(int(stamp_ns), 10**9)
    return Time(sec=sec, nanosec=nanosec)


def _sphere(index, frame_id, x, y, scale, rgb, stamp):
    marker = Marker(ns='balls', id=index, type=Marker.SPHERE, action=Marker.ADD)
    marker.header.frame_id = frame_id
    marker.header.stamp = stamp
    marker.pose.position.x = x
    marker.pose.position.y = y
    marker.pose.orientation.w = 1.0
    marker.scale.x, marker.scale.y, marker.scale.z = scale
    marker.color = ColorRGBA(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0)
    return marker


def _find(block, value, dtype):
    """Offset of the one place a sentinel value is written in a marker's bytes."""
    needle = np.array([value], dtype=dtype).tobytes()
    at = block.find(needle)
    if at < 0 or block.find(needle, at + 1) >= 0:
        raise ValueError(f'sentinel {value} not found exactly once')
    return at


class SphereLayout:
    """Where the varying fields of one sphere marker sit, learned from rclpy's own bytes."""

    # Sentinels: values that occur nowhere else in a marker's bytes.
    X, Y, R, G, B = 1234.5625, -4321.125, 0.1234567, 0.3456789, 0.5678912
    SCALE = (777.25, 778.25, 779.25)
    SEC, NANOSEC, ID = 1_234_567, 987_654_321, 0x5EED

    def __init__(self, frame_id):
        stamp = Time(sec=self.SEC, nanosec=self.NANOSEC)
        spheres = [_sphere(self.ID + k, frame_id, self.X, self.Y, self.SCALE,
                           (self.R, self.G, self.B), stamp) for k in range(2)]
        one = serialize_message(MarkerArray(markers=spheres[:1]))
        two = serialize_message(MarkerArray(markers=spheres))
        self.stride = len(two) - len(one)
        start = _COUNT + 4
        block = two[start:start + self.stride]
        if self.stride % 8:
            raise ValueError('sphere blocks are not a multiple of 8 bytes')
        self.block = np.frombuffer(block, dtype=np.uint8).copy()
        self.id = _find(block, self.ID, '<i4')
        self.sec = _find(block, self.SEC, '<i4')
        self.nanosec = _find(block, self.NANOSEC, '<u4')
        self.x = _find(block, self.X, '<f8')
        self.y = _find(block, self.Y, '<f8')
        self.scale = [_find(block, value, '<f8') for value in self.SCALE]
        self.rgb = [_find(block, value, '<f4') for value in (self.R, self.G, self.B)]
        # rclpy leaves stray bytes in padding, so blocks cannot be compared byte for byte:
        # check instead that two copies of the block, ids rewritten, decode as two spheres.
        pair = np.tile(self.block, (2, 1))
        pair[:, self.id:self.id + 4] = np.arange(2, dtype='<i4').view(np.uint8).reshape(2, 4)
        decoded = deserialize_message(two[:start] + pair.tobytes(), MarkerArray).markers
        if [(m.id, m.pose.position.x, m.scale.z) for m in decoded] != [
                (0, self.X, self.SCALE[2]), (1, self.X, self.SCALE[2])]:
            raise ValueError('sphere blocks do not repeat')


class MarkerBuilder:
    """Keeps the MarkerArray bytes of one world and refreshes the sphere positions."""

    def __init__(self):
        self._layout = None
        self._blocks = None
        self._wall_marker = None
        self._count = 0

    def reset(self, radii, walls, frame_id):
        """Prepare the markers of a new world (delete_all() clears the old ones in RViz)."""
        n = len(radii)
        self._count = n + (1 if len(walls) else 0)
        layout = self._layout = SphereLayout(frame_id)
        blocks = np.tile(layout.block, (n, 1))
        blocks[:, layout.id:layout.id + 4] = np.arange(n, dtype='<i4').view(np.uint8).reshape(
            n, 4)
        for offset in layout.scale:
            self._write_f8(blocks, offset, 2.0 * np.asarray(radii, dtype=np.float64))
        colours = ball_colours(n).astype('<f4')
        for channel, offset in enumerate(layout.rgb):
            blocks[:, offset:offset + 4] = colours[:, channel:channel + 1].copy().view(
                np.uint8)
        self._blocks = blocks
        self._wall_marker = None
        if len(walls):
            marker = Marker(ns='walls', id=0, type=Marker.LINE_LIST, action=Marker.ADD)
            marker.header.frame_id = frame_id
            marker.pose.orientation.w = 1.0
            marker.scale.x = WALL_WIDTH
            marker.color = ColorRGBA(r=0.85, g=0.85, b=0.85, a=1.0)
            marker.points = [Point(x=float(x), y=float(y)) for x1, y1, x2, y2 in walls
                             for x, y in ((x1, y1), (x2, y2))]
            self._wall_marker = marker

    @staticmethod
    def _write_f8(blocks, offset, values):
        blocks[:, offset:offset + 8] = np.ascontiguousarray(values, dtype='<f8').view(
            np.uint8).reshape(-1, 8)

    def delete_all(self):
        """A MarkerArray that clears every marker this node published before."""
        return MarkerArray(markers=[Marker(action=Marker.DELETEALL)])

    def build(self, positions, stamp_ns):
        """The MarkerArray, as CDR bytes, for the current positions and stamp."""
        layout = self._layout
        blocks = self._blocks
        sec, nanosec = divmod(int(stamp_ns), 10**9)
        blocks[:, layout.sec:layout.sec + 4] = np.frombuffer(
            np.array([sec], '<i4').tobytes(), np.uint8)
        blocks[:, layout.nanosec:layout.nanosec + 4] = np.frombuffer(
            np.array([nanosec], '<u4').tobytes(), np.uint8)
        self._write_f8(blocks, layout.x, positions[:, 0])
        self._write_f8(blocks, layout.y, positions[:, 1])
        walls = b''
        if self._wall_marker is not None:
            # The sphere blocks are multiples of 8 bytes, so the walls block has the same
            # alignment after them as first in an array of its own.
            self._wall_marker.header.stamp = _stamp(stamp_ns)
            walls = serialize_message(MarkerArray(markers=[self._wall_marker]))[_COUNT + 4:]
        header = b'\x00\x01\x00\x00' + np.array([self._count], '<u4').tobytes()
        return header + blocks.tobytes() + walls
