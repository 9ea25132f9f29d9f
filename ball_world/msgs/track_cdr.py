"""Tracks as users publish them, read from CDR bytes: MarkerArray and PoseArray.

ball_world_score reads a user's tracker output from any ROS 2 MCAP (ros2 bag record's, or
another tool's): untrusted bytes. Every length is checked against the bytes that are there
(msgs.cdr's reader), so a bad count cannot make a huge allocation, and a message that does
not decode is a ValueError saying so, never a crash of the tool.

visualization_msgs/Marker gained fields in ROS 2 Iron (texture_resource, texture,
uv_coordinates, mesh_file); a recording says which layout it carries in its schema, so both
are read: `textured` is whether the schema has them (Iron, Jazzy and later).
"""
from typing import NamedTuple

import numpy as np

from ball_world.msgs.cdr import _Reader, decode_pose_array

MARKER_ARRAY = 'visualization_msgs/msg/MarkerArray'
POSE_ARRAY = 'geometry_msgs/msg/PoseArray'
#: Marker actions: ADD (= MODIFY) carries a track; DELETE and DELETEALL carry none.
ADD = 0


class TrackMarker(NamedTuple):
    """The fields of a Marker a track needs: its stamp, frame, identity and position."""

    stamp_ns: int
    frame_id: str
    ns: str
    id: int
    action: int
    x: float
    y: float


class _TrackReader(_Reader):
    """The CDR reader with the few more primitives a Marker has."""

    def i32(self):
        value = self.u32()
        return value - (1 << 32) if value >= 1 << 31 else value

    def skip(self, size, alignment, count):
        """Skip a sequence of `count` elements of `size` bytes (checked like any read)."""
        if count:
            self._take(size * count, alignment)

    def octets(self):
        """Skip a uint8[] (its bytes are checked to be there)."""
        self.skip(1, 1, self.count(1))

    def flag(self):
        self._take(1, 1)


def is_textured(definition):
    """Whether a MarkerArray schema's text has the fields Iron added."""
    return 'texture_resource' in definition


def decode_marker_array(data, textured=True):
    """MarkerArray bytes -> [TrackMarker] in message order (ValueError when malformed)."""
    reader = _TrackReader(data)
    # The smallest Marker: header 8 + 5, three ints, pose and scale 80, colour 16, ...
    markers = []
    for _ in range(reader.count(150)):
        stamp_ns = reader.stamp_ns()
        frame_id = reader.string()
        ns = reader.string()
        marker_id, _, action = reader.i32(), reader.i32(), reader.i32()
        pose = reader.f64(7)
        reader.f64(3)  # scale
        reader.f32(4)  # colour
        reader.i32()  # lifetime
        reader.u32()
        reader.flag()  # frame_locked
        reader.skip(24, 8, reader.count(24))  # points
        reader.skip(16, 4, reader.count(16))  # colors
        if textured:
            reader.string()  # texture_resource
            reader.stamp_ns()  # texture: CompressedImage header, format, data
            reader.string()
            reader.string()
            reader.octets()
            reader.skip(8, 4, reader.count(8))  # uv_coordinates
        reader.string()  # text
        reader.string()  # mesh_resource
        if textured:
            reader.string()  # mesh_file: filename, data
            reader.octets()
        reader.flag()  # mesh_use_embedded_materials
        markers.append(TrackMarker(stamp_ns, frame_id, ns, marker_id, action,
                                   float(pose[0]), float(pose[1])))
    return markers


def decode_poses(data):
    """PoseArray bytes -> (stamp_ns, frame_id, positions (N, 2))."""
    stamp_ns, frame_id, positions = decode_pose_array(data)
    return stamp_ns, frame_id, np.asarray(positions, dtype=np.float64)
