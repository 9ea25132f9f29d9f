"""What a Foxglove user gets from an MCAP alone: markers, /clock, named stats, the layout.

The markers are decoded as Foxglove's 3D panel would read them (mcap_ros2 and rosbags, from
the recorded schema) and checked against the simulation's own truth: one sphere per ball
with the ball's diameter, at the ball's recorded position for that step, and the walls as a
line list; a DELETEALL when each segment starts. The shipped layout must be valid JSON that
names only topics a recording holds and stats fields by their real index.
"""
import json
from pathlib import Path

from ball_world_testing.harness import read_mcap_ros2, ROSBAGS_TYPES, Truth
import numpy as np
import pytest
from rosbags.rosbag2 import Reader as RosbagsReader

from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import MARKERS_PERIOD_NS, McapSink
from ball_world.simulation import Simulation
from ball_world.step_record import STATS_FIELDS

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / 'foxglove' / 'ball_world.json'
FIRST = {'rate_hz': 20.0, 'random.count': 12, 'random.seed': 3}
SECOND = {'rate_hz': 40.0, 'random.count': 7, 'random.seed': 9,
          'arena': [0.0, 0.0, 6.0, 5.0], 'walls': [1.0, 4.0, 5.0, 4.5]}
DELETEALL = 3  # visualization_msgs/Marker action
SPHERE, LINE_LIST = 2, 5


def record(path, first=FIRST, second=SECOND, steps=(30, 25)):
    truth = Truth()
    simulation = Simulation(first, sinks=[McapSink(path), truth])
    for _ in range(steps[0]):
        simulation.step()
    simulation.reset(second)
    for _ in range(steps[1]):
        simulation.step()
    simulation.close()
    return truth


def decoded(path, topic):
    """(log time, decoded message) of every message on a topic, via mcap_ros2."""
    return [(log_time, msg) for _, log_time, msg in read_mcap_ros2(path, [topic])]


def is_delete_all(msg):
    return [m.action for m in msg.markers] == [DELETEALL]


def segment_of(truth, log_time):
    starts = [info.log_offset_ns for _, info in truth.segments]
    return max(i for i, start in enumerate(starts) if start <= log_time)


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp('fox') / 'run.mcap'
    return path, record(path)


def test_markers_show_sized_balls_at_their_positions_and_walls_in_every_segment(recorded):
    path, truth = recorded
    markers = decoded(path, '/markers')
    by_log_time = {r.log_time_ns: r for r in truth.records}
    deletes = [log_time for log_time, msg in markers if is_delete_all(msg)]
    # each segment starts by clearing the previous world, at its first log time
    assert deletes == [info.log_offset_ns for _, info in truth.segments]
    full = [(log_time, msg) for log_time, msg in markers if not is_delete_all(msg)]
    for segment, (world, info) in enumerate(truth.segments):
        mine = [(t, msg) for t, msg in full if segment_of(truth, t) == segment]
        last = max(r.stamp_ns for r in truth.records
                   if segment_of(truth, r.log_time_ns) == segment)
        # dt (50 and 25 ms) divides the period: markers at step 0 and every period after
        assert [t - info.log_offset_ns for t, _ in mine] == \
            list(range(0, last + 1, MARKERS_PERIOD_NS))
        for log_time, msg in mine:
            spheres = [m for m in msg.markers if m.ns == 'balls']
            walls = [m for m in msg.markers if m.ns == 'walls']
            assert [m.id for m in spheres] == list(range(len(world.radii)))
            assert {m.type for m in spheres} == {SPHERE}
            assert {m.header.frame_id for m in msg.markers} == {'world'}
            scales = np.array([[m.scale.x, m.scale.y, m.scale.z] for m in spheres])
            assert (scales == 2.0 * world.radii[:, None]).all()
            centres = np.array([[m.pose.position.x, m.pose.position.y] for m in spheres])
            assert (centres == by_log_time[log_time].positions).all()
            assert len(walls) == 1 and walls[0].type == LINE_LIST
            points = np.array([[p.x, p.y] for p in walls[0].points]).reshape(-1, 4)
            assert (points == world.walls).all()


def test_markers_decode_in_rosbags_with_the_counts_and_qos_ros2_bag_info_shows(recorded):
    path, truth = recorded
    with RosbagsReader(path) as reader:
        connections = {c.topic: c for c in reader.connections}
        marker = connections['/markers']
        assert marker.msgtype == 'visualization_msgs/msg/MarkerArray'
        qos = marker.ext.offered_qos_profiles[0]
        assert (qos.reliability.name, qos.durability.name, qos.depth) == \
            ('RELIABLE', 'TRANSIENT_LOCAL', 1)
        arrays = [ROSBAGS_TYPES.deserialize_cdr(raw, marker.msgtype)
                  for _, _, raw in reader.messages([marker])]
        assert connections['/balls'].msgcount == len(truth.records)
    assert marker.msgcount == len(arrays) == len(decoded(path, '/markers'))
    sizes = {len(world.radii) + 1 for world, _ in truth.segments}  # spheres and the walls
    assert {len(array.markers) for array in arrays} == sizes | {1}  # and the DELETEALLs


def test_markers_follow_reset_worlds_of_other_sizes(tmp_path):
    # a world with more balls, then fewer: the DELETEALL is what removes the extra spheres
    truth = record(tmp_path / 'run.mcap', first={**FIRST, 'random.count': 30},
                   second={**FIRST, 'random.count': 4}, steps=(3, 3))
    markers = decoded(tmp_path / 'run.mcap', '/markers')
    second_start = truth.segments[1][1].log_offset_ns
    at_reset = [msg for t, msg in markers if t == second_start]
    assert [len(msg.markers) for msg in at_reset] == [1, 4 + 1]
    assert at_reset[0].markers[0].action == DELETEALL


def test_clock_is_recorded_per_step_only_while_publish_clock_is_on(tmp_path):
    path = tmp_path / 'run.mcap'
    truth = record(path, first={**FIRST, 'publish_clock': True},
                   second={**SECOND, 'publish_clock': False}, steps=(10, 10))
    clock = decoded(path, '/clock')
    first_segment = [r for r in truth.records if segment_of(truth, r.log_time_ns) == 0]
    # the node's /clock carries simulation time (back to 0 at a reset), logged at the step
    assert [(t, m.clock.sec * 10**9 + m.clock.nanosec) for t, m in clock] == \
        [(r.log_time_ns, r.stamp_ns) for r in first_segment]
    with RosbagsReader(path) as reader:
        connection = next(c for c in reader.connections if c.topic == '/clock')
        qos = connection.ext.offered_qos_profiles[0]
        assert (connection.msgtype, qos.reliability.name, qos.depth) == \
            ('rosgraph_msgs/msg/Clock', 'BEST_EFFORT', 1)
        assert connection.msgcount == len(first_segment)
    record(tmp_path / 'off.mcap', first={**FIRST, 'publish_clock': False},
           second={**SECOND, 'publish_clock': False}, steps=(3, 3))
    assert '/clock' not in Recording(tmp_path / 'off.mcap').topics


def test_stats_name_each_value_in_its_own_dim(recorded):
    path, truth = recorded
    (_, first), *_ = decoded(path, '/stats')
    assert [(d.label, d.size, d.stride) for d in first.layout.dim] == \
        [(name, 1, 1) for name in STATS_FIELDS]
    assert first.data[STATS_FIELDS.index('kinetic_energy')] == truth.records[0].kinetic_energy


def _panel_ids(tree):
    if isinstance(tree, str):
        return [tree]
    return _panel_ids(tree['first']) + _panel_ids(tree['second'])


def test_layout_is_valid_json_naming_recorded_topics_and_stats_by_index(recorded):
    path, _ = recorded
    layout = json.loads(LAYOUT.read_text())
    config = layout['configById']
    assert sorted(_panel_ids(layout['layout'])) == sorted(config)
    topics = Recording(path).topics
    scene = config['3D!world']
    assert scene['followTf'] == 'world'
    # The robots' topics are there when ball_0 and ball_1 are agents (test_agent_views and
    # test_scans check them), /map with a map (test_map_views).
    robots = {'/ball_0/odom', '/ball_0/scan', '/ball_0/ground_truth', '/ball_1/ground_truth',
              '/bumper_markers'}
    assert set(scene['topics']) - robots - {'/map'} == {'/markers', '/balls'} <= set(topics)
    assert all(settings['visible'] for settings in scene['topics'].values())
    plotted = []
    for panel_id, panel in config.items():
        if not panel_id.startswith('Plot!') or panel_id == 'Plot!bumpers':  # test_agent_views
            continue
        for series in panel['paths']:
            topic, _, field = series['value'].partition('.data[')
            assert topic in topics and topics[topic].type == 'std_msgs/msg/Float64MultiArray'
            index = int(field.rstrip(']'))
            assert series['label'] == STATS_FIELDS[index]
            plotted.append(index)
    assert sorted(plotted) == list(range(len(STATS_FIELDS)))
