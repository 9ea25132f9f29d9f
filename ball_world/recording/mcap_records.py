"""An MCAP file's records (https://mcap.dev/spec) written by hand, a batch of messages at once.

Why not the `mcap` package's Writer: it makes every message an object and writes its fields
one by one through a BytesIO, about 9 us a message in Python; 1,000 robots with their own
topics record 30,000 messages a second, on a writer thread that shares the GIL with the
stepping one (docs/performance.md). Here the messages of one log time are one call: a few
numpy operations make all their record headers (sequence numbers included) and their message
index entries, and the batch becomes one byte string that is CRC'd and compressed into the
open chunk at once (ChunkBody); a chunk's message indexes are made from its entries as
arrays when it is closed. The Python work per message is a few list items.

What a file holds is what the `mcap` package's Writer (1.6, as McapSink used it) wrote, record
for record: the magic and the Header; Schema and Channel records inside the open chunk, ahead
of the batch that first needs them; Chunks (lz4, zstd or uncompressed, each with the CRC of
its records) closed only when the caller says so, each followed by one MessageIndex per
channel in it; Metadata and Attachment records (with their CRC) between chunks; DataEnd (no
data section CRC); then the summary: every Schema and Channel, the Statistics, the
ChunkIndexes, AttachmentIndexes and MetadataIndexes, one SummaryOffset per group; the Footer
with the summary's CRC; the magic. What may differ in bytes, never in what a reader gets: a
chunk's message indexes and the Statistics' counts go in channel order (the Writer's: first
message order); a chunk's uncompressed size counts its schemas and channels too, so a chunk
may be cut a step apart from where the Writer's was; an lz4 chunk is a frame of independent
64 kB blocks without its content size (the Writer's: linked blocks, the size stated), which
every lz4 reader takes and which compresses as small in about a third less time here.

Compression, zlib's CRC and the file writes release the GIL on buffers this size (lz4's frame
compress around LZ4F_compressUpdate, zstandard's C extension, zlib.crc32 past 5 kB), so on the
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
#: Compressions of the chunks, and how each is named in a Chunk record.
COMPRESSIONS = {'zstd': 'zstd', 'lz4': 'lz4', 'none': ''}
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
#: One entry of a map<uint16, uint64>: a ChunkIndex's (channel, offset of its MessageIndex),
#: the Statistics' (channel, messages). A MessageIndex's entries are two uint64 each.
_CHANNEL_VALUE = np.dtype([('channel', '<u2'), ('value', '<u8')])
#: A Channel record up to its topic: opcode, length, id, schema id, the topic's length.
_CHANNEL_HEAD = struct.Struct('<BQHHI')
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


def _runs(ranked):
    """Where each run of equal values of a sorted array starts, and its length."""
    first = np.flatnonzero(ranked[1:] != ranked[:-1]) + 1
    first = np.concatenate((np.zeros(1, dtype=first.dtype), first))
    return first, np.diff(np.append(first, len(ranked)))


class ChunkBody:
    """The records of the open chunk, compressed as they come.

    A batch's records arrive as one byte string while they are still in the CPU's cache: its
    CRC is carried on, and lz4 compresses it into the chunk's frame at once (a frame
    without its content size, which lz4's readers do not need). zstd compresses the whole
    chunk when it is closed, so its frame states its size, as the Writer's did (a reader
    may size its output from it); 'none' keeps the byte strings. Either way no chunk is
    ever joined from thousands of pieces: that took about 5 ms a 4 MiB chunk, more than
    compressing it.
    """

    def __init__(self, compression):
        self.compression = compression
        self.size = 0  # uncompressed bytes
        self.crc = 0
        self._compressor = None
        self._out = []  # compressed pieces (lz4) or the byte strings as given

    def add(self, data):
        self.size += len(data)
        self.crc = zlib.crc32(data, self.crc)
        if self.compression == 'lz4':
            if self._compressor is None:
                self._compressor = lz4.frame.LZ4FrameCompressor(block_linked=False)
                self._out.append(self._compressor.begin())
            self._out.append(self._compressor.compress(data))
        else:
            self._out.append(data)

    def finish(self):
        """The compressed bytes, as pieces to write in order."""
        if self.compression == 'lz4':
            if self._compressor is None:
                return [lz4.frame.compress(b'')]
            return self._out + [self._compressor.flush()]
        if self.compression == 'zstd':
            return [zstandard.compress(b''.join(self._out))]
        return self._out


class McapRecords:
    """Writes one MCAP file to a binary stream (the records listed in the module docstring).

    start() first, finish() last; in between, schema() and channel() give ids, messages()
    adds a batch of messages at one log time to the open chunk, flush() closes the chunk and
    hands everything to the stream's OS file, metadata() and attachment() write their
    record at once (the caller closes the chunk first when order matters).
    """

    def __init__(self, stream, compression='lz4'):
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}, got "
                             f'{compression!r}')
        self._stream = stream
        self.compression = compression
        self._compression = text(COMPRESSIONS[compression])
        self._position = 0  # bytes handed to the stream
        self._schemas = []  # Schema records, id order
        self._channels = []  # Channel records, id order
        self._tails = {}  # a channel's encoding and metadata -> their bytes
        self._counts = np.zeros(256, dtype=np.int64)  # messages of each channel id
        self._marks = np.zeros_like(self._counts)  # scratch of _sequences
        self.message_count = 0
        self.start_time = None  # smallest and largest log time of a message
        self.end_time = None
        self._chunk_count = 0
        self._loose = []  # records for the open chunk not yet in its body (schemas, channels)
        self._loose_size = 0
        self._chunk_indexes = []
        self._attachment_indexes = []
        self._metadata_indexes = []
        self._new_chunk()

    def _new_chunk(self):
        self._body = ChunkBody(self.compression)
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
        return self._body.size + self._loose_size

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
        # The encoding and metadata are the same few for thousands of robots' topics.
        key = (message_encoding, *metadata.items())
        tail = self._tails.get(key)
        if tail is None:
            tail = self._tails[key] = text(message_encoding) + string_map(metadata)
        name = topic.encode('utf-8')
        channel = _CHANNEL_HEAD.pack(Opcode.CHANNEL, 8 + len(name) + len(tail), channel_id,
                                     schema_id, len(name)) + name + tail
        self._channels.append(channel)
        self._add_part(channel)
        if channel_id >= len(self._counts):
            self._counts = np.concatenate([self._counts, np.zeros_like(self._counts)])
            self._marks = np.zeros_like(self._counts)
        return channel_id

    def _add_part(self, data):
        """A schema or channel record: it goes into the chunk with the next batch."""
        self._loose.append(data)
        self._loose_size += len(data)

    def messages(self, log_time, channels, datas):
        """Messages at one log time (also their publish time) into the open chunk, in order.

        channels: the channel id of each (from channel()); datas: their bytes (bytes-like, a
        byte an item: anything else is refused before it is written). Each message's sequence
        is its channel's count in this file, modulo 2**32, as the node's publishers number
        them from 1.
        """
        count = len(datas)
        if not count:
            return
        if len(channels) != count:
            raise ValueError(f'{len(channels)} channels for {count} messages')
        ids = np.array(channels, dtype=np.int64)
        if ids.min() < 1 or ids.max() > len(self._channels):
            raise ValueError('a message names a channel that was not made')
        lengths = np.array(list(map(len, datas)), dtype=np.int64)
        heads = np.empty(count, dtype=_MESSAGE)
        heads['opcode'] = Opcode.MESSAGE
        heads['length'] = lengths + (MESSAGE_HEAD - 9)
        heads['channel'] = ids
        counts = self._counts[ids]
        heads['sequence'] = (self._sequences(ids) % _SEQUENCE_MODULO).astype(np.uint32)
        heads['log_time'] = log_time
        heads['publish_time'] = log_time
        sizes = lengths + MESSAGE_HEAD
        parts = [None] * (2 * count)
        parts[0::2] = heads.view(f'V{MESSAGE_HEAD}').tolist()
        parts[1::2] = datas
        batch = b''.join(self._loose + parts)
        if len(batch) != self._loose_size + int(sizes.sum()):  # len() was not their bytes
            self._counts[ids] = counts
            raise ValueError('message data must be bytes, a byte an item')
        self._batches.append((ids, log_time, np.cumsum(sizes) - sizes + self.pending))
        self._loose, self._loose_size = [], 0
        self._body.add(batch)
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
        # Mostly each channel has one message in a batch: find out cheaply (each message
        # marks its channel with its place; a channel named twice keeps one mark).
        places = np.arange(len(ids))
        self._marks[ids] = places
        if (self._marks[ids] == places).all():
            sequences = self._counts[ids] + 1
            self._counts[ids] = sequences
            return sequences
        order = np.argsort(ids, kind='stable')
        ranked = ids[order]
        first, sizes = _runs(ranked)
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
        body = self._body
        if self._loose:
            body.add(b''.join(self._loose))
            self._loose, self._loose_size = [], 0
        pieces = body.finish()
        compressed = sum(map(len, pieces))
        head = (_CHUNK_TIMES.pack(self._chunk_start, self._chunk_end, body.size, body.crc)
                + self._compression + _U64.pack(compressed))
        chunk_start = self._position
        self._write(_RECORD.pack(Opcode.CHUNK, len(head) + compressed) + head)
        for piece in pieces:
            self._write(piece)
        chunk_length = self._position - chunk_start
        indexes, offsets = self._message_indexes(self._position)
        self._write(indexes)
        self._chunk_indexes.append(record(Opcode.CHUNK_INDEX, b''.join((
            _U64.pack(self._chunk_start), _U64.pack(self._chunk_end), _U64.pack(chunk_start),
            _U64.pack(chunk_length), _U32.pack(len(offsets)), offsets,
            _U64.pack(len(indexes)), self._compression, _U64.pack(compressed),
            _U64.pack(body.size)))))
        self._chunk_count += 1
        self._new_chunk()

    def _message_indexes(self, start):
        """The closing chunk's MessageIndex records (one per channel), which begin at file
        offset `start`, and the ChunkIndex's map of where each one is.

        Channels with as many messages in the chunk (most of them: every robot's odometry)
        have records of one size, made as one structured array; the records go by that size,
        then channel (the map says where each is; no reader needs an order).
        """
        ids = np.concatenate([batch[0] for batch in self._batches])
        times = np.repeat(np.array([batch[1] for batch in self._batches], dtype=np.uint64),
                          [len(batch[0]) for batch in self._batches])
        offsets = np.concatenate([batch[2] for batch in self._batches])
        # Each channel's messages in file order (ids fit 16 bits: numpy's radix sort).
        order = np.argsort(ids.astype(np.uint16), kind='stable')
        ranked = ids[order]
        first, sizes = _runs(ranked)
        entries = np.empty((len(ids), 2), dtype='<u8')  # (log time, offset), as bytes
        entries[:, 0] = times[order]
        entries[:, 1] = offsets[order]
        entries = entries.view('V16').reshape(-1)  # one item each: rows gather fast
        records, maps, at = [], [], start
        for size in np.flatnonzero(np.bincount(sizes)).tolist():
            chosen = first[sizes == size]
            heads = np.empty(len(chosen), dtype=_INDEX_HEAD)
            heads['opcode'] = Opcode.MESSAGE_INDEX
            heads['length'] = 6 + 16 * size
            heads['channel'] = ranked[chosen]
            heads['entries'] = 16 * size
            block = np.empty((len(chosen), _INDEX_HEAD.itemsize + 16 * size), dtype=np.uint8)
            block[:, :_INDEX_HEAD.itemsize] = heads.view(np.uint8).reshape(len(chosen), -1)
            block[:, _INDEX_HEAD.itemsize:] = entries[
                chosen[:, None] + np.arange(size)].view(np.uint8).reshape(len(chosen), -1)
            where = np.empty(len(chosen), dtype=_CHANNEL_VALUE)
            where['channel'] = ranked[chosen]
            where['value'] = at + block.shape[1] * np.arange(len(chosen))
            records.append(block.tobytes())
            maps.append(where.tobytes())
            at += block.nbytes
        return b''.join(records), b''.join(maps)

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
        table = np.empty(len(counts), dtype=_CHANNEL_VALUE)
        table['channel'] = counts
        table['value'] = self._counts[counts]
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
