"""The shipped RViz config and Foxglove layout show the robots of worlds/sandbox.yaml (ball_0,
ball_1): TF, odometry, ground truth and bumper hits.

Both name topics, types and frames: every one is checked against what a real node started
with the sandbox world publishes (its publishers' names, types and QoS) and what its
recording holds, so a renamed topic, a display of the wrong type or a QoS that never
matches fails here.
"""
import json
from pathlib import Path

from geometry_msgs.msg import PoseArray, Vector3Stamped
from nav_msgs.msg import OccupancyGrid, Odometry
import pytest
import rclpy
from rclpy.parameter import Parameter
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray
import yaml

from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.ros.agents import ODOM_QOS
from ball_world.ros.node import BallWorld
from ball_world.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = ('ball_0', 'ball_1')
#: The message type each RViz display class draws.
RVIZ_TYPES = {'rviz_default_plugins/Odometry': Odometry,
              'rviz_default_plugins/MarkerArray': MarkerArray,
              'rviz_default_plugins/LaserScan': LaserScan,
              'rviz_default_plugins/PoseArray': PoseArray,
              'rviz_default_plugins/Map': OccupancyGrid}
RVIZ_DURABILITY = {'Transient Local': 'transient_local', 'Volatile': 'volatile'}
RVIZ_RELIABILITY = {'Reliable': 'reliable', 'Best Effort': 'best_effort'}


def sandbox_parameters():
    """worlds/sandbox.yaml's parameters, its map named by absolute path."""
    document = yaml.safe_load((ROOT / 'worlds' / 'sandbox.yaml').read_text())
    parameters = dict(document['/**']['ros__parameters'])
    parameters['map'] = str(ROOT / parameters['map'])
    return parameters


@pytest.fixture(scope='module')
def sandbox_publishers():
    """{topic: publisher} of a real node of the sandbox world (its agents' topics too)."""
    context = rclpy.Context()
    rclpy.init(context=context)
    overrides = [Parameter(name, value=value) for name, value in sandbox_parameters().items()]
    node = BallWorld(context=context, parameter_overrides=overrides)
    try:
        agents_node = node.agent_topics._io  # the node of the per-agent publishers
        publishers = list(node.publishers) + list(agents_node.publishers)
        yield {publisher.topic_name: publisher for publisher in publishers}
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.fixture(scope='module')
def sandbox_recording(tmp_path_factory):
    """The topics of a recorded second of the sandbox world, its robots driving."""
    path = tmp_path_factory.mktemp('sandbox') / 'sandbox.mcap'
    simulation = Simulation(sandbox_parameters(), sinks=[McapSink(path)])
    for _ in range(60):
        simulation.command('ball_0', 0.2, 0.0, 1.0)
        simulation.command('ball_1', 0.2, 0.0, -1.0)
        simulation.step()
    simulation.close()
    return Recording(path).topics


def rviz_displays():
    rviz = yaml.safe_load((ROOT / 'rviz' / 'ball_world.rviz').read_text())
    return {d['Name']: d for d in rviz['Visualization Manager']['Displays']}


def foxglove_layout():
    return json.loads((ROOT / 'foxglove' / 'ball_world.json').read_text())


def test_rviz_shows_tf_frames_odometry_ground_truth_and_bumpers():
    displays = rviz_displays()
    tf = displays['TF']
    assert tf['Enabled'] and tf['Show Names'] and tf['Frames']['All Enabled']
    topics = {name: (d['Class'], d['Topic']['Value']) for name, d in displays.items()
              if 'Topic' in d}
    assert topics['Odometry ball_0'] == ('rviz_default_plugins/Odometry', '/ball_0/odom')
    for robot in ROBOTS:
        assert topics[f'Ground truth {robot}'] == ('rviz_default_plugins/Odometry',
                                                   f'/{robot}/ground_truth')
    assert topics['Bumpers'] == ('rviz_default_plugins/MarkerArray', '/bumper_markers')
    # the truth is drawn apart from the odometry, so a drift shows
    assert displays['Ground truth ball_0']['Shape']['Color'] != \
        displays['Odometry ball_0']['Shape']['Color']
    assert all(displays[name]['Enabled'] for name in topics)


def test_every_rviz_display_subscribes_to_what_the_sandbox_node_publishes(
        sandbox_publishers):
    for name, display in rviz_displays().items():
        if 'Topic' not in display:
            continue
        topic = display['Topic']['Value']
        assert topic in sandbox_publishers, f'{name}: nothing publishes {topic}'
        publisher = sandbox_publishers[topic]
        assert publisher.msg_type is RVIZ_TYPES[display['Class']], name
        qos = publisher.qos_profile
        # A transient-local display on a volatile topic sees nothing; a best-effort
        # publisher never reaches a reliable display.
        assert RVIZ_DURABILITY[display['Topic']['Durability Policy']] == \
            qos.durability.name.lower(), name
        assert RVIZ_RELIABILITY[display['Topic']['Reliability Policy']] == \
            qos.reliability.name.lower(), name
    assert sandbox_publishers['/ball_1/ground_truth'].qos_profile.depth == ODOM_QOS.depth


def test_foxglove_3d_panel_shows_the_robots_truth_and_bumpers_from_live_topics(
        sandbox_publishers):
    scene = foxglove_layout()['configById']['3D!world']
    assert scene['scene']['transforms']['showLabel'] is True
    assert scene['followTf'] == 'world'  # the parent of every <name>/odom in /tf_static
    topics = scene['topics']
    for robot in ROBOTS:
        assert topics[f'/{robot}/ground_truth']['visible'] is True
    assert topics['/bumper_markers']['visible'] is True
    expected = {'/ball_0/odom': Odometry, '/ball_0/scan': LaserScan, '/map': OccupancyGrid,
                '/ball_0/ground_truth': Odometry, '/ball_1/ground_truth': Odometry,
                '/bumper_markers': MarkerArray, '/markers': MarkerArray, '/balls': PoseArray}
    assert set(topics) == set(expected)
    for topic, message_type in expected.items():
        assert sandbox_publishers[topic].msg_type is message_type, topic


def test_foxglove_opens_a_sandbox_recording_with_truth_and_bumper_plots(
        sandbox_recording, sandbox_publishers):
    layout = foxglove_layout()
    scene = layout['configById']['3D!world']
    topics = sandbox_recording
    for topic in scene['topics']:
        if topic != '/bumper_markers':  # live only: a recording has the bumpers themselves
            assert topic in topics, topic
    for robot in ROBOTS:
        assert topics[f'/{robot}/ground_truth'].type == 'nav_msgs/msg/Odometry'
        assert topics[f'/{robot}/odom'].type == 'nav_msgs/msg/Odometry'
    assert topics['/tf'].type == topics['/tf_static'].type == 'tf2_msgs/msg/TFMessage'
    bumpers = layout['configById']['Plot!bumpers']
    plotted = [series['value'] for series in bumpers['paths']]
    assert plotted == [f'/{robot}/bumper.vector.{axis}' for robot in ROBOTS
                       for axis in 'xy']
    for path in plotted:
        topic = path.partition('.')[0]
        assert sandbox_publishers[topic].msg_type is Vector3Stamped
        assert hasattr(Vector3Stamped().vector, path.rpartition('.')[2])
    assert 'Plot!bumpers' in json.dumps(layout['layout'])
