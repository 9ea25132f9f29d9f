"""The agents' numpy CDR encoders (Odometry, TFMessage, LaserScan) against rclpy and mcap_ros2.

As in test_cdr.py, rclpy is the reference: our bytes go through deserialize_message, rclpy's
serialize_message output through our decoders, and values are compared, never bytes (rmw
leaves uninitialised padding). Frame names of every length modulo 8 move the float64 blocks
across all alignments.
"""
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage

from ball_world.core.orientation import yaw_to_quaternion
from ball_world.msgs import agent_cdr, definitions as msgdefs

COUNTS = (0, 1, 3, 100)
STAMPS = (0, 1, 999_999_999, 123_456_789_012_345, 2 ** 31 * 10 ** 9 - 1, -1_700_000_000)
RELEASED_TF_MESSAGE_HASH = (
    'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087')


def _frames(count, seed, suffix):
    """Frame names of random lengths 0..17 (every alignment, some empty), NUL-free."""
    rng = np.random.default_rng(seed)
    return [f'{"n" * int(rng.integers(0, 12))}{index}/{suffix}'[:int(rng.integers(0, 18))]
            for index in range(count)]


def _agents(count, seed):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-1e4, 1e4, size=(count, 2))
    yaws = rng.uniform(-np.pi, np.pi, size=count)
    twists = rng.normal(0.0, 3.0, size=(count, 3))
    return positions, yaws, twists


def _stamp_ns(stamp):
    return stamp.sec * 10 ** 9 + stamp.nanosec


def _time(stamp_ns):
    return Time(sec=stamp_ns // 10 ** 9, nanosec=stamp_ns % 10 ** 9)


@pytest.mark.parametrize('count', COUNTS)
def test_odometry_reads_back_through_rclpy(count):
    positions, yaws, twists = _agents(count, seed=count)
    frames, children = _frames(count, 1, 'odom'), _frames(count, 2, 'base_link')
    stamp_ns = 42_000_000_017
    messages = agent_cdr.encode_odometry(stamp_ns, frames, children, positions, yaws, twists)
    assert len(messages) == count
    for index, data in enumerate(messages):
        msg = deserialize_message(data, Odometry)
        assert _stamp_ns(msg.header.stamp) == stamp_ns
        assert (msg.header.frame_id, msg.child_frame_id) == (frames[index], children[index])
        pose, twist = msg.pose.pose, msg.twist.twist
        assert (pose.position.x, pose.position.y, pose.position.z) == (
            positions[index, 0], positions[index, 1], 0.0)
        half = yaws[index] / 2
        rotation = (pose.orientation.x, pose.orientation.y, pose.orientation.z,
                    pose.orientation.w)
        assert rotation == (0.0, 0.0, np.sin(half), np.cos(half))
        assert (twist.linear.x, twist.linear.y, twist.linear.z) == (
            twists[index, 0], twists[index, 1], 0.0)
        assert (twist.angular.x, twist.angular.y, twist.angular.z) == (0.0, 0.0, twists[index, 2])
        assert not msg.pose.covariance.any() and not msg.twist.covariance.any()


@pytest.mark.parametrize('stamp_ns', STAMPS)
def test_odometry_stamps(stamp_ns):
    (data,) = agent_cdr.encode_odometry(stamp_ns, ['odom'], ['base'], [[1.0, 2.0]], [0.5],
                                        [[0.0, 0.0, 0.0]])
    assert _stamp_ns(deserialize_message(data, Odometry).header.stamp) == stamp_ns
    assert agent_cdr.decode_odometry(data).stamp_ns == stamp_ns


@pytest.mark.parametrize('count', COUNTS)
def test_decode_odometry_matches_rclpy(count):
    rng = np.random.default_rng(10 + count)
    frames, children = _frames(count, 3, 'odom'), _frames(count, 4, 'base_link')
    for index in range(count):
        values = rng.normal(size=85)
        msg = Odometry()
        msg.header.stamp = _time(int(rng.integers(0, 2 ** 31 * 10 ** 9)))
        msg.header.frame_id, msg.child_frame_id = frames[index], children[index]
        pose, twist = msg.pose.pose, msg.twist.twist
        (pose.position.x, pose.position.y, pose.position.z, pose.orientation.x,
         pose.orientation.y, pose.orientation.z, pose.orientation.w) = values[:7].tolist()
        msg.pose.covariance = values[7:43]
        (twist.linear.x, twist.linear.y, twist.linear.z, twist.angular.x, twist.angular.y,
         twist.angular.z) = values[43:49].tolist()
        msg.twist.covariance = values[49:85]
        got = agent_cdr.decode_odometry(serialize_message(msg))
        assert got.stamp_ns == _stamp_ns(msg.header.stamp)
        assert (got.frame_id, got.child_frame_id) == (frames[index], children[index])
        np.testing.assert_array_equal(np.concatenate(
            [got.pose, got.pose_covariance, got.twist, got.twist_covariance]), values)


@pytest.mark.parametrize('count', COUNTS)
def test_tf_message_reads_back_through_rclpy(count):
    positions, yaws, _ = _agents(count, seed=20 + count)
    frames, children = _frames(count, 5, 'odom'), _frames(count, 6, 'base_link')
    stamp_ns = 7_000_000_123
    data = agent_cdr.encode_tf_message(stamp_ns, frames, children, positions, yaws)
    msg = deserialize_message(data, TFMessage)
    assert len(msg.transforms) == count
    for index, transform in enumerate(msg.transforms):
        assert _stamp_ns(transform.header.stamp) == stamp_ns
        assert (transform.header.frame_id, transform.child_frame_id) == (
            frames[index], children[index])
        t, r = transform.transform.translation, transform.transform.rotation
        assert (t.x, t.y, t.z) == (positions[index, 0], positions[index, 1], 0.0)
        half = yaws[index] / 2
        assert (r.x, r.y, r.z, r.w) == (0.0, 0.0, np.sin(half), np.cos(half))
    decoded = agent_cdr.decode_tf_message(data)
    assert decoded.stamps_ns == [stamp_ns] * count
    assert (decoded.frame_ids, decoded.child_frame_ids) == (frames, children)
    np.testing.assert_array_equal(decoded.transforms[:, :2], positions)
    np.testing.assert_array_equal(decoded.transforms[:, 3:], yaw_to_quaternion(yaws))


@pytest.mark.parametrize('count', COUNTS)
def test_decode_tf_message_matches_rclpy(count):
    rng = np.random.default_rng(30 + count)
    frames, children = _frames(count, 7, 'a'), _frames(count, 8, 'b')
    values = rng.normal(size=(count, 7))
    stamps = [int(s) for s in rng.integers(0, 2 ** 31 * 10 ** 9, size=count)]
    msg = TFMessage()
    for index in range(count):
        transform = TransformStamped()
        transform.header.stamp = _time(stamps[index])
        transform.header.frame_id, transform.child_frame_id = frames[index], children[index]
        t, r = transform.transform.translation, transform.transform.rotation
        t.x, t.y, t.z, r.x, r.y, r.z, r.w = values[index].tolist()
        msg.transforms.append(transform)
    got = agent_cdr.decode_tf_message(serialize_message(msg))
    assert got.stamps_ns == [_stamp_ns(_time(s)) for s in stamps]
    assert (got.frame_ids, got.child_frame_ids) == (frames, children)
    np.testing.assert_array_equal(got.transforms.reshape(count, 7), values)


def test_static_identities_are_the_same_call_with_zeros():
    data = agent_cdr.encode_tf_message(0, ['world', 'world'], ['ball_0/odom', 'ball_1/odom'],
                                       np.zeros((2, 2)), np.zeros(2))
    for transform in deserialize_message(data, TFMessage).transforms:
        t, r = transform.transform.translation, transform.transform.rotation
        assert (t.x, t.y, t.z, r.x, r.y, r.z, r.w) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def test_cached_layouts_do_not_leak_between_frame_sets():
    """Every template is a separate buffer: interleaved frame sets each read back their own."""
    sets = [(['a'], ['b']), (['odom_x', 'q'], ['base', 'rr']), (['a'], ['b']), ([], [])]
    for round_index in range(3):
        for set_index, (frames, children) in enumerate(sets):
            positions, yaws, twists = _agents(len(frames), seed=100 * round_index + set_index)
            stamp_ns = 10 ** 9 * round_index + set_index
            tf = agent_cdr.decode_tf_message(agent_cdr.encode_tf_message(
                stamp_ns, frames, children, positions, yaws))
            assert tf.frame_ids == frames and tf.stamps_ns == [stamp_ns] * len(frames)
            np.testing.assert_array_equal(tf.transforms[:, :2], positions)
            odometry = [agent_cdr.decode_odometry(data) for data in agent_cdr.encode_odometry(
                stamp_ns, frames, children, positions, yaws, twists)]
            assert [o.child_frame_id for o in odometry] == children
            np.testing.assert_array_equal(
                np.array([o.twist[[0, 1, 5]] for o in odometry]).reshape(-1, 3), twists)


def _scan_values(count, seed):
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.0, 20.0, size=count)
    if count:
        ranges[rng.integers(0, count, size=max(1, count // 10))] = np.inf
        ranges[rng.integers(0, count, size=max(1, count // 20))] = -np.inf
    fields = rng.uniform(-4.0, 4.0, size=7)
    return fields, ranges


@pytest.mark.parametrize('beams', (0, 1, 7, 360))
def test_laser_scans_encoded_at_once_are_each_scans_bytes(beams):
    """encode_laser_scans: row k's bytes are encode_laser_scan's of that row, frame and
    range_min, to the byte (infinities, NaN, -0.0, frames of every length, a stamp past
    2**32 ns)."""
    rng = np.random.default_rng(beams)
    count = 40
    table = rng.uniform(0.0, 12.0, size=(count, beams))
    table[rng.random(table.shape) < 0.1] = np.inf
    table[rng.random(table.shape) < 0.05] = -np.inf
    table[rng.random(table.shape) < 0.02] = np.nan
    table[rng.random(table.shape) < 0.02] = -0.0
    frames = [f'r{"x" * (k % 6)}_{k}/base_link' for k in range(count)]
    range_mins = rng.uniform(0.1, 0.4, count)
    range_mins[3] = -0.0
    shared = (-3.1, 3.05, 0.0175, 0.0, 0.1)
    stamp = 2**32 + 12_345
    batch = agent_cdr.encode_laser_scans(stamp, frames, *shared, range_mins.tolist(), 12.0,
                                         table)
    alone = [agent_cdr.encode_laser_scan(stamp, frame, *shared[:5], low, 12.0, row)
             for frame, low, row in zip(frames, range_mins.tolist(), table)]
    assert batch == alone
    with pytest.raises(ValueError, match='one scan each'):
        agent_cdr.encode_laser_scans(stamp, frames[:-1], *shared, range_mins.tolist(), 12.0,
                                     table)


def test_laser_scans_of_many_fans_and_frames_in_turn_each_read_back_their_own():
    """encode_laser_scan keeps the bytes of the fans and frames it saw (a scan step encodes
    the same few a thousand times): scans of fans that differ in one bit (0.0 and -0.0,
    NaN, the next float) and of many frames, in turn, each read back as their own."""
    rng = np.random.default_rng(5)
    fans = [rng.uniform(-4.0, 4.0, size=7) for _ in range(3)]
    fans += [fans[0].copy() for _ in range(3)]
    fans[3][5] = 0.0
    fans[4][5] = -0.0
    fans[5][6] = np.nextafter(np.float32(fans[0][6]), np.float32(np.inf))
    fans.append(np.full(7, np.nan))
    for turn in range(3):
        for k, fields in enumerate(fans):
            frame_id = f'ball_{(turn * 7 + k) % 5}/base_link'
            ranges = rng.uniform(0.0, 12.0, size=k)
            data = agent_cdr.encode_laser_scan(turn * 10 + k, frame_id, *fields, ranges)
            decoded = agent_cdr.decode_laser_scan(data)
            assert (decoded.stamp_ns, decoded.frame_id) == (turn * 10 + k, frame_id)
            assert np.asarray(decoded[2:9], dtype=np.float32).tobytes() == (
                fields.astype(np.float32).tobytes())
            assert decoded.ranges.tobytes() == ranges.astype(np.float32).tobytes()


@pytest.mark.parametrize('count', (0, 1, 3, 360))
@pytest.mark.parametrize('with_intensities', (False, True))
def test_laser_scan_reads_back_through_rclpy(count, with_intensities):
    fields, ranges = _scan_values(count, seed=count)
    intensities = np.arange(count) * 0.5 if with_intensities else ()
    frame_id = _frames(1, count, 'base_link')[0]
    data = agent_cdr.encode_laser_scan(9_000_000_001, frame_id, *fields, ranges, intensities)
    msg = deserialize_message(data, LaserScan)
    assert (_stamp_ns(msg.header.stamp), msg.header.frame_id) == (9_000_000_001, frame_id)
    got = [msg.angle_min, msg.angle_max, msg.angle_increment, msg.time_increment,
           msg.scan_time, msg.range_min, msg.range_max]
    np.testing.assert_array_equal(got, fields.astype(np.float32))
    np.testing.assert_array_equal(msg.ranges, ranges.astype(np.float32))
    np.testing.assert_array_equal(msg.intensities, np.asarray(intensities, dtype=np.float32))
    decoded = agent_cdr.decode_laser_scan(data)
    assert (decoded.stamp_ns, decoded.frame_id) == (9_000_000_001, frame_id)
    np.testing.assert_array_equal(decoded[2:9], fields.astype(np.float32))
    np.testing.assert_array_equal(decoded.ranges, ranges.astype(np.float32))


@pytest.mark.parametrize('count', (0, 5, 360))
def test_decode_laser_scan_matches_rclpy(count):
    fields, ranges = _scan_values(count, seed=50 + count)
    msg = LaserScan()
    msg.header.stamp = _time(123_000_000_456)
    msg.header.frame_id = 'ball_3/base_link'
    (msg.angle_min, msg.angle_max, msg.angle_increment, msg.time_increment, msg.scan_time,
     msg.range_min, msg.range_max) = fields.astype(np.float32).tolist()
    msg.ranges = ranges.astype(np.float32).tolist()
    msg.intensities = np.full(count, 7.0, dtype=np.float32).tolist()
    got = agent_cdr.decode_laser_scan(serialize_message(msg))
    assert (got.stamp_ns, got.frame_id) == (123_000_000_456, 'ball_3/base_link')
    np.testing.assert_array_equal(got[2:9], fields.astype(np.float32))
    np.testing.assert_array_equal(got.ranges, ranges.astype(np.float32))
    np.testing.assert_array_equal(got.intensities, np.full(count, 7.0))


def test_encoders_reject_bad_input():
    one = dict(positions=[[0.0, 0.0]], yaws=[0.0])
    with pytest.raises(ValueError):
        agent_cdr.encode_odometry(0, ['a'], ['b', 'c'], twists=[[0.0] * 3], **one)
    with pytest.raises(ValueError):
        agent_cdr.encode_odometry(0, ['a'], ['b'], twists=[[0.0] * 2], **one)
    with pytest.raises(ValueError):
        agent_cdr.encode_tf_message(0, ['a', 'b'], ['c', 'd'], **one)
    with pytest.raises(ValueError):
        agent_cdr.encode_tf_message(0, ['a\x00'], ['b'], **one)
    with pytest.raises(ValueError):
        agent_cdr.encode_tf_message(2 ** 31 * 10 ** 9, ['a'], ['b'], **one)
    with pytest.raises(ValueError):
        agent_cdr.encode_laser_scan(0, 'bad\x00frame', 0, 0, 0, 0, 0, 0, 0, [1.0])


def test_decoders_reject_truncated_and_malformed_bytes():
    (odometry,) = agent_cdr.encode_odometry(5, ['ball_0/odom'], ['ball_0/base_link'],
                                            [[1.0, 2.0]], [0.3], [[1.0, 0.0, 0.5]])
    tf = agent_cdr.encode_tf_message(5, ['a', 'bb'], ['c', 'dd'], np.ones((2, 2)), [0.1, 0.2])
    scan = agent_cdr.encode_laser_scan(5, 'ball_0/base_link', -3, 3, 0.1, 0, 0.1, 0.2, 12,
                                       np.ones(60), np.ones(60))
    for decode, data in ((agent_cdr.decode_odometry, odometry),
                         (agent_cdr.decode_tf_message, tf),
                         (agent_cdr.decode_laser_scan, scan)):
        for cut in (0, 3, 4, 9, 17, len(data) - 8, len(data) - 1):
            with pytest.raises(ValueError):
                decode(data[:cut])
        with pytest.raises(ValueError):  # big-endian encapsulation
            decode(b'\x00\x00' + data[2:])
    huge_count = bytearray(tf)
    huge_count[4:8] = (2 ** 31).to_bytes(4, 'little')  # the transforms sequence length
    with pytest.raises(ValueError):
        agent_cdr.decode_tf_message(bytes(huge_count))


def _mcap_decode(type_name, data):
    schema = Schema(id=1, name=type_name, encoding='ros2msg',
                    data=msgdefs.message_definition(type_name).encode())
    return DecoderFactory().decoder_for('cdr', schema)(data)


def test_definitions_decode_our_bytes_through_mcap_ros2():
    positions, yaws, twists = _agents(3, seed=60)
    frames, children = ['ball_0/odom', 'x', 'ball_22/odom'], ['ball_0/base_link', 'y', 'z']
    for index, data in enumerate(agent_cdr.encode_odometry(
            3_000_000_004, frames, children, positions, yaws, twists)):
        msg = _mcap_decode('nav_msgs/msg/Odometry', data)
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 4)
        assert (msg.header.frame_id, msg.child_frame_id) == (frames[index], children[index])
        position, rotation = msg.pose.pose.position, msg.pose.pose.orientation
        assert (position.x, position.y, position.z) == (*positions[index], 0.0)
        assert [rotation.x, rotation.y, rotation.z, rotation.w] == yaw_to_quaternion(
            yaws[index]).tolist()
        assert (msg.twist.twist.linear.x, msg.twist.twist.linear.y,
                msg.twist.twist.angular.z) == tuple(twists[index])
        assert list(msg.pose.covariance) == [0.0] * 36

    msg = _mcap_decode('tf2_msgs/msg/TFMessage', agent_cdr.encode_tf_message(
        5, frames, children, positions, yaws))
    assert [t.child_frame_id for t in msg.transforms] == children
    assert [(t.transform.translation.x, t.transform.translation.y)
            for t in msg.transforms] == [tuple(p) for p in positions]

    ranges = np.array([1.0, np.inf, -np.inf, 2.5])
    msg = _mcap_decode('sensor_msgs/msg/LaserScan', agent_cdr.encode_laser_scan(
        6, 'ball_0/base_link', -np.pi, np.pi / 2, np.pi / 2, 0.0, 0.1, 0.35, 12.0, ranges))
    assert msg.header.frame_id == 'ball_0/base_link'
    assert (msg.range_min, msg.range_max) == (np.float32(0.35), 12.0)
    np.testing.assert_array_equal(msg.ranges, ranges)
    assert list(msg.intensities) == []


def test_schema_texts_name_their_dependencies_as_rosbag2_does():
    deps = {type_name: [line[5:] for line in msgdefs.message_definition(type_name).splitlines()
                        if line.startswith('MSG: ')]
            for type_name in ('nav_msgs/msg/Odometry', 'tf2_msgs/msg/TFMessage',
                              'sensor_msgs/msg/LaserScan')}
    assert deps == {
        'nav_msgs/msg/Odometry': [
            'geometry_msgs/PoseWithCovariance', 'geometry_msgs/Pose', 'geometry_msgs/Point',
            'geometry_msgs/Quaternion', 'geometry_msgs/TwistWithCovariance',
            'geometry_msgs/Twist', 'geometry_msgs/Vector3', 'std_msgs/Header',
            'builtin_interfaces/Time'],
        'tf2_msgs/msg/TFMessage': [
            'geometry_msgs/TransformStamped', 'geometry_msgs/Transform',
            'geometry_msgs/Quaternion', 'geometry_msgs/Vector3', 'std_msgs/Header',
            'builtin_interfaces/Time'],
        'sensor_msgs/msg/LaserScan': ['std_msgs/Header', 'builtin_interfaces/Time'],
    }


def test_type_hashes_are_the_ones_the_middleware_announces(probe):
    assert msgdefs.type_hash('tf2_msgs/msg/TFMessage') == RELEASED_TF_MESSAGE_HASH
    types = {'nav_msgs/msg/Odometry': Odometry, 'tf2_msgs/msg/TFMessage': TFMessage,
             'sensor_msgs/msg/LaserScan': LaserScan}
    for index, message_type in enumerate(types.values()):
        probe.node.create_publisher(message_type, f'hash_{index}', QoSProfile(depth=1))
    for index, type_name in enumerate(types):
        (endpoint,) = probe.node.get_publishers_info_by_topic(f'hash_{index}')
        assert msgdefs.type_hash(type_name) == str(endpoint.topic_type_hash), type_name
