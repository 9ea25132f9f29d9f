"""nav_msgs/msg/OccupancyGrid as CDR bytes, written and read with numpy (see msgs.cdr).

Why by hand: a 2-million-cell map as an rclpy message is a Python sequence of 2 million ints
(seconds to build and convert); its bytes are a short header and the cells' int8 block, which
numpy writes in one copy. The same bytes are published on `map`, recorded in the MCAP and
decoded by replay, info and the tests.

Layout after the encapsulation header: header (stamp, frame_id), info (map_load_time,
resolution float32, width and height uint32, origin pose: position and orientation float64,
8-aligned), data (uint32 count, then one int8 per cell, row 0 first: the map's bottom row).
"""
import struct
from typing import NamedTuple

import numpy as np

from ball_world.msgs.cdr import _header_payload, _pad, _split_stamp, ENCAPSULATION

_INFO_HEAD = struct.Struct('<iIfII')  # map_load_time sec, nanosec; resolution; width, height
_POSE = struct.Struct('<7d')
_U32 = struct.Struct('<I')


class DecodedGrid(NamedTuple):
    """An OccupancyGrid's fields as plain values; data int8 (height, width), row 0 bottom."""

    stamp_ns: int
    frame_id: str
    load_time_ns: int
    resolution: float  # the float32 the message carries, as a Python float
    width: int
    height: int
    origin: tuple  # position x, y, z, orientation x, y, z, w
    data: np.ndarray


def encode_occupancy_grid(stamp_ns, frame_id, occupancy_map):
    """The OccupancyGrid nav2_map_server publishes for a core.occupancy_map.OccupancyMap.

    Stamp and map_load_time are `stamp_ns` (the simulation time the map is published at);
    the origin's orientation is the yaw's (always 0 here: other yaws are refused).
    """
    data = np.ascontiguousarray(occupancy_map.data, dtype=np.int8)
    height, width = data.shape
    yaw = occupancy_map.yaml.origin[2]
    x, y = occupancy_map.origin
    head = _header_payload(stamp_ns, frame_id)
    head += b'\x00' * _pad(len(head), 4)
    head += _INFO_HEAD.pack(*_split_stamp(stamp_ns), occupancy_map.yaml.resolution, width,
                            height)
    head += b'\x00' * _pad(len(head), 8)
    head += _POSE.pack(x, y, 0.0, 0.0, 0.0, np.sin(yaw * 0.5), np.cos(yaw * 0.5))
    head += _U32.pack(data.size)
    return b''.join((ENCAPSULATION, head, data.tobytes()))


def decode_occupancy_grid(message):
    """DecodedGrid of an OccupancyGrid's CDR bytes (ValueError for anything else)."""
    if len(message) < 4 or bytes(message[:4]) != ENCAPSULATION:
        raise ValueError('not little-endian CDR')
    payload = memoryview(message)[4:]
    try:
        sec, nanosec, length = struct.unpack_from('<iII', payload, 0)
        end = 12 + length
        if length < 1 or end > len(payload) or payload[end - 1] != 0:
            raise ValueError('bad frame_id')
        frame_id = bytes(payload[12:end - 1]).decode('utf-8')
        offset = end + _pad(end, 4)
        load_sec, load_nanosec, resolution, width, height = _INFO_HEAD.unpack_from(
            payload, offset)
        offset += _INFO_HEAD.size
        offset += _pad(offset, 8)
        origin = _POSE.unpack_from(payload, offset)
        offset += _POSE.size
        (count,) = _U32.unpack_from(payload, offset)
        offset += 4
    except (struct.error, UnicodeDecodeError) as error:
        raise ValueError(f'truncated or corrupt OccupancyGrid: {error}') from None
    if count != width * height or offset + count > len(payload):
        raise ValueError(f'OccupancyGrid of {width} x {height} cells holds {count} values in '
                         f'{len(payload) - offset} bytes')
    data = np.frombuffer(payload, dtype=np.int8, count=count, offset=offset)
    return DecodedGrid(stamp_ns=sec * 10**9 + nanosec, frame_id=frame_id,
                       load_time_ns=load_sec * 10**9 + load_nanosec,
                       resolution=float(resolution), width=width, height=height,
                       origin=origin, data=data.reshape(height, width))
