"""A bag directory of split MCAP files read as one recording, with the interface of Recording.

Why: the tools (info, resim, replay, to_rrd) take a path and read a Recording; a split run
(recording.split_writer) must read as the same run. open_recording(path) gives a Recording
for a file and a RecordingSet for a directory: the files metadata.yaml lists, in order,
each read as a Recording (so every check of an untrusted file applies to each).

A set with a hole is still read, so that the tools can do what can be done and say what
cannot: a file metadata.yaml lists that is gone is named in `missing`, and the steps it
held are a gap. Files of the bag that it does not list are said in `problem` when they are
the recorder's next ones (a file being written when it stopped: ball_world_repair adds
it), and in `strays` otherwise (a copy such as `run_000.mcap`: no tool takes it for part of
the set, recording.bag.classify_names).

Files continue each other: a segment that goes on in the next file appears there again
(same index and log offset, with the state it resumes from), and is one segment here, the
first file's copy kept: when max_files removed the files before it, that copy is the one
with the resume state, so re-simulation starts there. When the file before is missing or
ends earlier than the next one resumes (a truncated file), the next file's copy is kept as
a segment of its own (the same index, starting at its resume step): `gaps` says which steps
lie between, and a tool picks the run up again from that state.
"""
import dataclasses
from dataclasses import dataclass
import os

from ball_world.recording.bag import classify_names, missing_metadata, read_listing
from ball_world.recording.mcap_reader import load_untrusted, Recording, RecordingError


def open_recording(path):
    """A Recording for a file, a RecordingSet for a bag directory (RecordingError if not)."""
    if os.path.isdir(path):
        return RecordingSet(path)
    return Recording(path)


def _load_yaml(text, what, limit):
    return load_untrusted(text, what, limit, json_text=False)


@dataclass(frozen=True)
class Gap:
    """Steps of a segment that are not in the set: after `last` (the last step before, or
    None when the segment's earlier steps are all gone) up to `resumes` (the step the next
    file resumes from; its first step is resumes + 1); `why` says what is missing."""

    segment: int
    last: object
    resumes: int
    why: str

    def describe(self):
        steps = (f'the steps before step {self.resumes + 1}' if self.last is None
                 else f'steps {self.last + 1}-{self.resumes}')
        return f'segment {self.segment}: {steps} are not in the set ({self.why})'


def _first_log_time(path):
    """The first log time of a file's messages, or None when it cannot say."""
    try:
        return Recording(path).start_ns
    except RecordingError:
        return None


def _start_of(segment):
    """Log time of a segment's first step in its file: its resume step's next, or step 0."""
    if segment.resume is None:
        return segment.log_offset_ns
    return segment.log_offset_ns + (segment.resume.step + 1) * segment.dt_ns


class RecordingSet:
    """The files of a bag directory as one recording (see the module docstring).

    Besides Recording's attributes: `files`, the Recordings in order; `missing`, the names
    listed but gone; `gaps` (Gap); `strays`, (name, why) of files left out; `stopped`, what
    metadata.yaml says stopped the recorder (a write error), if anything. header,
    has_summary and problem describe the set: the first file's header, whether every file
    is finished, and what is wrong (files without summary, unlisted, missing, stopped).
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        try:
            listing = read_listing(self.path, _load_yaml)
        except ValueError as error:
            raise RecordingError(str(error)) from None
        except OSError as error:
            raise RecordingError(error.strerror or str(error)) from None
        self.stopped = listing.stopped
        self.files = []
        self.missing = []
        self._names = []  # each present file's name, and the listed files gone just before it
        gone = []
        for name in listing.names:
            file_path = os.path.join(self.path, name)
            if not os.path.lexists(file_path):
                self.missing.append(name)
                gone.append(name)
                continue
            try:
                self.files.append(Recording(file_path))
            except RecordingError as error:
                raise RecordingError(f'{name}: {error}') from None
            self._names.append((name, gone))
            gone = []
        if not self.files:
            if self.stopped:
                raise RecordingError(missing_metadata(self.path, self.stopped))
            raise RecordingError('none of the files metadata.yaml lists is there '
                                 f"({', '.join(self.missing)})")
        self._combine(listing.names)

    def _combine(self, names):
        files = self.files
        self.header = files[0].header
        self.size = sum(f.size for f in files)
        self.complete_bytes = sum(f.complete_bytes for f in files)
        self.has_summary = all(f.has_summary for f in files)
        problems = [f'{os.path.basename(f.path)}: {f.problem}' for f in files if f.problem]
        candidates, self.strays = classify_names(self.path, os.listdir(self.path), names)
        unlisted = []
        last_end = max((f.end_ns for f in files if f.end_ns is not None), default=None)
        for name in candidates:  # the recorder's next files, unless they go back in time
            first = _first_log_time(os.path.join(self.path, name))
            if first is not None and last_end is not None and first <= last_end:
                self.strays.append((name, f'its log times begin at {first / 1e9:.9g} s, not '
                                          f'after the set before it ({last_end / 1e9:.9g} s): '
                                          'not part of this run'))
            else:
                unlisted.append(name)
        self.unlisted = unlisted
        if unlisted:
            problems.append(f"{', '.join(unlisted)} not listed in metadata.yaml (a file "
                            'being written when the recorder stopped)')
        if self.missing:
            problems.append(f"{', '.join(self.missing)}, listed in metadata.yaml, "
                            f"{'is' if len(self.missing) == 1 else 'are'} missing")
        if self.stopped:
            problems.append(f'the recorder stopped: {self.stopped}')
        self.problem = '; '.join(problems) or None
        self.compressions = set().union(*(f.compressions for f in files))
        self.chunk_count = sum(f.chunk_count for f in files)
        self.message_count = sum(f.message_count for f in files)
        starts = [f.start_ns for f in files if f.start_ns is not None]
        ends = [f.end_ns for f in files if f.end_ns is not None]
        self.start_ns = min(starts) if starts else None
        self.end_ns = max(ends) if ends else None
        last_end = None
        for (name, _), f in zip(self._names, files):
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
        self._merge_segments()
        # Where each file picks a segment up (its copy with a resume state), merged or not:
        # after a jump inside a file (a damaged chunk dropped), the run goes on from there.
        self.resume_points = {
            (segment.index, segment.log_offset_ns, segment.resume.step): segment
            for f in files for segment in f.segments if segment.resume is not None}
        self.roles = {}
        self.agent_roles = {}  # the agents' topics (Recording.agent_roles) of every file
        self.agent_message_roles = {}  # and their scans, ground truth and bumpers
        for f in files:
            for topic, role in f.roles.items():
                self.roles.setdefault(topic, role)
            for topic, role in f.agent_roles.items():
                self.agent_roles.setdefault(topic, role)
            for topic, role in f.agent_message_roles.items():
                self.agent_message_roles.setdefault(topic, role)

    def _merge_segments(self):
        """segments: every file's segments in log-time order, a segment that goes on from the
        file before it merged into that file's copy; gaps where it cannot go on."""
        entries = []  # [segment, start log time, positions of its first and last file]
        self.gaps = []
        previous_end = None  # (segment key, last step) the file before ends with
        for position, ((name, gone), f) in enumerate(zip(self._names, self.files)):
            for segment in sorted(f.segments, key=lambda s: s.log_offset_ns):
                key = (segment.index, segment.log_offset_ns)
                seen = entries and (entries[-1][0].index, entries[-1][0].log_offset_ns) == key
                if segment.resume is not None and seen:
                    last = previous_end[1] if previous_end and previous_end[0] == key \
                        else None
                    if not gone and last == segment.resume.step:
                        entries[-1][3] = position  # it goes on here: one segment
                        continue
                    self.gaps.append(Gap(segment.index, last, segment.resume.step,
                                         self._why(position, gone, last)))
                elif segment.resume is not None and (entries or gone):
                    # its start was in a file that is gone (the set may begin with a file
                    # that resumes: max_files removed the ones before, which is no gap)
                    self.gaps.append(Gap(segment.index, None, segment.resume.step,
                                         self._why(position, gone, None)))
                entries.append([segment, _start_of(segment), position, position])
            previous_end = self._last_step(f)
        self.segments = [entry[0] for entry in entries]
        self._offsets = [entry[1] for entry in entries]
        self._ends = []
        for number, (segment, _, _, last) in enumerate(entries):
            following = entries[number + 1] if number + 1 < len(entries) else None
            if following is not None and following[2] == last:
                self._ends.append(following[1] - segment.dt_ns)  # a reset in that file
            else:
                self._ends.append(self.files[last].end_ns)

    def _why(self, position, gone, last):
        name = self._names[position][0]
        if gone:
            return (f"{', '.join(gone)}, listed in metadata.yaml, "
                    f"{'is' if len(gone) == 1 else 'are'} missing")
        before = self._names[position - 1][0] if position else 'the set'
        ends = 'does not hold them' if last is None else f'ends at step {last}'
        return f'{before} {ends}; {name} resumes later'

    @staticmethod
    def _last_step(f):
        """(segment key, step) of a file's last step: its last segment's, from its end."""
        if f.end_ns is None or not f.segments:
            return None
        segment = f.segments[-1]
        return ((segment.index, segment.log_offset_ns),
                (f.end_ns - segment.log_offset_ns) // segment.dt_ns)

    def segment_end_ns(self, position):
        """The last log time of segments[position] in the set."""
        return self._ends[position]

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
