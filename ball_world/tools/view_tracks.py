"""ball_world_view_tracks: draw a tracker's tracks into a world's live Rerun view.

A tracker (ball_world_tracker, or yours) publishes its tracks as a
visualization_msgs/MarkerArray, one sphere per track (marker id = track id), as RViz shows
them. This node does for the Rerun view what RViz's MarkerArray display does: it listens to
`<agent>/tracks` and draws each track as a ring of the sphere's size at
`arena/tracks/<agent>` of the world's recording, over the balls (no label: the balls'
names are there already).

Rerun merges what several programs log under one recording id into one recording: give the
world a `view.recording_id` and this node the same `recording_id` (ball_world_demo does).
Tracks are put on the view's `sim_time` timeline at their stamp; a reset of the world starts
its stamps again at 0 while the view's time goes on, so after one the tracks follow on from
the last time drawn (near enough for a live view: they are drawn at the present).

    ball_world_view_tracks --ros-args -p agent:=ball_1 -p recording_id:=ID \\
        -p view:=rerun+http://127.0.0.1:9876/proxy
"""
import sys

import numpy as np

from ball_world.recording.rerun_log import APPLICATION_ID, SIM_TIME, VIEW_FLUSH_SECONDS

PROG = 'ball_world_view_tracks'
#: Where a tracker's tracks go in the view: under the arena's +y-up transform.
TRACKS = 'arena/tracks'
#: Light green over a dark casing (rerun_casing: 9.8:1 on it): the ring reads on balls,
#: rays, map cells and either theme (the dark green alone had 1.13:1 on the map's cells).
TRACK_COLOR = (80, 230, 120)
#: The ring's radius, UI points (its casing is CASING_POINTS wider).
TRACK_RADIUS = 1.25
#: Vertices of a track's ring.
RING_VERTICES = 24


def rings(centres, radii):
    """(n, RING_VERTICES + 1, 2) closed circles around centres (n, 2)."""
    angles = np.linspace(0.0, 2.0 * np.pi, RING_VERTICES + 1)
    circle = np.column_stack((np.cos(angles), np.sin(angles)))
    return (np.asarray(centres, dtype=np.float64)[:, None, :]
            + np.asarray(radii, dtype=np.float64)[:, None, None] * circle[None, :, :])


def ring_strips(centres, radii):
    """rr.LineStrips2D of the tracks' rings, cased (rerun_casing), over the balls."""
    from ball_world.recording.rerun_casing import cased_strips
    return cased_strips(rings(centres, radii), TRACK_COLOR, TRACK_RADIUS, 40.0)


class TrackTimes:
    """The view's time for a track's stamp: the stamp, shifted forward after a reset so the
    times never go back (see the module doc)."""

    def __init__(self):
        self.offset_ns = 0
        self.last_ns = None

    def __call__(self, stamp_ns):
        if self.last_ns is not None and stamp_ns + self.offset_ns < self.last_ns:
            self.offset_ns = self.last_ns - stamp_ns
        self.last_ns = stamp_ns + self.offset_ns
        return self.last_ns


def _node_class():
    from rclpy.node import Node
    import rerun as rr
    from visualization_msgs.msg import Marker, MarkerArray

    from ball_world.recording.rerun_outlet import finish_view, new_stream, parse_view

    class ViewTracks(Node):
        """<agent>/tracks in, rings in the Rerun view out."""

        def __init__(self):
            super().__init__('ball_world_view_tracks')
            self.agent = self.text('agent', 'ball_0')
            view = self.text('view', 'rerun+http://127.0.0.1:9876/proxy')
            recording = self.text('recording_id', '')
            try:
                parse_view(view)
            except ValueError as error:
                raise ValueError(f"parameter 'view': {error}") from None
            if not recording:
                raise ValueError("parameter 'recording_id': give the world's view.recording_id")
            self.rr = rr
            self.stream = new_stream(APPLICATION_ID, recording, flush_seconds=VIEW_FLUSH_SECONDS)
            self.view = view
            self.connected = False
            self.entity = f'{TRACKS}/{self.agent}'
            self.times = TrackTimes()
            self.create_subscription(MarkerArray, f'{self.agent}/tracks', self.on_tracks, 10)
            self.sphere = Marker.SPHERE
            self.get_logger().info(f'drawing {self.agent}/tracks into {view}')

        def text(self, name, default):
            value = self.declare_parameter(name, default).value
            if not isinstance(value, str):
                raise ValueError(f"parameter '{name}': expected a string, got {value!r}")
            return value

        def on_tracks(self, msg):
            spheres = [m for m in msg.markers if m.type == self.sphere]
            if not msg.markers:
                return
            if not self.connected:
                # Only once tracks come, so after the world opened the recording with its
                # layout: a viewer that met this stream first would lay the page out itself.
                self.stream.connect_grpc(self.view)
                self.connected = True
            stamp = msg.markers[-1].header.stamp
            self.stream.set_time(SIM_TIME, duration=np.timedelta64(
                self.times(stamp.sec * 1_000_000_000 + stamp.nanosec), 'ns'))
            centres = np.array([(m.pose.position.x, m.pose.position.y) for m in spheres],
                               dtype=np.float64).reshape(-1, 2)
            radii = np.array([0.5 * m.scale.x for m in spheres], dtype=np.float64)
            self.stream.log(self.entity, ring_strips(centres, radii))

        def close(self):
            if self.connected:  # bounded: the viewer may have gone first (rerun_outlet)
                finish_view(self.stream, self.view)

    return ViewTracks


def main(args=None):
    import rclpy
    from rclpy.utilities import remove_ros_args

    from ball_world.ros.rcl_init import creating_node
    from ball_world.ros.stopping import stopped_by_signal
    argv = sys.argv if args is None else args
    try:
        own = remove_ros_args(argv)[1:]
    except Exception as error:  # noqa: B902 - rcl reports bad arguments as generic errors
        fail(f'bad ROS arguments: {error}')
    if own in (['-h'], ['--help']):
        print(f'usage: {PROG} [--ros-args -p NAME:=VALUE ...]\n\n{__doc__}')
        return 0
    if own:
        fail(f"unrecognized arguments: {' '.join(own)} (see --help)")
    node = None
    try:
        with stopped_by_signal():
            rclpy.init(args=argv)
            with creating_node(PROG):
                node = _node_class()()
            while rclpy.ok():
                rclpy.spin_once(node, timeout_sec=0.1)
    except ValueError as error:
        fail(error)
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def fail(message):
    print(f'{PROG}: {message}', file=sys.stderr)
    sys.exit(2)


if __name__ == '__main__':
    sys.exit(main())
