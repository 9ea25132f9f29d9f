"""CDR encoders and decoders for the few message types ball_world publishes and records.

Why not rclpy: building 10,000 Pose objects and calling serialize_message costs tens of
milliseconds per step, while the bytes are a fixed header followed by a dense float64 block
that numpy can write in one pass. The same bytes go to the publisher (as a serialized
message) and to the MCAP recorder, so the simulation never round-trips through Python
message objects.

Format: XCDR1 plain CDR, little-endian, behind the 4-byte encapsulation header
b'\\x00\\x01\\x00\\x00'. Primitive alignment is relative to the first byte after that header
(4-byte types to 4, float64 to 8). Strings are a uint32 length that counts the trailing NUL,
the UTF-8 bytes, then the NUL. Sequences are a uint32 count followed by the elements; no
padding is written for an empty sequence, nor after the last field.

Decoders accept only the little-endian encapsulation (what every x86/ARM rmw writes) and
ignore trailing bytes, because rmw serializers may leave padding or stray bytes at the end.
"""
import functools
import struct
import threading

import numpy as np

from ball_world.core.orientation import yaw_to_quaternion

ENCAPSULATION = b'\x00\x01\x00\x00'
_HEADER_LEN = len(ENCAPSULATION)
_ENCAPSULATION_U8 = np.frombuffer(ENCAPSULATION, dtype=np.uint8)
_NS_PER_S = 10 ** 9
_INT32_MIN = -2 ** 31
_INT32_MAX = 2 ** 31 - 1

_U32 = struct.Struct('<I')
_STAMP = struct.Struct('<iI')
_VEC3 = struct.Struct('<3d')

# One pose in a PoseArray: position x, y, z then orientation x, y, z, w.
_POSE_FIELDS = 7
# z and the identity orientation (0, 0, 0, 1) shared by every pose ball_world publishes.
_POSE_CONSTANT_TAIL = np.array([0.0, 0.0, 0.0, 0.0, 1.0])

STATE_COLUMNS = 4  # x, y, vx, vy
STATE_LABELS = ('ball', 'x_y_vx_vy')


def _pad(offset: int, alignment: int) -> int:
    """Bytes of padding needed so that payload offset `offset` is a multiple of `alignment`."""
    return -offset % alignment


def _split_stamp(stamp_ns: int) -> tuple:
    """Split integer nanoseconds into builtin_interfaces/Time (sec, nanosec).

    Floor division keeps nanosec in [0, 1e9) for negative stamps too, the convention
    builtin_interfaces/Time documents (-1.7 s is sec -2, nanosec 3e8).
    """
    stamp_ns = int(stamp_ns)
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ValueError(f'stamp {stamp_ns} ns does not fit builtin_interfaces/Time')
    return sec, nanosec


def _string_bytes(text: str, offset: int) -> bytes:
    """A CDR string starting at payload offset `offset` (padding before the length included)."""
    raw = text.encode('utf-8')
    if b'\x00' in raw:
        raise ValueError(f'CDR strings cannot contain NUL: {text!r}')
    return b'\x00' * _pad(offset, 4) + _U32.pack(len(raw) + 1) + raw + b'\x00'


def _header_payload(stamp_ns: int, frame_id: str) -> bytes:
    """std_msgs/Header at payload offset 0: stamp (sec, nanosec) then frame_id."""
    return _STAMP.pack(*_split_stamp(stamp_ns)) + _string_bytes(frame_id, _STAMP.size)


class _Scratch:
    """A reusable output buffer: header + prefix + a float64 block, copied out by tobytes().

    Why reuse: a fresh 560 kB numpy buffer per 10,000-ball message costs ~0.5 ms in page faults
    on first touch, several times the cost of filling it. Reusing one buffer also lets the
    constant pose fields (z, identity orientation) survive between calls with the same layout.
    The lock makes concurrent encoders safe; the block is 8-aligned in memory because the
    allocation starts 4 bytes before the buffer.
    """

    def __init__(self):
        self.lock = threading.Lock()
        self.raw = np.empty(0, dtype=np.uint8)
        self.layout = None  # what the float64 block's constant fields were last written for

    def prepare(self, prefix: bytes, count: int) -> tuple:
        """Write header + prefix + padding; return (buffer, float64 block, layout key).

        Call with self.lock held. The layout key changes whenever the block may have moved or
        been reallocated, so callers rewrite constant fields when it differs from self.layout.
        """
        block_at = len(prefix) + (_pad(len(prefix), 8) if count else 0)
        total = _HEADER_LEN + block_at + 8 * count
        if self.raw.size < total + 4:
            self.raw = np.empty(total + 4 + total // 4, dtype=np.uint8)
            self.layout = None
        buf = self.raw[4:4 + total]
        buf[:_HEADER_LEN] = _ENCAPSULATION_U8
        buf[_HEADER_LEN:_HEADER_LEN + len(prefix)] = np.frombuffer(prefix, dtype=np.uint8)
        buf[_HEADER_LEN + len(prefix):_HEADER_LEN + block_at] = 0
        block = buf[_HEADER_LEN + block_at:].view(np.float64)
        return buf, block, (block_at, count)


_POSE_SCRATCH = _Scratch()
_STATE_SCRATCH = _Scratch()


def _as_rows(array, columns: int, name: str) -> np.ndarray:
    """Validate an (N, columns) float array; an empty input of any shape means N = 0."""
    array = np.asarray(array, dtype=np.float64)
    if array.size == 0:
        return array.reshape(0, columns)
    if array.ndim != 2 or array.shape[1] != columns:
        raise ValueError(f'{name} must have shape (N, {columns}), got {array.shape}')
    return array


def encode_pose_array(positions: np.ndarray, stamp_ns: int, frame_id: str,
                      headings=None) -> bytes:
    """geometry_msgs/msg/PoseArray: pose i at (x_i, y_i, 0) with identity orientation.

    headings: (rows, yaws) of the poses that turn (the agents), their orientation the
    rotation by yaw about z (core.orientation: w >= 0); None: all identity.
    """
    positions = _as_rows(positions, 2, 'positions')
    n = positions.shape[0]
    prefix = _header_payload(stamp_ns, frame_id)
    prefix += b'\x00' * _pad(len(prefix), 4) + _U32.pack(n)
    with _POSE_SCRATCH.lock:
        buf, block, layout = _POSE_SCRATCH.prepare(prefix, n * _POSE_FIELDS)
        poses = block.reshape(n, _POSE_FIELDS)
        if _POSE_SCRATCH.layout != layout:
            poses[:, 2:] = _POSE_CONSTANT_TAIL
            _POSE_SCRATCH.layout = layout
        poses[:, :2] = positions
        if headings is None:
            return buf.tobytes()
        rows, yaws = headings
        poses[rows, 3:] = yaw_to_quaternion(np.asarray(yaws, dtype=np.float64))
        data = buf.tobytes()
        poses[rows, 3:] = _POSE_CONSTANT_TAIL[1:]  # the identity again, for the next call
        return data


def rows_layout(labels, count: int, columns: int) -> bytes:
    """The MultiArrayLayout and data length of a Float64MultiArray of `count` rows of
    `columns`: dims (labels[0], count, count * columns), (labels[1], columns, columns),
    data_offset 0 (how `state` and a swarm's `agent_commands` lay out their rows)."""
    dims = ((labels[0], count, count * columns), (labels[1], columns, columns))
    out = _U32.pack(len(dims))
    for label, size, stride in dims:
        out += _string_bytes(label, len(out))
        out += b'\x00' * _pad(len(out), 4) + struct.pack('<II', size, stride)
    return out + b'\x00' * _pad(len(out), 4) + struct.pack('<II', 0, count * columns)


@functools.lru_cache(maxsize=8)
def _state_prefix(n: int) -> bytes:
    """The MultiArrayLayout and data length of a state message: they depend only on N."""
    return rows_layout(STATE_LABELS, n, STATE_COLUMNS)


def encode_state(positions: np.ndarray, velocities: np.ndarray, stamp_ns=None) -> bytes:
    """std_msgs/msg/Float64MultiArray with rows (x, y, vx, vy), one per ball.

    Layout dims: ('ball', N, 4N) and ('x_y_vx_vy', 4, 4), data_offset 0. Float64MultiArray
    has no header, so `stamp_ns` is accepted for symmetry with the other encoders and ignored.
    """
    positions = _as_rows(positions, 2, 'positions')
    velocities = _as_rows(velocities, 2, 'velocities')
    n = positions.shape[0]
    if velocities.shape[0] != n:
        raise ValueError(f'{n} positions but {velocities.shape[0]} velocities')
    with _STATE_SCRATCH.lock:
        buf, block, _ = _STATE_SCRATCH.prepare(_state_prefix(n), n * STATE_COLUMNS)
        rows = block.reshape(n, STATE_COLUMNS)
        rows[:, :2] = positions
        rows[:, 2:] = velocities
        return buf.tobytes()


def encode_float64_vector(values, labels) -> bytes:
    """std_msgs/msg/Float64MultiArray of a few named numbers: one dim per value, in order.

    dim i is (labels[i], size 1, stride 1): it names data[i] where readers show the layout
    (Foxglove's raw message view, `ros2 topic echo`), instead of one label joining all the
    names. Used for the per-step `stats` topic.
    """
    values = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    n = values.size
    if len(labels) != n:
        raise ValueError(f'{n} values but {len(labels)} labels')
    out = _U32.pack(n)
    for label in labels:
        out += _string_bytes(label, len(out))
        out += b'\x00' * _pad(len(out), 4) + struct.pack('<II', 1, 1)
    out += struct.pack('<II', 0, n)
    out += b'\x00' * (_pad(len(out), 8) if n else 0)
    return ENCAPSULATION + out + values.tobytes()


def encode_vector3_stamped(stamp_ns: int, frame_id: str, x: float, y: float,
                           z: float) -> bytes:
    """geometry_msgs/msg/Vector3Stamped: how impulses arrive and how they are recorded."""
    prefix = _header_payload(stamp_ns, frame_id)
    return (ENCAPSULATION + prefix + b'\x00' * _pad(len(prefix), 8)
            + _VEC3.pack(float(x), float(y), float(z)))


def encode_string(text: str) -> bytes:
    """std_msgs/msg/String: how world edits are published and recorded (one JSON text each)."""
    return ENCAPSULATION + _string_bytes(text, 0)


def encode_clock(stamp_ns: int) -> bytes:
    """rosgraph_msgs/msg/Clock: what /clock carries when the node drives simulated time."""
    return ENCAPSULATION + _STAMP.pack(*_split_stamp(stamp_ns))


class _Reader:
    """Bounds-checked cursor over a CDR buffer; every short read raises ValueError."""

    def __init__(self, data):
        self.data = memoryview(data).cast('B')
        if len(self.data) < _HEADER_LEN:
            raise ValueError(f'CDR buffer of {len(self.data)} bytes has no encapsulation')
        if bytes(self.data[:2]) != ENCAPSULATION[:2]:
            raise ValueError(f'not little-endian plain CDR: {bytes(self.data[:4])!r}')
        self.pos = _HEADER_LEN

    def _take(self, size: int, alignment: int) -> int:
        start = self.pos + _pad(self.pos - _HEADER_LEN, alignment)
        end = start + size
        if size < 0 or end > len(self.data):
            raise ValueError(f'CDR buffer truncated: need {end} bytes, have {len(self.data)}')
        self.pos = end
        return start

    def u32(self) -> int:
        return _U32.unpack_from(self.data, self._take(4, 4))[0]

    def stamp_ns(self) -> int:
        sec, nanosec = _STAMP.unpack_from(self.data, self._take(8, 4))
        return sec * _NS_PER_S + nanosec

    def string(self) -> str:
        length = self.u32()
        if length == 0:
            raise ValueError('CDR string length 0: the terminating NUL is missing')
        start = self._take(length, 1)
        raw = bytes(self.data[start:start + length])
        if raw[-1] != 0:
            raise ValueError('CDR string is not NUL-terminated')
        return raw[:-1].decode('utf-8')

    def f64(self, count: int) -> np.ndarray:
        if count == 0:
            return np.empty(0)
        start = self._take(8 * count, 8)
        return np.frombuffer(self.data, dtype='<f8', count=count, offset=start).copy()

    def f32(self, count: int) -> np.ndarray:
        if count == 0:
            return np.empty(0, dtype=np.float32)
        start = self._take(4 * count, 4)
        return np.frombuffer(self.data, dtype='<f4', count=count, offset=start).copy()

    def count(self, element_size: int) -> int:
        """A sequence length, checked against the bytes left so a bad length cannot OOM."""
        n = self.u32()
        if n * element_size > len(self.data) - self.pos:
            raise ValueError(f'CDR sequence of {n} elements overruns the buffer')
        return n


def decode_pose_array(data: bytes) -> tuple:
    """PoseArray bytes -> (stamp_ns, frame_id, positions (N, 2)); z and orientation dropped."""
    reader = _Reader(data)
    stamp_ns = reader.stamp_ns()
    frame_id = reader.string()
    n = reader.count(8 * _POSE_FIELDS)
    poses = reader.f64(n * _POSE_FIELDS).reshape(n, _POSE_FIELDS)
    return stamp_ns, frame_id, poses[:, :2].copy()


def decode_pose_orientations(data: bytes) -> np.ndarray:
    """PoseArray bytes -> each pose's orientation (N, 4) as (x, y, z, w)."""
    reader = _Reader(data)
    reader.stamp_ns()
    reader.string()
    n = reader.count(8 * _POSE_FIELDS)
    poses = reader.f64(n * _POSE_FIELDS).reshape(n, _POSE_FIELDS)
    return poses[:, 3:7].copy()


def decode_state_layout(data: bytes) -> tuple:
    """Float64MultiArray bytes -> (dims [(label, size, stride)], data_offset, data (M,))."""
    reader = _Reader(data)
    dims = []
    for _ in range(reader.count(12)):
        dims.append((reader.string(), reader.u32(), reader.u32()))
    data_offset = reader.u32()
    values = reader.f64(reader.count(8))
    return dims, data_offset, values


def decode_state(data: bytes) -> np.ndarray:
    """State bytes -> (N, 4) rows (x, y, vx, vy), checked against the layout encode_state writes.

    Why strict: a layout that disagrees with the data means the bytes are not ball_world state.
    """
    dims, data_offset, values = decode_state_layout(data)
    if len(dims) != 2 or dims[1][1] != STATE_COLUMNS or data_offset != 0:
        raise ValueError(f'not a ball_world state layout: dims={dims}, offset={data_offset}')
    n = dims[0][1]
    if values.size != n * STATE_COLUMNS:
        raise ValueError(f'state layout says {n} balls but data has {values.size} values')
    return values.reshape(n, STATE_COLUMNS)


def decode_vector3_stamped(data: bytes) -> tuple:
    """Vector3Stamped bytes -> (stamp_ns, frame_id, x, y, z)."""
    reader = _Reader(data)
    stamp_ns = reader.stamp_ns()
    frame_id = reader.string()
    x, y, z = (float(v) for v in reader.f64(3))
    return stamp_ns, frame_id, x, y, z


def decode_string(data: bytes) -> str:
    """std_msgs/msg/String bytes -> its text (bad UTF-8 raises ValueError too)."""
    return _Reader(data).string()
