"""A recording is untrusted input: every tool answers a bad file with one line, never a crash.

Each case of the hostile user (issue 10, item 8) is crafted from a real recording, with
siblings that prove the mechanism rather than the one value: other sizes of a bomb, other
nestings, other bad numbers. Then a seeded fuzz (truncations, bit flips, random bytes) runs
every offline tool and checks the contract: exit 0, or a non-zero exit with exactly one line
on stderr, never a traceback and never a hang (each run has a deadline).
"""
import contextlib
from dataclasses import replace
import io
import json
import os
from pathlib import Path
import random
import resource
import signal
import subprocess
import sys

from ball_world_testing.harness import rewrite_recording
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message,
                          Metadata, MetadataIndex, Schema, Statistics)
from mcap.writer import Writer
import pytest
from rclpy.qos import ReliabilityPolicy

from ball_world.msgs.cdr import decode_pose_array, encode_float64_vector
from ball_world.msgs.definitions import message_definition
from ball_world.recording.mcap_reader import (load_untrusted, MAX_CHUNK_BYTES, MAX_SMALL_TEXT,
                                              RecordingError, Scan)
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation
from ball_world.tools import info, repair, replay, resim, to_rrd

MAGIC = b'\x89MCAP0\r\n'
PARAMS = {'rate_hz': 20.0, 'random.count': 12, 'random.seed': 3}
GIB = 1 << 30
#: Generous: a tool that has not answered in this long is hanging.
DEADLINE = 60


class Hung(BaseException):
    """Raised by the deadline: a BaseException, so no tool's `except Exception` hides it."""


@contextlib.contextmanager
def deadline(seconds=DEADLINE):
    def expire(signum, frame):
        raise Hung(f'no answer within {seconds} s')

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


TOOLS = {
    'info': lambda path, out: info.main([str(path)]),
    'resim': lambda path, out: resim.main([str(path)]),
    'to_rrd': lambda path, out: to_rrd.main([str(path), '-o', str(out) + '.rrd', '--force']),
    'repair': lambda path, out: repair.main([str(path), '-o', str(out) + '.mcap', '--force']),
    # bad files are refused before ROS starts; /balls is where the crafted type is
    'replay': lambda path, out: replay.main([str(path), '--topics', '/balls']),
}


def run_tool(name, path, workdir):
    """(exit code, stdout, stderr) of a tool's main on a file, within the deadline."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), deadline():
        code = TOOLS[name](path, workdir / f'out-{name}')
    return code, out.getvalue(), err.getvalue()


def refused(name, path, workdir):
    """The one line a tool answers a bad file with (it must exit 2)."""
    code, out, err = run_tool(name, path, workdir)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, (name, code, out, err)
    assert not list(workdir.glob(f'out-{name}*')), 'a refused file left an output behind'
    return lines[0]


@pytest.fixture(scope='module')
def source(tmp_path_factory):
    """A small valid recording (zstd chunks), 20 steps."""
    path = tmp_path_factory.mktemp('hostile') / 'run.mcap'
    simulation = Simulation(PARAMS, sinks=[McapSink(path, 'zstd')])
    for _ in range(20):
        simulation.step()
    simulation.close()
    return path


def with_parameters(source, target, **changes):
    """The recording with changed parameters in its metadata (JSON and YAML alike)."""
    def edit(values):
        document = json.loads(values['parameters_json'])
        tree = document['ball_world']['ros__parameters']
        for name, value in changes.items():
            node = tree
            *path, leaf = name.split('.')
            for part in path:
                node = node.setdefault(part, {})
            node[leaf] = value
        text = json.dumps(document)
        return {**values, 'parameters_json': text, 'parameters': text}
    return rewrite_recording(source, target, metadata=edit)


# Metadata --------------------------------------------------------------------------------

@pytest.mark.parametrize('dt_ns', ['0', '-50000000', '1e9', '', 'fifty', '9' * 5000,
                                   '3600000000001'])
def test_bad_dt_ns_is_one_line_in_every_tool(source, tmp_path, dt_ns):
    path = rewrite_recording(source, tmp_path / 'bad.mcap',
                             metadata=lambda values: {**values, 'dt_ns': dt_ns})
    for name in TOOLS:
        assert "'dt_ns'" in refused(name, path, tmp_path)


def test_dt_ns_must_be_what_the_parameters_give(source, tmp_path):
    path = rewrite_recording(source, tmp_path / 'bad.mcap',
                             metadata=lambda values: {**values, 'dt_ns': '40000000'})
    assert refused('resim', path, tmp_path).endswith(
        "'dt_ns' is 40000000 but the parameters give 50000000")


@pytest.mark.parametrize('depth', [100, 10_000, 1_000_000])
def test_deeply_nested_parameters_are_refused_without_recursion(source, tmp_path, depth):
    nested = '[' * depth + ']' * depth
    path = rewrite_recording(source, tmp_path / 'deep.mcap',
                             metadata=lambda values: {**values, 'parameters_json': nested})
    line = refused('info', path, tmp_path)
    assert ("not a 'ball_world: ros__parameters:' document" if depth == 100
            else "'parameters_json' nests too deeply") in line, line


def test_parameters_nesting_deeper_than_any_parameter_is_refused(source, tmp_path):
    deep = {'a': {'b': {'c': {'d': 1}}}}
    path = with_parameters(source, tmp_path / 'deep.mcap', random=deep)
    assert 'nest deeper than any ball_world parameter' in refused('resim', path, tmp_path)


@pytest.mark.parametrize('levels', [3, 9])
def test_yaml_alias_bombs_are_refused_not_expanded(source, tmp_path, levels):
    lines = ['a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]']
    lines += [f'a{k}: &a{k} [' + ', '.join([f'*a{k - 1}'] * 10) + ']'
              for k in range(1, levels)]
    bomb = '\n'.join(lines) + '\n'
    path = rewrite_recording(source, tmp_path / 'bomb.mcap', metadata=lambda values: {
        key: value for key, value in {**values, 'parameters': bomb}.items()
        if key != 'parameters_json'})
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for name in TOOLS:
        assert 'YAML aliases are not accepted' in refused(name, path, tmp_path)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # kB


def test_metadata_with_wrong_shapes_is_refused(source, tmp_path):
    cases = {
        'topics': ({'topics': '{"balls": 5}'}, "'topics' is not a map"),
        'no parameters': ({'parameters_json': '[]'}, "not a 'ball_world: ros__parameters:'"),
        'frame': ({'frame_id': 'x' * 10_000}, "'frame_id' is not a name"),
        'segment': ({'segment': '-1'}, "'segment' is -1"),
    }
    for name, (changes, complaint) in cases.items():
        path = rewrite_recording(source, tmp_path / 'bad.mcap',
                                 metadata=lambda values: {**values, **changes})
        assert complaint in refused('info', path, tmp_path), name


# Worlds the node would refuse --------------------------------------------------------------

@pytest.mark.parametrize('changes, parameter', [
    ({'random.count': 1_000_000_000}, 'random.count'),
    ({'random.count': 1e9}, 'random.count'),
    ({'random.radius': [1e-9, 1e-9]}, 'random.radius'),
    ({'balls.x': [1.0], 'balls.y': [1.0], 'balls.vx': [0.0], 'balls.vy': [0.0],
      'balls.radius': [1e-9], 'balls.mass': [1.0], 'random.count': 11}, 'balls.radius'),
    ({'balls.x': [5.0] * 200_000, 'balls.y': [5.0] * 200_000, 'balls.vx': [0.0] * 200_000,
      'balls.vy': [0.0] * 200_000, 'balls.radius': [0.1] * 200_000,
      'balls.mass': [1.0] * 200_000, 'random.count': 0}, 'balls.'),
])
def test_worlds_the_node_refuses_are_refused_by_every_tool_before_building(
        source, tmp_path, changes, parameter):
    """Depends on the parameter table (core.parameters.checked, through scenario)."""
    path = with_parameters(source, tmp_path / 'world.mcap', **changes)
    for name in TOOLS:
        line = refused(name, path, tmp_path)
        assert f"parameter '{parameter}" in line, (name, line)


@pytest.mark.parametrize('count', [30_000, 13])
def test_a_world_other_than_the_recorded_one_is_refused_before_it_is_built(
        source, tmp_path, count):
    # valid parameters (no overlap: a grid), but not the 12 balls the recording holds
    side = int(count ** 0.5) + 1
    xs = [1.0 + 2.0 * (k % side) for k in range(count)]
    ys = [1.0 + 2.0 * (k // side) for k in range(count)]
    path = with_parameters(source, tmp_path / 'other.mcap', arena=[0.0, 0.0, 2.0 * side,
                                                                   2.0 * side],
                           random={'count': 0}, balls={
                               'x': xs, 'y': ys, 'vx': [0.0] * count, 'vy': [0.0] * count,
                               'radius': [0.5] * count, 'mass': [1.0] * count})
    for name in ('resim', 'to_rrd', 'info'):
        line = refused(name, path, tmp_path)
        assert f'its parameters make {count:,} balls but the recording has 12' in line, line


# Decompression bombs ------------------------------------------------------------------------

def zstd_rle_bomb(size):
    """A zstd frame of RLE blocks that inflates to `size` zero bytes: about size / 32768."""
    block = 128 << 10
    frame = bytearray(b'\x28\xb5\x2f\xfd\x00\x38')  # magic; no content size; 128 KiB window
    for k in range(size // block):
        last = int(k == size // block - 1)
        frame += (last | 1 << 1 | block << 3).to_bytes(3, 'little') + b'\x00'
    return bytes(frame)


def lz4_bomb(size):
    import lz4.frame
    compressor = lz4.frame.LZ4FrameCompressor()
    zeros = bytes(1 << 20)
    parts = [compressor.begin()] + [compressor.compress(zeros) for _ in range(size >> 20)]
    return b''.join(parts + [compressor.flush()])


def put(out, record):
    builder = RecordBuilder()
    record.write(builder)
    data = builder.end()
    start = len(out)
    out.extend(data)
    return start, len(data)


def bomb_recording(path, metadata, compression, data, declared, summary=True):
    """A ball_world recording whose one chunk is `data`, declaring `declared` bytes."""
    out = bytearray(MAGIC)
    schema = Schema(id=1, name='geometry_msgs/msg/PoseArray', encoding='ros2msg',
                    data=message_definition('geometry_msgs/msg/PoseArray').encode())
    channel = Channel(id=1, topic='/balls', message_encoding='cdr', schema_id=1, metadata={})
    put(out, Header(profile='ros2', library='crafted'))
    put(out, schema)
    put(out, channel)
    metadata_at, metadata_length = put(out, Metadata(name='ball_world', metadata=metadata))
    chunk = Chunk(message_start_time=0, message_end_time=0, uncompressed_size=declared,
                  uncompressed_crc=0, compression=compression, data=data)
    chunk_at, chunk_length = put(out, chunk)
    if summary:
        put(out, DataEnd(data_section_crc=0))
        summary_at = len(out)
        put(out, schema)
        put(out, channel)
        put(out, Statistics(message_count=1, schema_count=1, channel_count=1,
                            attachment_count=0, metadata_count=1, chunk_count=1,
                            message_start_time=0, message_end_time=0,
                            channel_message_counts={1: 1}))
        put(out, ChunkIndex(message_start_time=0, message_end_time=0,
                            chunk_start_offset=chunk_at, chunk_length=chunk_length,
                            message_index_offsets={1: 0}, message_index_length=0,
                            compression=compression, compressed_size=len(data),
                            uncompressed_size=declared))
        put(out, MetadataIndex(offset=metadata_at, length=metadata_length, name='ball_world'))
        put(out, Footer(summary_start=summary_at, summary_offset_start=0, summary_crc=0))
        out.extend(MAGIC)
    path.write_bytes(bytes(out))
    return path


def first_metadata(path):
    with open(path, 'rb') as stream:
        return dict(next(make_reader(stream).iter_metadata()).metadata)


@pytest.mark.parametrize('compression, inflates, declared', [
    ('zstd', 3 * GIB, 3 * GIB),  # declares it: refused before decompressing
    ('zstd', 3 * GIB, 4 << 20),  # lies: decompression stops one byte past the declared size
    ('zstd', 1 * GIB, MAX_CHUNK_BYTES + 1),
    ('lz4', 300 << 20, 4 << 20),
    ('lz4', 300 << 20, 300 << 20),
])
@pytest.mark.parametrize('summary', [True, False])
def test_decompression_bombs_are_refused_quickly_with_a_reason(
        source, tmp_path, compression, inflates, declared, summary):
    data = zstd_rle_bomb(inflates) if compression == 'zstd' else lz4_bomb(inflates)
    path = bomb_recording(tmp_path / 'bomb.mcap', first_metadata(source), compression, data,
                          declared, summary)
    if compression == 'zstd' and inflates == 3 * GIB:
        assert path.stat().st_size < 110_000  # about the 98 kB file
    # a child with 2 GiB of address space: inflating the bomb would fail loudly there
    script = ('import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1 << 31, 1 << 31))'
              '; from ball_world.tools import info, resim; '
              'sys.exit(10 * info.main([sys.argv[1]]) + resim.main([sys.argv[1]]))')
    result = subprocess.run([sys.executable, '-c', script, str(path)], capture_output=True,
                            text=True, timeout=DEADLINE)
    assert result.returncode == 22, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 2 and 'Traceback' not in result.stderr, result.stderr
    reason = (f'declares {declared:,} bytes uncompressed, more than the {MAX_CHUNK_BYTES:,}'
              if declared > MAX_CHUNK_BYTES else
              f'declares {declared:,} bytes uncompressed but inflates to more bytes')
    assert all(reason in line for line in lines), lines


# Messages that are not what the node writes ------------------------------------------------

def test_messages_that_do_not_decode_or_do_not_agree_are_refused(source, tmp_path):
    cases = {
        'stats with two values': (
            lambda topic, t, data: encode_float64_vector([1.0, 2.0], ('a', 'b'))
            if topic == '/stats' else data, 'stats has 2 values, not 6'),
        'a truncated pose array': (
            lambda topic, t, data: data[:30] if topic == '/balls' else data,
            'undecodable message'),
        'poses and state of different counts': (
            lambda topic, t, data: _drop_pose(data) if topic == '/balls' else data,
            'balls has 11 poses but state 12 rows'),
        'a collision count that is not a count': (
            lambda topic, t, data: encode_float64_vector(
                [1.0, 0.0, 0.0, float('nan'), 0.0, float('nan')], ('k',) * 6)
            if topic == '/stats' else data, 'stats ball_ball is nan, not a count'),
    }
    for name, (edit, complaint) in cases.items():
        path = rewrite_recording(source, tmp_path / 'bad.mcap', data=edit)
        assert complaint in refused('to_rrd', path, tmp_path), name


def _drop_pose(data):
    stamp, frame_id, positions = decode_pose_array(data)
    from ball_world.msgs.cdr import encode_pose_array
    return encode_pose_array(positions[:-1], stamp, frame_id)


@pytest.mark.parametrize('jump', [2, 10**10])
def test_resim_never_simulates_a_gap_and_says_what_it_did_not_check(source, tmp_path, jump):
    # the last step's messages moved far ahead: a crafted gap must not be re-simulated (10^10
    # steps would take days), and what lies after it has no state to go on from
    last = 19 * 50_000_000
    moved = last + (jump - 1) * 50_000_000
    path = rewrite_recording(
        source, tmp_path / 'gap.mcap',
        edit=lambda item: replace(item, log_time=moved, publish_time=moved)
        if isinstance(item, Message) and item.log_time >= last else item)
    code, out, err = run_tool('resim', path, tmp_path)
    assert code == 3, (code, out, err)
    assert 'segment 0: 19 steps compared (last step 18), ' in out
    missing = 'step 19' if jump == 2 else f'steps 19-{17 + jump}'
    assert (f'segment 0: {missing} NOT CHECKED: segment 0 jumps from step 18 to step '
            f'{18 + jump}: the steps between are not recorded') in out
    assert (f'segment 0: step {18 + jump} NOT CHECKED: no state to go on from after the steps '
            'missing before them') in out
    assert out.strip().endswith('NOT ALL STEPS COULD BE CHECKED (see above)')


def test_replay_refuses_types_it_would_have_to_import_and_survives_a_qos_bomb(
        source, tmp_path):
    def edit(item):  # no messages; PoseArray's schema renamed
        if isinstance(item, Schema) and item.name.endswith('PoseArray'):
            return replace(item, name='antigravity/msg/Fly')
        return None if isinstance(item, Message) else item

    path = rewrite_recording(source, tmp_path / 'types.mcap', edit=edit)
    assert 'antigravity' not in sys.modules
    line = refused('replay', path, tmp_path)
    assert "'antigravity/msg/Fly' is not an installed ROS message type" in line
    assert 'antigravity' not in sys.modules
    bomb = '- &a [' + ', '.join(['1'] * 10) + ']\n- &b [' + ', '.join(['*a'] * 10) + ']\n'
    with pytest.raises(RecordingError, match='YAML aliases are not accepted'):
        load_untrusted(bomb, 'offered_qos_profiles', MAX_SMALL_TEXT, json_text=False)
    assert replay.qos_profile(bomb).reliability == ReliabilityPolicy.RELIABLE  # the default


# Not ball_world, not MCAP, not whole --------------------------------------------------------

def test_files_that_are_not_ball_world_recordings(source, tmp_path):
    chatter = tmp_path / 'chatter.mcap'
    with open(chatter, 'wb') as out:
        writer = Writer(out)
        writer.start('ros2', 'other')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg',
                                        message_definition('std_msgs/msg/String').encode())
        channel = writer.register_channel('/chatter', 'cdr', schema)
        writer.add_message(channel, 1, b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00', 1)
        writer.finish()
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    text = tmp_path / 'text.mcap'
    text.write_text('not an mcap at all')
    for name in TOOLS:
        if name == 'info':
            # ball_world_info tells what any ROS 2 MCAP holds, as ros2 bag info does (a
            # recording of topics: ball_world_cli record, tools.info_topics)
            code, out, err = run_tool(name, chatter, tmp_path)
            assert code == 0 and err == '', (out, err)
            assert 'not a ball_world run' in out and '/chatter  std_msgs/msg/String  1' in out
        else:
            assert refused(name, chatter, tmp_path).endswith(
                "no 'ball_world' metadata record: not a ball_world recording")
        assert 'not an MCAP file (bad magic)' in refused(name, empty, tmp_path)
        assert 'not an MCAP file (bad magic)' in refused(name, text, tmp_path)
    fifo = tmp_path / 'fifo.mcap'
    os.mkfifo(fifo)  # with no writer: opening it to read would wait forever
    for name in TOOLS:
        assert refused(name, fifo, tmp_path).endswith(f'{fifo}: is a FIFO, not a regular file')
        assert refused(name, Path('/dev/zero'), tmp_path).endswith(
            '/dev/zero: is a character device, not a regular file')
        # a directory is read as a bag of split files (test_split_recordings): this one
        # has no metadata.yaml and no split file
        assert refused(name, tmp_path, tmp_path).endswith(
            f'{tmp_path}: is a directory without metadata.yaml, not a bag of split files')
    assert 'No such file' in refused('info', tmp_path / 'missing.mcap', tmp_path)


def fuzz_cases(data, seed=10, count=36):
    """(label, bytes): truncations, bit flips in the chunks and elsewhere, random bytes."""
    rng = random.Random(seed)
    with open_bytes(data) as stream:
        chunk_spans = [(record_end - len(record.data), record_end) for record_end, record in
                       _chunks(stream, len(data))]
    cases = []
    for _ in range(count // 3):
        cut = rng.randrange(len(MAGIC), len(data))
        cases.append((f'cut at {cut}', data[:cut]))
    for k in range(count // 3):
        start, end = rng.choice(chunk_spans) if k % 2 else (0, len(data))
        at = rng.randrange(start, end)
        flipped = bytearray(data)
        flipped[at] ^= 1 << rng.randrange(8)
        cases.append((f'bit flip at {at}', bytes(flipped)))
    for k in range(count - 2 * (count // 3)):
        noise = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 4000)))
        cases.append((f'random bytes {k}', (MAGIC if k % 2 else b'') + noise))
    return cases


def open_bytes(data):
    return contextlib.closing(io.BytesIO(data))


def _chunks(stream, size):
    """(end offset of the record, chunk) of every chunk, found by scanning."""
    scan = Scan(stream, size)
    found = []
    for record in scan.records():
        if type(record).__name__ == 'Chunk':
            found.append((scan.end, record))
    return found


@pytest.mark.parametrize('compression', ['zstd', 'lz4', 'none'])
def test_fuzzed_recordings_get_an_answer_from_every_tool(tmp_path, compression):
    path = tmp_path / 'source.mcap'
    simulation = Simulation(PARAMS, sinks=[McapSink(path, compression, chunk_bytes=4000)])
    for step in range(20):
        if step in (4, 9):
            simulation.queue_impulse('ball_2', 0.1, 0.2)
        simulation.step()
    simulation.reset({**PARAMS, 'random.count': 5})
    for _ in range(5):
        simulation.step()
    simulation.close()
    data = path.read_bytes()
    for label, mutated in fuzz_cases(data, seed=len(compression), count=24):
        path.write_bytes(mutated)
        for name in ('info', 'resim', 'to_rrd', 'repair'):
            code, out, err = run_tool(name, path, tmp_path)
            lines = [line for line in err.splitlines() if line.strip()]
            assert code in (0, 1, 2), (label, name, code)
            assert 'Traceback' not in out + err, (label, name, err)
            if code == 2:
                assert len(lines) == 1, (label, name, err)


def test_info_escapes_control_characters_from_the_file(source, tmp_path, capsys):
    def edit(item):  # no messages; control characters in the library and a topic
        if isinstance(item, Header):
            return replace(item, library='lib\x1b]0;title\x07')
        if isinstance(item, Channel) and item.topic == '/impulse':
            return replace(item, topic='/imp\x1b[2J')
        return None if isinstance(item, Message) else item

    path = rewrite_recording(source, tmp_path / 'escapes.mcap', edit=edit)
    assert info.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert '\x1b' not in out and "'/imp\\x1b[2J'" in out and "'lib\\x1b]0;title\\x07'" in out


def test_a_damaged_summary_is_read_around_and_reported(source, tmp_path, capsys):
    data = bytearray(source.read_bytes())
    footer = data[-8 - 29:-8]
    summary_start = int.from_bytes(footer[9:17], 'little')
    data[summary_start + 20] ^= 0x40  # inside the summary: its CRC no longer matches
    path = tmp_path / 'summary.mcap'
    path.write_bytes(bytes(data))
    assert info.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert 'summary:     NO (its data ends properly but its summary is missing or ' \
        'damaged)' in out
    assert resim.main([str(path)]) == 0  # every step is still there
