"""recording.mcap_records: the MCAP records McapSink writes, a step's messages at once.

The reference is what the `mcap` package's Writer made of the same calls (McapSink wrote
through it before): a run with a map, robots with scans, commands, spawns, a deletion, a
state set, pushes, /clock, markers, a reset to another world and edits after the last step
is recorded by both at once, and every reader sees the same file: mcap's summary (schemas,
channels, statistics), metadata and attachments, every message (topic, sequence, log and
publish time, bytes) read through the chunk indexes, whole and by topics and time ranges, the
records in stream order, rosbags' connections and counts, ball_world's own tools. The
message indexes, which mcap's Python reader does not use, are checked against the spec:
every entry names a message of its channel at its offset in the chunk, and every message
has one. Hypothesis writes random batches and flushes and checks the same of each file.
"""
import collections
import io
from pathlib import Path

from hypothesis import given, settings, strategies as st
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, MessageIndex
from mcap.stream_reader import breakup_chunk, StreamReader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader as RosbagsReader
from visualization_msgs.msg import MarkerArray
import yaml

from ball_world.core.edits import Ball
from ball_world.recording import mcap_writer
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_records import MAX_ID, McapRecords
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import info, resim

ROOT = Path(__file__).resolve().parents[1]
_WRITER_COMPRESSIONS = {'lz4': CompressionType.LZ4, 'zstd': CompressionType.ZSTD,
                        'none': CompressionType.NONE}


class ThroughMcapWriter:
    """McapRecords' calls made through the `mcap` package's Writer, as McapSink made them
    before mcap_records: the reference a file's meaning is compared with."""

    def __init__(self, stream, compression='lz4'):
        self._stream = stream
        self._writer = Writer(stream, chunk_size=2 ** 62,
                              compression=_WRITER_COMPRESSIONS[compression])
        self._counts = collections.Counter()
        self.message_count = 0
        self.start_time = self.end_time = None
        self.pending = 0

    @property
    def position(self):
        return self._stream.tell()

    def counts(self):
        return dict(self._counts)

    def start(self, profile, library):
        self._writer.start(profile=profile, library=library)

    def schema(self, name, encoding, data):
        return self._writer.register_schema(name, encoding, data)

    def channel(self, topic, message_encoding, schema_id, metadata):
        return self._writer.register_channel(topic, message_encoding, schema_id,
                                             metadata=metadata)

    def messages(self, log_time, channels, datas):
        for channel, data in zip(channels, datas):
            self._counts[channel] += 1
            self._writer.add_message(channel, log_time=log_time, data=data,
                                     publish_time=log_time,
                                     sequence=self._counts[channel] % 2 ** 32)
            self.pending += len(data) + 31
        if datas:
            self.message_count += len(datas)
            self.start_time = min(log_time, self.start_time or log_time)
            self.end_time = max(log_time, self.end_time or log_time)

    def flush(self):
        self._writer.flush()
        self.pending = 0

    def metadata(self, name, values):
        self._writer.add_metadata(name, values)

    def attachment(self, log_time, create_time, name, media_type, data):
        self._writer.add_attachment(create_time=create_time, log_time=log_time, name=name,
                                    media_type=media_type, data=data)

    def finish(self):
        self._writer.finish()


def reference_sink(path, **options):
    """An McapSink writing through the mcap package's Writer (ThroughMcapWriter)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(mcap_writer, 'McapRecords', ThroughMcapWriter)
        return McapSink(path, **options)


def sandbox_parameters():
    """worlds/sandbox.yaml (a map, two robots with scanners), /clock on."""
    document = yaml.safe_load((ROOT / 'worlds' / 'sandbox.yaml').read_text())
    parameters = dict(document['/**']['ros__parameters'])
    parameters['map'] = str(ROOT / parameters['map'])
    return {**parameters, 'publish_clock': True, 'rate_hz': 20.0}


def play(sinks):
    """The run both sinks record: see the module docstring."""
    simulation = Simulation(sandbox_parameters(), sinks=sinks)
    for k in range(1, 41):
        simulation.command('ball_0', 0.2, 0.0, 1.0)
        simulation.command('ball_1', 0.2, 0.0, -1.0 if k < 20 else 0.5)
        if k == 8:
            simulation.spawn([SpawnRequest('rover', False, Ball(-0.55, -0.55, 0.0, 0.0, 0.1, 1.0),
                                           agent=True),
                              SpawnRequest('pebble', False,
                                           Ball(0.55, 0.55, 0.1, 0.0, 0.05, 0.2))])
        if k == 15:
            simulation.queue_impulse('ball_0', 0.05, -0.02)
            simulation.queue_impulse('pebble', 0.01, 0.0)
        if k == 22:
            x, y = simulation.world.positions[simulation.index_of['rover']].tolist()
            simulation.set_state('rover', x, y, 0.0, 0.0, yaw=1.0)
        if k == 30:
            simulation.delete('pebble')
        simulation.step()
        if k % 7 == 0:
            simulation.flush()
    simulation.reset({'rate_hz': 20.0, 'random.count': 30, 'random.seed': 4,
                      'arena': [0.0, 0.0, 6.0, 5.0]})
    for k in range(25):
        if k == 5:
            simulation.queue_impulse('ball_3', 0.2, 0.1)
        simulation.step()
    simulation.queue_impulse('ball_1', 0.1, 0.2)
    simulation.delete('ball_0')  # after the last step: a closing record
    simulation.close()


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    """(new, reference): the run recorded through mcap_records and through mcap's Writer,
    with chunks small enough that both files have many."""
    folder = tmp_path_factory.mktemp('mcap_records')
    new, old = folder / 'new.mcap', folder / 'old.mcap'
    play([McapSink(new, chunk_bytes=48 << 10), reference_sink(old, chunk_bytes=48 << 10)])
    return new, old


def summary_of(path):
    with open(path, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    statistics = summary.statistics
    return {
        'schemas': {i: (s.name, s.encoding, s.data) for i, s in summary.schemas.items()},
        'channels': {i: (c.topic, c.message_encoding, c.schema_id, c.metadata)
                     for i, c in summary.channels.items()},
        'statistics': (statistics.message_count, statistics.schema_count,
                       statistics.channel_count, statistics.attachment_count,
                       statistics.metadata_count, statistics.message_start_time,
                       statistics.message_end_time, dict(statistics.channel_message_counts)),
        'attachment_indexes': [(a.name, a.media_type, a.log_time, a.create_time, a.data_size)
                               for a in summary.attachment_indexes],
        'metadata_indexes': [m.name for m in summary.metadata_indexes],
    }


def comparable(topic, data):
    """A message's bytes, but a MarkerArray's as the message: rclpy leaves stray bytes in
    its padding (msgs.markers.SphereLayout), so two sinks' markers differ there."""
    if topic.endswith('/markers'):
        return deserialize_message(data, MarkerArray)
    return data


def messages_of(path, **selection):
    """(topic, sequence, log time, publish time, bytes) of every message, through the
    chunk indexes (in log time order)."""
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        return [(channel.topic, message.sequence, message.log_time, message.publish_time,
                 comparable(channel.topic, message.data))
                for _, channel, message in reader.iter_messages(**selection)]


def read_with(path, method):
    """The fields of what a reader's method gives (one record or each of many)."""
    with open(path, 'rb') as stream:
        found = getattr(make_reader(stream), method)()
        return vars(found) if method == 'get_header' else [vars(r) for r in found]


def stream_records(path):
    """Every record but the chunks' frames, indexes and the summary, in file order, as
    (type, fields): what a reader that streams the file sees."""
    skipped = ('Chunk', 'MessageIndex', 'ChunkIndex', 'Statistics', 'SummaryOffset',
               'Footer', 'DataEnd', 'AttachmentIndex', 'MetadataIndex')
    with open(path, 'rb') as stream:
        records = list(StreamReader(stream, validate_crcs=True).records)
    topics = {r.id: r.topic for r in records if isinstance(r, Channel)}
    return [(type(r).__name__, {**vars(r), 'data': comparable(topics[r.channel_id], r.data)}
             if isinstance(r, Message) else vars(r))
            for r in records if type(r).__name__ not in skipped]


def check_message_indexes(path):
    """Every chunk's MessageIndex records name each of its messages, by channel, log time
    and offset in the chunk, and nothing else; their offsets and lengths are those the
    ChunkIndex gives. Returns how many chunks there are."""
    data = Path(path).read_bytes()
    with open(path, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    for chunk_index in summary.chunk_indexes:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(
            data[chunk_index.chunk_start_offset + 9:
                 chunk_index.chunk_start_offset + chunk_index.chunk_length])))
        assert data[chunk_index.chunk_start_offset] == Opcode.CHUNK
        assert (chunk.message_start_time, chunk.message_end_time, chunk.compression,
                len(chunk.data), chunk.uncompressed_size) == (
            chunk_index.message_start_time, chunk_index.message_end_time,
            chunk_index.compression, chunk_index.compressed_size,
            chunk_index.uncompressed_size)
        records = list(breakup_chunk(chunk, validate_crc=True))
        plain = _plain_records(chunk)
        messages = {offset: record for offset, record in zip(plain, records)
                    if isinstance(record, Message)}
        assert min(m.log_time for m in messages.values()) == chunk.message_start_time
        assert max(m.log_time for m in messages.values()) == chunk.message_end_time
        indexed = {}
        start = chunk_index.chunk_start_offset + chunk_index.chunk_length
        assert sum(1 for _ in chunk_index.message_index_offsets) == len(
            {m.channel_id for m in messages.values()})
        end = start
        for channel, offset in chunk_index.message_index_offsets.items():
            assert data[offset] == Opcode.MESSAGE_INDEX
            length = int.from_bytes(data[offset + 1:offset + 9], 'little')
            index = MessageIndex.read(ReadDataStream(io.BytesIO(
                data[offset + 9:offset + 9 + length])))
            assert index.channel_id == channel
            for log_time, at in index.records:
                message = messages[at]
                assert (message.channel_id, message.log_time) == (channel, log_time)
                indexed[at] = channel
            end = max(end, offset + 9 + length)
        assert end - start == chunk_index.message_index_length
        assert sorted(indexed) == sorted(messages)
    return len(summary.chunk_indexes)


def _plain_records(chunk):
    """The offset in the chunk's records of each record breakup_chunk gives, from the
    records' frames (opcode and length)."""
    raw = _decompressed(chunk)
    offsets, at = [], 0
    while at < len(raw):
        offsets.append(at)
        at += 9 + int.from_bytes(raw[at + 1:at + 9], 'little')
    return offsets


def _decompressed(chunk):
    if chunk.compression == 'lz4':
        import lz4.frame
        return lz4.frame.decompress(chunk.data)
    if chunk.compression == 'zstd':
        import zstandard
        return zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size)
    return chunk.data


def test_mcap_readers_see_the_run_as_the_mcap_writer_wrote_it(files):
    new, old = files
    assert summary_of(new) == summary_of(old)
    everything = messages_of(old)
    assert messages_of(new) == everything
    assert len(everything) > 500
    for get in ('iter_metadata', 'iter_attachments', 'get_header'):
        assert read_with(new, get) == read_with(old, get)
    assert len(read_with(new, 'iter_attachments')) == 2  # the map's YAML and image
    times = sorted({m[2] for m in everything})
    topics = ['/clock', '/ball_1/odom', '/rover/cmd_vel', '/edits', '/map', '/tf_static']
    for start, end in ((None, times[10]), (times[30], times[50]), (times[-5], None)):
        for chosen in (None, topics):
            selection = {'starting_at': start, 'ending_before': end, 'topics': chosen}
            assert messages_of(new, **selection) == messages_of(old, **selection)
            assert messages_of(new, **selection, reverse=True) == \
                messages_of(old, **selection, reverse=True)
    assert stream_records(new) == stream_records(old)
    assert check_message_indexes(new) > 5


def test_ros2_decoding_rosbags_and_ball_world_tools_read_both_alike(files, capsys):
    new, old = files
    with open(new, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = sum(1 for _ in reader.iter_decoded_messages(log_time_order=False))
    assert decoded == len(messages_of(old))
    seen = []
    for path in (new, old):
        with RosbagsReader(path) as reader:
            seen.append(({c.topic: (c.msgtype, c.msgcount, c.ext.offered_qos_profiles)
                          for c in reader.connections}, reader.message_count,
                         reader.start_time, reader.end_time))
    assert seen[0] == seen[1]
    outputs = []
    for path in (new, old):
        assert info.main([str(path)]) == 0
        outputs.append(capsys.readouterr().out.replace(str(path), 'FILE'))
    assert outputs[0].splitlines()[2:] == outputs[1].splitlines()[2:]
    assert resim.main([str(new)]) == 0, capsys.readouterr()
    assert 'identical' in capsys.readouterr().out
    steps = [[(s.segment, s.step, s.log_time_ns, s.balls_cdr, len(s.impulses), len(s.edits))
              for s in Recording(path).steps()] for path in (new, old)]
    assert steps[0] == steps[1]


@pytest.mark.parametrize('compression', ['zstd', 'none'])
def test_rosbags_and_mcap_read_every_compression(tmp_path, compression):
    new, old = tmp_path / 'new.mcap', tmp_path / 'old.mcap'
    simulation = Simulation(sandbox_parameters(), sinks=[
        McapSink(new, compression=compression, chunk_bytes=16 << 10),
        reference_sink(old, compression=compression, chunk_bytes=16 << 10)])
    for _ in range(12):
        simulation.command('ball_0', 0.2, 0.0, 1.0)
        simulation.step()
    simulation.close()
    assert messages_of(new) == messages_of(old)
    assert check_message_indexes(new) > 1
    counts = []
    for path in (new, old):
        with RosbagsReader(path) as reader:
            counts.append(sum(1 for _ in reader.messages()))
    assert counts[0] == counts[1] == len(messages_of(old))


# McapRecords on its own ---------------------------------------------------------------

batches = st.lists(st.tuples(st.lists(st.integers(1, 5), max_size=12), st.booleans()),
                   min_size=1, max_size=8)


@settings(max_examples=30, deadline=None)
@given(batches=batches, compression=st.sampled_from(['lz4', 'zstd', 'none']))
def test_random_batches_read_back_in_order_with_sequences_and_indexes(tmp_path_factory,
                                                                      batches, compression):
    path = tmp_path_factory.mktemp('batches') / 'batches.mcap'
    written = []
    with open(path, 'wb') as stream:
        records = McapRecords(stream, compression)
        records.start('ros2', 'test')
        schema = records.schema('std_msgs/msg/String', 'ros2msg', b'string data')
        for n in range(5):
            assert records.channel(f'/t{n}', 'cdr', schema, {'n': str(n)}) == n + 1
        for k, (channels, flush) in enumerate(batches):
            datas = [bytes([k, len(written) % 256]) * (i % 3) for i, _ in enumerate(channels)]
            records.messages(1000 + k, channels, datas)
            written += [(f'/t{c - 1}', 1000 + k, d) for c, d in zip(channels, datas)]
            if flush:
                records.flush()
        counts = records.counts()
        records.finish()
    expected = collections.Counter(topic for topic, _, _ in written)
    assert counts == {int(t[2:]) + 1: n for t, n in expected.items()}
    read = messages_of(path)
    assert [(t, log, d) for t, _, log, _, d in read] == written
    sequences = collections.defaultdict(list)
    for topic, sequence, _, _, _ in read:
        sequences[topic].append(sequence)
    assert all(s == list(range(1, len(s) + 1)) for s in sequences.values())
    statistics = summary_of(path)['statistics']
    assert statistics[0] == len(written) and statistics[7] == {
        int(t[2:]) + 1: n for t, n in expected.items()}
    if written:
        assert statistics[5:7] == (written[0][1], written[-1][1])
        check_message_indexes(path)


def test_an_empty_file_reads(tmp_path):
    path = tmp_path / 'empty.mcap'
    with open(path, 'wb') as stream:
        records = McapRecords(stream, 'lz4')
        records.start('ros2', 'test')
        records.channel('/t', 'cdr', records.schema('s', 'ros2msg', b''), {})
        records.flush()  # a chunk of a channel alone stays open: no empty chunk
        records.finish()
    with open(path, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    assert (summary.statistics.message_count, summary.statistics.chunk_count,
            summary.statistics.message_start_time, list(summary.channels)) == (0, 0, 0, [1])


def test_refused_messages_leave_nothing_behind(tmp_path):
    path = tmp_path / 'refused.mcap'
    with open(path, 'wb') as stream:
        records = McapRecords(stream, 'none')
        records.start('ros2', 'test')
        schema = records.schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channel = records.channel('/t', 'cdr', schema, {})
        with pytest.raises(ValueError, match='a message names a channel that was not made'):
            records.messages(5, [channel + 1], [b'x'])
        with pytest.raises(ValueError, match='1 channels for 2 messages'):
            records.messages(5, [channel], [b'x', b'y'])
        with pytest.raises(ValueError, match='message data must be bytes, a byte an item'):
            records.messages(5, [channel, channel], [b'x', np.zeros(2)])
        records.messages(6, [channel], [b'kept'])  # the refusals left nothing behind
        records.metadata('m', {'k': 'v'})
        records.finish()
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert (summary.statistics.message_count, summary.statistics.channel_count,
                len(summary.chunk_indexes)) == (1, 1, 1)
        assert [m.metadata for m in reader.iter_metadata()] == [{'k': 'v'}]
    assert messages_of(path) == [('/t', 1, 6, 6, b'kept')]
    with pytest.raises(ValueError, match='compression must be one of zstd, lz4, none'):
        McapRecords(io.BytesIO(), 'gzip')
    records = McapRecords(io.BytesIO(), 'none')
    for n in range(MAX_ID):
        records.channel('/t', 'cdr', 0, {})
    with pytest.raises(ValueError, match='at most 65,535 channels'):
        records.channel('/t', 'cdr', 0, {})
