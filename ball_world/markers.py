"""RViz markers: a sphere per ball (scale = diameter) and the walls as one line list.

Building thousands of Marker objects is the slow part of rclpy, so the builder makes them
once per world and only moves the spheres on each publish; the node publishes markers on
their own (lower) wall-clock rate, on a latched topic so a late RViz still gets the walls.
"""
import colorsys

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

#: Line width of the walls, m.
WALL_WIDTH = 0.05


def ball_colour(index):
    """A stable, well-spread colour per ball index (golden-ratio hues): (r, g, b) in 0..1."""
    hue = (index * 0.618033988749895) % 1.0
    return colorsys.hsv_to_rgb(hue, 0.65, 0.95)


def _stamp(stamp_ns):
    sec, nanosec = divmod(int(stamp_ns), 10**9)
    return Time(sec=sec, nanosec=nanosec)


class MarkerBuilder:
    """Keeps one MarkerArray per world and refreshes its sphere positions."""

    def __init__(self):
        self.frame_id = 'world'
        self._spheres = []
        self._walls = None
        self._clear = True

    def reset(self, radii, walls, frame_id):
        """Make the markers of a new world; the next build first deletes the old ones."""
        self.frame_id = frame_id
        self._spheres = []
        for i, radius in enumerate(radii):
            marker = Marker(ns='balls', id=i, type=Marker.SPHERE, action=Marker.ADD)
            marker.pose.orientation.w = 1.0
            marker.scale.x = marker.scale.y = marker.scale.z = 2.0 * float(radius)
            r, g, b = ball_colour(i)
            marker.color = ColorRGBA(r=r, g=g, b=b, a=1.0)
            self._spheres.append(marker)
        self._walls = Marker(ns='walls', id=0, type=Marker.LINE_LIST, action=Marker.ADD)
        self._walls.pose.orientation.w = 1.0
        self._walls.scale.x = WALL_WIDTH
        self._walls.color = ColorRGBA(r=0.85, g=0.85, b=0.85, a=1.0)
        self._walls.points = [Point(x=float(x), y=float(y)) for x1, y1, x2, y2 in walls
                              for x, y in ((x1, y1), (x2, y2))]
        self._clear = True

    def build(self, positions, stamp_ns, frame_id=None):
        """The MarkerArray for the current positions."""
        frame_id = frame_id or self.frame_id
        stamp = _stamp(stamp_ns)
        markers = []
        if self._clear:
            markers.append(Marker(action=Marker.DELETEALL))
            self._clear = False
        for marker, (x, y) in zip(self._spheres, positions.tolist()):
            marker.header.stamp = stamp
            marker.header.frame_id = frame_id
            marker.pose.position.x = x
            marker.pose.position.y = y
            markers.append(marker)
        if self._walls.points:
            self._walls.header.stamp = stamp
            self._walls.header.frame_id = frame_id
            markers.append(self._walls)
        return MarkerArray(markers=markers)
