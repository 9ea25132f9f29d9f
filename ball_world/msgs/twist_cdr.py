"""Decoders of the velocity commands agents take: geometry_msgs/msg/Twist and TwistStamped.

Why raw bytes: a flood of cmd_vel (thousands a second from several publishers) must cost the
node as little as possible per message; reading six float64 from the CDR buffer is cheaper
than rclpy building a message object, and the bytes are what the recording keeps.
"""
import struct

from ball_world.msgs.cdr import _HEADER_LEN, _header_payload, _pad, _Reader, ENCAPSULATION

_TWIST = struct.Struct('<6d')


def decode_twist(data):
    """Twist bytes -> (linear x, y, z, angular x, y, z); ValueError on malformed bytes."""
    if len(data) >= _HEADER_LEN + _TWIST.size and data[:2] == ENCAPSULATION[:2]:
        return _TWIST.unpack_from(data, _HEADER_LEN)  # the common case, without a reader
    return tuple(float(v) for v in _Reader(data).f64(6))


def decode_twist_stamped(data):
    """TwistStamped bytes -> (stamp_ns, frame_id, (linear x, y, z, angular x, y, z))."""
    reader = _Reader(data)
    stamp_ns = reader.stamp_ns()
    frame_id = reader.string()
    return stamp_ns, frame_id, tuple(float(v) for v in reader.f64(6))


def encode_twist(vx, vy, wz):
    """Twist bytes of a planar command (linear x, y; angular z), for commands given in code."""
    return ENCAPSULATION + _TWIST.pack(vx, vy, 0.0, 0.0, 0.0, wz)


def encode_twist_stamped(stamp_ns, frame_id, vx, vy, wz):
    """TwistStamped bytes of a planar command."""
    header = _header_payload(stamp_ns, frame_id)
    return (ENCAPSULATION + header + b'\x00' * _pad(len(header), 8)
            + _TWIST.pack(vx, vy, 0.0, 0.0, 0.0, wz))
