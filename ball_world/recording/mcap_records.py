"""An MCAP file's records (https://mcap.dev/spec) written by hand, a batch of messages at once.

Why not the `mcap` package's Writer: it makes every message an object and writes its fields
one by one through a BytesIO, about 9 us a message in Python; 1,000 robots with their own
topics record 30,000 messages a second, on a writer thread that shares the GIL with the
stepping one (docs/performance.md). Here the messages of one log time are one call: a few
numpy operations make all their record headers (sequence numbers included) and their message
index entries, and the records wait as a list of byte strings until the chunk is closed; a
chunk's message indexes are made from its entries as arrays. The Python work per message is
a few list items.

What a file holds is what the `mcap` package's Writer (1.6, as McapSink used it) wrote, record
for record: the magic and the Header; Schema and Channel records inside the open chunk, ahead
of the first message that needs them; Chunks (lz4, zstd or uncompressed, each with the CRC of
its records) closed only when the caller says so, each followed by one MessageIndex per
channel in it; Metadata and Attachment records (with their CRC) between chunks; DataEnd (no
data section CRC); then the summary: every Schema and Channel, the Statistics, the
ChunkIndexes, AttachmentIndexes and MetadataIndexes, one SummaryOffset per group; the Footer
with the summary's CRC; the magic. Two things may differ in bytes, never in what a reader
gets: the message indexes of a chunk and the counts in the Statistics go in channel order
(the Writer's: first message order), and a chunk's uncompressed size is exact.

Compression, zlib's CRC and the file writes release the GIL on buffers this size (lz4's frame
compress around LZ4F_compressFrame, zstandard's C extension, zlib.crc32 past 5 kB), so on the
writer thread they run beside stepping. An OSError from the stream is not caught: the caller
(McapSink) makes it one line.
"""
import struct
import zlib

import lz4.frame
from mcap.opcode import Opcode
import numpy as np
import zstandard

MAGIC = b'\x89MCAP0\r\n'
#: Compressions of the chunks and how each is written in a Chunk record.
COMPRESSORS = {'zstd': zstandard.compress, 'lz4': lz4.frame.compress, 'none': None}
_COMPRESSION_NAMES = {'lz4': 'lz4', 'zstd': 'zstd', 'none': ''}
#: Channel and schema ids are uint16 in every record that names them; 0 means none.
MAX_ID = 0xFFFF
_SEQUENCE_MODULO = 2 ** 32  # a Message's sequence is a uint32

_RECORD = struct.Struct('<BQ')
_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')
#: A Message record up to its data: opcode, length, channel, sequence, log and publish time.
_MESSAGE = np.dtype([('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'),
                     ('sequence', '<u4'), ('log_time', '<u8'), ('publish_time', '<u8')])
MESSAGE_HEAD = _MESSAGE.itemsize  # 31 bytes
#: A MessageIndex record up to its entries: opcode, length, channel, the entries' byte length.
_INDEX_HEAD = np.dtype([('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'),
                        ('entries', '<u4')])
#: One (log time, offset) entry of a MessageIndex; one (channel, offset) of a ChunkIndex's map.
_INDEX_ENTRY = np.dtype([('log_time', '<u8'), ('offset', '<u8')])
_CHANNEL_OFFSET = np.dtype([('channel', '<u2'), ('offset', '<u8')])
_CHUNK_TIMES = struct.Struct('<QQQI')  # start, end, uncompressed size, uncompressed CRC
_STATISTICS = struct.Struct('<QHIIIIQQ')


def text(value):
    """A string field: uint32 byte length and UTF-8."""
    data = value.encode('utf-8')
    return _U32.pack(len(data)) + data


def string_map(values):
    """A map<string, string> field: uint32 byte length and key, value strings in order."""
    data = b''.join(text(key) + text(value) for key, value in values.items())
    return _U32.pack(len(data)) + data


def record(opcode, body):
    """A whole record: opcode, uint64 length of the body, the body."""
    return _RECORD.pack(opcode, len(body)) + body


class McapRecords:
    """Writes one MCAP file to a binary stream (the records listed in the module docstring).

    start() first, finish() last; in between, schema() and channel() give ids, messages()
    adds a batch of messages at one log time to the open chunk, flush() closes the chunk and
    hands everything to the stream's OS file, metadata() and attachment() write their
    record at once (the caller closes the chunk first when order matters).
    """

    def __init__(self, stream, compression='lz4'):
        if compression not in COMPRESSORS:
            raise ValueError(f"compression must be one of {', '.join(COMPRESSORS)}, got "
                             f'{compression!r}')
        self._stream = stream
        self._compress = COMPRESSORS[compression]
        self._compression = text(_COMPRESSION_NAMES[compression])
        self._position = 0  # bytes handed to the stream
        self._schemas = []  # Schema records, id order
        self._channels = []  # Channel records, id order
        self._counts = np.zeros(256, dtype=np.int64)  # messages of each channel id
        self.message_count = 0
        self.start_time = None  # smallest and largest log time of a message
        self.end_time = None
        self._chunk_count = 0
        self._chunk_indexes = []
        self._attachment_indexes = []
        self._metadata_indexes = []
        self._new_chunk()

    def _new_chunk(self):
        self._parts = []  # the open chunk's records
        self._size = 0  # their bytes
        self._batches = []  # (channels, log time, offsets) of each batch in the chunk
        self._chunk_start = None
        self._chunk_end = None

    @property
    def position(self):
        """Bytes handed to the stream so far."""
        return self._position

    @property
    def pending(self):
        """Bytes of records in the open chunk (uncompressed)."""
        return self._size

    def counts(self):
        """{channel id: messages} of every channel that has any."""
        channels = np.flatnonzero(self._counts)
        return dict(zip(channels.tolist(), self._counts[channels].tolist()))

    def _write(self, data):
        self._stream.write(data)
        self._position += len(data)

    def start(self, profile, library):
        self._write(MAGIC)
        self._write(record(Opcode.HEADER, text(profile) + text(library)))

    def schema(self, name, encoding, data):
        """A new schema's id; its record goes into the open chunk."""
        schema_id = len(self._schemas) + 1
        if schema_id > MAX_ID:
            raise ValueError(f'an MCAP file holds at most {MAX_ID:,} schemas')
        body = _U16.pack(schema_id) + text(name) + text(encoding) + _U32.pack(len(data)) + data
        self._schemas.append(record(Opcode.SCHEMA, body))
        self._add_part(self._schemas[-1])
        return schema_id

    def channel(self, topic, message_encoding, schema_id, metadata):
        """A new channel's id; its record goes into the open chunk."""
        channel_id = len(self._channels) + 1
        if channel_id > MAX_ID:
            raise ValueError(f'an MCAP file holds at most {MAX_ID:,} channels')
        body = (_U16.pack(channel_id) + _U16.pack(schema_id) + text(topic)
                + text(message_encoding) + string_map(metadata))
        self._channels.append(record(Opcode.CHANNEL, body))
        self._add_part(self._channels[-1])
        if channel_id >= len(self._counts):
            self._counts = np.concatenate([self._counts, np.zeros_like(self._counts)])
        return channel_id

    def _add_part(self, data):
        self._parts.append(data)
        self._size += len(data)

    def messages(self, log_time, channels, datas):
        """Messages at one log time (also their publish time) into the open chunk, in order.

        channels: the channel id of each (from channel()); datas: their bytes. Each message's
        sequence is its channel's count in this file, modulo 2**32, as the node's publishers
        number them from 1.
        """
        count = len(datas)
        if not count:
            return
        if len(channels) != count:
            raise ValueError(f'{len(channels)} channels for {count} messages')
        ids = np.array(channels, dtype=np.int64)
        if ids.min() < 1 or ids.max() > len(self._channels):
            raise ValueError('a message names a channel that was not made')
        lengths = np.fromiter(map(len, datas), dtype=np.int64, count=count)
        heads = np.empty(count, dtype=_MESSAGE)
        heads['opcode'] = Opcode.MESSAGE
        heads['length'] = lengths + (MESSAGE_HEAD - 9)
        heads['channel'] = ids
        heads['sequence'] = (self._sequences(ids) % _SEQUENCE_MODULO).astype(np.uint32)
        heads['log_time'] = log_time
        heads['publish_time'] = log_time
        ends = np.cumsum(lengths + MESSAGE_HEAD)
        self._batches.append((ids, log_time, ends - (lengths + MESSAGE_HEAD) + self._size))
        parts = [None] * (2 * count)
        parts[0::2] = heads.view(f'V{MESSAGE_HEAD}').tolist()
        parts[1::2] = datas
        self._parts += parts
        self._size += int(ends[-1])
        self.message_count += count
        if self._chunk_start is None:
            self._chunk_start = self._chunk_end = log_time
        else:
            self._chunk_start = min(self._chunk_start, log_time)
            self._chunk_end = max(self._chunk_end, log_time)
        if self.start_time is None:
            self.start_time = self.end_time = log_time
        else:
            self.start_time = min(self.start_time, log_time)
            self.end_time = max(self.end_time, log_time)

    def _sequences(self, ids):
        """Each message's sequence number before the modulo, and its channel counted."""
        if len(ids) == 1:
            self._counts[ids] += 1
            return self._counts[ids]
        order = np.argsort(ids, kind='stable')
        ranked = ids[order]
        first = np.flatnonzero(np.r_[True, ranked[1:] != ranked[:-1]])
        sizes = np.diff(np.r_[first, len(ids)])
        # A message's rank among its channel's in this batch, counted from 1.
        rank = np.empty(len(ids), dtype=np.int64)
        rank[order] = np.arange(1, len(ids) + 1) - np.repeat(first, sizes)
        sequences = self._counts[ids] + rank
        self._counts[ranked[first]] += sizes
        return sequences

    def flush(self):
        """Close the open chunk, if it holds a message, and flush the stream to the OS.

        A chunk of schemas and channels alone stays open: they go with the next message.
        """
        if self._batches:
            self._close_chunk()
        self._stream.flush()

    def _close_chunk(self):
        data = b''.join(self._parts)
        compressed = data if self._compress is None else self._compress(data)
        head = (_CHUNK_TIMES.pack(self._chunk_start, self._chunk_end, len(data),
                                  zlib.crc32(data))
                + self._compression + _U64.pack(len(compressed)))
        chunk_start = self._position
        self._write(_RECORD.pack(Opcode.CHUNK, len(head) + len(compressed)) + head)
        self._write(compressed)
        chunk_length = self._position - chunk_start
        indexes, offsets = self._message_indexes(self._position)
        self._write(indexes)
        self._chunk_indexes.append(record(Opcode.CHUNK_INDEX, b''.join((
            _U64.pack(self._chunk_start), _U64.pack(self._chunk_end), _U64.pack(chunk_start),
            _U64.pack(chunk_length), _U32.pack(len(offsets)), offsets,
            _U64.pack(len(indexes)), self._compression, _U64.pack(len(compressed)),
            _U64.pack(len(data))))))
        self._chunk_count += 1
        self._new_chunk()

    def _message_indexes(self, start):
        """The closing chunk's MessageIndex records (one per channel, channel order), which
        begin at file offset `start`, and the ChunkIndex's map of where each one is."""
        ids = np.concatenate([batch[0] for batch in self._batches])
        times = np.concatenate([np.full(len(batch[0]), batch[1], dtype=np.uint64)
                                for batch in self._batches])
        offsets = np.concatenate([batch[2] for batch in self._batches])
        order = np.argsort(ids, kind='stable')  # each channel's messages in file order
        ranked = ids[order]
        first = np.flatnonzero(np.r_[True, ranked[1:] != ranked[:-1]])
        sizes = np.diff(np.r_[first, len(ids)])
        entries = np.empty(len(ids), dtype=_INDEX_ENTRY)
        entries['log_time'] = times[order]
        entries['offset'] = offsets[order]
        heads = np.empty(len(first), dtype=_INDEX_HEAD)
        heads['opcode'] = Opcode.MESSAGE_INDEX
        heads['length'] = 6 + 16 * sizes
        heads['channel'] = ranked[first]
        heads['entries'] = 16 * sizes
        where = np.empty(len(first), dtype=_CHANNEL_OFFSET)
        where['channel'] = ranked[first]
        where['offset'] = start + _INDEX_HEAD.itemsize * np.arange(len(first)) + 16 * first
        entry_bytes = entries.tobytes()
        bounds = (16 * np.r_[first, len(ids)]).tolist()
        parts = [None] * (2 * len(first))
        parts[0::2] = heads.view(f'V{_INDEX_HEAD.itemsize}').tolist()
        parts[1::2] = [entry_bytes[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
        return b''.join(parts), where.tobytes()

    def metadata(self, name, values):
        """A Metadata record (values: {str: str}), at once."""
        data = record(Opcode.METADATA, text(name) + string_map(values))
        self._metadata_indexes.append(record(Opcode.METADATA_INDEX, b''.join((
            _U64.pack(self._position), _U64.pack(len(data)), text(name)))))
        self._write(data)

    def attachment(self, log_time, create_time, name, media_type, data):
        """An Attachment record with its CRC, at once."""
        body = (_U64.pack(log_time) + _U64.pack(create_time) + text(name) + text(media_type)
                + _U64.pack(len(data)) + bytes(data))
        whole = record(Opcode.ATTACHMENT, body + _U32.pack(zlib.crc32(body)))
        self._attachment_indexes.append(record(Opcode.ATTACHMENT_INDEX, b''.join((
            _U64.pack(self._position), _U64.pack(len(whole)), _U64.pack(log_time),
            _U64.pack(create_time), _U64.pack(len(data)), text(name), text(media_type)))))
        self._write(whole)

    def statistics(self):
        """The Statistics record of what was written."""
        counts = np.flatnonzero(self._counts)
        table = np.empty(len(counts), dtype=_CHANNEL_OFFSET)
        table['channel'] = counts
        table['offset'] = self._counts[counts]
        return record(Opcode.STATISTICS, _STATISTICS.pack(
            self.message_count, len(self._schemas), len(self._channels),
            len(self._attachment_indexes), len(self._metadata_indexes), self._chunk_count,
            self.start_time or 0, self.end_time or 0)
            + _U32.pack(table.nbytes) + table.tobytes())

    def finish(self):
        """Close the open chunk; write DataEnd, the summary, the Footer and the magic."""
        if self._batches:
            self._close_chunk()
        self._write(record(Opcode.DATA_END, _U32.pack(0)))
        summary_start = self._position
        groups = ((Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels),
                  (Opcode.STATISTICS, [self.statistics()]),
                  (Opcode.CHUNK_INDEX, self._chunk_indexes),
                  (Opcode.ATTACHMENT_INDEX, self._attachment_indexes),
                  (Opcode.METADATA_INDEX, self._metadata_indexes))
        summary, offsets, at = [], [], summary_start
        for opcode, records in groups:
            group = b''.join(records)
            summary.append(group)
            offsets.append(record(Opcode.SUMMARY_OFFSET, struct.pack('<BQQ', opcode, at,
                                                                     len(group))))
            at += len(group)
        summary += offsets
        data = b''.join(summary)
        footer = struct.pack('<BQQQ', Opcode.FOOTER, 20, summary_start, at)
        self._write(data)
        self._write(footer + _U32.pack(zlib.crc32(footer, zlib.crc32(data))))
        self._write(MAGIC)
        self._stream.flush()
