"""Repair of one MCAP file: every complete, readable record copied into a finished file.

A SIGKILLed or crashed recorder leaves an MCAP without summary and footer, possibly ending in
a torn record. Most readers (rosbags, ros2 bag, Foxglove's indexed view) then refuse the
file. This copies every complete record (header, schemas, channels, messages, metadata,
attachments) into a new MCAP written with a summary, in the same order, and reports what it
kept and what it had to drop. The source is untrusted: chunks are decompressed within the
reader's bound, and every 'ball_world' metadata record is checked as the tools check it (a
file that has none is not a ball_world recording, and nothing is written).

Damage in the middle of a file (a bit flipped on disk, a sector lost) is not the end of it:
a record whose framing holds but whose content does not (a chunk failing its CRC) is skipped,
and where the framing itself is broken, reading resumes at the next record a valid summary
lists. Channels and schemas that only a lost chunk declared are taken from that summary.
What was skipped is RepairReport.damage: data lost for good, which the report names (bytes
and log times) and ball_world_repair exits non-zero for, never calling it success. A file
that only ends early (its writer was killed) loses its torn tail, as every recorder would.

The output is written next to the target under a locked temporary name and moved into
place only when complete (recording.files.PartialOutput), so the input is never damaged,
even with -o IN; an existing output is replaced only with --force (or -o IN); and the
temporary file of a repair that was killed is removed by the next one.
"""
from dataclasses import dataclass, field
import os

from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from ball_world.recording.files import open_regular, PartialOutput, same_path
from ball_world.recording.mcap_reader import (Damage, METADATA_NAME, read_summary,
                                              RecordingError, Scan, Segment)
from ball_world.tools.progress import Progress

PROG = 'ball_world_repair'

_COMPRESSIONS = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                 '': CompressionType.NONE}


@dataclass
class RepairReport:
    """What a repair kept and dropped."""

    source_bytes: int = 0
    kept_bytes: int = 0  # the complete records end here in the source
    problem: str = None  # why the source could not be read to its end, if so
    had_summary: bool = False
    messages: dict = field(default_factory=dict)  # topic -> count
    schemas: int = 0
    channels: int = 0
    metadata: int = 0
    segments: int = 0  # 'ball_world' metadata records
    attachments: int = 0
    dropped_messages: int = 0  # on channels never declared
    start_ns: int = None
    end_ns: int = None
    damage: list = field(default_factory=list)  # mcap_reader.Damage: lost in the middle

    @property
    def lost_data(self):
        """Whether recorded data was lost for good (not only a killed writer's torn tail)."""
        return bool(self.damage or self.dropped_messages)


def _first_compression(path, size):
    """The compression of the source's first chunk ('' when none), so the copy keeps it."""
    with open_regular(path) as stream:
        scan = Scan(stream, size, go_on=True)
        for record in scan.records():
            if isinstance(record, Chunk):
                return record.compression
    return 'zstd'


def _summary(path, size):
    with open_regular(path) as stream:
        return read_summary(stream, size)


def repair(source, target, force=False, stream=None, folder=None):
    """Copy every complete, readable record of `source` into a finished MCAP at `target`.

    folder: a recording.files.Folder in which `target` is a plain name (a bag directory's
    file repaired in place). Raises RecordingError (not a ball_world MCAP) or OSError
    (files.FileRefused included); then nothing is written. Progress goes to `stream`.
    """
    size = os.path.getsize(source)
    summary = _summary(source, size)
    compression = _COMPRESSIONS.get(_first_compression(source, size), CompressionType.ZSTD)
    report = RepairReport(source_bytes=size)
    in_place = same_path(source, folder.join(target) if folder is not None else target)
    output = PartialOutput(target, force or in_place, 'pass --force', folder=folder)
    progress = Progress(size, 'bytes', PROG, stream)
    resume_at = () if summary is None else (
        [index.chunk_start_offset for index in summary.chunk_indexes]
        + [index.offset for index in summary.metadata_indexes])
    try:
        with output.claim.writer() as written, open_regular(source) as stream_in:
            scan = Scan(stream_in, size, go_on=True, resume_at=resume_at)
            _copy(scan, Writer(written, compression=compression), report, progress, summary)
            report.kept_bytes = scan.end
            report.problem = scan.problem
            report.had_summary = scan.finished
            report.damage = _damage(scan, summary)
        if not report.segments:
            raise RecordingError(f"no '{METADATA_NAME}' metadata record: not a ball_world "
                                 'recording')
        output.commit()
    except BaseException:
        progress.abandon()
        output.discard()
        raise
    progress.advance(size - progress.done)  # what follows the data is not needed (an index)
    progress.finish()
    return report


def _damage(scan, summary):
    """What the scan skipped, with the log times of the chunks a valid summary knows; and
    every chunk that summary lists which the scan did not find where it says."""
    if summary is None:
        return list(scan.damage)
    indexes = {index.chunk_start_offset: index for index in summary.chunk_indexes}
    damage = []
    for item in scan.damage:
        index = indexes.get(item.start)
        if item.start_ns is None and index is not None:
            item = Damage(item.start, item.end, item.reason, index.message_start_time,
                          index.message_end_time)
        damage.append(item)
    skipped = {item.start for item in damage}
    for offset, index in sorted(indexes.items()):
        if offset not in scan.chunk_offsets and offset not in skipped and offset < scan.end:
            damage.append(Damage(offset, offset + index.chunk_length,
                                 'a chunk its summary lists is not there (its record header '
                                 'is damaged)', index.message_start_time,
                                 index.message_end_time))
    return sorted(damage, key=lambda item: item.start)


class _Registry:
    """Schemas and channels of the copy, by their ids in the source; those only a lost chunk
    declared are taken from the source's summary when it has one."""

    def __init__(self, writer, report, summary):
        self.writer = writer
        self.report = report
        self.summary = summary
        self.schemas = {}  # source id -> target id
        self.channels = {}  # source id -> (target id, topic)

    def schema(self, record):
        if record.id not in self.schemas:
            self.schemas[record.id] = self.writer.register_schema(
                record.name, record.encoding, record.data)
            self.report.schemas += 1
        return self.schemas[record.id]

    def channel(self, record):
        if record.id not in self.channels:
            schema = self.schemas.get(record.schema_id, 0)
            if not schema and self.summary is not None \
                    and record.schema_id in self.summary.schemas:
                schema = self.schema(self.summary.schemas[record.schema_id])
            channel = self.writer.register_channel(record.topic, record.message_encoding,
                                                   schema, dict(record.metadata))
            self.channels[record.id] = (channel, record.topic)
            self.report.channels += 1
        return self.channels[record.id]

    def of_message(self, channel_id):
        if channel_id not in self.channels and self.summary is not None \
                and channel_id in self.summary.channels:
            self.channel(self.summary.channels[channel_id])
        return self.channels.get(channel_id)


def _copy(scan, writer, report, progress, summary):
    registry = _Registry(writer, report, summary)
    started = False
    for record in scan.records():
        progress.advance(scan.end - progress.done)
        if isinstance(record, Header):
            if not started:
                writer.start(profile=record.profile, library=record.library)
                started = True
        elif not started:
            raise RecordingError('the file does not begin with an MCAP header record')
        elif isinstance(record, Schema):
            registry.schema(record)
        elif isinstance(record, Channel):
            registry.channel(record)
        elif isinstance(record, Message):
            _copy_message(writer, record, registry.of_message(record.channel_id), report)
        elif isinstance(record, Metadata):
            if record.name == METADATA_NAME:
                Segment.from_metadata(record.metadata)  # a crafted one stops the repair
                report.segments += 1
            writer.flush()  # keep the metadata between the messages it separated
            writer.add_metadata(record.name, dict(record.metadata))
            report.metadata += 1
        elif isinstance(record, Attachment):
            writer.add_attachment(record.create_time, record.log_time, record.name,
                                  record.media_type, record.data)
            report.attachments += 1
    progress.advance(scan.end - progress.done)
    if not started:
        raise RecordingError('no complete MCAP header record')
    writer.finish()


def _copy_message(writer, record, channel, report):
    if channel is None:
        report.dropped_messages += 1
        return
    channel, topic = channel
    writer.add_message(channel, log_time=record.log_time, data=record.data,
                       publish_time=record.publish_time, sequence=record.sequence)
    report.messages[topic] = report.messages.get(topic, 0) + 1
    report.start_ns = record.log_time if report.start_ns is None else min(
        report.start_ns, record.log_time)
    report.end_ns = record.log_time if report.end_ns is None else max(
        report.end_ns, record.log_time)


def default_target(source):
    """run.mcap -> run.repaired.mcap, beside the input."""
    root, extension = os.path.splitext(source)
    return f'{root}.repaired{extension or ".mcap"}'


def damage_lines(damage):
    """One line per stretch of lost data (mcap_reader.Damage), indented for a report."""
    lines = []
    for item in damage:
        span = ''
        if item.start_ns is not None:
            span = f', log time {item.start_ns / 1e9:.9g} s to {item.end_ns / 1e9:.9g} s'
        lines.append(f'  DAMAGED: bytes {item.start}-{item.end} cannot be read{span}, lost: '
                     f'{item.reason}')
    return lines


def describe(report, source, target):
    lines = [f'{source}: {report.source_bytes} bytes, '
             + ('it had a summary (rewritten anyway)' if report.had_summary else 'no summary')]
    lines.extend(damage_lines(report.damage))
    if report.problem:
        lines.append(f'  kept the complete records up to byte {report.kept_bytes}; dropped '
                     f'{report.source_bytes - report.kept_bytes} bytes: {report.problem}')
    total = sum(report.messages.values())
    span = ''
    if total:
        span = (f', log time {report.start_ns / 1e9:.9g} s to {report.end_ns / 1e9:.9g} s')
    lines.append(f'  kept {total} messages{span}, {report.schemas} schemas, '
                 f'{report.channels} channels, {report.metadata} metadata records, '
                 f'{report.attachments} attachments')
    for topic, count in sorted(report.messages.items()):
        lines.append(f'    {topic}: {count}')
    if report.dropped_messages:
        lines.append(f'  dropped {report.dropped_messages} messages on undeclared channels')
    lines.append(f'wrote {target}')
    return '\n'.join(lines)
