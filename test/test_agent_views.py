"""The shipped RViz config and Foxglove layout show agents through TF and odometry.

Both name topics and frames: they are checked against what a node with an agent publishes
and what its recording holds, so a renamed topic or frame fails here.
"""
import json
from pathlib import Path

import yaml

from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.ros.agents import ODOM_QOS
from ball_world.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]


def recording_with_an_agent(path):
    simulation = Simulation({'random.count': 4, 'agents': ['ball_0']}, sinks=[McapSink(path)])
    simulation.command('ball_0', 1.0, 0.0, 1.0)
    for _ in range(5):
        simulation.step()
    simulation.close()
    return Recording(path)


def test_rviz_shows_tf_frames_and_ball_0_odometry():
    rviz = yaml.safe_load((ROOT / 'rviz' / 'ball_world.rviz').read_text())
    displays = {d['Class']: d for d in rviz['Visualization Manager']['Displays']}
    tf = displays['rviz_default_plugins/TF']
    assert tf['Enabled'] and tf['Show Names'] and tf['Frames']['All Enabled']
    odom = displays['rviz_default_plugins/Odometry']
    assert odom['Enabled'] and odom['Topic']['Value'] == '/ball_0/odom'
    assert odom['Topic']['Reliability Policy'].lower() == ODOM_QOS.reliability.name.lower()
    assert odom['Topic']['Durability Policy'].lower() == ODOM_QOS.durability.name.lower()


def test_foxglove_3d_panel_labels_tf_frames_and_reads_a_recorded_odom(tmp_path):
    layout = json.loads((ROOT / 'foxglove' / 'ball_world.json').read_text())
    scene = layout['configById']['3D!world']
    assert scene['scene']['transforms']['showLabel'] is True
    recording = recording_with_an_agent(tmp_path / 'agent.mcap')
    topics = recording.topics
    odom_topics = [topic for topic in scene['topics'] if topic.endswith('/odom')]
    assert odom_topics == ['/ball_0/odom']
    assert topics['/ball_0/odom'].type == 'nav_msgs/msg/Odometry'
    assert topics['/tf'].type == 'tf2_msgs/msg/TFMessage'
    assert topics['/tf_static'].type == 'tf2_msgs/msg/TFMessage'
    assert scene['followTf'] == 'world'  # the parent of every <name>/odom in /tf_static
