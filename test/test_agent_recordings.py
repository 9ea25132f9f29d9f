"""Recordings with agents: cmd_vel as received, odom, /tf, /tf_static; re-simulated bit for bit.

A Simulation with an McapSink is driven directly, as the node drives it: commands given as
the bytes a cmd_vel subscription receives, world edits of agents between steps, impulses on
agents. The drive impulses are not recorded (recording.agent_topics): ball_world_resim must
rebuild every one from the recorded commands and match balls, state, odom (pose, heading,
twist) and /tf to the bit, with either backend and in exact mode.
"""
import math

from ball_world_testing.harness import rewrite_recording, Truth
from geometry_msgs.msg import Twist, TwistStamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import pytest
from rclpy.serialization import serialize_message

from ball_world.core.edits import Ball
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import info, resim

BASE = {'rate_hz': 50.0, 'random.count': 12, 'random.seed': 5, 'agents': ['ball_0', 'ball_3'],
        'agent.cmd_timeout': 0.2}
# step -> commands (agent, forward, left, yaw rate) given before it
SCRIPT = {2: [('ball_0', 1.5, 0.0, 2.0)], 3: [('ball_3', -0.5, 0.5, 0.0)],
          20: [('ball_0', 0.0, 0.0, -1.0), ('ball_0', 0.8, -0.2, 0.5)],
          35: [('rover', 1.0, 0.0, 1.0)], 50: [('ball_3', 3.0, 0.0, -5.0)]}


def command_bytes(vx, vy, wz, stamped):
    twist = Twist()
    twist.linear.x, twist.linear.y, twist.linear.z = vx, vy, 0.25  # z: ignored, kept
    twist.angular.z = wz
    if not stamped:
        return serialize_message(twist)
    message = TwistStamped()
    message.header.frame_id = 'base_link'
    message.twist = twist
    return serialize_message(message)


def record_run(path, stamped=False, steps=70, also=(), **overrides):
    """A scripted run recorded to `path` (and to the sinks `also`): commands, a spawned
    agent (rover, step 30), a heading set and a push (step 40), a deletion (step 60)."""
    parameters = {**BASE, 'agent.cmd_vel_stamped': stamped, **overrides}
    simulation = Simulation(parameters, sinks=[McapSink(path), *also])
    for k in range(1, steps + 1):
        if k == 30:
            x, y = 9.0, 9.0
            [name], _ = simulation.spawn([SpawnRequest('rover', False,
                                                       Ball(x, y, 0.0, 0.0, 0.15, 0.5),
                                                       agent=True)])
            assert name == 'rover'
        if k == 40:
            x, y = simulation.world.positions[simulation.index_of['ball_3']].tolist()
            simulation.set_state('ball_3', x, y, 0.0, 0.0, yaw=2.5)
            simulation.queue_impulse('ball_0', 0.05, -0.02)
        for name, vx, vy, wz in SCRIPT.get(k, []):
            simulation.command(name, vx, vy, wz, command_bytes(vx, vy, wz, stamped))
        if k == 60:
            simulation.delete('ball_0')
        simulation.step()
    simulation.close()
    return path


@pytest.mark.parametrize('overrides', [
    {'physics.backend': 'numpy'}, {'physics.backend': 'numba'},
    {'physics.mode': 'exact'}, {'physics.backend': 'numpy', 'agent.cmd_vel_stamped': True}],
    ids=['numpy', 'numba', 'exact', 'stamped'])
def test_a_run_with_agents_resimulates_bit_for_bit(tmp_path, capsys, overrides):
    stamped = overrides.pop('agent.cmd_vel_stamped', False)
    live = Truth()
    path = record_run(tmp_path / 'agents.mcap', stamped=stamped, also=[live], **overrides)
    assert resim.main([str(path)]) == 0, capsys.readouterr()
    out = capsys.readouterr().out
    assert 'all 71 recorded steps re-simulate bit-identically' in out
    steps = list(Recording(path).steps())
    assert sum(len(step.commands) for step in steps) == 6
    # the push of step 40 only: the drives' impulses (many) were made again from the commands
    assert sum(len(step.impulses) for step in steps) == 1
    assert sum(i.drive for record in live.records for i in record.impulses) > 50
    assert set(steps[35].odom) == {'ball_0', 'ball_3', 'rover'}
    assert set(steps[61].odom) == {'ball_3', 'rover'}


def test_resim_notices_a_changed_command(tmp_path, capsys):
    path = record_run(tmp_path / 'agents.mcap')
    changed = command_bytes(1.5, 0.0, 2.0, False)
    faster = command_bytes(1.5000000000000002, 0.0, 2.0, False)
    rewrite_recording(path, tmp_path / 'tampered.mcap',
                      data=lambda topic, log_time, data: faster if data == changed else data)
    assert resim.main([str(tmp_path / 'tampered.mcap')]) == 1
    out = capsys.readouterr().out
    # the drive made from it moves ball_0 otherwise (in the last bit) in the step it acts on
    assert 'first difference: segment 0 step 2 ball 0 state' in out


def test_other_readers_see_cmd_vel_odom_and_tf_with_their_types(tmp_path):
    path = record_run(tmp_path / 'agents.mcap', steps=40)
    decoded = {}
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, ros in reader.iter_decoded_messages():
            decoded.setdefault(channel.topic, (schema.name, []))[1].append((message, ros))
    assert {topic: value[0] for topic, value in decoded.items()
            if 'ball_' in topic or 'rover' in topic or topic.startswith('/tf')} == {
        '/ball_0/cmd_vel': 'geometry_msgs/msg/Twist',
        '/ball_3/cmd_vel': 'geometry_msgs/msg/Twist',
        '/rover/cmd_vel': 'geometry_msgs/msg/Twist',
        '/ball_0/odom': 'nav_msgs/msg/Odometry', '/ball_3/odom': 'nav_msgs/msg/Odometry',
        '/rover/odom': 'nav_msgs/msg/Odometry',
        '/tf': 'tf2_msgs/msg/TFMessage', '/tf_static': 'tf2_msgs/msg/TFMessage',
        # Every agent scans (agent.scan.samples defaults to 360): issue 22's lidar.
        '/ball_0/scan': 'sensor_msgs/msg/LaserScan', '/ball_3/scan': 'sensor_msgs/msg/LaserScan',
        '/rover/scan': 'sensor_msgs/msg/LaserScan',
        # The truth beside the odometry (Stage's base_pose_ground_truth).
        '/ball_0/ground_truth': 'nav_msgs/msg/Odometry',
        '/ball_3/ground_truth': 'nav_msgs/msg/Odometry',
        '/rover/ground_truth': 'nav_msgs/msg/Odometry'}
    # `impulse` holds the push of step 40 alone: the drives' impulses are not recorded
    assert [(message.log_time, ros.header.frame_id) for message, ros in
            decoded['/impulse'][1]] == [(40 * 20_000_000, 'ball_0')]
    truth = decoded['/ball_3/ground_truth'][1][-1][1]
    assert (truth.header.frame_id, truth.child_frame_id) == ('world', 'ball_3/base_link')
    first_command = decoded['/ball_0/cmd_vel'][1][0]
    assert first_command[1].linear.x == 1.5 and first_command[1].linear.z == 0.25
    assert first_command[0].log_time == 2 * 20_000_000  # the step it took effect
    assert len(decoded['/tf'][1]) == 41 and len(decoded['/ball_0/odom'][1]) == 41
    statics = [ros for _, ros in decoded['/tf_static'][1]]
    assert [[t.child_frame_id for t in s.transforms] for s in statics] == [
        ['ball_0/odom', 'ball_3/odom'], ['ball_0/odom', 'ball_3/odom', 'rover/odom']]
    last = decoded['/ball_3/odom'][1][-1][1]
    assert last.header.frame_id == 'ball_3/odom'
    assert last.child_frame_id == 'ball_3/base_link'
    yaw = 2.0 * math.atan2(last.pose.pose.orientation.z, last.pose.pose.orientation.w)
    assert -math.pi <= yaw <= math.pi


def test_a_world_without_agents_records_no_agent_channel(tmp_path):
    path = tmp_path / 'plain.mcap'
    simulation = Simulation({'random.count': 5}, sinks=[McapSink(path)])
    for _ in range(5):
        simulation.step()
    simulation.close()
    topics = set(Recording(path).topics)
    assert topics == {'/balls', '/state', '/stats', '/impulse', '/markers', '/clock'}


def test_info_counts_agents_and_commands(tmp_path, capsys):
    path = record_run(tmp_path / 'agents.mcap')
    assert info.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert 'agents:      3 (ball_0, ball_3, rover), 6 commands' in out


@pytest.mark.parametrize('text, words', [
    ('{"kind": "spawn", "name": "a", "x": 1.0, "y": 1.0, "vx": 0.0, "vy": 0.0, "radius": 0.2, '
     '"mass": 1.0, "impulses_before": 0, "agent": 1}', 'agent is 1, not true'),
    ('{"kind": "set_state", "name": "a", "x": 1.0, "y": 1.0, "vx": 0.0, "vy": 0.0, '
     '"radius": 0.0, "mass": 0.0, "impulses_before": 0, "yaw": "north"}', 'yaw is'),
    ('{"kind": "delete", "name": "a", "x": 0.0, "y": 0.0, "vx": 0.0, "vy": 0.0, '
     '"radius": 0.0, "mass": 0.0, "impulses_before": 0, "yaw": 1.0}', 'not an edit with'),
])
def test_agent_keys_of_recorded_edits_are_checked_as_untrusted(text, words):
    from ball_world.msgs.cdr import encode_string
    from ball_world.recording.mcap_reader import parse_edit, RecordingError
    with pytest.raises(RecordingError, match=words):
        parse_edit(encode_string(text), 0)


def test_agent_keys_of_recorded_edits_are_read_back():
    from ball_world.msgs.cdr import encode_string
    from ball_world.recording.mcap_reader import parse_edit
    edit = parse_edit(encode_string(
        '{"kind": "set_state", "name": "a", "x": 1.0, "y": 1.0, "vx": 0.0, "vy": 0.0, '
        '"radius": 0.0, "mass": 0.0, "impulses_before": 0, "yaw": -0.5}'), 0)
    assert edit.yaw == -0.5 and not edit.agent


def test_hostile_agent_messages_get_one_line_or_a_difference(tmp_path, capsys):
    from ball_world.tools import to_rrd
    path = record_run(tmp_path / 'agents.mcap', steps=20)
    bad = tmp_path / 'bad.mcap'
    rewrite_recording(path, bad, data=lambda topic, log_time, data: b'\x00\x01\x00\x00\x01'
                      if topic in ('/ball_3/odom', '/ball_3/cmd_vel') and log_time == 60_000_000
                      else data)
    assert resim.main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'undecodable' in err
    odom_only = tmp_path / 'odom.mcap'
    # the lowest bit of the pose's x (after the stamp and the two frame names)
    rewrite_recording(path, odom_only, data=lambda topic, log_time, data:
                      data[:52] + bytes([data[52] ^ 1]) + data[53:]
                      if topic == '/ball_3/odom' and log_time == 100_000_000 else data)
    assert resim.main([str(odom_only)]) == 1
    assert 'first difference: segment 0 step 5 odom of ball_3' in capsys.readouterr().out
    assert to_rrd.main([str(bad), '-o', str(tmp_path / 'bad.rrd')]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err
