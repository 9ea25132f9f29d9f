"""ball_world_repair: make a recording whose writer was killed readable by every tool again.

An .rrd is repaired by tools.repair_rrd (through Rerun's own reader); what follows is MCAP.

A SIGKILLed or crashed recorder leaves an MCAP without summary and footer, possibly ending in
a torn record. Most readers (rosbags, ros2 bag, Foxglove's indexed view) then refuse the
file. This copies every complete record (header, schemas, channels, messages, metadata,
attachments) into a new MCAP written with a summary, in the same order, and reports what it
kept and what it had to drop: a torn last record, or everything from the first corrupt
record on. The source is untrusted: chunks are decompressed within the reader's bound, and
every 'ball_world' metadata record is checked as the tools check it (a file that has none
is not a ball_world recording, and nothing is written).

The output is written next to the target under a locked temporary name and moved into
place only when complete (recording.files.PartialOutput), so the input is never damaged,
even with -o IN; an existing output is replaced only with --force (or -o IN); and the
temporary file of a repair that was killed is removed by the next one.
"""
import argparse
from dataclasses import dataclass, field
import os
import sys

from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from ball_world.recording.files import open_regular, PartialOutput, same_path
from ball_world.recording.mcap_reader import METADATA_NAME, RecordingError, Scan, Segment
from ball_world.tools import print_report
from ball_world.tools.progress import Progress
from ball_world.tools.repair_rrd import describe as describe_rrd, repair_rrd

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


def _first_compression(path, size):
    """The compression of the source's first chunk ('' when none), so the copy keeps it."""
    with open_regular(path) as stream:
        for record in Scan(stream, size).records():
            if isinstance(record, Chunk):
                return record.compression
    return 'zstd'


def repair(source, target, force=False, stream=None):
    """Copy every complete record of `source` into a finished MCAP at `target`.

    Raises RecordingError (not a ball_world MCAP) or OSError (files.FileRefused included);
    then nothing is written. Progress goes to `stream` (stderr).
    """
    size = os.path.getsize(source)
    compression = _COMPRESSIONS.get(_first_compression(source, size), CompressionType.ZSTD)
    report = RepairReport(source_bytes=size)
    in_place = same_path(source, target)
    output = PartialOutput(target, force or in_place, 'pass --force')
    progress = Progress(size, 'bytes', PROG, stream)
    try:
        with output.claim.writer() as written, open_regular(source) as stream_in:
            scan = Scan(stream_in, size)
            _copy(scan, Writer(written, compression=compression), report, progress)
            report.kept_bytes = scan.end
            report.problem = scan.problem
            report.had_summary = scan.finished
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


def _copy(scan, writer, report, progress):
    schemas = {}  # source id -> target id
    channels = {}  # source id -> (target id, topic)
    started = False
    for record in scan.records():
        progress.advance(scan.end - progress.done)
        if isinstance(record, Header):
            writer.start(profile=record.profile, library=record.library)
            started = True
        elif not started:
            raise RecordingError('the file does not begin with an MCAP header record')
        elif isinstance(record, Schema) and record.id not in schemas:
            schemas[record.id] = writer.register_schema(record.name, record.encoding,
                                                        record.data)
            report.schemas += 1
        elif isinstance(record, Channel) and record.id not in channels:
            schema = schemas.get(record.schema_id, 0)
            channel = writer.register_channel(record.topic, record.message_encoding, schema,
                                              dict(record.metadata))
            channels[record.id] = (channel, record.topic)
            report.channels += 1
        elif isinstance(record, Message):
            _copy_message(writer, record, channels, report)
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


def _copy_message(writer, record, channels, report):
    if record.channel_id not in channels:
        report.dropped_messages += 1
        return
    channel, topic = channels[record.channel_id]
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


def describe(report, source, target):
    lines = [f'{source}: {report.source_bytes} bytes, '
             + ('it had a summary (rewritten anyway)' if report.had_summary else 'no summary')]
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


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog=PROG,
        description='Recover a truncated recording (writer killed: an MCAP without summary, '
                    'an .rrd without footer, a torn last record) into a complete file holding '
                    'every complete record; a bag directory of split files is repaired in '
                    'place and its metadata.yaml rewritten.')
    parser.add_argument('input', help='the damaged .mcap or .rrd (Rerun), or a bag directory')
    parser.add_argument('-o', '--output', help='where to write (default: '
                                               'INPUT.repaired.mcap or .rrd; may be INPUT '
                                               'itself)')
    parser.add_argument('--force', action='store_true',
                        help='replace the output file if it exists')
    args = parser.parse_args(argv)
    if os.path.isdir(args.input):
        return _main_bag(args)
    target = args.output or default_target(args.input)
    if args.input.endswith('.rrd'):
        return _reported(args, lambda: repair_rrd(args.input, target, args.force),
                         lambda report: describe_rrd(report, args.input, target))
    return _reported(args, lambda: repair(args.input, target, args.force),
                     lambda report: describe(report, args.input, target))


def _main_bag(args):
    """A bag directory of split files: repaired in place (tools.repair_bag)."""
    from ball_world.tools.repair_bag import check_bag, repair_bag

    def work():
        if args.output:
            check_bag(args.input)
            raise RecordingError('a bag directory is repaired in place; -o is for one file')
        return repair_bag(args.input)
    return _reported(args, work, '\n'.join)


def _reported(args, work, text):
    """Do `work`, print `text` of its result; return the exit code (2: one line on stderr).

    One place for how a file and a bag directory report failure: an unreadable recording
    named with its path, an OS error (which names its own path) as it is.
    """
    try:
        report = work()
    except RecordingError as error:
        print(f'{PROG}: {args.input}: {error}', file=sys.stderr)
        return 2
    except OSError as error:
        print(f'{PROG}: {error}', file=sys.stderr)
        return 2
    print_report(text(report))
    return 0


if __name__ == '__main__':
    sys.exit(main())
