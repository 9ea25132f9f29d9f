"""Read a ball_world MCAP recording: its segments, its messages, and its steps in order.

A recording is untrusted input: any tool may be handed a file that was cut off, bit-flipped
or crafted. So every length is checked against the bytes that are really there before it is
read, chunks are decompressed by this module with a bound on their output (a 98 kB file must
not inflate to gigabytes), metadata is parsed without recursion or YAML aliases, and the
recorded parameters are checked by the node's own rules (core.scenario) before any world is
built from them. Anything wrong is a RecordingError with one line saying what and where.

A finished recording has a summary and is read through its chunk indexes. A recording whose
writer was killed has no summary and may end in a torn record; it is read front to back,
stopping at the first record that is not complete (every complete chunk is still read, and
`problem` says where reading stopped). A record that is complete but corrupt is an error,
not an end: ball_world_repair keeps what comes before it.

World edits are read the same way: each recorded `edits` text is bounded in size, parsed
as JSON within a bounded nesting, and every field is checked (kind, an entity name, finite
numbers, radius and mass within core.limits, impulses_before within the step's impulses)
before any tool acts on it.

feed_sinks() turns a recording back into the WorldSnapshot / RunInfo / StepRecord stream the
node produced, so any Sink (the Rerun logger, a second MCAP) can be fed from a file. It
follows each segment's balls through its edits (BallRoster): which names exist, in which
order, with which radii and masses, so impulses find their ball by name and every record
carries the balls as they were at its step; and where the agents' drives were not recorded
(agent_topics: every file written since they were left out, and a swarm's), it makes them
again from the recorded commands (remade_drives), so each record holds the impulses the
node applied, drives marked, as the live one did.
"""
import bisect
import dataclasses
from dataclasses import dataclass
import functools
import hashlib
import heapq
import io
import json
import math
import os
import re
import struct
from typing import Optional
import zlib

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd,
                          Footer, Header, Message, Metadata, MetadataIndex, Schema, Statistics)
from mcap.stream_reader import breakup_chunk
from mcap.summary import Summary
import numpy as np
import yaml

from ball_world.core import limits
from ball_world.core.edits import NAME_PATTERN
from ball_world.core.occupancy_map import load_map, MapError, MapFiles
from ball_world.core.parameters import checked, ParameterError
from ball_world.core.scenario import build_world, step_duration_ns
from ball_world.msgs.agent_cdr import decode_command_rows
from ball_world.msgs.cdr import (decode_pose_array, decode_state, decode_state_layout,
                                 decode_string, decode_vector3_stamped)
from ball_world.msgs.map_cdr import encode_occupancy_grid
from ball_world.recording import agent_topics
from ball_world.recording.files import open_regular
from ball_world.recording.mcap_writer import (EVENT_ROLES, flatten_parameters, MAP_KEYS,
                                              METADATA_NAME, NODE_NAME, STEP_TOPICS)
from ball_world.recording.remade_drives import RemadeDrives
from ball_world.recording.resume import parse_resume, ResumeState
from ball_world.step_record import (AppliedEdit, AppliedImpulse, PendingEvents, RunInfo,
                                    STATS_FIELDS, StepRecord, WorldSnapshot)

MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEAD = struct.Struct('<BQ')
#: A footer record: opcode, length 20, summary_start, summary_offset_start, summary_crc.
_FOOTER = struct.Struct('<BQQQI')

#: Largest uncompressed chunk accepted. The writer cuts chunks at 4 MiB between steps, so a
#: chunk is at most 4 MiB plus one step; the largest world (limits.MAX_BALLS) makes a step
#: of about 45 MB (poses, state, a burst of impulses and its markers). A chunk declaring more
#: is refused before anything is decompressed, and no chunk inflates past what it declares.
MAX_CHUNK_BYTES = 256 << 20
#: Largest parameters document (JSON or YAML) in a metadata record: 100,000 explicit balls
#: take about 15 MB.
MAX_PARAMETERS_TEXT = 64 << 20
#: Largest `topics` document and QoS text.
MAX_SMALL_TEXT = 64 << 10
#: Parameter names have at most two dots ('balls.x'): the parameters document nests at most
#: this deep below ros__parameters.
MAX_PARAMETER_NESTING = 3
#: Longest recorded edit (its JSON text). The node writes about 250 characters plus the
#: name (at most limits.MAX_NAME_LENGTH); anything much longer was not written by it.
MAX_EDIT_TEXT = 4096
#: An edit's kinds and fields, exactly as step_record.AppliedEdit has them.
EDIT_KINDS = ('spawn', 'delete', 'set_state')
_EDIT_NUMBERS = ('x', 'y', 'vx', 'vy', 'radius', 'mass')
_EDIT_FIELDS = frozenset(('kind', 'name', *_EDIT_NUMBERS, 'impulses_before'))
#: Keys only edits of agents carry: a spawn's 'agent': true, a set_state's 'yaw'.
_AGENT_EDIT_FIELDS = {'spawn': 'agent', 'set_state': 'yaw'}
#: Roles a segment's topics may lack: recordings made before edits were recorded.
_OPTIONAL_ROLES = ('edits',)
_WHOLE_NUMBER = re.compile(r'-?[0-9]{1,19}')
_TOPIC_NAME = re.compile(r'/?[A-Za-z_~{][A-Za-z0-9_/{}~]{0,255}')

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
_SUMMARY_PARSERS = {
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK_INDEX: ChunkIndex.read,
    Opcode.METADATA_INDEX: MetadataIndex.read,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex.read,
    Opcode.STATISTICS: Statistics.read,
}
#: Longest name of a map file a segment may give (core.parameters' longest path).
MAX_MAP_NAME = 4096
#: Largest attachment read as a map file: the largest map image (core.limits).
MAX_MAP_ATTACHMENT = limits.MAX_MAP_IMAGE_BYTES
_SHA256 = re.compile(r'[0-9a-f]{64}')


class RecordingError(Exception):
    """A file that is not a readable ball_world recording; the message says why."""


def _text(value, limit=60):
    """A short, printable rendering of an untrusted value for an error message."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + '...'


# Records and chunks, read with every length checked -------------------------------------

def _decompress(compression, data, size):
    """Decompress a chunk's data to at most `size` + 1 bytes (one more shows a lie)."""
    if compression == '':
        return data
    if compression == 'zstd':
        import zstandard
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data)) as reader:
            return reader.read(size + 1)
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    raise RecordingError(f'a chunk uses the unknown compression {_text(compression)}')


def chunk_records(chunk):
    """The records inside a chunk, decompressed within MAX_CHUNK_BYTES and CRC-checked."""
    size = chunk.uncompressed_size
    if size > MAX_CHUNK_BYTES:
        raise RecordingError(f'a chunk declares {size:,} bytes uncompressed, more than the '
                             f'{MAX_CHUNK_BYTES:,} any ball_world recording needs')
    try:
        data = _decompress(chunk.compression, chunk.data, size)
    except RecordingError:
        raise
    except Exception as error:  # noqa: B902 - each codec raises its own types on bad data
        raise RecordingError(f'a {chunk.compression} chunk does not decompress: '
                             f'{error or type(error).__name__}') from None
    if len(data) != size:
        more = 'more' if len(data) > size else f'only {len(data):,}'
        raise RecordingError(f'a chunk declares {size:,} bytes uncompressed but inflates to '
                             f'{more} bytes')
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise RecordingError('a chunk fails its CRC check: its bytes are corrupt')
    plain = Chunk(message_start_time=chunk.message_start_time,
                  message_end_time=chunk.message_end_time, uncompressed_size=size,
                  uncompressed_crc=0, compression='', data=data)
    try:
        return breakup_chunk(plain)
    except Exception as error:  # noqa: B902 - corrupt records raise anything
        raise RecordingError(f'a chunk holds a corrupt record: '
                             f'{error or type(error).__name__}') from None


class CorruptChunk(RecordingError):
    """A chunk whose framing holds but whose content does not (its CRC, its compression, a
    record inside): `start_ns` and `end_ns` are the log times its header says it held."""

    def __init__(self, message, start_ns, end_ns):
        super().__init__(message)
        self.start_ns = start_ns
        self.end_ns = end_ns


def _parse(opcode, body):
    """The records of one complete record body: [record] or [chunk, *its records] or []."""
    if opcode == Opcode.MESSAGE:
        return [Message.read(ReadDataStream(io.BytesIO(body)), len(body))]
    parser = _PARSERS.get(opcode)
    if parser is None:
        return []  # indexes and records this reader does not need
    record = parser(ReadDataStream(io.BytesIO(body)))
    if isinstance(record, Chunk):
        # The fixed fields are 40 bytes; a shorter body means the data length field lies.
        if len(body) != 40 + len(record.compression.encode()) + len(record.data):
            raise ValueError('chunk data length does not match the record length')
        try:
            return [record, *chunk_records(record)]
        except RecordingError as error:
            raise CorruptChunk(str(error), record.message_start_time,
                               record.message_end_time) from None
    return [record]


def _read_record(stream, offset, size, opcode):
    """The parsed record of type `opcode` at `offset`, or RecordingError."""
    stream.seek(offset)
    head = stream.read(_RECORD_HEAD.size)
    if len(head) < _RECORD_HEAD.size:
        raise RecordingError(f'no record at byte {offset}: the file ends there')
    found, length = _RECORD_HEAD.unpack(head)
    if found != opcode:
        raise RecordingError(f'the index points at byte {offset}, where no '
                             f'{Opcode(opcode).name.lower()} record is')
    if length > size - offset - _RECORD_HEAD.size:
        raise RecordingError(f'the record at byte {offset} needs {length:,} bytes; the file '
                             'ends before')
    try:
        return _parse(opcode, stream.read(length))
    except CorruptChunk as error:
        raise RecordingError(f'the record at byte {offset}: {error} (ball_world_repair '
                             'keeps every other record)') from None
    except RecordingError as error:
        raise RecordingError(f'the record at byte {offset}: {error}') from None
    except Exception as error:  # noqa: B902 - corrupt bytes raise anything
        raise RecordingError(f'the record at byte {offset} is corrupt: '
                             f'{error or type(error).__name__}') from None


@dataclass(frozen=True)
class Damage:
    """Bytes of a file that hold no readable record, skipped by a Scan told to go on:
    [start, end) in the file, why, and the log times they held when known (a chunk's)."""

    start: int
    end: int
    reason: str
    start_ns: Optional[int] = None
    end_ns: Optional[int] = None


class Scan:
    """Reads an MCAP front to back, record by record, up to the first incomplete one.

    records() yields every complete top-level record of the data section in file order;
    a Chunk is yielded itself and then the records inside it, and only if it is whole
    (its length fits in the file, it inflates to what it declares and its CRC matches).
    After iterating: `end` is the byte offset after the last complete record, `finished`
    is True when the data section ended properly (DataEnd or Footer), and `problem`
    otherwise says where and why reading stopped; `corrupt` is True when that was a
    complete record with bad content, rather than a file cut short.

    go_on=True (ball_world_repair): a complete record with bad content is skipped, and
    said in `damage` (Damage), instead of ending the scan; where the framing itself is
    broken (a zero opcode, a length past the end), reading resumes at the next of
    `resume_at` (record offsets a valid summary lists) if there is one.
    """

    def __init__(self, stream, size, go_on=False, resume_at=()):
        self.stream = stream
        self.size = size
        self.end = 0
        self.finished = False
        self.problem = None
        self.corrupt = False
        self.go_on = go_on
        self.resume_at = sorted(resume_at)
        self.damage = []
        self.chunk_offsets = set()  # where the chunks that were read whole begin

    def _resume(self, offset, reason):
        """The offset to read on from after broken framing at `offset`, or None."""
        if not self.go_on:
            return None
        position = bisect.bisect_right(self.resume_at, offset)
        if position == len(self.resume_at) or self.resume_at[position] >= self.size:
            return None
        following = self.resume_at[position]
        self.damage.append(Damage(offset, following, reason))
        return following

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
            broken = None
            if opcode == 0:
                broken = f'no valid record at byte {offset} (zero bytes)'
            elif length > self.size - body_at:
                broken = (f'the record at byte {offset} is cut off: it needs {length} '
                          f'bytes, {self.size - body_at} are left')
            if broken is not None:
                following = self._resume(offset, broken)
                if following is None:
                    self.problem = broken
                    return
                offset = self.end = following
                stream.seek(offset)
                continue
            try:
                parsed = _parse(opcode, stream.read(length))
            except Exception as error:  # noqa: B902 - corrupt bytes raise anything
                reason = (f'the record at byte {offset} is corrupt: '
                          f'{error or type(error).__name__}')
                if not self.go_on:
                    self.problem = reason
                    self.corrupt = True
                    return
                self.damage.append(Damage(offset, body_at + length, reason,
                                          getattr(error, 'start_ns', None),
                                          getattr(error, 'end_ns', None)))
                offset = self.end = body_at + length
                continue
            if opcode == Opcode.CHUNK:
                self.chunk_offsets.add(offset)
            offset = self.end = body_at + length
            yield from parsed
            if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                self.finished = True
                return


def read_summary(stream, size):
    """The summary of a finished MCAP, or None when there is none or it does not hold up.

    Read by hand (footer, then the summary section as one bounded block, its CRC checked),
    so that lengths in a damaged footer or index can never make a read past the file.
    """
    footer_at = size - len(MAGIC) - _FOOTER.size
    if footer_at < len(MAGIC):
        return None
    stream.seek(footer_at)
    tail = stream.read(_FOOTER.size + len(MAGIC))
    if len(tail) != _FOOTER.size + len(MAGIC) or tail[_FOOTER.size:] != MAGIC:
        return None
    opcode, length, start, offsets_at, crc = _FOOTER.unpack(tail[:_FOOTER.size])
    if opcode != Opcode.FOOTER or length != _FOOTER.size - _RECORD_HEAD.size \
            or not len(MAGIC) <= start < footer_at:
        return None
    stream.seek(start)
    section = stream.read(footer_at - start)
    if crc and zlib.crc32(tail[:_FOOTER.size - 4], zlib.crc32(section)) != crc:
        return None
    summary = Summary()
    try:
        _fill_summary(summary, section)
    except Exception:  # noqa: B902 - a corrupt summary is read as none: the file is scanned
        return None
    return summary if summary.statistics is not None else None


def _fill_summary(summary, section):
    position = 0
    while position < len(section):
        opcode, length = _RECORD_HEAD.unpack_from(section, position)
        body_at = position + _RECORD_HEAD.size
        if length > len(section) - body_at:
            raise ValueError('a summary record runs past the summary section')
        parser = _SUMMARY_PARSERS.get(opcode)
        if parser is not None:
            record = parser(ReadDataStream(io.BytesIO(section[body_at:body_at + length])))
            if isinstance(record, Schema):
                summary.schemas[record.id] = record
            elif isinstance(record, Channel):
                summary.channels[record.id] = record
            elif isinstance(record, ChunkIndex):
                summary.chunk_indexes.append(record)
            elif isinstance(record, MetadataIndex):
                summary.metadata_indexes.append(record)
            elif isinstance(record, AttachmentIndex):
                summary.attachment_indexes.append(record)
            else:
                summary.statistics = record
        position = body_at + length


# Untrusted metadata --------------------------------------------------------------------

class _NoAliasLoader(yaml.SafeLoader):
    """YAML without aliases: a few hundred bytes of nested aliases expand to gigabytes."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            raise yaml.YAMLError('YAML aliases are not accepted in a recording')
        return super().compose_node(parent, index)


def load_untrusted(text, what, limit, json_text=True):
    """Parse JSON (or YAML without aliases) from a recording, bounded in size and nesting."""
    if not isinstance(text, str):
        raise RecordingError(f'{what} is not text')
    if len(text) > limit:
        raise RecordingError(f'{what} is {len(text):,} characters long; at most {limit:,} '
                             'are accepted')
    try:
        if json_text:
            return json.loads(text)
        return yaml.load(text, Loader=_NoAliasLoader)
    except RecursionError:
        raise RecordingError(f'{what} nests too deeply') from None
    except (ValueError, yaml.YAMLError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise RecordingError(f'{what} does not parse: {reason}') from None


def _whole_number(values, key, low, high):
    text = values.get(key)
    if not isinstance(text, str) or not _WHOLE_NUMBER.fullmatch(text):
        raise RecordingError(f"'{key}' is {_text(text)}, not a whole number")
    value = int(text)
    if not low <= value <= high:
        raise RecordingError(f"'{key}' is {value:,}; it must be between {low:,} and "
                             f'{high:,}')
    return value


def _flat_parameters(document):
    """The flat {name: value} of a params-file document, refusing any other shape."""
    if not isinstance(document, dict) or not isinstance(document.get(NODE_NAME), dict) \
            or not isinstance(document[NODE_NAME].get('ros__parameters'), dict):
        raise RecordingError(f"the parameters are not a '{NODE_NAME}: ros__parameters:' "
                             'document')

    def depth(node, level):
        if level > MAX_PARAMETER_NESTING:
            raise RecordingError('the parameters nest deeper than any ball_world parameter')
        for value in node.values():
            if isinstance(value, dict):
                depth(value, level + 1)

    depth(document[NODE_NAME]['ros__parameters'], 1)
    return flatten_parameters(document)


def _topics(values):
    if 'topics' not in values:
        return {role: f'/{role}' for role in STEP_TOPICS}
    topics = load_untrusted(values['topics'], "'topics'", MAX_SMALL_TEXT)
    if not isinstance(topics, dict) or any(
            role not in topics for role in STEP_TOPICS
            if role not in _OPTIONAL_ROLES) or not all(
            isinstance(topic, str) and _TOPIC_NAME.fullmatch(topic)
            for topic in topics.values()):
        raise RecordingError(f"'topics' is not a map of every role to a topic name: "
                             f'{_text(topics)}')
    return topics


# Untrusted edits -----------------------------------------------------------------------

def _edit_number(fields, key):
    value = fields[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RecordingError(f'{key} is {_text(value)}, not a number')
    try:
        value = float(value)
    except OverflowError:
        raise RecordingError(f'{key} is too large for a float') from None
    if not math.isfinite(value):
        raise RecordingError(f'{key} is {value}, not a finite number')
    return value


def parse_edit(data, impulse_count):
    """The AppliedEdit a recorded `edits` message holds, checked as untrusted input.

    data: the message's CDR bytes (std_msgs/String). impulse_count: how many impulses its
    step recorded, the most impulses_before may be. Raises RecordingError naming the field.
    """
    if len(data) > MAX_EDIT_TEXT + 16:  # the CDR header, length and NUL around the text
        raise RecordingError(f'the message is {len(data):,} bytes long; an edit is at most '
                             f'{MAX_EDIT_TEXT:,} characters')
    try:
        text = decode_string(data)
    except ValueError as error:
        raise RecordingError(f'not a std_msgs/String: {error}') from None
    fields = load_untrusted(text, 'the text', MAX_EDIT_TEXT)
    kind = fields.get('kind') if isinstance(fields, dict) else None
    extra = _AGENT_EDIT_FIELDS.get(kind) if isinstance(kind, str) else None
    agent = {}
    if extra is not None and extra in fields:
        fields = dict(fields)
        value = fields.pop(extra)
        if extra == 'agent' and value is not True:
            raise RecordingError(f'agent is {_text(value)}, not true')
        agent[extra] = value if extra == 'agent' else _edit_number({extra: value}, extra)
    if not isinstance(fields, dict) or set(fields) != _EDIT_FIELDS:
        shown = sorted(map(str, fields)) if isinstance(fields, dict) else fields
        raise RecordingError(f'not an edit with the fields {", ".join(sorted(_EDIT_FIELDS))}: '
                             f'{_text(shown)}')
    kind, name, before = fields['kind'], fields['name'], fields['impulses_before']
    if kind not in EDIT_KINDS:
        raise RecordingError(f'kind is {_text(kind)}, not one of {", ".join(EDIT_KINDS)}')
    if not (isinstance(name, str) and len(name) <= limits.MAX_NAME_LENGTH
            and NAME_PATTERN.fullmatch(name)):
        raise RecordingError(f'name {_text(name)} is not an entity name (a letter, then '
                             f'letters, digits or underscores, at most '
                             f'{limits.MAX_NAME_LENGTH} characters)')
    numbers = {key: _edit_number(fields, key) for key in _EDIT_NUMBERS}
    if kind == 'spawn':
        for key, low, high in (('radius', limits.MIN_RADIUS, limits.MAX_RADIUS),
                               ('mass', limits.MIN_MASS, limits.MAX_MASS)):
            if not low <= numbers[key] <= high:
                raise RecordingError(f'{key} {numbers[key]:g} is outside {low:g} to {high:g}')
    if isinstance(before, bool) or not isinstance(before, int) \
            or not 0 <= before <= impulse_count:
        raise RecordingError(f'impulses_before is {_text(before)}, not a count from 0 to the '
                             f'{impulse_count} impulses of its step')
    return AppliedEdit(kind=kind, name=name, impulses_before=before, text=text, **numbers,
                       **agent)


def parse_edits(messages, impulse_count):
    """The AppliedEdits of one step's `edits` messages, in order (see parse_edit)."""
    edits = []
    for position, data in enumerate(messages):
        try:
            edit = parse_edit(data, impulse_count)
            if edits and edit.impulses_before < edits[-1].impulses_before:
                raise RecordingError(f'impulses_before goes back from '
                                     f'{edits[-1].impulses_before} to {edit.impulses_before}')
        except RecordingError as error:
            raise RecordingError(f'edit {position}: {error}') from None
        edits.append(edit)
    return tuple(edits)


# The map's files ---------------------------------------------------------------------

def _map_reference(values):
    """(YAML name, image name, YAML SHA-256, image SHA-256) from segment metadata, or None."""
    present = [key for key in MAP_KEYS if key in values]
    if not present:
        return None
    if len(present) != len(MAP_KEYS):
        missing = [key for key in MAP_KEYS if key not in values]
        raise RecordingError(f"it names a map but lacks '{missing[0]}'")
    names = [values[key] for key in MAP_KEYS[:2]]
    hashes = [values[key] for key in MAP_KEYS[2:]]
    for key, name in zip(MAP_KEYS, names):
        if not isinstance(name, str) or not name or len(name) > MAX_MAP_NAME \
                or not name.isprintable():
            raise RecordingError(f"'{key}' is not a file name: {_text(name)}")
    for key, digest in zip(MAP_KEYS[2:], hashes):
        if not isinstance(digest, str) or not _SHA256.fullmatch(digest):
            raise RecordingError(f"'{key}' is not a SHA-256 digest: {_text(digest)}")
    return (*names, *hashes)


def _map_names(metadata):
    """The map file names the 'ball_world' metadata records give (attachments to read)."""
    return {record.metadata[key] for record in metadata for key in MAP_KEYS[:2]
            if key in record.metadata}


def _attached(attachments, name, digest):
    """The bytes of the attachment called `name` whose SHA-256 is `digest`, or None."""
    for attachment_name, data in attachments:
        if attachment_name == name and hashlib.sha256(data).hexdigest() == digest:
            return data
    return None


def _with_map_files(segments, attachments):
    """The segments, each that names a map holding its files' bytes (RecordingError when
    the file does not have them)."""
    found = []
    for segment in segments:
        reference = segment.map_reference
        if reference is not None:
            yaml_name, image_name, yaml_digest, image_digest = reference
            yaml_bytes = _attached(attachments, yaml_name, yaml_digest)
            image_bytes = _attached(attachments, image_name, image_digest)
            for name, data in ((yaml_name, yaml_bytes), (image_name, image_bytes)):
                if data is None:
                    raise RecordingError(f'segment {segment.index}: its map file '
                                         f'{_text(name)} is not attached to the recording')
            segment = dataclasses.replace(segment, map_files=MapFiles(
                yaml_name=yaml_name, yaml_bytes=yaml_bytes, image_name=image_name,
                image_bytes=image_bytes))
        found.append(segment)
    return found


@functools.lru_cache(maxsize=4)
def _loaded_map(files):
    return load_map(files)


def _decoded_map(files, segment_index):
    """core.occupancy_map.load_map of a recording's map files, decoded once per map."""
    try:
        return _loaded_map(files)
    except MapError as error:
        raise RecordingError(f'segment {segment_index}: its recorded map: {error}') from None


# What a recording holds ---------------------------------------------------------------

@dataclass(frozen=True)
class Segment:
    """One run of the world between a start or reset and the next reset."""

    index: int
    log_offset_ns: int
    dt_ns: int
    frame_id: str
    package_version: str
    parameters: dict  # flat names ('balls.x'), checked and merged over the defaults
    topics: dict  # logical name -> recorded topic
    # Where a split file continues the segment (its first step is resume.step + 1).
    resume: Optional[ResumeState] = None
    # The map's files, when the parameters name one: (YAML name, image name, their SHA-256)
    # from the metadata, and their bytes, found among the file's attachments.
    map_reference: Optional[tuple] = None
    map_files: Optional[MapFiles] = None
    # Whether the agents' drive impulses are on `impulse`: in files written before they were
    # left out (agent_topics.drives_recorded), but a swarm's; re-simulation makes them again.
    drives_recorded: bool = True

    @property
    def occupancy_map(self):
        """The recorded map, decoded (once per distinct map), or None without one."""
        if self.map_files is None:
            return None
        return _decoded_map(self.map_files, self.index)

    def map_cdr(self):
        """The /map bytes the node published at the segment start, or None."""
        occupancy_map = self.occupancy_map
        if occupancy_map is None:
            return None
        return encode_occupancy_grid(0, self.frame_id, occupancy_map)

    @classmethod
    def from_metadata(cls, values):
        """The segment a 'ball_world' metadata record describes, checked as the node would.

        The parameters must pass the node's own checks (core.parameters: every value
        against its type and range, so no count, size or radius past core.limits) and give
        the recorded dt, before any world is built from them.
        """
        index = _whole_number(values, 'segment', 0, 2**63 - 1)
        try:
            segment = cls._checked(values, index)
        except RecordingError as error:
            raise RecordingError(f"segment {index}: '{METADATA_NAME}' metadata: "
                                 f'{error}') from None
        return segment

    @classmethod
    def _checked(cls, values, index):
        log_offset_ns = _whole_number(values, 'log_offset_ns', 0, 2**63 - 1)
        dt_ns = _whole_number(values, 'dt_ns', 1, round(limits.MAX_DT * 1e9))
        if 'parameters_json' in values:
            document = load_untrusted(values['parameters_json'], "'parameters_json'",
                                      MAX_PARAMETERS_TEXT)
        else:
            document = load_untrusted(values.get('parameters'), "'parameters'",
                                      MAX_PARAMETERS_TEXT, json_text=False)
        try:
            parameters = checked(_flat_parameters(document))
            expected_dt_ns = step_duration_ns(parameters)
        except ParameterError as error:
            raise RecordingError(str(error)) from None
        if expected_dt_ns != dt_ns:
            raise RecordingError(f"'dt_ns' is {dt_ns} but the parameters give "
                                 f'{expected_dt_ns}')
        frame_id = values.get('frame_id', parameters['frame_id'])
        version = values.get('package_version', '')
        for key, text in (('frame_id', frame_id), ('package_version', version)):
            if not isinstance(text, str) or len(text) > limits.MAX_NAME_LENGTH \
                    or not text.isprintable():
                raise RecordingError(f"'{key}' is not a name: {_text(text)}")
        try:
            resume = parse_resume(values, lambda text, what: load_untrusted(
                text, what, MAX_PARAMETERS_TEXT))
        except ValueError as error:
            raise RecordingError(f'the state it resumes from: {error}') from None
        map_reference = _map_reference(values)
        if bool(parameters['map']) != (map_reference is not None):
            raise RecordingError(
                f"the parameters name the map {_text(parameters['map'])} but it keeps no copy "
                "of the map's files" if parameters['map'] else
                "it names map files but its parameters have no 'map'")
        try:
            drives = agent_topics.drives_recorded(values, parameters)
        except ValueError as error:
            raise RecordingError(str(error)) from None
        return cls(index=index, log_offset_ns=log_offset_ns, dt_ns=dt_ns, frame_id=frame_id,
                   package_version=version, parameters=parameters, topics=_topics(values),
                   resume=resume, map_reference=map_reference, drives_recorded=drives)

    def expected_balls(self):
        """How many balls the parameters make (explicit and random), without building."""
        return len(self.parameters['balls.x']) + self.parameters['random.count']

    def check_ball_count(self, recorded):
        """Refuse a step whose ball count the parameters cannot give, before any building.

        A segment continued in a split file has its balls in its resume state, and its
        first step's edits may change their number: nothing to check against.
        """
        if self.resume is not None:
            return
        expected = self.expected_balls()
        if recorded != expected:
            raise RecordingError(f'segment {self.index}: its parameters make {expected:,} '
                                 f'balls but the recording has {recorded:,}')


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
    # An agent's own drive, not a push: only in a recording made while drives were recorded
    # (their bytes also on <name>/drive: agent_topics); False in one made before that, and
    # now never (drives are not recorded; feed_sinks makes them again: remade_drives).
    drive: bool = False


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
    edits: tuple = ()  # AppliedEdit applied before this step, in order (checked)
    # Agents (recording.agent_topics): commands taken before this step, in order, as
    # (agent name, vx, vy, wz, bytes); each agent's odom bytes {name: bytes}; /tf's bytes.
    commands: tuple = ()
    odom: Optional[dict] = None
    tf_cdr: Optional[bytes] = None
    # Read with Recording.steps(agent_messages=True) only: {(kind, agent name): bytes} of the
    # step's scans, ground truth and bumpers (agent_topics.AGENT_MESSAGE_KINDS).
    agent_messages: Optional[dict] = None
    # A swarm's commands (agent.topics none) taken before this step: (K, 4) rows (ball, vx,
    # vy, wz), ball the row in this step's balls (agent_topics.COMMANDS); None without.
    command_rows: Optional[np.ndarray] = None

    @property
    def complete(self):
        return (self.positions is not None and self.state is not None
                and self.stats is not None)

    @property
    def closing(self):
        """Whether this is a closing record: impulses and edits applied after the segment's
        last step (the run ended or was reset before another step), with no balls, state or
        stats of their own (step_record.PendingEvents). A crash never leaves one: a step's
        messages are written in one chunk."""
        return (self.positions is None and self.state is None and self.stats is None
                and bool(self.impulses or self.edits))

    @property
    def ball_count(self):
        """Balls in this step's messages (None when it has neither balls nor state)."""
        for rows in (self.positions, self.state):
            if rows is not None:
                return len(rows)
        return None

    def stat(self, name):
        return float(self.stats[STATS_FIELDS.index(name)])


def decode_stats(data):
    """The STATS_FIELDS values of a `stats` message (ValueError if it has another count)."""
    values = decode_state_layout(data)[2]
    if len(values) != len(STATS_FIELDS):
        raise ValueError(f'stats has {len(values)} values, not {len(STATS_FIELDS)}')
    return values


class Recording:
    """A ball_world MCAP file, summary or not (see the module docstring).

    Attributes: header (mcap Header), has_summary, problem (why a file without summary
    could not be read to its end, or None), complete_bytes, size, topics
    ({topic: TopicInfo}), segments ([Segment] in log-time order), compressions (set of
    chunk compressions), chunk_count, message_count, start_ns / end_ns (log times).
    Raises RecordingError for a file that is not a readable ball_world recording; its
    message does not repeat the path (the tools print it once, in front).
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        try:
            self._load()
        except OSError as error:
            raise RecordingError(error.strerror or str(error)) from None

    def _load(self):
        with open_regular(self.path) as stream:
            self.size = os.fstat(stream.fileno()).st_size
            if stream.read(len(MAGIC)) != MAGIC:
                raise RecordingError('not an MCAP file (bad magic)')
            summary = read_summary(stream, self.size)
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
        segments = [Segment.from_metadata(record.metadata) for record in self.metadata]
        if not segments:
            raise RecordingError(f"no '{METADATA_NAME}' metadata record: not a ball_world "
                                 'recording')
        segments = _with_map_files(segments, self._attachments)
        del self._attachments
        self.segments = sorted(segments, key=lambda s: s.log_offset_ns)
        self._offsets = [s.log_offset_ns for s in self.segments]
        self.roles = {}  # recorded topic -> step role, for the topics steps() reads
        for segment in self.segments:
            for role, topic in segment.topics.items():
                if role in STEP_TOPICS:
                    self.roles.setdefault(topic, role)
        # The agents' topics: (kind, agent name) of each, and their types.
        namespaces = {agent_topics.namespace_of(segment.topics) for segment in self.segments
                      if 'balls' in segment.topics}
        self.agent_roles = {}
        self.agent_message_roles = {}  # scans, ground truth, bumpers: (kind, agent name)
        for topic, info in self.topics.items():
            role = agent_topics.agent_role(topic, namespaces)
            if role is not None:
                self.agent_roles[topic] = (*role, info.type)
            found = agent_topics.agent_message(topic)
            if found is not None and topic.rpartition('/')[0].rpartition('/')[0] in namespaces:
                self.agent_message_roles[topic] = found

    def _read_indexed(self, stream, summary):
        self.header = _read_record(stream, len(MAGIC), self.size, Opcode.HEADER)[0]
        self.has_summary = True
        self.problem = None
        self.complete_bytes = self.size
        self.schemas = dict(summary.schemas)
        self.channels = dict(summary.channels)
        self.metadata = [_read_record(stream, index.offset, self.size, Opcode.METADATA)[0]
                         for index in summary.metadata_indexes
                         if index.name == METADATA_NAME]
        wanted = _map_names(self.metadata)
        self._attachments = [
            (record.name, record.data) for index in summary.attachment_indexes
            if index.name in wanted and index.data_size <= MAX_MAP_ATTACHMENT
            for record in _read_record(stream, index.offset, self.size, Opcode.ATTACHMENT)]
        self.compressions = {index.compression for index in summary.chunk_indexes}
        self.chunk_count = len(summary.chunk_indexes)
        self._chunk_indexes = list(summary.chunk_indexes)
        stats = summary.statistics
        self._counts = dict(stats.channel_message_counts)
        self.start_ns = stats.message_start_time if stats.message_count else None
        self.end_ns = stats.message_end_time if stats.message_count else None

    def _read_scanned(self, stream):
        scan = Scan(stream, self.size)
        self.header = None
        self.has_summary = False
        self.schemas, self.channels, self.metadata = {}, {}, []
        self._attachments = []  # (name, bytes) of the attachments that may be map files
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
            elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                self.metadata.append(record)
            elif isinstance(record, Attachment) and len(record.data) <= MAX_MAP_ATTACHMENT:
                self._attachments.append((record.name, record.data))
            elif isinstance(record, Header):
                self.header = record
        if scan.corrupt:
            raise RecordingError(f'{scan.problem} (ball_world_repair keeps the records '
                                 'before it)')
        if self.header is None:
            raise RecordingError('no MCAP header record')
        self.problem = scan.problem or ('its data ends properly but its summary is missing '
                                        'or damaged')
        self.complete_bytes = scan.end

    # Messages -------------------------------------------------------------------------

    def _channel_ids(self, topics):
        if topics is None:
            return None
        return {channel_id for channel_id, channel in self.channels.items()
                if channel.topic in topics}

    def messages(self, topics=None):
        """RecordedMessages in log-time order (file order for a file without summary)."""
        wanted = self._channel_ids(None if topics is None else set(topics))
        with open_regular(self.path) as stream:
            if self.has_summary:
                records = self._indexed_messages(stream, wanted)
            else:
                records = (record for record in Scan(stream, self.size).records()
                           if isinstance(record, Message))
            for record in records:
                if wanted is None or record.channel_id in wanted:
                    yield self._message(record)

    def _chunks(self, wanted):
        """The chunk indexes that may hold messages of the wanted channels."""
        return [index for index in self._chunk_indexes
                if wanted is None or not index.message_index_offsets
                or not wanted.isdisjoint(index.message_index_offsets)]

    def _chunk_messages(self, stream, index, wanted):
        records = _read_record(stream, index.chunk_start_offset, self.size, Opcode.CHUNK)
        return [record for record in records[1:] if isinstance(record, Message)
                and (wanted is None or record.channel_id in wanted)]

    def _indexed_messages(self, stream, wanted):
        """Messages of the chunks in log-time order (file order among equal times).

        Chunks are opened in order of their first log time, and only once every message
        already read is later than that time, so at most the overlapping chunks are held.
        """
        chunks = sorted(self._chunks(wanted),
                        key=lambda index: (index.message_start_time, index.chunk_start_offset))
        pending = []
        order = 0
        position = 0
        while position < len(chunks) or pending:
            while position < len(chunks) and (
                    not pending or chunks[position].message_start_time <= pending[0][0]):
                for record in self._chunk_messages(stream, chunks[position], wanted):
                    heapq.heappush(pending, (record.log_time, order, record))
                    order += 1
                position += 1
            yield heapq.heappop(pending)[2]

    def last_message(self, topic):
        """The last message on a topic, or None (reads only the last chunk when indexed)."""
        if not self.has_summary:
            last = None
            for last in self.messages([topic]):
                pass
            return last
        wanted = self._channel_ids({topic})
        best = None
        with open_regular(self.path) as stream:
            for index in sorted(self._chunks(wanted), key=lambda i: i.message_end_time,
                                reverse=True):
                if best is not None and index.message_end_time < best.log_time:
                    break
                for record in self._chunk_messages(stream, index, wanted):
                    if best is None or record.log_time >= best.log_time:
                        best = record
        return None if best is None else self._message(best)

    def messages_at(self, times, topics):
        """{log time: [RecordedMessage]} of the messages on `topics` at any of `times`.

        Indexed, only the chunks spanning one of the times are read; without summary the
        file is scanned once for all of them.
        """
        times = set(times)
        wanted = self._channel_ids(set(topics))
        found = {}
        if not self.has_summary:
            for message in self.messages(topics):
                if message.log_time_ns in times:
                    found.setdefault(message.log_time_ns, []).append(message)
            return found
        with open_regular(self.path) as stream:
            for index in self._chunks(wanted):
                if not any(index.message_start_time <= t <= index.message_end_time
                           for t in times):
                    continue
                for record in self._chunk_messages(stream, index, wanted):
                    if record.log_time in times:
                        found.setdefault(record.log_time, []).append(self._message(record))
        return found

    def _message(self, record):
        channel = self.channels.get(record.channel_id)
        if channel is None:
            raise RecordingError(f'a message on channel {record.channel_id}, '
                                 'which the file never declares')
        schema = self.schemas.get(channel.schema_id)
        return RecordedMessage(topic=channel.topic, type=schema.name if schema else '',
                               log_time_ns=record.log_time,
                               publish_time_ns=record.publish_time,
                               sequence=record.sequence, data=record.data)

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
            raise RecordingError(f'a message at log time {log_time_ns} ns comes '
                                 'before the first segment')
        return position

    def edits(self):
        """(segment position, step, AppliedEdit) of every recorded edit, in order.

        Each is checked as steps() checks it, but only the impulse and edit topics are
        read: counting edits decodes no poses.
        """
        topics = {topic: role for topic, role in self.roles.items() if role in EVENT_ROLES}
        builder = None
        for message in self.messages(topics):
            if builder is None or message.log_time_ns != builder.log_time_ns:
                if builder is not None:
                    yield from builder.edits()
                position = self.segment_at(message.log_time_ns)
                builder = _StepBuilder(position, self.segments[position], message.log_time_ns)
            builder.add(topics[message.topic], message.data)
        if builder is not None:
            yield from builder.edits()

    def steps(self, agent_messages=False):
        """RecordedSteps in order: every log time of the ball_world topics, decoded.

        agent_messages: also the agents' scans, ground truth and bumpers of each step
        (RecordedStep.agent_messages), for the sinks that draw them.
        """
        builder = None
        agents = self.agent_roles
        extra = self.agent_message_roles if agent_messages else {}
        for message in self.messages({**self.roles, **agents, **extra}):
            if builder is None or message.log_time_ns != builder.log_time_ns:
                if builder is not None:
                    yield builder.build()
                position = self.segment_at(message.log_time_ns)
                builder = _StepBuilder(position, self.segments[position], message.log_time_ns,
                                       agent_messages)
            if message.topic in agents:
                builder.add_agent(agents[message.topic], message.data)
            elif message.topic in extra:
                builder.agent_messages[extra[message.topic]] = message.data
            else:
                builder.add(self.roles[message.topic], message.data)
        if builder is not None:
            yield builder.build()


class _StepBuilder:
    def __init__(self, position, segment, log_time_ns, agent_messages=False):
        self.position = position
        self.segment = segment
        self.log_time_ns = log_time_ns
        self.data = {}
        self.events = {role: [] for role in EVENT_ROLES}
        self.commands = []
        self.command_rows = None  # a swarm's commands: the bytes of agent_commands
        self.drives = {}  # agent name -> the bytes of its drive's impulse
        self.odom = None
        self.tf = None
        self.agent_messages = {} if agent_messages else None

    def add_agent(self, role, data):
        """A message of an agent topic: role is (kind, agent name, type name)."""
        kind, name, type_name = role
        if kind == agent_topics.COMMAND:
            self.commands.append((name, type_name, data))
        elif kind == agent_topics.COMMANDS:
            self.command_rows = data
        elif kind == agent_topics.DRIVE:
            self.drives[name] = data
        elif kind == agent_topics.ODOM:
            self.odom = self.odom or {}
            self.odom[name] = data
        else:
            self.tf = data

    def add(self, role, data):
        if role in self.events:
            self.events[role].append(data)
        else:
            self.data[role] = data

    @property
    def step(self):
        return (self.log_time_ns - self.segment.log_offset_ns) // self.segment.dt_ns

    def _edits(self, impulse_count):
        try:
            return parse_edits(self.events['edits'], impulse_count)
        except RecordingError as error:
            raise RecordingError(f'segment {self.segment.index} step {self.step}: recorded '
                                 f'{error}') from None

    def edits(self):
        """(segment position, step, AppliedEdit) of this log time's edits."""
        if not self.events['edits']:
            return []
        step = self.step
        return [(self.position, step, edit)
                for edit in self._edits(len(self.events['impulse']))]

    def build(self):
        stamp_ns = self.log_time_ns - self.segment.log_offset_ns
        positions = state = stats = balls_stamp = None
        try:
            if 'balls' in self.data:
                balls_stamp, _, positions = decode_pose_array(self.data['balls'])
            if 'state' in self.data:
                state = decode_state(self.data['state'])
            if 'stats' in self.data:
                stats = decode_stats(self.data['stats'])
            impulses = tuple(RecordedImpulse(*decode_vector3_stamped(cdr), cdr=cdr)
                             for cdr in self.events['impulse'])
            commands = tuple((name, *agent_topics.decode_command(data, type_name), data)
                             for name, type_name, data in self.commands)
            command_rows = (None if self.command_rows is None
                            else decode_command_rows(self.command_rows))
        except ValueError as error:
            raise RecordingError(f'undecodable message at log time {self.log_time_ns} ns: '
                                 f'{error}') from None
        if positions is not None and state is not None and len(positions) != len(state):
            raise RecordingError(f'at log time {self.log_time_ns} ns balls has '
                                 f'{len(positions)} poses but state {len(state)} rows')
        edits = self._edits(len(impulses))
        if self.drives:
            impulses = self._drives_marked(impulses, edits)
        return RecordedStep(
            segment=self.position, step=self.step, stamp_ns=stamp_ns,
            log_time_ns=self.log_time_ns, positions=positions, state=state, stats=stats,
            impulses=impulses, balls_cdr=self.data.get('balls'),
            state_cdr=self.data.get('state'), stats_cdr=self.data.get('stats'),
            balls_stamp_ns=balls_stamp, edits=edits, commands=commands,
            odom=self.odom, tf_cdr=self.tf, agent_messages=self.agent_messages,
            command_rows=command_rows)

    def _drives_marked(self, impulses, edits):
        """The impulses with the drives' marked (RecordedImpulse.drive).

        The node applies a step's drive impulses together, right after the impulses its
        edits applied (the last edit's impulses_before) and before the pushes queued since:
        that block must be exactly the impulses recorded on the agents' drive topics, one
        per agent, byte for byte, or the file was not written by the node.
        """
        first = edits[-1].impulses_before if edits else 0
        block = impulses[first:first + len(self.drives)]
        if len(block) != len(self.drives) or any(
                self.drives.get(impulse.frame_id) != impulse.cdr for impulse in block):
            raise RecordingError(
                f'segment {self.segment.index} step {self.step}: the drive impulses of '
                f"{', '.join(sorted(map(_text, self.drives)))} are not the step's impulses "
                f'{first} to {first + len(self.drives) - 1} as applied')
        return (impulses[:first]
                + tuple(dataclasses.replace(impulse, drive=True) for impulse in block)
                + impulses[first + len(block):])


# Feeding sinks -------------------------------------------------------------------------

def segment_world(segment):
    """The World a segment's parameters (and recorded map) build (raises ScenarioError)."""
    return build_world(segment.parameters, segment.occupancy_map)


def snapshot_and_info(segment, first_step=None):
    """The WorldSnapshot and RunInfo the node gave its sinks when the segment began.

    Radii, masses and walls come from rebuilding the world; the step-0 positions and
    velocities are the recorded ones when step 0 was recorded. A first step whose ball
    count the parameters cannot give is refused before the world is built.
    """
    if first_step is not None and first_step.ball_count is not None:
        segment.check_ball_count(first_step.ball_count)
    world = segment_world(segment)
    positions = world.positions.copy()
    velocities = world.velocities.copy()
    radii, masses = world.radii.copy(), world.masses.copy()
    names = tuple(f'ball_{i}' for i in range(len(world)))
    if segment.resume is not None:  # a split file: the balls at the step it continues
        resume = segment.resume
        positions, velocities = resume.positions.copy(), resume.velocities.copy()
        radii, masses, names = resume.radii.copy(), resume.masses.copy(), resume.names
    elif first_step is not None and first_step.step == 0 and first_step.complete:
        positions = first_step.positions.copy()
        velocities = first_step.state[:, 2:4].copy()
    snapshot = WorldSnapshot(radii=radii, masses=masses,
                             walls=world.walls.segments.copy(), positions=positions,
                             velocities=velocities, dt_ns=segment.dt_ns,
                             frame_id=segment.frame_id, names=names,
                             occupancy_map=segment.occupancy_map, map_cdr=segment.map_cdr())
    info = RunInfo(parameters=dict(segment.parameters), topics=dict(segment.topics),
                   segment=segment.index, log_offset_ns=segment.log_offset_ns,
                   package_version=segment.package_version)
    return snapshot, info


class BallRoster:
    """The balls of one segment as its recorded edits change them: names, radii, masses.

    It starts from the segment's WorldSnapshot and applies every step's edits in the order
    the node applied them, between that step's impulses, so each impulse finds its ball by
    name where it was when it was applied (AppliedImpulse.ball, as the node recorded it).
    The recording is untrusted: an edit that the node could not have applied (a spawn
    under a name the segment already used, a deletion or state set of a ball that is not
    there, more than limits.MAX_BALLS balls) or an impulse for a ball that is not there is
    a RecordingError. names, radii and masses are new objects only after a spawn or a
    deletion, as the node hands them on; `changed` says so until a record takes it.
    """

    def __init__(self, snapshot, segment_index):
        self.segment_index = segment_index
        self.names = tuple(snapshot.names)
        self.radii = snapshot.radii
        self.masses = snapshot.masses
        self.changed = False
        self._index_of = None  # name -> index, built when first needed
        self._used = None  # every name the segment has given, deleted ones included
        self._lists = None  # (names, radii, masses) as lists while a step edits them

    def __len__(self):
        return len(self.names)

    def follow(self, step):
        """Apply the step's edits; returns its impulses as AppliedImpulses."""
        if not step.edits and not step.impulses:
            return ()
        where = f'segment {self.segment_index} step {step.step}'
        if self._index_of is None:
            self._index_of = {name: i for i, name in enumerate(self.names)}
            self._used = set(self.names)
        edits = step.edits
        done = 0
        impulses = []
        for position, impulse in enumerate(step.impulses):
            while done < len(edits) and edits[done].impulses_before <= position:
                self._apply(edits[done], where)
                done += 1
            ball = self._index_of.get(impulse.frame_id)
            if ball is None:
                raise RecordingError(f'{where}: a recorded impulse is for '
                                     f'{_text(impulse.frame_id)}, which is no ball then')
            impulses.append(AppliedImpulse(ball=ball, jx=impulse.x, jy=impulse.y,
                                           frame_id=impulse.frame_id, cdr=impulse.cdr,
                                           drive=impulse.drive))
        for edit in edits[done:]:
            self._apply(edit, where)
        if self._lists is not None:
            names, radii, masses = self._lists
            self.names = tuple(names)
            self.radii = np.array(radii, dtype=np.float64)
            self.masses = np.array(masses, dtype=np.float64)
            self._lists = None
            self.changed = True
        return tuple(impulses)

    def take_changed(self):
        """Whether the balls changed since the last call (a record's world_changed)."""
        changed, self.changed = self.changed, False
        return changed

    def _apply(self, edit, where):
        name = edit.name
        index_of = self._index_of
        if edit.kind == 'set_state':
            if name not in index_of:
                raise RecordingError(f"{where}: a recorded edit sets the state of '{name}', "
                                     'which is no ball then')
            return
        if self._lists is None:
            self._lists = (list(self.names), self.radii.tolist(), self.masses.tolist())
        names, radii, masses = self._lists
        if edit.kind == 'spawn':
            if name in self._used:
                raise RecordingError(f"{where}: a recorded edit spawns '{name}', a name its "
                                     'segment already used')
            if len(names) >= limits.MAX_BALLS:
                raise RecordingError(f'{where}: a recorded spawn would make more than '
                                     f'{limits.MAX_BALLS:,} balls')
            index_of[name] = len(names)
            self._used.add(name)
            names.append(name)
            radii.append(edit.radius)
            masses.append(edit.mass)
            return
        index = index_of.pop(name, None)
        if index is None:
            raise RecordingError(f"{where}: a recorded edit deletes '{name}', which is no "
                                 'ball then')
        for values in (names, radii, masses):
            del values[index]
        for position in range(index, len(names)):
            index_of[names[position]] = position


def _count(step, name):
    """A collision count from a step's stats: a whole number, or RecordingError."""
    value = step.stat(name)
    if not (math.isfinite(value) and value >= 0 and value.is_integer()):
        raise RecordingError(f'step {step.step}: stats {name} is {value}, not a count')
    return int(value)


def step_record(step, impulses, roster, swarm=None):
    """The StepRecord the node wrote for a complete RecordedStep.

    impulses: what roster.follow(step) returned; the roster then holds the step's balls.
    swarm: the segment's agent_topics.SwarmAgents when its agents are a swarm (their
    headings come from `balls`), having followed the step's edits.
    """
    rtf = step.stat('real_time_factor')
    try:
        if swarm is not None:
            agents = swarm.frame(step.balls_cdr, roster.names)
        else:
            agents = agent_topics.recorded_frame(step.odom, roster.names,
                                                 step.agent_messages)
    except ValueError as error:
        raise RecordingError(f'step {step.step}: an agent message does not decode: '
                             f'{error}') from None
    return StepRecord(
        step=step.step, stamp_ns=step.stamp_ns, log_time_ns=step.log_time_ns,
        positions=step.positions.copy(), velocities=step.state[:, 2:4].copy(),
        ball_ball=_count(step, 'ball_ball'), ball_wall=_count(step, 'ball_wall'),
        kinetic_energy=step.stat('kinetic_energy'),
        momentum=np.array([step.stat('momentum_x'), step.stat('momentum_y')]),
        balls_cdr=step.balls_cdr, state_cdr=step.state_cdr, stats_cdr=step.stats_cdr,
        impulses=impulses, real_time_factor=None if math.isnan(rtf) else rtf,
        edits=step.edits, names=roster.names, radii=roster.radii, masses=roster.masses,
        world_changed=roster.take_changed(), agents=agents)


def _ignore(events):
    """write_pending of a sink that does not record edits."""


def _swarm(info, snapshot):
    """The SwarmAgents of a segment whose agents are a swarm (agent.topics none), else
    None."""
    if not agent_topics.swarm(info.parameters):
        return None
    return agent_topics.SwarmAgents(info.parameters, snapshot.names)


def _remade_drives(segment, snapshot):
    """The RemadeDrives of a segment whose drives are not recorded, else None."""
    if segment.drives_recorded:
        return None
    try:
        return RemadeDrives(segment.parameters, snapshot, segment.dt_ns, segment.resume)
    except ParameterError as error:
        raise RecordingError(f'segment {segment.index}: {error}') from None


def feed_sinks(path, sinks, close=True, passed_over=None):
    """Replay a recording into Sinks as the node would have: returns the steps fed.

    Each segment starts with start_segment(WorldSnapshot, RunInfo), then every complete
    step goes to write_step in order (a step cut off by a crash is skipped, but its edits
    still count), and a closing record to write_pending, for the sinks that take it. The
    sinks are flushed at the end, and closed unless close=False.

    A segment that jumps over steps (a damaged chunk dropped by ball_world_repair) cannot
    be followed past the jump: the balls' names, sizes and masses there are not known. Its
    steps are passed over up to the next segment, or the next state a split file resumes
    from (recording_set.RecordingSet), and said in `passed_over` (a list, if given) as
    (segment index, first step, last step).
    """
    recording = Recording(path) if isinstance(path, (str, os.PathLike)) else path
    current = started = None  # segment positions: followed, and begun in the sinks
    roster = snapshot = info = swarm = drives = None
    fed = 0
    last = skipping = None  # the last step followed; the steps being passed over
    for step in recording.steps(agent_messages=True):
        if step.segment != current:
            segment = recording.segments[step.segment]
            snapshot, info = snapshot_and_info(segment, step)
            roster = BallRoster(snapshot, segment.index)
            swarm = _swarm(info, snapshot)
            drives = _remade_drives(segment, snapshot)
            current = step.segment
            last = skipping = None
        elif skipping is not None:
            segment = recording.segments[current]
            point = getattr(recording, 'resume_points', {}).get(
                (segment.index, segment.log_offset_ns, step.step - 1))
            if point is None:
                skipping[2] = max(skipping[2], step.step)
                continue
            # a later file of a set picks the segment up here: on from its state
            snapshot, info = snapshot_and_info(point, step)
            roster = BallRoster(snapshot, point.index)
            swarm = _swarm(info, snapshot)
            drives = _remade_drives(point, snapshot)
            started = skipping = None
        elif last is not None and step.step > last + 1 and not step.closing:
            skipping = [recording.segments[current].index, step.step, step.step]
            if passed_over is not None:
                passed_over.append(skipping)
            continue
        impulses = roster.follow(step)
        if swarm is not None:
            swarm.follow(step.edits)
        if drives is not None and not step.closing:
            impulses = drives.follow(step, impulses, roster)
        if not step.closing:
            last = step.step
        if step.closing and started == current:
            events = PendingEvents(step=step.step, stamp_ns=step.stamp_ns,
                                   log_time_ns=step.log_time_ns, impulses=impulses,
                                   edits=step.edits)
            for sink in sinks:
                getattr(sink, 'write_pending', _ignore)(events)
        if not step.complete:
            continue
        if started != current:
            for sink in sinks:
                sink.start_segment(snapshot, info)
            started = current
        if len(step.positions) != len(roster):
            raise RecordingError(f'step {step.step} of segment '
                                 f'{recording.segments[current].index} has '
                                 f'{len(step.positions)} balls, not {len(roster)}')
        record = step_record(step, impulses, roster, swarm)
        for sink in sinks:
            sink.write_step(record)
        fed += 1
    for sink in sinks:
        sink.flush()
        if close:
            sink.close()
    return fed
