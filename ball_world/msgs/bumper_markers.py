"""RViz markers of the agents' bumper hits: an arrow per hit, from the agent along the impulse.

Why markers: RViz has no display for a Vector3Stamped, and a hit lasts one step. Each hit of
a step becomes an ARROW in namespace 'bumpers' (id: the agent's row), in the world frame
(frame_id), from the agent's centre along the impulse, sized as below, with a lifetime of
BUMPER_SHOWN s so RViz shows it long enough to be seen. Few per step: rclpy objects suffice.
"""
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
import numpy as np
from visualization_msgs.msg import Marker, MarkerArray


#: How a hit is drawn, in RViz here and in Rerun (recording.rerun_agents) alike: orange-red
#: (apart from the headings' yellow and the impulses' pink), as long as the velocity change
#: times BUMPER_SECONDS but at least BUMPER_MIN_RADII radii, for BUMPER_SHOWN simulated s.
BUMPER_COLOR = (255, 80, 0)
BUMPER_SECONDS = 0.25
BUMPER_MIN_RADII = 1.5
BUMPER_SHOWN = 0.5


def bumper_markers(record, frame_id):
    """The MarkerArray of a StepRecord's bumper hits, or None when no agent was hit."""
    frame = record.agents
    if frame is None or not frame.bumpers:
        return None
    sec, nanosec = divmod(int(record.stamp_ns), 10**9)
    lifetime_sec, lifetime_ns = divmod(round(BUMPER_SHOWN * 1e9), 10**9)
    row_of = {name: row for row, name in enumerate(frame.names)}
    markers = []
    for bumper in frame.bumpers:
        row = row_of[bumper.name]
        index = int(frame.indices[row])
        yaw = float(frame.yaws[row])
        cos, sin = np.cos(yaw), np.sin(yaw)
        jx, jy = cos * bumper.x - sin * bumper.y, sin * bumper.x + cos * bumper.y
        size = float(np.hypot(jx, jy))
        radius = float(record.radii[index])
        length = max(size / float(record.masses[index]) * BUMPER_SECONDS,
                     BUMPER_MIN_RADII * radius)
        x, y = (float(v) for v in record.positions[index])
        scale = length / size if size > 0.0 else 0.0
        marker = Marker(ns='bumpers', id=row, type=Marker.ARROW, action=Marker.ADD,
                        points=[Point(x=x, y=y), Point(x=x + jx * scale, y=y + jy * scale)],
                        frame_locked=False)
        marker.header.frame_id = frame_id
        marker.header.stamp = Time(sec=sec, nanosec=nanosec)
        marker.lifetime = Duration(sec=lifetime_sec, nanosec=lifetime_ns)
        marker.scale.x = 0.2 * radius  # shaft diameter
        marker.scale.y = 0.4 * radius  # head diameter
        marker.scale.z = 0.5 * radius  # head length
        marker.pose.orientation.w = 1.0
        marker.color.r, marker.color.g, marker.color.b = (c / 255.0 for c in BUMPER_COLOR)
        marker.color.a = 1.0
        markers.append(marker)
    return MarkerArray(markers=markers)
