"""CDR encoders and decoders of the agents' messages: Odometry, TFMessage and LaserScan.

Why not rclpy: the same reason as cdr.py. With 100 agents every step publishes 100 Odometry
messages and a /tf message of 100 transforms; building them as Python objects and serializing
them costs milliseconds, while their bytes are fixed strings (frame names) around dense float64
blocks that numpy fills in one pass. The bytes go both to the publishers (raw) and to the MCAP
recorder. Format, alignment and strings are those of cdr.py (XCDR1 plain CDR, little-endian).

The messages of one set of frame names always have the same layout, so it is worked out once:
a template of the message bytes with the offsets of every stamp and every float64 block. A step
then writes the stamps and the numbers into the template and copies the bytes out. The
templates are cached per set of frame names (agents are few and change rarely).

Agents are planar: a pose is (x, y) with z 0 and a heading (yaw about z, as a quaternion with
w >= 0, core/orientation.py), a twist (vx, vy, wz) with the other components 0.

Covariances of ground truth are zeros, a documented choice: it is exact to the bit, and a zero
covariance says "known exactly" (Stage and Flatland's ground-truth odometry do the same); so is
odom without agent.odom.noise. With noise, odom carries the motion model's covariances
(core.odometry). Consumers that need a positive-definite covariance from ground truth (a
Kalman filter fusing it) should treat it as a measurement of their own choosing.
"""
import functools
import struct
import threading
from typing import NamedTuple

import numpy as np

from ball_world.core.orientation import yaw_to_quaternion
from ball_world.msgs.cdr import (_HEADER_LEN, _pad, _Reader, _split_stamp,
                                 _STAMP, _string_bytes, ENCAPSULATION, rows_layout)

# Odometry after child_frame_id: pose (position 3, orientation 4), its covariance (36),
# twist (linear 3, angular 3), its covariance (36): one float64 block.
_COVARIANCE = 36
_ODOM_POSE = slice(0, 7)
_ODOM_POSE_COVARIANCE = slice(7, 7 + _COVARIANCE)
_ODOM_TWIST = slice(7 + _COVARIANCE, 13 + _COVARIANCE)
_ODOM_TWIST_COVARIANCE = slice(13 + _COVARIANCE, 13 + 2 * _COVARIANCE)
_ODOM_FLOATS = 13 + 2 * _COVARIANCE
# A transform: translation (3) then rotation (4).
_TRANSFORM_FLOATS = 7
_U32 = struct.Struct('<I')


class _PayloadBuilder:
    """Writes one message payload (the bytes after the encapsulation), noting where its stamps
    and float64 blocks are: the template a _Batch fills."""

    def __init__(self):
        self.out = bytearray()
        self.stamps = []  # payload offsets of builtin_interfaces/Time fields
        self.blocks = []  # payload offsets of float64 blocks, in order

    def align(self, alignment: int):
        self.out += b'\x00' * _pad(len(self.out), alignment)

    def u32(self, value: int):
        self.align(4)
        self.out += _U32.pack(value)

    def stamp(self):
        self.align(4)
        self.stamps.append(len(self.out))
        self.out += bytes(8)

    def string(self, text: str):
        self.out += _string_bytes(text, len(self.out))

    def float64_block(self, count: int):
        self.align(8)
        self.blocks.append(len(self.out))
        self.out += bytes(8 * count)


class _Batch:
    """Messages of a fixed layout in one reusable buffer: stamps and numbers written in place.

    Each message is placed so that its payload starts 8-aligned in memory: a float64 block,
    8-aligned within the payload, is then a slice of one float64 view of the whole buffer, and
    all blocks are written with a single fancy-indexed assignment. Every block of a batch has
    the same number of floats.
    """

    def __init__(self, payloads, block_floats: int):
        spans, stamps, blocks = [], [], []
        at = 4  # the allocation starts 4 bytes before an 8-aligned payload
        for payload in payloads:
            start = at + _HEADER_LEN
            spans.append((at, start + len(payload.out)))
            stamps += [start + offset for offset in payload.stamps]
            blocks += [start + offset for offset in payload.blocks]
            at = start + len(payload.out)
            at += _pad(at + _HEADER_LEN, 8)
        self.raw = np.zeros(at + 8, dtype=np.uint8)
        for (begin, end), payload in zip(spans, payloads):
            self.raw[begin:begin + _HEADER_LEN] = np.frombuffer(ENCAPSULATION, dtype=np.uint8)
            self.raw[begin + _HEADER_LEN:end] = np.frombuffer(bytes(payload.out), dtype=np.uint8)
        self.spans = spans
        self.stamp_words = np.asarray(stamps, dtype=np.intp) // 4
        self.float_index = (np.asarray(blocks, dtype=np.intp)[:, None] // 8
                            + np.arange(block_floats))
        self.words = self.raw.view(np.uint32)
        self.floats = self.raw[:self.raw.size // 8 * 8].view(np.float64)
        self.lock = threading.Lock()

    def fill(self, stamp_ns: int, values: np.ndarray) -> list:
        """Write one stamp into every Time field and values (blocks, floats) into the blocks;
        return each message's bytes."""
        sec, nanosec = _split_stamp(stamp_ns)
        with self.lock:
            self.words[self.stamp_words] = sec & 0xFFFFFFFF
            self.words[self.stamp_words + 1] = nanosec
            self.floats[self.float_index] = values
            raw = self.raw
            return [raw[begin:end].tobytes() for begin, end in self.spans]


def _names(names, what: str) -> tuple:
    names = tuple(names)
    if not _all_strings(names):
        raise ValueError(f'{what} must be strings')
    return names


@functools.lru_cache(maxsize=16)
def _all_strings(names: tuple) -> bool:
    """Whether every name is a string, remembered: a step names the same agents as the last
    (the check cost 1.7 ms a call at 1,000 agents, three calls a step)."""
    return all(isinstance(name, str) for name in names)


def _frame_pairs(frame_ids, child_frame_ids) -> tuple:
    """Validated frame_ids and child_frame_ids as tuples, one pair per agent (Odometry and
    TFMessage name each agent's frames alike)."""
    frame_ids = _names(frame_ids, 'frame_ids')
    child_frame_ids = _names(child_frame_ids, 'child_frame_ids')
    if len(child_frame_ids) != len(frame_ids):
        raise ValueError(f'{len(frame_ids)} frame_ids but {len(child_frame_ids)} '
                         'child_frame_ids')
    return frame_ids, child_frame_ids


def _planar(positions, yaws, twists, count: int) -> tuple:
    """Validated (N, 2) positions, (N,) yaws and (N, 3) twists for `count` agents."""
    positions = np.asarray(positions, dtype=np.float64)
    yaws = np.asarray(yaws, dtype=np.float64)
    if count == 0 and positions.size == 0 and yaws.size == 0:
        positions, yaws = positions.reshape(0, 2), yaws.reshape(0)
    if positions.shape != (count, 2) or yaws.shape != (count,):
        raise ValueError(f'{count} agents need positions (N, 2) and yaws (N,), got '
                         f'{positions.shape} and {yaws.shape}')
    if twists is not None:
        twists = np.asarray(twists, dtype=np.float64)
        if twists.size == 0 and count == 0:
            twists = twists.reshape(0, 3)
        if twists.shape != (count, 3):
            raise ValueError(f'{count} agents need twists (N, 3) (vx, vy, wz), got '
                             f'{twists.shape}')
    return positions, yaws, twists


@functools.lru_cache(maxsize=8)
def _odometry_batch(frame_ids: tuple, child_frame_ids: tuple) -> _Batch:
    payloads = []
    for frame_id, child_frame_id in zip(frame_ids, child_frame_ids):
        payload = _PayloadBuilder()
        payload.stamp()
        payload.string(frame_id)
        payload.string(child_frame_id)
        payload.float64_block(_ODOM_FLOATS)
        payloads.append(payload)
    return _Batch(payloads, _ODOM_FLOATS)


def encode_odometry(stamp_ns: int, frame_ids, child_frame_ids, positions, yaws,
                    twists, pose_covariances=None, twist_covariances=None) -> list:
    """nav_msgs/msg/Odometry of each agent: one message's bytes per agent, in order.

    Agent i: header (stamp_ns, frame_ids[i]), child_frame_ids[i], pose (x, y, 0) with the
    heading yaws[i] as a quaternion, twist (vx, vy, 0) and (0, 0, wz) from twists[i], which are
    in the child frame (REP 105: odometry's twist is in the body frame). Covariances: (N, 36)
    row-major 6x6 each when given, else zeros (see the module's docstring).
    """
    frame_ids, child_frame_ids = _frame_pairs(frame_ids, child_frame_ids)
    positions, yaws, twists = _planar(positions, yaws, twists, len(frame_ids))
    values = _planar_poses(positions, yaws, _ODOM_FLOATS)
    twist = values[:, _ODOM_TWIST]
    twist[:, 0:2] = twists[:, 0:2]
    twist[:, 5] = twists[:, 2]
    if pose_covariances is not None:
        values[:, _ODOM_POSE_COVARIANCE] = pose_covariances
    if twist_covariances is not None:
        values[:, _ODOM_TWIST_COVARIANCE] = twist_covariances
    return _odometry_batch(frame_ids, child_frame_ids).fill(stamp_ns, values)


def _planar_poses(positions, yaws, width):
    """Rows of `width` floats starting with a pose: (x, y, 0) then the heading as a quaternion
    (x, y, z, w), the rest zero: how Odometry's pose and a Transform both begin."""
    values = np.zeros((len(positions), width))
    values[:, 0:2] = positions
    values[:, 3:7] = yaw_to_quaternion(yaws)
    return values


@functools.lru_cache(maxsize=8)
def _tf_batch(frame_ids: tuple, child_frame_ids: tuple) -> _Batch:
    payload = _PayloadBuilder()
    payload.u32(len(frame_ids))
    for frame_id, child_frame_id in zip(frame_ids, child_frame_ids):
        payload.stamp()
        payload.string(frame_id)
        payload.string(child_frame_id)
        payload.float64_block(_TRANSFORM_FLOATS)
    return _Batch([payload], _TRANSFORM_FLOATS)


def encode_tf_message(stamp_ns: int, frame_ids, child_frame_ids, positions, yaws) -> bytes:
    """tf2_msgs/msg/TFMessage of one planar transform per agent, all stamped stamp_ns.

    Transform i: frame_ids[i] -> child_frame_ids[i], translation (x, y, 0), rotation the yaw as
    a quaternion. /tf of every agent (odom -> base_link) in one message, as
    robot_state_publisher sends a whole robot's frames; /tf_static's identities are the same
    call with zero positions and yaws.
    """
    frame_ids, child_frame_ids = _frame_pairs(frame_ids, child_frame_ids)
    positions, yaws, _ = _planar(positions, yaws, None, len(frame_ids))
    values = _planar_poses(positions, yaws, _TRANSFORM_FLOATS)
    (message,) = _tf_batch(frame_ids, child_frame_ids).fill(stamp_ns, values)
    return message


def encode_laser_scan(stamp_ns: int, frame_id: str, angle_min: float, angle_max: float,
                      angle_increment: float, time_increment: float, scan_time: float,
                      range_min: float, range_max: float, ranges, intensities=()) -> bytes:
    """sensor_msgs/msg/LaserScan: the numbers as float32, as the message declares them.

    ranges (and intensities, empty when the scanner has none, as REP 117 allows) are cast to
    float32 once, vectorised; +inf and -inf (REP 117's "nothing in range" and "closer than
    range_min") stay infinite.
    """
    ranges = np.ascontiguousarray(ranges, dtype='<f4').reshape(-1)
    if isinstance(intensities, tuple) and not intensities:  # (the scanners' own: none)
        intensities_cdr = _NO_INTENSITIES
    else:
        intensities = np.ascontiguousarray(intensities, dtype='<f4').reshape(-1)
        intensities_cdr = _U32.pack(intensities.size) + intensities.tobytes()
    return _laser_scan(_STAMP.pack(*_split_stamp(stamp_ns)), frame_id,
                       (angle_min, angle_max, angle_increment, time_increment, scan_time,
                        range_min, range_max),
                       _U32.pack(ranges.size), ranges.tobytes(), intensities_cdr)


def encode_laser_scans(stamp_ns: int, frame_ids, angle_min: float, angle_max: float,
                       angle_increment: float, time_increment: float, scan_time: float,
                       range_mins, range_max: float, table) -> list:
    """encode_laser_scan of every row of `table` (N, beams), row k in frame_ids[k] with
    range_min range_mins[k], the other numbers shared, no intensities: the same bytes, made
    at once. Why: a scan step of 1,000 robots made their messages one call each, each
    casting its row and packing its numbers (3.5-6.2 ms for 1,000, 2.1-3.2 ms here, where
    the table is cast once: docs/performance.md)."""
    table = np.ascontiguousarray(table, dtype='<f4')
    count = len(frame_ids)
    if table.ndim != 2 or table.shape[0] != count or len(range_mins) != count:
        raise ValueError(f'{count} frames, {len(range_mins)} range_mins and a table of '
                         f'shape {table.shape} do not make one scan each')
    stamp = _STAMP.pack(*_split_stamp(stamp_ns))
    samples = _U32.pack(table.shape[1])
    rows = table.tobytes()
    width = table.shape[1] * 4
    messages = []
    for k, (frame_id, range_min) in enumerate(zip(frame_ids, range_mins)):
        messages.append(_laser_scan(
            stamp, frame_id, (angle_min, angle_max, angle_increment, time_increment,
                              scan_time, range_min, range_max),
            samples, rows[k * width:(k + 1) * width], _NO_INTENSITIES))
    return messages


def _laser_scan(stamp, frame_id, numbers, *sequences):
    """A LaserScan's bytes from its packed stamp, its frame, its seven numbers (float64,
    sent as float32) and its two sequences as CDR has them (length, then float32s): what
    both encoders above write."""
    prefix = stamp + _frame_string(frame_id)
    return b''.join((ENCAPSULATION, prefix, b'\x00' * _pad(len(prefix), 4),
                     _scan_fields(_FIELDS.pack(*numbers)), *sequences))


#: An empty float32 sequence, as CDR has it: its length, 0.
_NO_INTENSITIES = b'\x00' * 4
#: LaserScan's seven numbers before its ranges, as float64 (a cache key: every bit counts,
#: so -0.0 is not 0.0).
_FIELDS = struct.Struct('<7d')


@functools.lru_cache(maxsize=65536)
def _scan_fields(packed):
    """The seven numbers (float64, _FIELDS) as the message's float32, rounded as numpy
    rounds them. Why kept: every scan step encodes each robot's fan again (one a robot:
    range_min follows its radius), and each made the same arrays again (with the frame's
    bytes and the empty intensities, 2 of a LaserScan's 4.7 us, measured)."""
    return np.frombuffer(packed, dtype='<f8').astype('<f4').tobytes()


@functools.lru_cache(maxsize=65536)
def _frame_string(frame_id):
    """A header's frame_id as CDR has it after the stamp (ValueError for a NUL, not kept)."""
    return _string_bytes(frame_id, _STAMP.size)


class DecodedOdometry(NamedTuple):
    """An Odometry message's fields; pose and twist as the message orders them."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    pose: np.ndarray             # (7,): position x, y, z, orientation x, y, z, w
    pose_covariance: np.ndarray  # (36,), row-major 6x6
    twist: np.ndarray            # (6,): linear x, y, z, angular x, y, z
    twist_covariance: np.ndarray  # (36,)


class DecodedTransforms(NamedTuple):
    """A TFMessage's transforms, one row per transform."""

    stamps_ns: list
    frame_ids: list
    child_frame_ids: list
    transforms: np.ndarray  # (N, 7): translation x, y, z, rotation x, y, z, w


class DecodedScan(NamedTuple):
    """A LaserScan's fields; the float32 numbers widened to float (exactly)."""

    stamp_ns: int
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: np.ndarray       # (N,) float32
    intensities: np.ndarray  # (M,) float32


def decode_odometry(data: bytes) -> DecodedOdometry:
    """Odometry bytes (ours or any rmw's) -> its fields; ValueError on malformed bytes."""
    reader = _Reader(data)
    stamp_ns = reader.stamp_ns()
    frame_id = reader.string()
    child_frame_id = reader.string()
    block = reader.f64(_ODOM_FLOATS)
    return DecodedOdometry(stamp_ns, frame_id, child_frame_id, block[_ODOM_POSE],
                           block[_ODOM_POSE_COVARIANCE], block[_ODOM_TWIST],
                           block[_ODOM_TWIST_COVARIANCE])


def decode_tf_message(data: bytes) -> DecodedTransforms:
    """TFMessage bytes -> its transforms; ValueError on malformed bytes."""
    reader = _Reader(data)
    # The smallest TransformStamped: stamp 8, two empty strings 2 x 5, padding, 7 float64.
    count = reader.count(8 + 10 + _TRANSFORM_FLOATS * 8)
    stamps, frame_ids, child_frame_ids = [], [], []
    transforms = np.empty((count, _TRANSFORM_FLOATS))
    for index in range(count):
        stamps.append(reader.stamp_ns())
        frame_ids.append(reader.string())
        child_frame_ids.append(reader.string())
        transforms[index] = reader.f64(_TRANSFORM_FLOATS)
    return DecodedTransforms(stamps, frame_ids, child_frame_ids, transforms)


def decode_laser_scan(data: bytes) -> DecodedScan:
    """LaserScan bytes -> its fields; ValueError on malformed bytes."""
    reader = _Reader(data)
    stamp_ns = reader.stamp_ns()
    frame_id = reader.string()
    fields = [float(value) for value in reader.f32(7)]
    ranges = reader.f32(reader.count(4))
    intensities = reader.f32(reader.count(4))
    return DecodedScan(stamp_ns, frame_id, *fields, ranges, intensities)


#: A swarm's commands of a step (agent.topics none): std_msgs/msg/Float64MultiArray rows
#: (ball, vx, vy, wz), its layout's dims labelled so.
COMMAND_LABELS = ('command', 'ball_vx_vy_wz')
_COMMAND_COLUMNS = 4


def encode_command_rows(rows) -> bytes:
    """Float64MultiArray of (K, 4) rows (ball, vx, vy, wz): dims (command, K, 4K) and
    (ball_vx_vy_wz, 4, 4), data_offset 0, as `state` lays out its rows."""
    rows = np.ascontiguousarray(rows, dtype='<f8').reshape(-1, _COMMAND_COLUMNS)
    out = rows_layout(COMMAND_LABELS, len(rows), _COMMAND_COLUMNS)
    out += b'\x00' * (_pad(len(out), 8) if rows.size else 0)
    return ENCAPSULATION + out + rows.tobytes()


def decode_command_rows(data: bytes) -> np.ndarray:
    """A swarm's commands (K, 4) back from their bytes; ValueError unless the layout is
    encode_command_rows' and every ball is a whole number >= 0."""
    reader = _Reader(data)
    dims = [(reader.string(), reader.u32(), reader.u32()) for _ in range(reader.count(12))]
    offset = reader.u32()
    values = reader.f64(reader.count(8))
    if ([label for label, _, _ in dims] != list(COMMAND_LABELS) or offset != 0
            or dims[1][1] != _COMMAND_COLUMNS or values.size != dims[0][1] * _COMMAND_COLUMNS):
        raise ValueError(f'not a layout of agent commands: dims={dims}, offset={offset}, '
                         f'{values.size} values')
    rows = np.array(values, dtype=np.float64).reshape(-1, _COMMAND_COLUMNS)
    balls = rows[:, 0]
    if not (np.isfinite(rows).all() and (balls >= 0).all() and (balls == np.floor(balls)).all()):
        raise ValueError('agent commands hold a ball row that is not a whole number >= 0, or '
                         'a value that is not finite')
    return rows
