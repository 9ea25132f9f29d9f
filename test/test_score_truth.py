"""Ground truth for ball_world_score is what the live scan could really see, from where the
agent really was: a map's cells hide balls as walls do, and a drifting odometry (noisy /tf)
never moves the scan's origin or heading.

Every check compares the scorer's `visible` with the recorded scan itself (noise-free
ranges: a ball is visible exactly when a recorded beam ends on its surface), so a scorer
that ignores the map or takes /tf for the truth fails here, not only one that crashes.
"""
import json

from ball_world_testing.harness import open_rrd, without_messages
from mcap_ros2.writer import Writer as Ros2Writer
import numpy as np
import pytest

from ball_world.core import lidar
from ball_world.core.parameters import checked
from ball_world.msgs.definitions import message_definition
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.rerun_map import MAP_CELLS
from ball_world.scans import fan_from, scan_grid
from ball_world.simulation import Simulation
from ball_world.tools import score, score_bench
from ball_world.tools.score_recording import read_run, RecordingError

#: 5 m x 5 m of free cells at 0.05 m, a solid block in the middle: x 2.4-2.6, y 1.5-3.5.
COLUMNS = ROWS = 100
BLOCK = (slice(30, 70), slice(48, 52))  # rows (y), columns (x) of the map's grid
#: ball_0 scans; ball_1 is behind the block; ball_2 and ball_3 are in the open.
MAP_BALLS = {'balls.x': [1.0, 4.0, 1.0, 2.5], 'balls.y': [2.5, 2.5, 4.2, 0.6],
             'balls.vx': [0.0] * 4, 'balls.vy': [0.0] * 4, 'balls.radius': [0.2] * 4,
             'balls.mass': [1.0] * 4}
MARKERS = 'visualization_msgs/msg/MarkerArray'


def write_map(folder):
    """A nav2 map (trinary PGM: 0 occupied, 254 free) of the block; its YAML's path."""
    cells = np.full((ROWS, COLUMNS), 254, dtype=np.uint8)
    cells[BLOCK] = 0
    image = cells[::-1]  # the image's first row is the map's last
    (folder / 'block.pgm').write_bytes(f'P5\n{COLUMNS} {ROWS}\n255\n'.encode() + image.tobytes())
    (folder / 'block.yaml').write_text(
        'image: block.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n'
        'occupied_thresh: 0.65\nfree_thresh: 0.196\n')
    return folder / 'block.yaml'


def record(path, parameters, steps, command):
    """Run `parameters` recorded to `path`, ball_0 given `command` every step; the records."""
    simulation = Simulation(parameters, sinks=[McapSink(path)])
    records = [simulation.last_record]
    for _ in range(steps):
        simulation.command('ball_0', *command)
        records.append(simulation.step()[0])
    simulation.close()
    return records


def seen_by_the_scan(scan, tolerance=1e-5):
    """The balls a recorded noise-free scan's beams end on (from its true pose), to the
    float32 of LaserScan's ranges."""
    x, y, yaw = scan.truth_pose
    message = scan.message
    ranges = np.asarray(message.ranges, dtype=np.float64)
    angles = yaw + message.angle_min + np.arange(len(ranges)) * message.angle_increment
    hit = np.isfinite(ranges)
    ends = np.column_stack((x + ranges[hit] * np.cos(angles[hit]),
                            y + ranges[hit] * np.sin(angles[hit])))
    gaps = np.abs(np.hypot(ends[:, None, 0] - scan.positions[None, :, 0],
                           ends[:, None, 1] - scan.positions[None, :, 1]) - scan.radii[None])
    return set(np.flatnonzero((gaps < tolerance).any(axis=0)).tolist())


def oracle_tracks(path, scans):
    """An MCAP of a MarkerArray per scan with every ball's true position (world frame)."""
    with open(path, 'wb') as stream:
        writer = Ros2Writer(stream)
        schema = writer.register_msgdef(MARKERS, message_definition(MARKERS))
        for scan in scans:
            stamp = scan.stamp_ns
            header = {'stamp': {'sec': stamp // 10**9, 'nanosec': stamp % 10**9},
                      'frame_id': 'world'}
            markers = [{'header': header, 'action': 3}] + [
                {'header': header, 'id': i, 'action': 0, 'type': 2,
                 'pose': {'position': {'x': float(x), 'y': float(y), 'z': 0.0},
                          'orientation': {'w': 1.0}}}
                for i, (x, y) in enumerate(scan.positions)]
            writer.write_message('/my/tracks', schema, {'markers': markers}, log_time=stamp,
                                 publish_time=stamp)
        writer.finish()


@pytest.fixture(scope='module')
def map_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp('map_truth')
    parameters = {'map': str(write_map(folder)), 'arena': [], 'random.count': 0,
                  'agents': ['ball_0'], 'agent.scan.noise_stddev': 0.0, 'rate_hz': 60.0,
                  'physics.backend': 'numpy', **MAP_BALLS}
    path = folder / 'run.mcap'
    record(path, parameters, 30, (0.0, 0.0, 1.0))  # turning on the spot
    (segment,) = read_run(path, 'ball_0')
    return path, segment


def test_a_ball_behind_a_map_wall_is_not_ground_truth(map_run):
    _, segment = map_run
    assert len(segment.scans) == 6  # 10 Hz over half a second at 60 Hz, step 0 included
    for scan in segment.scans:
        visible = set(np.flatnonzero(scan.visible).tolist())
        assert visible == {2, 3}, (scan.step, visible)
        assert visible == seen_by_the_scan(scan)
        # The walls alone (the scorer before maps) would have counted ball_1 as seen.
        fan = fan_from(checked({'agent.scan.noise_stddev': 0.0}), 0.2)
        blind = lidar.seen_balls(scan.positions, scan.radii, segment.walls,
                                 scan.positions[0], scan.truth_pose[2], fan, 0)
        assert 1 in blind.tolist()


def test_the_recorded_maps_grid_is_the_worlds_cell_for_cell(map_run, tmp_path):
    path, _ = map_run
    (segment,) = Recording(path).segments
    grid = scan_grid(segment.parameters, segment.occupancy_map)
    world = Simulation(segment.parameters, occupancy_map=segment.occupancy_map).world
    assert grid.solid.tobytes() == world.static.scan_grid.solid.tobytes()
    assert grid.frame.tolist() == world.static.scan_grid.frame.tolist()
    assert int(grid.solid.sum()) == 40 * 4
    assert scan_grid(checked({}), None).empty


def test_a_track_on_the_hidden_ball_is_dont_care(map_run, tmp_path, capsys):
    path, segment = map_run
    oracle_tracks(tmp_path / 'tracks.mcap', segment.scans)
    code = score.main([str(path), '--tracks', str(tmp_path / 'tracks.mcap'), '/my/tracks',
                       '--json', '--rerun', str(tmp_path / 'scored.rrd')])
    out, err = capsys.readouterr()
    assert code == 0, err
    report = json.loads(out)
    scans = len(segment.scans)
    # every scan: ball_1 hidden, and the oracle's track on it neither a hit nor a false
    # positive; the scanner's own ball is hidden from itself too
    assert report['truth'] == {'visible': 2 * scans, 'hidden': 2 * scans}
    assert report['dont_care'] == 2 * scans
    figures = report['figures']
    assert figures['CLR_TP'] == 2 * scans and figures['CLR_FP'] == 0
    assert figures['MOTA'] == 1.0 and figures['HOTA'] == pytest.approx(1.0)
    # the scored view draws the map that hid ball_1, and no drift (no odometry noise)
    content = rrd_content(tmp_path / 'scored.rrd')
    assert any(entity == f'/{MAP_CELLS}' for entity, _ in content)
    assert not any(content[('/arena/agent/odom', 'Arrows2D:vectors')])


def rrd_content(path):
    """{(entity path, component): [number of instances, per row logged]} of a scored .rrd."""
    reader = open_rrd(path)
    (store,) = reader.recordings()
    content = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        for index, field in enumerate(batch.schema):
            if (field.metadata or {}).get(b'rerun:kind') == b'data':
                content.setdefault((chunk.entity_path, field.name), []).extend(
                    len(value or ()) for value in batch.column(index).to_pylist())
    return content


NOISY = {'random.count': 12, 'random.seed': 3, 'agents': ['ball_0'], 'rate_hz': 60.0,
         'physics.backend': 'numpy', 'agent.odom.noise': [1.0, 1.0, 1.0, 1.0],
         'agent.scan.noise_stddev': 0.0, 'agent.scan.samples': 61,
         'agent.scan.angle_min': -0.5, 'agent.scan.angle_max': 0.5}
COMMAND = (0.5, 0.0, 0.4)


@pytest.fixture(scope='module')
def noisy_run(tmp_path_factory):
    path = tmp_path_factory.mktemp('noisy_truth') / 'run.mcap'
    records = record(path, NOISY, 360, COMMAND)
    (segment,) = read_run(path, 'ball_0')
    return path, records, segment


def test_with_noisy_odometry_the_truth_is_the_true_pose_not_tf(noisy_run):
    _, records, segment = noisy_run
    by_step = {r.step: r for r in records}
    drift = []
    for scan in segment.scans:
        record_ = by_step[scan.step]
        row = record_.agents.names.index('ball_0')
        x, y, yaw = scan.truth_pose
        assert (x, y) == tuple(record_.positions[record_.agents.indices[row]].tolist())
        assert yaw == pytest.approx(float(record_.agents.yaws[row]), abs=1e-12)
        drift.append(abs(np.angle(np.exp(1j * (scan.pose[2] - yaw)))))
        assert set(np.flatnonzero(scan.visible).tolist()) == seen_by_the_scan(scan)
    assert max(drift) > 0.05  # /tf (the tracker's input) really drifted from the truth


def test_the_scored_view_draws_the_true_pose_and_where_tf_drifted(noisy_run, tmp_path,
                                                                  capsys):
    path, _, segment = noisy_run
    assert score.main([str(path), '--rerun', str(tmp_path / 'scored.rrd')]) == 0, \
        capsys.readouterr().err
    content = rrd_content(tmp_path / 'scored.rrd')
    drifted = [scan.pose != scan.truth_pose for scan in segment.scans]
    assert content[('/arena/agent/odom', 'Arrows2D:vectors')] == [int(d) for d in drifted]
    assert any(drifted) and not drifted[0]  # the odometry starts at the truth
    # the agent's own ball found at its true pose at every scan
    assert content[('/arena/agent', 'Points2D:positions')] == [1] * len(segment.scans)


def test_visibility_from_the_drifting_tf_would_be_wrong(noisy_run):
    """The test above would catch a scorer that takes /tf's heading: it sees other balls."""
    _, _, segment = noisy_run
    differ = 0
    for scan in segment.scans:
        index = scan.names.index('ball_0')
        fan = fan_from(checked(NOISY), float(scan.radii[index]))
        from_tf = lidar.seen_balls(scan.positions, scan.radii, segment.walls,
                                   scan.positions[index], scan.pose[2], fan, index)
        differ += set(from_tf.tolist()) != set(np.flatnonzero(scan.visible).tolist())
    assert differ > 0


def test_a_scene_with_noise_and_a_map_scores_as_its_recording(map_run, tmp_path):
    path, _ = map_run
    (recorded,) = Recording(path).segments
    parameters = {**recorded.parameters, 'agent.odom.noise': [1.0, 1.0, 1.0, 1.0],
                  'agent.scan.angle_min': -0.5, 'agent.scan.angle_max': 0.5,
                  'agent.scan.samples': 61}
    scene = score_bench.Scene('map', checked(parameters), 'ball_0', (0.3, 0.0, 1.0), 90)
    simulated = score_bench.simulated_scans(scene)
    copy = tmp_path / 'scene.mcap'
    record(copy, parameters, 90, (0.3, 0.0, 1.0))
    (segment,) = read_run(copy, 'ball_0')
    assert len(simulated) == len(segment.scans) == 16
    hidden_by_the_map = 0
    for mine, theirs in zip(simulated, segment.scans):
        assert mine.truth_pose == theirs.truth_pose and mine.pose == theirs.pose
        assert mine.visible.tolist() == theirs.visible.tolist()
        assert set(np.flatnonzero(mine.visible).tolist()) == seen_by_the_scan(mine)
        hidden_by_the_map += not mine.visible[1]
    assert hidden_by_the_map > 0


def test_a_noisy_recording_without_ground_truth_is_one_line(noisy_run, tmp_path):
    """A file whose ground truth was dropped (a filtered copy) cannot be scored from /tf."""
    path, _, _ = noisy_run
    kept = tmp_path / 'no_truth.mcap'
    without_messages(path, kept, lambda topic: topic.endswith('/ground_truth'))
    with pytest.raises(RecordingError, match='no ball_0/ground_truth at the scan of step 0'):
        read_run(kept, 'ball_0')
