"""The map through the running node and its recordings: /map, edits, resim, replay, Rerun.

/map is compared with an independent reading of the map server's rules on the real maps
(trinary: p = (255 - v) / 255 for negate 0; 100 above occupied_thresh, 0 below free_thresh,
-1 between; the image's first row is the map's last), never with the loader's output.
"""
from pathlib import Path
import shutil

from ball_world_testing.harness import (executable, InProcessWorld, open_rrd, Probe,
                                        read_mcap_ros2, run_tool)
from geometry_msgs.msg import PoseArray, PoseStamped
from nav_msgs.msg import OccupancyGrid
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from simulation_interfaces.msg import Result
from simulation_interfaces.srv import SetEntityState, SpawnEntity
from std_srvs.srv import Trigger

from ball_world.core import limits
from ball_world.recording.rerun_map import MAP, MAP_CELLS

MAPS = Path(__file__).resolve().parents[1] / 'maps'
WORLDS = Path(__file__).resolve().parents[1] / 'worlds'
#: How RViz, Foxglove and a Nav2 costmap subscribe to a map (nav2_map_server's QoS).
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def expected_grid(name):
    """The grid nav2_map_server publishes for a real map, read from its files here."""
    fields = dict(line.split(':', 1) for line in (MAPS / f'{name}.yaml').read_text().splitlines())
    occupied, free = float(fields['occupied_thresh']), float(fields['free_thresh'])
    data = (MAPS / f'{name}.pgm').read_bytes()
    width, height = {'tb3_sandbox': (384, 384), 'depot': (604, 307)}[name]
    assert data.startswith(b'P5') and f'{width} {height}\n255\n'.encode() in data[:80]
    pixels = np.frombuffer(data[-width * height:], dtype=np.uint8).reshape(height, width)
    p = (255.0 - pixels) / 255.0
    return np.where(p > occupied, 100, np.where(p < free, 0, -1)).astype(np.int8)[::-1]


def grid_of(message):
    return np.array(message.data, dtype=np.int8).reshape(message.info.height,
                                                         message.info.width)


def copy_maps(folder):
    folder.mkdir(parents=True, exist_ok=True)
    for name in ('tb3_sandbox.yaml', 'tb3_sandbox.pgm', 'depot.yaml', 'depot.pgm'):
        shutil.copy(MAPS / name, folder / name)
    return folder


SANDBOX_ROBOTS = {'balls.x': [-2.0, 2.0], 'balls.y': [-0.5, -0.5], 'balls.vx': [0.0, 0.0],
                  'balls.vy': [0.0, 0.0], 'balls.radius': [0.105, 0.105],
                  'balls.mass': [1.0, 1.0], 'agents': ['ball_0', 'ball_1']}


@pytest.fixture(scope='module')
def world():
    made = InProcessWorld(map=str(MAPS / 'tb3_sandbox.yaml'), arena=[], rate_hz=50.0,
                          **{'random.count': 8, 'markers.rate_hz': 0.0}, **SANDBOX_ROBOTS)
    yield made
    made.close()


def test_a_late_transient_local_subscriber_gets_the_map_server_map(world):
    world.spin_until(lambda: len(world.balls) >= 5, 'the world to step')
    late = Probe('late_costmap')  # a process of its own would be a participant of its own
    try:
        heard = late.listen(OccupancyGrid, '/map', qos=LATCHED)
        late.spin_until(lambda: heard, 'the latched map')
        message = heard[0]
    finally:
        late.close()
    assert message.header.frame_id == 'world'
    assert (message.info.width, message.info.height) == (384, 384)
    assert message.info.resolution == float(np.float32(0.05))
    origin = message.info.origin
    assert (origin.position.x, origin.position.y, origin.position.z) == (-10.0, -10.0, 0.0)
    assert (origin.orientation.z, origin.orientation.w) == (0.0, 1.0)
    assert np.array_equal(grid_of(message), expected_grid('tb3_sandbox'))


def test_the_map_goes_out_again_after_a_reset_and_in_a_new_frame(world):
    heard = world.probe.listen(OccupancyGrid, '/map', qos=LATCHED)
    world.spin_until(lambda: len(heard) == 1, 'the latched map')
    assert world.call(Trigger, 'reset', Trigger.Request()).success
    world.spin_until(lambda: len(heard) == 2, 'the map after the reset')
    assert np.array_equal(grid_of(heard[1]), expected_grid('tb3_sandbox'))
    world.probe.set_parameters('/ball_world', {'frame_id': 'map'})
    try:
        world.spin_until(lambda: len(heard) == 3, 'the map in the new frame')
        assert heard[2].header.frame_id == 'map'
        assert np.array_equal(grid_of(heard[2]), grid_of(heard[0]))
    finally:
        world.probe.set_parameters('/ball_world', {'frame_id': 'world'})


def pose_at(x, y):
    pose = PoseStamped()
    pose.pose.position.x, pose.pose.position.y = x, y
    pose.pose.orientation.w = 1.0
    return pose


def test_spawn_and_set_state_onto_a_pillar_are_refused(world):
    """The sandbox's middle pillar covers (0, 0): nothing may be put there."""
    spawned = world.call(SpawnEntity, 'spawn_entity', SpawnEntity.Request(
        name='onto_pillar', uri='ball', resource_string='radius: 0.1',
        initial_pose=pose_at(0.0, 0.0)))
    assert spawned.result.result == SpawnEntity.Response.INVALID_POSE
    assert "overlaps the map's solid cell" in spawned.result.error_message
    request = SetEntityState.Request(entity='ball_1')
    request.state.pose = pose_at(0.0, 0.0).pose
    moved = world.call(SetEntityState, 'set_entity_state', request)
    assert moved.result.result == SetEntityState.Response.INVALID_POSE
    assert "overlaps the map's solid cell" in moved.result.error_message
    beside = world.call(SpawnEntity, 'spawn_entity', SpawnEntity.Request(
        name='beside', uri='ball', resource_string='radius: 0.1',
        initial_pose=pose_at(0.5, -0.5)))
    assert beside.result.result == Result.RESULT_OK, beside.result.error_message


def test_map_is_read_only_once_started(world):
    names = [item.name for item in world.node.describe_parameters(['map'])]
    assert names == ['map'] and world.node.describe_parameters(['map'])[0].read_only
    result = world.node.set_parameters([Parameter('map', value='elsewhere.yaml')])[0]
    assert not result.successful


@pytest.mark.parametrize('break_it, words', [
    (lambda d: (d / 'tb3_sandbox.pgm').unlink(), 'tb3_sandbox.pgm (named by '),
    (lambda d: (d / 'tb3_sandbox.pgm').write_bytes((MAPS / 'tb3_sandbox.pgm').read_bytes()[:999]),
     'truncated: the image needs 147,456 bytes of pixels'),
    (lambda d: (d / 'tb3_sandbox.yaml').write_text(
        (MAPS / 'tb3_sandbox.yaml').read_text().replace('0.000000]', '0.5]')),
     "'origin' yaw is 0.5 rad"),
    # A checkerboard of 1,100 x 1,100 cells: inside the cells' limit, but its boundary runs
    # would build an index of gigabytes (issue 33): counted and refused before any is made.
    (lambda d: (d / 'tb3_sandbox.pgm').write_bytes(
        b'P5\n1100 1100\n255\n'
        + (np.add.outer(np.arange(1100), np.arange(1100)) % 2 * 254).astype(np.uint8).tobytes()),
     f'boundary runs (edges between solid and free cells, merged along each grid line); a '
     f'world takes at most {limits.MAX_MAP_RUNS:,}'),
])
def test_the_node_refuses_a_bad_map_in_one_line(tmp_path, break_it, words):
    folder = copy_maps(tmp_path / 'maps')
    break_it(folder)
    code, out, err = run_tool('ball_world', '--ros-args', '-p',
                              f'map:={folder / "tb3_sandbox.yaml"}', '-p', 'arena:=[]')
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ball_world: parameter 'map': ")
    assert words in lines[0] and 'Traceback' not in err + out


# Recordings -------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    """A split recording (bag directory) and an .rrd of a run in the sandbox, whose map
    files are then moved away: everything below works from the recording alone."""
    folder = tmp_path_factory.mktemp('maprun')
    maps = copy_maps(folder / 'maps')
    values = {'map': str(maps / 'tb3_sandbox.yaml'), 'arena': '[]', 'max_steps': '240',
              'rate_hz': '0.0', 'dt': '0.01', 'random.count': '10', 'random.seed': '4',
              'record.mcap': str(folder / 'bag'), 'record.max_seconds': '1.0',
              'record.rerun': str(folder / 'run.rrd'), 'markers.rate_hz': '0.0',
              'balls.x': '[-2.0, 2.0]', 'balls.y': '[-0.5, -0.5]', 'balls.vx': '[0.4, 0.0]',
              'balls.vy': '[0.0, 0.3]', 'balls.radius': '[0.105, 0.105]',
              'balls.mass': '[1.0, 1.0]', 'agents': '[ball_0]'}
    arguments = [part for name, value in values.items() for part in ('-p', f'{name}:={value}')]
    code, _, err = run_tool('ball_world', '--ros-args', *arguments)
    assert code == 0, err
    (folder / 'stderr.txt').write_text(err)  # what a test failing on the files shows
    shutil.move(maps, folder / 'moved_away')
    return folder


def test_a_recording_resimulates_bit_for_bit_without_the_map_files(recorded):
    files = sorted((recorded / 'bag').glob('*.mcap'))
    assert len(files) == 3  # split every 1 s of the 2.4: each file carries the map
    code, out, err = run_tool('ball_world_resim', str(recorded / 'bag'))
    assert code == 0, out + err
    assert 'all 241 recorded steps re-simulate bit-identically' in out
    code, out, err = run_tool('ball_world_resim', str(files[-1]))  # a later file alone
    assert code == 0 and 're-simulate bit-identically' in out, out + err


def test_each_split_file_holds_the_map_for_ros2_bag_play_and_foxglove(recorded):
    expected = expected_grid('tb3_sandbox')
    for path in sorted((recorded / 'bag').glob('*.mcap')):
        (message,) = [msg for _, _, msg in read_mcap_ros2(path, ['/map'])]
        grid = np.array(message.data, dtype=np.int8).reshape(message.info.height,
                                                             message.info.width)
        assert np.array_equal(grid, expected)
        code, out, err = run_tool('ball_world_info', str(path))
        assert code == 0, err
        assert ('map:         tb3_sandbox.yaml and tb3_sandbox.pgm (attached): 384 x 384 cells '
                'of 0.05 m at (-10, -10) m, trinary') in out
        occupied, free, unknown = ((expected == v).sum() for v in (100, 0, -1))
        assert (f'{occupied:,} occupied, {free:,} free, {unknown:,} unknown; '
                f'{occupied + unknown:,} solid cells (unknown solid)') in out


def test_replay_republishes_the_map_latched(recorded, processes):
    listener = Probe('late_rviz')
    try:
        first = sorted((recorded / 'bag').glob('*.mcap'))[0]
        balls = listener.listen(PoseArray, '/balls')
        replay = processes.start([executable('ball_world_replay'), str(first), '--loop',
                                  '--topics', '/map', '/balls'])
        listener.spin_until(lambda: balls, 'the replay to play', process=replay)
        # Subscribed after the map went out (with the first step): transient local brings
        # it anyway, as a late RViz or costmap needs.
        late = listener.listen(OccupancyGrid, '/map', qos=LATCHED)
        listener.spin_until(lambda: late, 'the replayed map', process=replay)
        assert np.array_equal(grid_of(late[0]), expected_grid('tb3_sandbox'))
    finally:
        listener.close()  # before the replay is killed (test/conftest.py, probes)


def test_rerun_draws_the_map_where_it_is(recorded):
    # record.rerun splits with the MCAP (run_<i>.rrd): each part opens on its own, the map
    # in it
    parts = sorted(recorded.glob('run_*.rrd'))
    assert [part.name for part in parts] == ['run_0.rrd', 'run_1.rrd', 'run_2.rrd'], \
        (recorded / 'stderr.txt').read_text()
    for part in parts:
        map_in_rrd(part)


def map_in_rrd(path):
    expected = expected_grid('tb3_sandbox')
    reader = open_rrd(str(path))
    found = {}
    for store in reader.recordings():
        for chunk in reader.stream(store=store):
            if chunk.entity_path in (f'/{MAP}', f'/{MAP_CELLS}'):
                batch = chunk.to_record_batch()
                for name in batch.schema.names:
                    found[name] = batch.column(name).to_pylist()[0][0]  # row 0, instance 0
    assert found['Transform3D:translation'] == [-10.0, -10.0, 0.0]
    assert found['Transform3D:scale'] == [float(np.float32(0.05))] * 2 + [1.0]
    image_format = found['SegmentationImage:format']
    assert (image_format['width'], image_format['height']) == (384, 384)
    classes = np.array(found['SegmentationImage:buffer'], dtype=np.uint8).reshape(384, 384)
    # Class v + 1 for value v, 0 for unknown: the image's rows are the map's, bottom first.
    assert np.array_equal(classes.astype(np.int16) - 1, expected)
    colours = {item['class_id']: item['class_description']['info']['color']
               for item in found['AnnotationContext:context']}
    assert colours[1] & 0xFF == 0  # free cells are not drawn
    assert colours[101] & 0xFF == 0xFF  # occupied cells are opaque
