"""Read a ball_world MCAP recording: its segments, its messages, and its steps in order.

A finished recording has a summary, and is read through mcap's indexed SeekingReader. A
recording whose writer was killed has no summary and may end in a torn record; it is read
front to back with mcap's record parsers, stopping at the first record that is not complete
(every complete chunk is still read, and `problem` says where reading stopped).

feed_sinks() turns a recording back into the WorldSnapshot / RunInfo / StepRecord stream the
node produced, so any Sink (the Rerun logger, a second MCAP) can be fed from a file.
"""
import bisect
from dataclasses import dataclass
import io
import json
import math
import os
import struct
from typing import Optional

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (Attachment, Channel, Chunk, DataEnd, Footer, Header, Message,
                          Metadata, Schema)
from mcap.stream_reader import breakup_chunk
import numpy as np
import yaml

from ball_world.core.impulses import ImpulseRejected, parse_ball
from ball_world.core.scenario import build_world, DEFAULTS
from ball_world.msgs.cdr import (decode_pose_array, decode_state, decode_state_layout,
                                 decode_vector3_stamped)
from ball_world.recording.mcap_writer import flatten_parameters, METADATA_NAME, TOPIC_TYPES
from ball_world.step_record import AppliedImpulse, RunInfo, STATS_FIELDS, StepRecord, WorldSnapshot

MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEAD = struct.Struct('<BQ')
_PARSERS = {
    Opcode.HEADER: Header.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.METADATA: Metadata.read,
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.DATA_END: DataEnd.read,
    Opcode.FOOTER: Footer.read,
}


class RecordingError(Exception):
    """A file that is not a readable ball_world recording; the message says why."""


# Scanning a file that may be truncated --------------------------------------------------

class Scan:
    """Reads an MCAP front to back, record by record, up to the first incomplete one.

    records() yields every complete top-level record of the data section in file order;
    a Chunk is yielded itself and then the records inside it, and only if it is whole
    (its length fits in the file and its CRC matches). After iterating: `end` is the byte
    offset after the last complete record, `finished` is True when the data section ended
    properly (DataEnd or Footer), and `problem` otherwise says where and why reading stopped.
    """

    def __init__(self, stream, size):
        self.stream = stream
        self.size = size
        self.end = 0
        self.finished = False
        self.problem = None

    def records(self):
        stream = self.stream
        stream.seek(0)
        if stream.read(len(MAGIC)) != MAGIC:
            raise RecordingError('not an MCAP file (bad magic)')
        offset = self.end = len(MAGIC)
        while True:
            head = stream.read(_RECORD_HEAD.size)
            if len(head) < _RECORD_HEAD.size:
                self.problem = (f'the file ends at byte {self.size} without a footer'
                                if not head else
                                f'the record at byte {offset} is cut off in its header')
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            body_at = offset + _RECORD_HEAD.size
            if opcode == 0:
                self.problem = f'no valid record at byte {offset} (zero bytes)'
                return
            if length > self.size - body_at:
                self.problem = (f'the record at byte {offset} is cut off: it needs {length} '
                                f'bytes, {self.size - body_at} are left')
                return
            try:
                parsed = _parse(opcode, stream.read(length))
            except Exception as error:  # noqa: B902 - corrupt bytes raise anything
                self.problem = f'the record at byte {offset} is corrupt: {error}'
                return
            offset = self.end = body_at + length
            yield from parsed
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                self.finished = True
                return


def _parse(opcode, body):
    """The records of one complete record body: [record] or [chunk, *its records] or []."""
    parser = _PARSERS.get(opcode)
    if opcode == Opcode.MESSAGE:
        return [Message.read(ReadDataStream(io.BytesIO(body)), len(body))]
    if parser is None:
        return []  # indexes and records this reader does not need
    record = parser(ReadDataStream(io.BytesIO(body)))
    if isinstance(record, Chunk):
        # The fixed fields are 40 bytes; a shorter body means the data length field lies.
        if len(body) != 40 + len(record.compression.encode()) + len(record.data):
            raise ValueError('chunk data length does not match the record length')
        return [record, *breakup_chunk(record, validate_crc=True)]
    return [record]


# What a recording holds ---------------------------------------------------------------

@dataclass(frozen=True)
class Segment:
    """One run of the world between a start or reset and the next reset."""

    index: int
    log_offset_ns: int
    dt_ns: int
    frame_id: str
    package_version: str
    parameters: dict  # flat names ('balls.x'), merged over scenario.DEFAULTS
    topics: dict  # logical name -> recorded topic

    @classmethod
    def from_metadata(cls, values):
        try:
            if 'parameters_json' in values:
                document = json.loads(values['parameters_json'])
            else:
                document = yaml.safe_load(values['parameters'])
            parameters = {**DEFAULTS, **flatten_parameters(document)}
            return cls(index=int(values['segment']),
                       log_offset_ns=int(values['log_offset_ns']),
                       dt_ns=int(values['dt_ns']),
                       frame_id=values.get('frame_id', parameters['frame_id']),
                       package_version=values.get('package_version', ''),
                       parameters=parameters,
                       topics=json.loads(values.get('topics', 'null'))
                       or {role: f'/{role}' for role in TOPIC_TYPES})
        except (KeyError, TypeError, ValueError, yaml.YAMLError) as error:
            raise RecordingError(f"unreadable '{METADATA_NAME}' metadata record: "
                                 f'{error!r}') from None


@dataclass(frozen=True)
class TopicInfo:
    """A recorded topic: its type, how many messages, and the QoS its publisher offered."""

    topic: str
    type: str
    message_count: int
    offered_qos_profiles: str
    type_hash: str


@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    type: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


@dataclass(frozen=True)
class RecordedImpulse:
    """An applied impulse as recorded: stamped with the step it was applied before."""

    stamp_ns: int
    frame_id: str
    x: float
    y: float
    z: float
    cdr: bytes


@dataclass(frozen=True)
class RecordedStep:
    """Everything recorded at one log time: one step of one segment.

    A step cut off by a crash may lack some of its messages (then `complete` is False).
    """

    segment: int  # position in Recording.segments
    step: int
    stamp_ns: int
    log_time_ns: int
    positions: Optional[np.ndarray]  # (N, 2) from balls
    state: Optional[np.ndarray]  # (N, 4) x, y, vx, vy
    stats: Optional[np.ndarray]  # STATS_FIELDS in order
    impulses: tuple
    balls_cdr: Optional[bytes]
    state_cdr: Optional[bytes]
    stats_cdr: Optional[bytes]
    balls_stamp_ns: Optional[int]  # header.stamp of the balls message

    @property
    def complete(self):
        return (self.positions is not None and self.state is not None
                and self.stats is not None)

    def stat(self, name):
        return float(self.stats[STATS_FIELDS.index(name)])


class Recording:
    """A ball_world MCAP file, summary or not (see the module docstring).

    Attributes: header (mcap Header), has_summary, problem (why a file without summary
    could not be read to its end, or None), complete_bytes, size, topics
    ({topic: TopicInfo}), segments ([Segment] in log-time order), compressions (set of
    chunk compressions), chunk_count, message_count, start_ns / end_ns (log times).
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        try:
            self._load()
        except OSError as error:
            raise RecordingError(f'{self.path}: {error.strerror or error}') from None
        except RecordingError as error:
            raise RecordingError(f'{self.path}: {error}') from None

    def _load(self):
        self.size = os.path.getsize(self.path)
        with open(self.path, 'rb') as stream:
            if stream.read(len(MAGIC)) != MAGIC:
                raise RecordingError('not an MCAP file (bad magic)')
            summary = _summary(stream)
            if summary is not None:
                self._read_indexed(stream, summary)
            else:
                self._read_scanned(stream)
        counts = self._counts
        self.topics = {}
        for channel_id, channel in sorted(self.channels.items()):
            schema = self.schemas.get(channel.schema_id)
            previous = self.topics.get(channel.topic)
            self.topics[channel.topic] = TopicInfo(
                topic=channel.topic, type=schema.name if schema else '',
                message_count=counts.get(channel_id, 0) + (
                    previous.message_count if previous else 0),
                offered_qos_profiles=channel.metadata.get('offered_qos_profiles', ''),
                type_hash=channel.metadata.get('topic_type_hash', ''))
        self.message_count = sum(counts.values())
        segments = [Segment.from_metadata(m.metadata) for m in self.metadata
                    if m.name == METADATA_NAME]
        self.segments = sorted(segments, key=lambda s: s.log_offset_ns)
        self._offsets = [s.log_offset_ns for s in self.segments]
        self.roles = {}
        for segment in self.segments:
            for role, topic in segment.topics.items():
                self.roles.setdefault(topic, role)

    def _read_indexed(self, stream, summary):
        stream.seek(0)
        reader = SeekingReader(stream)
        self.header = reader.get_header()
        self.has_summary = True
        self.problem = None
        self.complete_bytes = self.size
        self.schemas = dict(summary.schemas)
        self.channels = dict(summary.channels)
        self.metadata = list(reader.iter_metadata())
        self.compressions = {index.compression for index in summary.chunk_indexes}
        self.chunk_count = len(summary.chunk_indexes)
        stats = summary.statistics
        self._counts = dict(stats.channel_message_counts) if stats else {}
        self.start_ns = stats.message_start_time if stats else None
        self.end_ns = stats.message_end_time if stats else None

    def _read_scanned(self, stream):
        scan = Scan(stream, self.size)
        self.header = None
        self.has_summary = False
        self.schemas, self.channels, self.metadata = {}, {}, []
        self.compressions, self.chunk_count = set(), 0
        self._counts = {}
        self.start_ns = self.end_ns = None
        for record in scan.records():
            if isinstance(record, Message):
                self._counts[record.channel_id] = self._counts.get(record.channel_id, 0) + 1
                if self.start_ns is None:
                    self.start_ns = self.end_ns = record.log_time
                self.start_ns = min(self.start_ns, record.log_time)
                self.end_ns = max(self.end_ns, record.log_time)
            elif isinstance(record, Chunk):
                self.compressions.add(record.compression)
                self.chunk_count += 1
            elif isinstance(record, Schema):
                self.schemas[record.id] = record
            elif isinstance(record, Channel):
                self.channels[record.id] = record
            elif isinstance(record, Metadata):
                self.metadata.append(record)
            elif isinstance(record, Header):
                self.header = record
        if self.header is None:
            raise RecordingError('no MCAP header record')
        self.problem = scan.problem
        self.complete_bytes = scan.end

    # Messages -------------------------------------------------------------------------

    def messages(self, topics=None):
        """RecordedMessages in log-time order (file order for a file without summary)."""
        topics = None if topics is None else set(topics)
        with open(self.path, 'rb') as stream:
            if self.has_summary:
                reader = SeekingReader(stream)
                items = ((channel, message) for _, channel, message in
                         reader.iter_messages(topics=topics, log_time_order=True))
            else:
                items = ((self.channels[record.channel_id], record)
                         for record in Scan(stream, self.size).records()
                         if isinstance(record, Message))
            for channel, message in items:
                if topics is not None and channel.topic not in topics:
                    continue
                yield self._message(channel, message)

    def last_message(self, topic):
        """The last message on a topic, or None (reads only the last chunk when indexed)."""
        if self.has_summary:
            with open(self.path, 'rb') as stream:
                for _, channel, message in SeekingReader(stream).iter_messages(
                        topics=[topic], log_time_order=True, reverse=True):
                    return self._message(channel, message)
            return None
        last = None
        for last in self.messages([topic]):
            pass
        return last

    def _message(self, channel, message):
        schema = self.schemas.get(channel.schema_id)
        return RecordedMessage(topic=channel.topic, type=schema.name if schema else '',
                               log_time_ns=message.log_time,
                               publish_time_ns=message.publish_time,
                               sequence=message.sequence, data=message.data)

    # Steps ----------------------------------------------------------------------------

    def topic_of(self, role):
        """The recorded topic of a logical name ('balls', 'state', ...), or None."""
        for topic, topic_role in self.roles.items():
            if topic_role == role:
                return topic
        return None

    def segment_at(self, log_time_ns):
        """Position in `segments` of the segment a log time belongs to."""
        position = bisect.bisect_right(self._offsets, log_time_ns) - 1
        if position < 0:
            raise RecordingError(f'{self.path}: a message at log time {log_time_ns} ns comes '
                                 'before the first segment')
        return position

    def steps(self):
        """RecordedSteps in order: every log time of the ball_world topics, decoded."""
        builder = None
        for message in self.messages(self.roles):
            if builder is None or message.log_time_ns != builder.log_time_ns:
                if builder is not None:
                    yield builder.build()
                position = self.segment_at(message.log_time_ns)
                builder = _StepBuilder(position, self.segments[position], message.log_time_ns)
            builder.add(self.roles[message.topic], message.data)
        if builder is not None:
            yield builder.build()


def _summary(stream):
    """The summary of a finished MCAP, or None for a file whose writer did not finish."""
    try:
        stream.seek(-len(MAGIC), io.SEEK_END)
        if stream.read(len(MAGIC)) != MAGIC:
            return None
        stream.seek(0)
        summary = SeekingReader(stream).get_summary()
    except (McapError, ValueError, struct.error, OSError, UnicodeDecodeError):
        return None
    if summary is None or summary.statistics is None:
        return None
    return summary


class _StepBuilder:
    def __init__(self, position, segment, log_time_ns):
        self.position = position
        self.segment = segment
        self.log_time_ns = log_time_ns
        self.data = {}
        self.impulses = []

    def add(self, role, data):
        if role == 'impulse':
            self.impulses.append(data)
        else:
            self.data[role] = data

    def build(self):
        stamp_ns = self.log_time_ns - self.segment.log_offset_ns
        positions = state = stats = balls_stamp = None
        try:
            if 'balls' in self.data:
                balls_stamp, _, positions = decode_pose_array(self.data['balls'])
            if 'state' in self.data:
                state = decode_state(self.data['state'])
            if 'stats' in self.data:
                stats = decode_state_layout(self.data['stats'])[2]
            impulses = tuple(RecordedImpulse(*decode_vector3_stamped(cdr), cdr=cdr)
                             for cdr in self.impulses)
        except ValueError as error:
            raise RecordingError(f'undecodable message at log time {self.log_time_ns} ns: '
                                 f'{error}') from None
        return RecordedStep(
            segment=self.position, step=stamp_ns // self.segment.dt_ns, stamp_ns=stamp_ns,
            log_time_ns=self.log_time_ns, positions=positions, state=state, stats=stats,
            impulses=impulses, balls_cdr=self.data.get('balls'),
            state_cdr=self.data.get('state'), stats_cdr=self.data.get('stats'),
            balls_stamp_ns=balls_stamp)


# Feeding sinks -------------------------------------------------------------------------

def segment_world(segment):
    """The World a segment's parameters build (raises scenario.ScenarioError)."""
    return build_world(segment.parameters)


def snapshot_and_info(segment, first_step=None):
    """The WorldSnapshot and RunInfo the node gave its sinks when the segment began.

    Radii, masses and walls come from rebuilding the world; the step-0 positions and
    velocities are the recorded ones when step 0 was recorded.
    """
    world = segment_world(segment)
    positions = world.positions.copy()
    velocities = world.velocities.copy()
    if first_step is not None and first_step.step == 0 and first_step.complete:
        positions = first_step.positions.copy()
        velocities = first_step.state[:, 2:4].copy()
    if first_step is not None and first_step.positions is not None \
            and len(first_step.positions) != len(world):
        raise RecordingError(f'segment {segment.index}: its parameters build {len(world)} '
                             f'balls but the recording has {len(first_step.positions)}')
    snapshot = WorldSnapshot(radii=world.radii.copy(), masses=world.masses.copy(),
                             walls=world.walls.segments.copy(), positions=positions,
                             velocities=velocities, dt_ns=segment.dt_ns,
                             frame_id=segment.frame_id)
    info = RunInfo(parameters=dict(segment.parameters), topics=dict(segment.topics),
                   segment=segment.index, log_offset_ns=segment.log_offset_ns,
                   package_version=segment.package_version)
    return snapshot, info


def step_record(step):
    """The StepRecord the node wrote for a complete RecordedStep."""
    ball_count = len(step.positions)
    impulses = []
    for impulse in step.impulses:
        try:
            ball = parse_ball(impulse.frame_id, ball_count)
        except ImpulseRejected as error:
            raise RecordingError(f'recorded impulse at step {step.step}: {error}') from None
        impulses.append(AppliedImpulse(ball=ball, jx=impulse.x, jy=impulse.y,
                                       frame_id=impulse.frame_id, cdr=impulse.cdr))
    rtf = step.stat('real_time_factor')
    return StepRecord(
        step=step.step, stamp_ns=step.stamp_ns, log_time_ns=step.log_time_ns,
        positions=step.positions.copy(), velocities=step.state[:, 2:4].copy(),
        ball_ball=int(step.stat('ball_ball')), ball_wall=int(step.stat('ball_wall')),
        kinetic_energy=step.stat('kinetic_energy'),
        momentum=np.array([step.stat('momentum_x'), step.stat('momentum_y')]),
        balls_cdr=step.balls_cdr, state_cdr=step.state_cdr, stats_cdr=step.stats_cdr,
        impulses=tuple(impulses), real_time_factor=None if math.isnan(rtf) else rtf)


def feed_sinks(path, sinks, close=True):
    """Replay a recording into Sinks as the node would have: returns the steps fed.

    Each segment starts with start_segment(WorldSnapshot, RunInfo), then every complete
    step goes to write_step in order (a step cut off by a crash is skipped). The sinks
    are flushed at the end, and closed unless close=False.
    """
    recording = path if isinstance(path, Recording) else Recording(path)
    current = None
    fed = 0
    for step in recording.steps():
        if not step.complete:
            continue
        if step.segment != current:
            snapshot, info = snapshot_and_info(recording.segments[step.segment], step)
            for sink in sinks:
                sink.start_segment(snapshot, info)
            current = step.segment
        record = step_record(step)
        for sink in sinks:
            sink.write_step(record)
        fed += 1
    for sink in sinks:
        sink.flush()
        if close:
            sink.close()
    return fed
