"""A bag directory of split MCAP files read as one recording, with the interface of Recording.

Why: the tools (info, resim, replay, to_rrd) take a path and read a Recording; a split run
(recording.split_writer) must read as the same run. open_recording(path) gives a Recording
for a file and a RecordingSet for a directory: the files metadata.yaml lists, in order,
each read as a Recording (so every check of an untrusted file applies to each). A file it
lists that is not there is refused with one line naming it; files of the bag that it does
not list (one being written when the recorder was killed) are said in `problem`, and
ball_world_repair adds them.

Files continue each other: a segment that goes on in the next file appears there again
(same index and log offset, with the state it resumes from), and is one segment here,
the first file's copy kept: when max_files removed the files before it, that copy is the
one with the resume state, so re-simulation starts there.
"""
import dataclasses
import os

from ball_world.recording.bag import listed_files, numbered_files
from ball_world.recording.mcap_reader import load_untrusted, Recording, RecordingError


def open_recording(path):
    """A Recording for a file, a RecordingSet for a bag directory (RecordingError if not)."""
    if os.path.isdir(path):
        return RecordingSet(path)
    return Recording(path)


def _load_yaml(text, what, limit):
    return load_untrusted(text, what, limit, json_text=False)


class RecordingSet:
    """The files of a bag directory as one recording (see the module docstring).

    Besides Recording's attributes: `files`, the Recordings in order. header, has_summary
    and problem describe the set: the first file's header, whether every file is finished,
    and what is wrong with the first file that is not (or with the listing).
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        try:
            names = listed_files(self.path, _load_yaml)
        except ValueError as error:
            raise RecordingError(str(error)) from None
        except OSError as error:
            raise RecordingError(error.strerror or str(error)) from None
        self.files = []
        for name in names:
            file_path = os.path.join(self.path, name)
            if not os.path.lexists(file_path):
                raise RecordingError(f'{name}, listed in metadata.yaml, is missing: the set '
                                     'is incomplete')
            try:
                self.files.append(Recording(file_path))
            except RecordingError as error:
                raise RecordingError(f'{name}: {error}') from None
        self._combine(names)

    def _combine(self, names):
        files = self.files
        self.header = files[0].header
        self.size = sum(f.size for f in files)
        self.complete_bytes = sum(f.complete_bytes for f in files)
        self.has_summary = all(f.has_summary for f in files)
        problems = [f'{os.path.basename(f.path)}: {f.problem}' for f in files if f.problem]
        unlisted = [name for _, name in numbered_files(self.path) if name not in names]
        if unlisted:
            problems.append(f"{', '.join(unlisted)} not listed in metadata.yaml (a file "
                            'being written when the recorder stopped)')
        self.problem = '; '.join(problems) or None
        self.compressions = set().union(*(f.compressions for f in files))
        self.chunk_count = sum(f.chunk_count for f in files)
        self.message_count = sum(f.message_count for f in files)
        starts = [f.start_ns for f in files if f.start_ns is not None]
        ends = [f.end_ns for f in files if f.end_ns is not None]
        self.start_ns = min(starts) if starts else None
        self.end_ns = max(ends) if ends else None
        last_end = None
        for name, f in zip(names, files):
            if f.start_ns is not None and last_end is not None and f.start_ns <= last_end:
                raise RecordingError(f'{name} begins at log time {f.start_ns} ns, not after '
                                     f'the file before it ({last_end} ns): not one run')
            last_end = f.end_ns if f.end_ns is not None else last_end
        self.topics = {}
        for f in files:
            for topic, info in f.topics.items():
                previous = self.topics.get(topic)
                self.topics[topic] = info if previous is None else dataclasses.replace(
                    previous, message_count=previous.message_count + info.message_count)
        merged = {}
        for f in files:
            for segment in f.segments:
                merged.setdefault((segment.index, segment.log_offset_ns), segment)
        self.segments = sorted(merged.values(), key=lambda s: s.log_offset_ns)
        self._offsets = [s.log_offset_ns for s in self.segments]
        self.roles = {}
        self.agent_roles = {}  # the agents' topics (Recording.agent_roles) of every file
        for f in files:
            for topic, role in f.roles.items():
                self.roles.setdefault(topic, role)
            for topic, role in f.agent_roles.items():
                self.agent_roles.setdefault(topic, role)

    def messages(self, topics=None):
        """RecordedMessages of every file in order (files never overlap in log time)."""
        for f in self.files:
            yield from f.messages(topics)

    def messages_at(self, times, topics):
        """Recording.messages_at over the files (each file's log times its own)."""
        found = {}
        for f in self.files:
            for time, messages in f.messages_at(times, topics).items():
                found.setdefault(time, []).extend(messages)
        return found

    def last_message(self, topic):
        for f in reversed(self.files):
            message = f.last_message(topic)
            if message is not None:
                return message
        return None

    # The step views work on messages(), segments and roles alone: the same code as a file.
    topic_of = Recording.topic_of
    segment_at = Recording.segment_at
    edits = Recording.edits
    steps = Recording.steps
