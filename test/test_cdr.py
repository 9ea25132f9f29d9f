"""The numpy CDR encoders must produce bytes that real ROS 2 and MCAP decoders read exactly.

rclpy is the reference: our bytes go through rclpy.serialization.deserialize_message, and
rclpy's serialize_message output goes through our decoders. Bytes are never compared with
rclpy's, because rmw leaves uninitialised padding in its buffers. No ROS graph is needed.
"""
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose, PoseArray, Vector3Stamped
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ball_world.msgs import cdr, definitions as msgdefs

SIZES = (0, 1, 7, 1000)
FRAMES = ('map', 'world_frame', 'ab', '')
STAMPS = (0, 1, 999_999_999, 1_000_000_000, 123_456_789_012_345, 2 ** 31 * 10 ** 9 - 1)


def _positions(n, seed=0):
    return np.random.default_rng(seed).uniform(-1e3, 1e3, size=(n, 2))


def _stamp_ns(stamp):
    return stamp.sec * 10 ** 9 + stamp.nanosec


def _pose_array_msg(positions, stamp_ns, frame_id):
    msg = PoseArray()
    msg.header.frame_id = frame_id
    msg.header.stamp = Time(sec=stamp_ns // 10 ** 9, nanosec=stamp_ns % 10 ** 9)
    for x, y in positions.tolist():
        pose = Pose()
        pose.position.x, pose.position.y = x, y
        msg.poses.append(pose)
    return msg


@pytest.mark.parametrize('n', SIZES)
@pytest.mark.parametrize('frame_id', FRAMES)
def test_pose_array_reads_back_through_rclpy(n, frame_id):
    positions = _positions(n)
    stamp_ns = 123_456_789_012
    msg = deserialize_message(cdr.encode_pose_array(positions, stamp_ns, frame_id), PoseArray)
    assert _stamp_ns(msg.header.stamp) == stamp_ns
    assert msg.header.frame_id == frame_id
    assert len(msg.poses) == n
    got = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses]).reshape(n, 3)
    np.testing.assert_array_equal(got[:, :2], positions)
    np.testing.assert_array_equal(got[:, 2], 0.0)
    quats = [(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
             for p in msg.poses]
    assert all(q == (0.0, 0.0, 0.0, 1.0) for q in quats)


@pytest.mark.parametrize('stamp_ns', STAMPS)
def test_pose_array_stamps(stamp_ns):
    msg = deserialize_message(cdr.encode_pose_array(_positions(3), stamp_ns, 'map'), PoseArray)
    assert msg.header.stamp.sec == stamp_ns // 10 ** 9
    assert msg.header.stamp.nanosec == stamp_ns % 10 ** 9


def test_pose_array_reuses_buffer_across_layouts():
    """The cached scratch buffer must not leak constant fields between layouts."""
    for n, frame_id in ((5, 'map'), (3, 'world_frame'), (5, 'map'), (9, 'a'), (2, 'map')):
        positions = _positions(n, seed=n)
        data = cdr.encode_pose_array(positions, 7, frame_id)
        msg = deserialize_message(data, PoseArray)
        assert [p.orientation.w for p in msg.poses] == [1.0] * n
        assert [p.position.z for p in msg.poses] == [0.0] * n
        np.testing.assert_array_equal(cdr.decode_pose_array(data)[2], positions)


@pytest.mark.parametrize('n', SIZES)
@pytest.mark.parametrize('frame_id', FRAMES)
def test_decode_pose_array_matches_rclpy(n, frame_id):
    positions = _positions(n, seed=1)
    stamp_ns = 42_000_000_001
    ours = cdr.decode_pose_array(cdr.encode_pose_array(positions, stamp_ns, frame_id))
    theirs = cdr.decode_pose_array(
        serialize_message(_pose_array_msg(positions, stamp_ns, frame_id)))
    for stamp, frame, got in (ours, theirs):
        assert stamp == stamp_ns
        assert frame == frame_id
        assert got.shape == (n, 2)
        np.testing.assert_array_equal(got, positions)


@pytest.mark.parametrize('n', SIZES)
def test_state_reads_back_through_rclpy(n):
    positions, velocities = _positions(n, seed=2), _positions(n, seed=3)
    msg = deserialize_message(cdr.encode_state(positions, velocities), Float64MultiArray)
    dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    assert dims == [('ball', n, 4 * n), ('x_y_vx_vy', 4, 4)]
    assert msg.layout.data_offset == 0
    expected = np.hstack([positions, velocities])
    np.testing.assert_array_equal(np.array(msg.data).reshape(n, 4), expected)


@pytest.mark.parametrize('n', SIZES)
def test_decode_state_matches_rclpy(n):
    rows = np.hstack([_positions(n, seed=4), _positions(n, seed=5)])
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label='ball', size=n, stride=4 * n),
                      MultiArrayDimension(label='x_y_vx_vy', size=4, stride=4)]
    msg.data = rows.ravel().tolist()
    np.testing.assert_array_equal(cdr.decode_state(serialize_message(msg)), rows)
    np.testing.assert_array_equal(cdr.decode_state(cdr.encode_state(rows[:, :2], rows[:, 2:])),
                                  rows)


@pytest.mark.parametrize('frame_id', FRAMES + ('ball_12',))
@pytest.mark.parametrize('stamp_ns', STAMPS)
def test_vector3_stamped_round_trips(frame_id, stamp_ns):
    x, y, z = 1.5, -2.25e-3, 3e300
    data = cdr.encode_vector3_stamped(stamp_ns, frame_id, x, y, z)
    msg = deserialize_message(data, Vector3Stamped)
    assert (_stamp_ns(msg.header.stamp), msg.header.frame_id) == (stamp_ns, frame_id)
    assert (msg.vector.x, msg.vector.y, msg.vector.z) == (x, y, z)
    assert cdr.decode_vector3_stamped(data) == (stamp_ns, frame_id, x, y, z)
    assert cdr.decode_vector3_stamped(serialize_message(msg)) == (stamp_ns, frame_id, x, y, z)


@pytest.mark.parametrize('stamp_ns', STAMPS)
def test_clock(stamp_ns):
    msg = deserialize_message(cdr.encode_clock(stamp_ns), Clock)
    assert _stamp_ns(msg.clock) == stamp_ns
    assert msg.clock.nanosec < 10 ** 9


def test_negative_stamp_matches_ros_time_convention():
    msg = deserialize_message(cdr.encode_clock(-1_700_000_000), Clock)
    assert (msg.clock.sec, msg.clock.nanosec) == (-2, 300_000_000)


@pytest.mark.parametrize('stamp_ns', (2 ** 31 * 10 ** 9, -2 ** 31 * 10 ** 9 - 1))
def test_stamp_out_of_range_is_rejected(stamp_ns):
    with pytest.raises(ValueError):
        cdr.encode_clock(stamp_ns)


def test_encoders_reject_bad_input():
    with pytest.raises(ValueError):
        cdr.encode_pose_array(np.zeros((3, 3)), 0, 'map')
    with pytest.raises(ValueError):
        cdr.encode_state(np.zeros((3, 2)), np.zeros((2, 2)))
    with pytest.raises(ValueError):
        cdr.encode_pose_array(np.zeros((1, 2)), 0, 'bad\x00frame')


def test_decoders_reject_truncated_and_malformed_bytes():
    pose_bytes = cdr.encode_pose_array(_positions(4), 5, 'world_frame')
    state_bytes = cdr.encode_state(_positions(4), _positions(4))
    vec_bytes = cdr.encode_vector3_stamped(5, 'ball_3', 1.0, 2.0, 0.0)
    for decode, data in ((cdr.decode_pose_array, pose_bytes), (cdr.decode_state, state_bytes),
                         (cdr.decode_vector3_stamped, vec_bytes)):
        for cut in (0, 3, 4, 9, 17, len(data) - 8, len(data) - 1):
            with pytest.raises(ValueError):
                decode(data[:cut])
        with pytest.raises(ValueError):  # big-endian encapsulation
            decode(b'\x00\x00' + data[2:])
    huge_count = bytearray(pose_bytes)
    huge_count[28:32] = (2 ** 31).to_bytes(4, 'little')  # the poses sequence length
    with pytest.raises(ValueError):
        cdr.decode_pose_array(bytes(huge_count))
    no_nul = bytearray(vec_bytes)
    no_nul[22] = ord('x')  # the NUL ending 'ball_3'
    with pytest.raises(ValueError):
        cdr.decode_vector3_stamped(bytes(no_nul))
    wrong_size = state_bytes.replace(b'ball\x00\x00\x00\x00\x04', b'ball\x00\x00\x00\x00\x05')
    with pytest.raises(ValueError):  # layout says 5 balls, data holds 4
        cdr.decode_state(wrong_size)


def test_message_definition_layout_matches_rosbag2():
    text = msgdefs.message_definition('geometry_msgs/msg/PoseArray')
    separators = [line for line in text.splitlines() if line.startswith('MSG: ')]
    assert separators == ['MSG: geometry_msgs/Pose', 'MSG: geometry_msgs/Point',
                          'MSG: geometry_msgs/Quaternion', 'MSG: std_msgs/Header',
                          'MSG: builtin_interfaces/Time']
    assert text.startswith('# An array of poses with a header for global reference.\n')
    assert '\n\n' + '=' * 80 + '\nMSG: geometry_msgs/Pose\n' in text
    assert msgdefs.message_definition('geometry_msgs/PoseArray') == text


def test_type_hash():
    assert msgdefs.type_hash('geometry_msgs/msg/PoseArray').startswith('RIHS01_')
    assert len(msgdefs.type_hash('std_msgs/msg/Float64MultiArray')) == len('RIHS01_') + 64
    assert msgdefs.type_hash('no_such_pkg/msg/Nothing') == ''


def _mcap_decode(type_name, data):
    schema = Schema(id=1, name=type_name, encoding='ros2msg',
                    data=msgdefs.message_definition(type_name).encode())
    return DecoderFactory().decoder_for('cdr', schema)(data)


def test_definitions_decode_our_bytes_through_mcap_ros2():
    positions, velocities = _positions(7, seed=6), _positions(7, seed=7)
    msg = _mcap_decode('geometry_msgs/msg/PoseArray',
                       cdr.encode_pose_array(positions, 3_000_000_004, 'world_frame'))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 4)
    assert msg.header.frame_id == 'world_frame'
    got = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
    np.testing.assert_array_equal(got, np.hstack([positions, np.zeros((7, 1))]))
    assert all((p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
               == (0.0, 0.0, 0.0, 1.0) for p in msg.poses)

    msg = _mcap_decode('std_msgs/msg/Float64MultiArray', cdr.encode_state(positions, velocities))
    assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [
        ('ball', 7, 28), ('x_y_vx_vy', 4, 4)]
    np.testing.assert_array_equal(np.reshape(msg.data, (7, 4)),
                                  np.hstack([positions, velocities]))

    msg = _mcap_decode('geometry_msgs/msg/Vector3Stamped',
                       cdr.encode_vector3_stamped(5, 'ball_0', 1.0, -2.0, 0.5))
    assert (msg.header.frame_id, msg.vector.x, msg.vector.y, msg.vector.z) == (
        'ball_0', 1.0, -2.0, 0.5)

    msg = _mcap_decode('rosgraph_msgs/msg/Clock', cdr.encode_clock(10 ** 9 + 5))
    assert (msg.clock.sec, msg.clock.nanosec) == (1, 5)
