"""MCAP recordings: what McapSink writes, how other readers see it, and the tools around it.

Recordings are made by driving Simulation with an McapSink directly (no node), next to a
sink that keeps every record in memory: that is the ground truth every reader must match
bit for bit.
"""
import dataclasses
import errno
import io
import os
from pathlib import Path
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap

from ball_world_testing.harness import (DEADLINE, executable, rewrite_recording, ROSBAGS_TYPES,
                                        Truth)
from mcap.reader import make_reader, SeekingReader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
import rclpy
from rclpy.node import Node
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.rosbag2.errors import ReaderError
import yaml

from ball_world.msgs.cdr import decode_pose_array, encode_pose_array
from ball_world.msgs.definitions import message_definition, type_hash
from ball_world.recording.mcap_reader import feed_sinks, Recording, Scan
from ball_world.recording.mcap_writer import McapSink, NOT_REPEATED
from ball_world.simulation import Simulation
from ball_world.step_record import STATS_FIELDS
from ball_world.tools import info, repair, resim

ROOT = Path(__file__).resolve().parents[1]
# Without /clock (on by default): its channel is checked in test_foxglove.py.
PARAMS = {'rate_hz': 20.0, 'random.count': 12, 'random.seed': 3, 'publish_clock': False}
SECOND = {'rate_hz': 20.0, 'random.count': 8, 'random.seed': 9, 'arena': [0.0, 0.0, 6.0, 5.0],
          'publish_clock': False}
# Impulses queued before stepping into the step (key) whose stamp they will carry.
IMPULSES = {5: [(2, 0.3, -0.1)], 12: [(0, -0.2, 0.4), (1, 0.1, 0.0)]}
RESET_IMPULSES = {3: [(4, 0.05, 0.05)]}
# What rosbag2 Jazzy writes for a reliable, volatile, keep_last 10 publisher.
JAZZY_QOS = (
    '- history: keep_last\n  depth: 10\n  reliability: reliable\n  durability: volatile\n'
    '  deadline:\n    sec: 9223372036\n    nsec: 854775807\n'
    '  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n'
    '  liveliness: automatic\n'
    '  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n'
    '  avoid_ros_namespace_conventions: false')
TYPES = {'/balls': 'geometry_msgs/msg/PoseArray', '/state': 'std_msgs/msg/Float64MultiArray',
         '/stats': 'std_msgs/msg/Float64MultiArray',
         '/impulse': 'geometry_msgs/msg/Vector3Stamped'}
MARKERS = {'/markers': 'visualization_msgs/msg/MarkerArray'}
# What the node's markers publisher offers: reliable, transient local, keep_last 1.
MARKERS_QOS = JAZZY_QOS.replace('depth: 10', 'depth: 1').replace(
    'durability: volatile', 'durability: transient_local')


def run(simulation, steps, impulses=None):
    for k in range(1, steps + 1):
        for ball, jx, jy in (impulses or {}).get(simulation.step_index + 1, ()):
            simulation.queue_impulse(f'ball_{ball}', jx, jy)
        simulation.step()


def record(path, steps=30, reset_steps=12, compression='lz4', chunk_bytes=None):
    """A recording with impulses and (if reset_steps) a reset; returns its Truth."""
    truth = Truth()
    options = {} if chunk_bytes is None else {'chunk_bytes': chunk_bytes}
    simulation = Simulation(PARAMS, sinks=[McapSink(path, compression, **options), truth])
    run(simulation, steps, IMPULSES)
    if reset_steps:
        simulation.reset(SECOND)
        run(simulation, reset_steps, RESET_IMPULSES)
    simulation.close()
    return truth


def read_ros2(path):
    """(channel, message, decoded ROS message) of every message, via mcap_ros2's decoder."""
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(item.channel, item.message, item.decoded_message)
                for item in reader.iter_decoded_messages(log_time_order=False)]


def bits_equal(a, b):
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    return a.shape == b.shape and bool((a.view(np.uint64) == b.view(np.uint64)).all())


def expected_messages(truth):
    """(topic, log_time, impulse or None, record) in the order the sink writes them."""
    out = []
    for rec in truth.records:
        out.extend(('/impulse', rec.log_time_ns, impulse, rec) for impulse in rec.impulses)
        out.extend((topic, rec.log_time_ns, None, rec)
                   for topic in ('/balls', '/state', '/stats'))
    return out


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp('rec') / 'run.mcap'
    return path, record(path)


# Writing and reading back ----------------------------------------------------------------

@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_mcap_ros2_reads_back_exactly_what_the_simulation_produced(tmp_path, compression):
    path = tmp_path / 'run.mcap'
    truth = record(path, compression=compression)
    expected = expected_messages(truth)
    decoded = [item for item in read_ros2(path) if item[0].topic in TYPES]
    assert [(channel.topic, message.log_time) for channel, message, _ in decoded] == \
        [(topic, log_time) for topic, log_time, _, _ in expected]
    for (_, message, msg), (topic, log_time, impulse, item) in zip(decoded, expected):
        assert message.publish_time == log_time
        if topic == '/balls':
            poses = np.array([[p.position.x, p.position.y] for p in msg.poses])
            assert bits_equal(poses, item.positions)
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == item.stamp_ns
            assert msg.header.frame_id == 'world'
        elif topic == '/state':
            rows = np.array(msg.data).reshape(-1, 4)
            assert bits_equal(rows, np.concatenate((item.positions, item.velocities), 1))
            assert [d.label for d in msg.layout.dim] == ['ball', 'x_y_vx_vy']
        elif topic == '/stats':
            assert msg.data[0] == item.kinetic_energy
            assert list(msg.data[3:5]) == [item.ball_ball, item.ball_wall]
            # one labelled dim per value: dim i names data[i]
            assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == \
                [(name, 1, 1) for name in STATS_FIELDS]
        else:
            assert (msg.header.frame_id, msg.vector.x, msg.vector.y, msg.vector.z) == \
                (impulse.frame_id, impulse.jx, impulse.jy, 0.0)
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == item.stamp_ns


def test_rosbags_reads_the_bare_mcap_with_rosbag2_qos_and_schemas(recorded):
    path, truth = recorded
    with RosbagsReader(path) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in connections.items()} == {**TYPES, **MARKERS}
        for topic, connection in connections.items():
            qos = connection.ext.offered_qos_profiles[0]
            assert (qos.history.name, qos.depth, qos.reliability.name,
                    qos.durability.name) == (('KEEP_LAST', 1, 'RELIABLE', 'TRANSIENT_LOCAL')
                                             if topic == '/markers' else
                                             ('KEEP_LAST', 10, 'RELIABLE', 'VOLATILE'))
            assert connection.msgdef.data == message_definition({**TYPES, **MARKERS}[topic])
        balls = [ROSBAGS_TYPES.deserialize_cdr(raw, 'geometry_msgs/msg/PoseArray')
                 for _, _, raw in reader.messages([connections['/balls']])]
        markers = connections['/markers'].msgcount
        assert reader.message_count == len(expected_messages(truth)) + markers
    assert len(balls) == len(truth.records)
    for msg, rec in zip(balls, truth.records):
        assert bits_equal([[p.position.x, p.position.y] for p in msg.poses], rec.positions)


def test_file_has_ros2_profile_channel_metadata_and_segment_records(recorded):
    path, truth = recorded
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = list(reader.iter_metadata())
        log_times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
    assert header.profile == 'ros2' and header.library.startswith('ball_world 0.1.0')
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert (schema.encoding, channel.message_encoding) == ('ros2msg', 'cdr')
        assert schema.data.decode() == message_definition(schema.name)
        qos = MARKERS_QOS if channel.topic == '/markers' else JAZZY_QOS
        assert channel.metadata == {'offered_qos_profiles': qos,
                                    'topic_type_hash': type_hash(schema.name)}
        assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
    # a reset makes a second segment, and log times never go back in file order
    assert log_times == sorted(log_times)
    assert [m.name for m in metadata] == ['ball_world', 'ball_world']
    first, second = (m.metadata for m in metadata)
    assert (first['segment'], second['segment']) == ('0', '1')
    assert int(second['log_offset_ns']) == truth.records[30].log_time_ns + 50_000_000
    assert second['dt_ns'] == '50000000' and second['frame_id'] == 'world'
    assert second['backend'] == Simulation({}).world.backend  # what auto resolved to
    assert yaml.safe_load(second['parameters']) == yaml.safe_load(second['parameters_json'])
    params = yaml.safe_load(second['parameters'])['ball_world']['ros__parameters']
    assert params['arena'] == [0.0, 0.0, 6.0, 5.0] and params['random']['count'] == 8


def test_parameters_metadata_is_a_params_file_rcl_accepts(tmp_path):
    parameters = {**PARAMS, 'balls.x': [1.0, 2.5], 'balls.y': [1.0, 1.0],
                  'balls.vx': [0.5, -0.5], 'balls.vy': [0.0, 0.0],
                  'balls.radius': [0.2, 0.2], 'balls.mass': [1.0, 2.0],
                  'frame_id': 'map', 'record.mcap': str(tmp_path / 'run.mcap')}
    simulation = Simulation(parameters, sinks=[McapSink(tmp_path / 'run.mcap')])
    simulation.close()
    with open(tmp_path / 'run.mcap', 'rb') as stream:
        text = next(make_reader(stream).iter_metadata()).metadata['parameters']
    (tmp_path / 'params.yaml').write_text(text)
    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file',
                                      str(tmp_path / 'params.yaml')])
    try:
        node = Node('ball_world', context=context)
        effective = simulation.parameters
        for name, value in effective.items():
            if value == []:
                continue  # rcl reads [] as unset; the node takes its empty default
            got = node.declare_parameter(name, value).value
            expected = '' if name in NOT_REPEATED else value
            assert (list(got) if isinstance(value, list) else got) == expected, name
            assert type(got if not isinstance(value, list) else got[0]) is \
                type(expected if not isinstance(value, list) else expected[0]), name
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_recording_steps_and_feed_sinks_rebuild_every_record(recorded):
    path, truth = recorded
    recording = Recording(path)
    assert recording.has_summary and recording.problem is None
    assert [(s.index, s.log_offset_ns) for s in recording.segments] == \
        [(info.segment, info.log_offset_ns) for _, info in truth.segments]
    fed = Truth()
    assert feed_sinks(path, [fed]) == len(truth.records)
    assert fed.closed and fed.flushes == 1
    for (world, run_info), (got_world, got_info) in zip(truth.segments, fed.segments):
        for name in ('radii', 'masses', 'walls', 'positions', 'velocities'):
            assert bits_equal(getattr(got_world, name), getattr(world, name)), name
        assert (got_world.dt_ns, got_world.frame_id) == (world.dt_ns, world.frame_id)
        expected = {**run_info.parameters, 'record.mcap': '', 'record.rerun': ''}
        assert got_info.parameters == expected
        assert got_info.topics == {**run_info.topics, 'markers': '/markers'}
        assert (got_info.segment, got_info.log_offset_ns, got_info.package_version) == \
            (run_info.segment, run_info.log_offset_ns, run_info.package_version)
    assert len(fed.records) == len(truth.records)
    for got, want in zip(fed.records, truth.records):
        assert (got.step, got.stamp_ns, got.log_time_ns) == \
            (want.step, want.stamp_ns, want.log_time_ns)
        assert bits_equal(got.positions, want.positions)
        assert bits_equal(got.velocities, want.velocities)
        assert bits_equal(got.momentum, want.momentum)
        assert (got.kinetic_energy, got.ball_ball, got.ball_wall, got.real_time_factor) == \
            (want.kinetic_energy, want.ball_ball, want.ball_wall, want.real_time_factor)
        assert (got.balls_cdr, got.state_cdr, got.stats_cdr) == \
            (want.balls_cdr, want.state_cdr, want.stats_cdr)
        assert got.impulses == want.impulses


def test_info_reports_steps_segments_topics_impulses_and_energy(recorded, capsys):
    path, truth = recorded
    assert info.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert 'summary:     yes' in out
    # 30 + 12 steps; each segment also records its initial state, step 0.
    assert 'steps:       42 after the initial states (44 messages on /balls), in 2 segments' \
        in out
    assert '  0: from log time 0 s, steps 0-30' in out
    assert '  1: from log time 1.55 s, steps 0-12' in out
    assert '/impulse  geometry_msgs/msg/Vector3Stamped  4' in out
    assert 'segment 0 step 12 (0.6 s): ball_0 J = (-0.2, 0.4) N s' in out
    assert 'segment 1 step 3 (0.15 s): ball_4' in out
    assert f'{truth.records[0].kinetic_energy:.9g} J at start (segment 0)' in out
    assert f'{truth.records[-1].kinetic_energy:.9g} J at end (segment 1)' in out
    assert 'compression: lz4' in out


# Re-simulation ------------------------------------------------------------------------------

def test_resim_is_bit_identical_across_impulses_and_a_reset(recorded, capsys):
    path, _ = recorded
    assert resim.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert 'segment 0: 31 steps compared (last step 30), 3 impulses: identical' in out
    assert 'segment 1: 13 steps compared (last step 12), 1 impulses: identical' in out
    assert 'all 44 recorded steps re-simulate bit-identically' in out


def test_resim_reports_a_pose_changed_by_one_ulp(recorded, tmp_path, capsys):
    path, truth = recorded
    target = truth.records[17]

    def nudge(topic, log_time, data):
        if topic != '/balls' or log_time != target.log_time_ns:
            return data
        stamp, frame_id, positions = decode_pose_array(data)
        positions[4, 0] = np.nextafter(positions[4, 0], np.inf)
        return encode_pose_array(positions, stamp, frame_id)

    rewrite_recording(path, tmp_path / 'tampered.mcap', data=nudge)
    assert resim.main([str(tmp_path / 'tampered.mcap')]) == 1
    out = capsys.readouterr().out
    assert 'segment 0: 31 steps compared (last step 30), 3 impulses: 1 steps differ' in out
    assert 'first difference: segment 0 step 17 ball 4 balls x' in out
    ulp = np.spacing(target.positions[4, 0])
    assert f'largest difference: {ulp:.3g}' in out


def test_resim_notices_an_impulse_moved_to_another_ball(recorded, tmp_path, capsys):
    path, _ = recorded
    rewrite_recording(
        path, tmp_path / 'no_impulse.mcap',
        data=lambda topic, log_time, data: data if topic != '/impulse' or log_time != 250_000_000
        else data.replace(b'ball_2', b'ball_3'))
    assert resim.main([str(tmp_path / 'no_impulse.mcap')]) == 1
    out = capsys.readouterr().out
    assert 'first difference: segment 0 step 5 ' in out
    assert 'segment 1: 13 steps compared (last step 12), 1 impulses: identical' in out
    # the impulse changed ball 2's velocity in the recording and ball 3's in the re-run
    assert 'largest difference' in out and ' step 5 ball 2 state v' in out


# Crashes, truncation and repair ------------------------------------------------------------

WRITER = textwrap.dedent("""
    import sys
    from ball_world.recording.mcap_writer import McapSink
    from ball_world.simulation import Simulation
    params = {'rate_hz': 20.0, 'random.count': 40, 'random.seed': 5}
    sim = Simulation(params, sinks=[McapSink(sys.argv[1], chunk_bytes=20000)])
    while True:
        if sim.step_index == 7:
            sim.queue_impulse('ball_3', 0.2, 0.1)
        sim.step()
        if sim.step_index % 10 == 0:
            sim.flush()
            print(sim.step_index, flush=True)
""")


def test_sigkilled_recording_is_repaired_up_to_the_last_flush(tmp_path, capsys, processes):
    path = tmp_path / 'killed.mcap'
    child = processes.start([sys.executable, '-c', WRITER, str(path)], cwd=ROOT, stderr=None)
    try:
        flushed = [int(child.stdout.readline()) for _ in range(3)]
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    assert flushed == [10, 20, 30]
    with pytest.raises(ReaderError):
        RosbagsReader(path).open()  # what repair is for
    assert info.main([str(path)]) == 0
    assert f'Repair it: ball_world_repair {path}' in capsys.readouterr().out

    assert repair.main([str(path)]) == 0
    repaired = tmp_path / 'killed.repaired.mcap'
    assert f'wrote {repaired}' in capsys.readouterr().out
    steps = [s.step for s in Recording(repaired).steps()]
    assert steps == list(range(len(steps))) and len(steps) >= 31
    with RosbagsReader(repaired) as reader:
        assert reader.message_count == Recording(repaired).message_count
    assert resim.main([str(repaired)]) == 0
    assert 'identical' in capsys.readouterr().out


def test_unfinished_file_is_read_without_summary_up_to_the_last_flush(tmp_path):
    path = tmp_path / 'open.mcap'
    truth = Truth()
    simulation = Simulation(PARAMS, sinks=[McapSink(path), truth])
    run(simulation, 20, IMPULSES)
    simulation.flush()
    run(simulation, 3)  # after the flush: may or may not be on disk
    shutil.copy(path, tmp_path / 'copy.mcap')
    simulation.close()
    recording = Recording(tmp_path / 'copy.mcap')
    assert not recording.has_summary and 'without a footer' in recording.problem
    steps = list(recording.steps())
    assert [s.step for s in steps] == list(range(21))
    for step, rec in zip(steps, truth.records):
        assert bits_equal(step.positions, rec.positions)
    assert sum(len(s.impulses) for s in steps) == 3


def chunk_ends(path):
    with open(path, 'rb') as stream:
        summary = SeekingReader(stream).get_summary()
    return [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length, c.message_end_time)
            for c in summary.chunk_indexes]


def test_repair_keeps_every_complete_chunk_wherever_the_file_is_cut(tmp_path):
    path = tmp_path / 'full.mcap'
    truth = record(path, steps=40, reset_steps=10, chunk_bytes=6000)
    chunks = chunk_ends(path)
    assert len(chunks) >= 6
    data = path.read_bytes()
    (start, end, _), (next_start, _, _) = chunks[2], chunks[3]
    first_chunk = chunks[0][0]
    cuts = [first_chunk, first_chunk + 5, start, (start + end) // 2, end, end + 1,
            next_start + 30, len(data) - 40]
    expected_counts = {}
    for cut in cuts:
        source = tmp_path / f'cut{cut}.mcap'
        source.write_bytes(data[:cut])
        target = tmp_path / f'cut{cut}.repaired.mcap'
        assert repair.main([str(source), '-o', str(target)]) == 0
        last_log = max([t for _, e, t in chunks if e <= cut], default=-1)
        want = [r for r in truth.records if r.log_time_ns <= last_log]
        with open(target, 'rb') as stream:
            assert make_reader(stream).get_summary() is not None
        balls = [msg for channel, _, msg in read_ros2(target) if channel.topic == '/balls']
        assert len(balls) == len(want), cut
        for msg, rec in zip(balls, want):
            assert bits_equal([[p.position.x, p.position.y] for p in msg.poses],
                              rec.positions)
        with RosbagsReader(target) as reader:
            counts = {c.topic: c.msgcount for c in reader.connections if c.msgcount}
        expected_counts[cut] = counts
        assert counts.get('/balls', 0) == len(want)
    assert expected_counts[len(data) - 40]['/impulse'] == 4


def test_repair_in_place_and_rejects_non_mcap(tmp_path, capsys):
    path = tmp_path / 'run.mcap'
    record(path, steps=10, reset_steps=0)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    assert repair.main([str(path), '-o', str(path)]) == 0
    assert Recording(path).has_summary
    assert not list(tmp_path.glob('*.partial-*'))
    (tmp_path / 'text.mcap').write_text('not an mcap at all')
    assert repair.main([str(tmp_path / 'text.mcap')]) == 2
    assert 'not an MCAP file' in capsys.readouterr().err


# Failures ------------------------------------------------------------------------------------

def test_unwritable_paths_fail_at_construction_naming_the_path(tmp_path):
    missing = tmp_path / 'no' / 'such' / 'dir' / 'run.mcap'
    with pytest.raises(OSError) as raised:
        McapSink(missing)
    assert str(missing) in str(raised.value) and raised.value.errno == errno.ENOENT
    with pytest.raises(OSError) as raised:
        McapSink(tmp_path)
    assert str(raised.value) == f'{tmp_path}: is a directory, not a regular file'
    with pytest.raises(OSError) as raised:
        McapSink('/dev/full', overwrite=True)
    assert str(raised.value) == '/dev/full: is a character device, not a regular file'
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError):
        McapSink(tmp_path / 'x.mcap', compression='gzip')


def test_disk_full_mid_run_raises_once_and_the_simulation_goes_on(tmp_path):
    sink = McapSink(tmp_path / 'run.mcap', chunk_bytes=4000)
    failures = []
    simulation = Simulation(PARAMS, sinks=[sink], on_sink_failure=failures.append)
    run(simulation, 3)
    full = os.open('/dev/full', os.O_WRONLY)
    os.dup2(full, sink._file.fileno())  # the disk fills up under the open file
    os.close(full)
    run(simulation, 10)
    simulation.flush()
    assert len(failures) == 1 and failures[0].sink is sink
    assert failures[0].error.errno == errno.ENOSPC
    assert str(tmp_path / 'run.mcap') in str(failures[0].error)
    assert simulation.sinks == [] and simulation.step_index == 13
    sink.close()  # finished by the failure: nothing left to do, no second error
    with pytest.raises(ValueError):
        sink.write_step(simulation.last_record)


def test_log_time_going_back_is_refused(tmp_path):
    sink = McapSink(tmp_path / 'run.mcap')
    simulation = Simulation(PARAMS, sinks=[sink])
    run(simulation, 3)
    with pytest.raises(ValueError, match='log time went back'):
        sink.write_step(dataclasses.replace(simulation.last_record, log_time_ns=0))
    simulation.close()
    assert Recording(tmp_path / 'run.mcap').has_summary


def test_fsync_flush_and_scan_of_a_file_cut_in_a_record_header(tmp_path):
    path = tmp_path / 'run.mcap'
    sink = McapSink(path, compression='zstd', fsync=True)
    simulation = Simulation(PARAMS, sinks=[sink])
    run(simulation, 4)
    simulation.flush()
    size = os.path.getsize(path)
    # steps 0-4 (dt 50 ms): 3 messages each, and markers: a DELETEALL, then at 0, 0.1, 0.2 s
    messages = 5 * 3 + 4
    with open(path, 'rb') as stream:
        scan = Scan(io.BytesIO(stream.read(size)), size)
        assert sum(type(r).__name__ == 'Message' for r in scan.records()) == messages
    assert scan.end == size and scan.problem.startswith('the file ends')
    torn = path.read_bytes()[:size] + b'\x06\x00'
    scan = Scan(io.BytesIO(torn), len(torn))
    assert sum(type(r).__name__ == 'Message' for r in scan.records()) == messages
    assert scan.end == size and 'cut off in its header' in scan.problem
    simulation.close()


@pytest.mark.parametrize('tool', ['ball_world_info', 'ball_world_resim'])
def test_a_reader_that_stops_early_is_no_error(recorded, tool):
    """`ball_world_info run.mcap | head -1`: the tool ends quietly when the pipe closes."""
    path, _ = recorded
    command = f'{shlex.quote(executable(tool))} {shlex.quote(str(path))} | head -c 1'
    done = subprocess.run(['bash', '-o', 'pipefail', '-c', command], capture_output=True,
                          text=True, timeout=DEADLINE)
    assert done.returncode == 0, done.stderr
    assert 'Traceback' not in done.stderr and 'Broken pipe' not in done.stderr
    assert len(done.stdout) == 1


class _Interrupted:
    """A sink whose queueing of one step is cut by Ctrl-C, as a signal can land there."""

    def __init__(self, at_step):
        self.at_step, self.steps = at_step, []

    def start_segment(self, world, info):
        pass

    def write_step(self, record):
        if record.step == self.at_step:
            raise KeyboardInterrupt()
        self.steps.append(record.step)

    def flush(self):
        pass

    def close(self):
        pass


def test_a_ctrl_c_inside_one_sink_still_gives_the_step_to_the_sinks_after_it(tmp_path):
    cut, after = _Interrupted(at_step=3), _Interrupted(at_step=None)
    simulation = Simulation(PARAMS, sinks=[cut, after])
    run(simulation, 2)
    with pytest.raises(KeyboardInterrupt):
        simulation.step()
    assert after.steps == [0, 1, 2, 3] and cut.steps == [0, 1, 2]
    assert simulation.sinks == [cut, after]  # an interrupt is no sink failure
