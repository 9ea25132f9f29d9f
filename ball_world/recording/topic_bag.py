"""A bag directory of any topics, as `ros2 bag record -s mcap` writes one: the MCAP writing of
`ball_world_cli record`, without ROS (the caller hands it CDR bytes and the graph's facts).

Why not McapSink: that sink writes the node's StepRecords (balls, state, stats, edits...);
a recording of arbitrary topics needs only what rosbag2 itself writes for each message.
What is shared with the node's recorder is everything that decides whether a file is
usable and safe: the directory is claimed by recording.bag.claim_directory (an existing one
refused unless overwrite, a symlink refused whatever it points to, locked while recorded),
the file is made in it by Folder.claim (never through a symlink), schemas are the complete
'ros2msg' texts and hashes rosbag2 writes (msgs.definitions), channels carry the offered QoS
in rosbag2's YAML (mcap_writer.offered_qos_profiles), and metadata.yaml is the node's own
(recording.bag.write_metadata, written through a temporary file and a rename).

Layout: `<dir>/metadata.yaml` beside `<dir>/<dir>_0.mcap` (recording.bag.file_name), one
file. Chunks are closed at each flush() (the caller flushes every second), so a recorder
killed with SIGKILL loses at most the last second, and `ball_world_repair` completes the
file; close() writes the summary, the footer and metadata.yaml.
"""
import os

from mcap.writer import CompressionType, Writer

from ball_world.msgs.definitions import message_definition, type_hash
from ball_world.recording.bag import (claim_directory, file_name, FileSummary, reserve_space,
                                      TopicCount, write_metadata)
from ball_world.recording.mcap_writer import LIBRARY, McapRecordingError, offered_qos_profiles

_SEQUENCE_MODULO = 2 ** 32  # MCAP message sequence numbers are uint32


def qos_yaml(profiles):
    """offered_qos_profiles of a topic as rosbag2 writes it: one entry per publisher.

    profiles: (depth, reliability, durability) of each publisher, words as rosbag2 spells
    them ('reliable', 'best_effort', 'volatile', 'transient_local').
    """
    return '\n'.join(offered_qos_profiles(depth, reliability, durability)
                     for depth, reliability, durability in profiles)


class TopicBag:
    """`<directory>/<name>_0.mcap` and `<directory>/metadata.yaml`, written as messages come.

    Raises recording.files.FileRefused (naming the path) when the directory may not be
    made: it exists (without overwrite; hint says how to allow it), is a symlink, or is
    being recorded by another process; McapRecordingError on a write error.
    """

    def __init__(self, directory, overwrite=False, hint='', compression=CompressionType.ZSTD):
        self.path = os.fspath(directory).rstrip('/') or os.fspath(directory)
        self._claim = claim_directory(self.path, overwrite, hint)
        self._file_claim = None
        try:
            reserve_space(self._claim.folder)
            self._file_claim = self._claim.folder.claim(file_name(self.path, 0))
            self.file_path = self._file_claim.path
            self._file = self._file_claim.writer()
            self._writer = Writer(self._file, chunk_size=2 ** 62, compression=compression)
            self._writer.start(profile='ros2', library=LIBRARY)
            self._file.flush()
        except OSError as error:
            self._give_up()
            raise _error(getattr(self, 'file_path', self.path), error) from error
        self._schemas = {}
        self._channels = {}  # channel id -> TopicCount fields (topic, type, qos, hash)
        self._counts = {}
        self._sequences = {}
        self._first_ns = self._end_ns = None
        self._closed = False

    @property
    def message_count(self):
        return sum(self._counts.values())

    def add_topic(self, topic, type_name, qos_profiles=(), topic_hash=''):
        """A channel for `topic` (its messages CDR of `type_name`): the id write() takes.

        Raises LookupError when the type's .msg definition is not installed (a reader could
        not decode the messages).
        """
        schema = self._schemas.get(type_name)
        if schema is None:
            definition = message_definition(type_name).encode('utf-8')
            schema = self._schemas[type_name] = self._writer.register_schema(
                type_name, 'ros2msg', definition)
        topic_hash = topic_hash or type_hash(type_name)
        qos = qos_yaml(qos_profiles)
        channel = self._writer.register_channel(
            topic, 'cdr', schema, metadata={'offered_qos_profiles': qos,
                                            'topic_type_hash': topic_hash})
        self._channels[channel] = (topic, type_name, qos, topic_hash)
        self._counts[channel] = 0
        return channel

    def write(self, channel, log_time_ns, publish_time_ns, data):
        """One message: its CDR bytes, received at log_time_ns, sent at publish_time_ns."""
        if self._closed:
            raise ValueError(f'{self.path}: the recording is closed')
        sequence = (self._sequences.get(channel, 0) + 1) % _SEQUENCE_MODULO
        self._sequences[channel] = sequence
        self._counts[channel] += 1
        if self._first_ns is None or log_time_ns < self._first_ns:
            self._first_ns = log_time_ns
        if self._end_ns is None or log_time_ns > self._end_ns:
            self._end_ns = log_time_ns
        self._guard(self._writer.add_message, channel, log_time=log_time_ns, data=data,
                    publish_time=publish_time_ns, sequence=sequence)

    def flush(self):
        """Close the open chunk and hand it to the system: what a SIGKILL cannot take."""
        if not self._closed:
            self._guard(self._writer.flush)

    def close(self):
        """Finish the file (summary, footer) and write metadata.yaml; again: nothing."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
            self._file_claim.release()
        except OSError as error:
            self._give_up()
            raise _error(self.file_path, error) from error
        topics = {}
        for channel, (topic, type_name, qos, topic_hash) in self._channels.items():
            topics[topic] = TopicCount(topic=topic, type=type_name,
                                       message_count=self._counts[channel],
                                       offered_qos_profiles=qos, type_hash=topic_hash)
        summary = FileSummary(path=self.file_path, start_ns=self._first_ns,
                              end_ns=self._end_ns, message_count=self.message_count,
                              topics=topics)
        try:
            write_metadata(self._claim.folder, [summary])
        except OSError as error:
            raise _error(os.path.join(self.path, 'metadata.yaml'), error) from error
        finally:
            self._claim.release()

    def discard(self):
        """Give up a recording that never began: its file goes, and its directory if this
        bag made it (nothing else in a reused directory is touched)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        except OSError:
            pass  # the file is removed anyway
        self._give_up()

    def _guard(self, action, *args, **options):
        try:
            action(*args, **options)
        except OSError as error:
            self._closed = True
            self._give_up(keep=True)
            raise _error(self.file_path, error) from error

    def _give_up(self, keep=False):
        """After an error: drop the claims; a directory that holds nothing yet is removed."""
        if self._file_claim is not None:
            if keep:
                self._file_claim.release()
            else:
                self._file_claim.discard()
        if keep:
            self._claim.release()
        else:
            self._claim.discard()


def _error(path, error):
    return McapRecordingError(error.errno, error.strerror or str(error), path)
