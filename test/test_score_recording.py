"""The record -> track -> score loop on a real recording: an agent scanning a gas of balls,
recorded to MCAP by the node's own sink, scored by ball_world_score with the example
tracker (figures a working tracker reaches), and with a user's tracks read from another MCAP
(the ground truth itself: a perfect score, computed independently of the example tracker).
"""
from geometry_msgs.msg import Twist
from mcap_ros2.writer import Writer as Ros2Writer
import pytest
from rclpy.serialization import serialize_message

from ball_world.msgs.definitions import message_definition
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation
from ball_world.tools import score

PARAMETERS = {'rate_hz': 60.0, 'random.count': 20, 'random.seed': 3, 'agents': ['ball_0'],
              'physics.backend': 'numpy'}


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """Eight simulated seconds: ball_0 drives forward at 0.5 m/s turning at 0.4 rad/s."""
    path = tmp_path_factory.mktemp('score') / 'run.mcap'
    simulation = Simulation(PARAMETERS, sinks=[McapSink(path)])
    twist = Twist()
    twist.linear.x, twist.angular.z = 0.5, 0.4
    command = serialize_message(twist)  # recorded as received on cmd_vel
    for _ in range(8 * 60):
        simulation.command('ball_0', 0.5, 0.0, 0.4, command)
        simulation.step()
    simulation.close()
    return path


def test_the_example_tracker_scores_well_on_a_recorded_run(recording, capsys):
    frames = score.recorded_frames(recording, 'ball_0')
    assert len(frames) == 81  # 10 Hz for 8 s, and step 0
    figures = score.clear_mot(frames, 0.5)
    assert figures.truth > 800
    assert figures.mota > 0.7, figures.lines()
    assert figures.motp < 0.06, figures.lines()
    assert score.main([str(recording)]) == 0
    printed = capsys.readouterr().out
    assert f'MOTA {figures.mota:.4f}' in printed and f'MOTP {figures.motp:.4f} m' in printed


def test_a_users_tracks_from_another_mcap_are_scored_by_their_stamps(
        recording, tmp_path, capsys):
    # The "user" publishes the visible balls' true positions, under ids of their own: the
    # score must be perfect, whatever the example tracker would do.
    frames = score.recorded_frames(recording, 'ball_0')
    stamps = _scan_stamps(recording)
    tracks = tmp_path / 'tracks.mcap'
    with open(tracks, 'wb') as stream:
        writer = Ros2Writer(stream)
        schema = writer.register_msgdef('visualization_msgs/msg/MarkerArray',
                                        message_definition('visualization_msgs/msg/MarkerArray'))
        for stamp, (truth, _) in zip(stamps, frames):
            header = {'stamp': {'sec': stamp // 10**9, 'nanosec': stamp % 10**9},
                      'frame_id': 'world'}
            markers = [{'header': header, 'ns': 'tracks', 'id': 1000 + int(name[5:]),
                        'action': 0, 'pose': {'position': {'x': x, 'y': y, 'z': 0.0},
                                              'orientation': {'w': 1.0}}}
                       for name, (x, y) in truth.items()]
            writer.write_message('/my/tracks', schema, {'markers': markers}, stamp, stamp)
        writer.finish()
    assert score.main([str(recording), '--tracks', str(tracks), '/my/tracks']) == 0
    printed = capsys.readouterr().out
    assert 'MOTA 1.0000' in printed and 'MOTP 0.0000 m' in printed
    assert 'id switches 0' in printed


def test_bad_input_is_one_line(recording, tmp_path, capsys):
    assert score.main([str(recording), '--agent', 'ball_7']) == 1
    error = capsys.readouterr().err
    assert error.count('\n') == 1 and 'no ball_7/scan topic' in error
    missing = tmp_path / 'nothing.mcap'
    assert score.main([str(missing)]) == 1
    assert capsys.readouterr().err.count('\n') == 1


def _scan_stamps(path):
    from ball_world.msgs.agent_cdr import decode_laser_scan
    from ball_world.recording.mcap_reader import Recording
    recording = Recording(path)
    topic = next(c.topic for c in recording.channels.values() if c.topic.endswith('/scan'))
    return [decode_laser_scan(m.data).stamp_ns for m in recording.messages([topic])]


def test_gate_must_be_positive(recording):
    with pytest.raises(SystemExit):
        score.main([str(recording), '--gate', '-1'])
