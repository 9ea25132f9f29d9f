"""Many geometry_msgs/msg/Vector3Stamped of one stamp at once: the agents' drive impulses.

Why: with 100 agents a step applies up to 100 impulses, and encoding each with
cdr.encode_vector3_stamped (a header built from scratch) is most of their cost. The bytes are
the same (a test compares them): the stamp is packed once per call and each name's string
bytes, with the padding before the vector, once per name.
"""
import functools
import struct

from ball_world.msgs.cdr import _pad, _split_stamp, _string_bytes, ENCAPSULATION

_STAMP = struct.Struct('<iI')
_VEC3 = struct.Struct('<3d')


@functools.lru_cache(maxsize=4096)
def _name_part(frame_id):
    """frame_id as a CDR string after the stamp, with the padding before the float64s."""
    text = _string_bytes(frame_id, _STAMP.size)
    return text + b'\x00' * _pad(_STAMP.size + len(text), 8)


def encode_impulses(stamp_ns, frame_ids, xs, ys):
    """Vector3Stamped bytes of each (frame_id, x, y, 0), all stamped stamp_ns."""
    head = ENCAPSULATION + _STAMP.pack(*_split_stamp(stamp_ns))
    pack = _VEC3.pack
    return [head + _name_part(frame_id) + pack(x, y, 0.0)
            for frame_id, x, y in zip(frame_ids, xs, ys)]
