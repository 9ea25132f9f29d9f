"""ball_world_cli's parts without a world: the bag of topics it records, the YAML echo prints,
the lines hz prints, and the integer ranges taken from message fields."""
import argparse
import os

from ball_world_testing.harness import read_mcap_ros2, read_rosbags
from geometry_msgs.msg import Pose, PoseArray
import pytest
from rclpy.serialization import serialize_message
from simulation_interfaces.srv import StepSimulation
from std_msgs.msg import String
import yaml

from ball_world.recording.files import FileRefused
from ball_world.recording.topic_bag import TopicBag
from ball_world.tools.cli_client import finite, fits, UsageError
from ball_world.tools.cli_topics import message_text, plain, Rate


def test_a_bag_of_topics_reads_back_in_every_reader(tmp_path):
    bag = TopicBag(tmp_path / 'run')
    text = bag.add_topic('/chat', 'std_msgs/msg/String', [(10, 'reliable', 'volatile')])
    poses = bag.add_topic('/balls', 'geometry_msgs/msg/PoseArray')
    for i in range(5):
        bag.write(text, 1_000 + i, 900 + i, serialize_message(String(data=f'm{i}')))
    array = PoseArray(poses=[Pose() for _ in range(3)])
    bag.write(poses, 2_000, 2_000, serialize_message(array))
    bag.flush()
    bag.close()
    assert sorted(os.listdir(tmp_path / 'run')) == ['metadata.yaml', 'run_0.mcap']
    read = read_rosbags(tmp_path / 'run')
    assert [(t, m.data) for t, _, m in read if t == '/chat'] == [
        ('/chat', f'm{i}') for i in range(5)]
    assert [len(m.poses) for t, _, m in read if t == '/balls'] == [3]
    assert len(read_mcap_ros2(tmp_path / 'run' / 'run_0.mcap')) == 6
    metadata = yaml.safe_load((tmp_path / 'run' / 'metadata.yaml').read_text())
    information = metadata['rosbag2_bagfile_information']
    assert information['message_count'] == 6 and information['duration'] == {
        'nanoseconds': 1_000}
    chat = information['topics_with_message_count'][0]['topic_metadata']
    assert chat['offered_qos_profiles'][0]['reliability'] == 'reliable'
    assert chat['type_description_hash'].startswith('RIHS01_')


def test_a_bag_that_never_began_leaves_a_reused_folder_as_it_was(tmp_path):
    folder = tmp_path / 'run'
    folder.mkdir()
    (folder / 'notes.txt').write_text('mine')
    with pytest.raises(FileRefused, match='already exists; pass --overwrite'):
        TopicBag(folder, hint='pass --overwrite')
    bag = TopicBag(folder, overwrite=True)
    bag.discard()
    assert os.listdir(folder) == ['notes.txt']
    fresh = TopicBag(tmp_path / 'fresh')
    fresh.discard()
    assert not (tmp_path / 'fresh').exists()
    os.symlink(folder, tmp_path / 'link')
    with pytest.raises(FileRefused, match='is a symbolic link'):
        TopicBag(tmp_path / 'link', overwrite=True)


def test_echo_prints_yaml_cut_as_ros2_topic_echo_does():
    array = PoseArray(poses=[Pose() for _ in range(130)])
    array.header.frame_id = 'w\x1b[2J'  # a control character stays escaped in the YAML
    text = message_text(array)
    assert '\x1b' not in text
    data = yaml.safe_load(text)
    assert data['header']['frame_id'] == 'w\x1b[2J'
    assert len(data['poses']) == 129 and data['poses'][-1] == '...'
    assert data['poses'][0]['orientation'] == {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0}
    assert len(plain(array, truncate=None)['poses']) == 130
    assert plain(String(data='x' * 200))['data'] == 'x' * 128 + '...'


def test_hz_lines():
    rate = Rate(window=3)
    assert rate.line() == 'no new messages'
    for t in (0.0, 0.5, 1.0, 1.5, 2.5):
        rate.heard(t)
    # the window keeps the last 3 gaps: 0.5, 0.5, 1.0
    assert rate.line() == ('average rate: 1.500\n\tmin: 0.500s max: 1.000s std dev: 0.23570s '
                           'window: 4')
    assert rate.line() == 'no new messages'


def test_integers_fit_their_message_field_and_numbers_are_finite():
    assert fits(StepSimulation.Request, 'steps', 2 ** 64 - 1, 'steps') == 2 ** 64 - 1
    for bad in (2 ** 64, -1):
        with pytest.raises(UsageError, match='between 0 and 18446744073709551615'):
            fits(StepSimulation.Request, 'steps', bad, 'steps')
    for bad in ('nan', 'inf', '-inf', '1e400', 'east'):
        with pytest.raises(argparse.ArgumentTypeError):
            finite(bad)
    assert finite('-0.5') == -0.5


def test_drive_counts_for_from_the_process_start():
    """--for 5 ran 8.8 s under load: it counts from the process's start, Python's start-up
    and imports included, not from when run() began."""
    import subprocess
    import sys
    code = ('import time; from ball_world.tools.cli import process_started; '
            'now = time.monotonic(); print(now - process_started(now))')
    age = float(subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                               check=True).stdout)
    assert 0.0 < age < 60.0  # the interpreter's start-up and the import came first
