"""Record a long run as a rosbag2 bag directory of MCAP files, split by size or by time.

Why: one file that grows without bound is hard to move, open or repair, and the MCAP
writer keeps an index entry per chunk for the summary, so its memory grows with the file
too. SplitMcapSink wraps one McapSink per file: past record.max_bytes (bytes handed to the
file) or record.max_seconds (log time since the file's first step), the file is finished
(summary, footer) and the next one begun, always between two steps. Each writer is new, so
the writer's memory is bounded by one file.

Every file stands alone: a file begun inside a segment starts with that segment's
'ball_world' metadata record (parameters, topics) plus the state it continues from
(recording.resume: the step before its first, with every ball's name, position, velocity,
radius and mass; with agents, their headings and the commands in force; in exact mode the
predictions that step hands the next, core.exact_carry), then the
markers of that world (and whatever else McapSink writes at a segment start); its first
step carries the segment's /tf_static when there are agents. A reset starts the next
segment in whichever file is open (a due split is made first, so the new file begins with
the segment). A segment's closing record (edits after its last step) goes to the open file.

After each finished file metadata.yaml is rewritten (recording.bag), after record.max_files
is applied: the oldest files beyond it are removed, each said through `report`. A file's
entry in metadata.yaml is made from what its writer counted (McapSink.summary), so a split
costs the same whether the run has made ten files or ten thousand. Every file is made,
replaced and removed in the bag directory's Folder (recording.files): never through a
symlink, never outside it.

Errors are OSErrors whose text names the file (McapRecordingError): a full disk while the
next file starts leaves every finished file as it was, and metadata.yaml is written once
more, into space set aside for it (recording.bag.reserve_space), saying what stopped the
recorder (custom_data), so `ball_world_info` tells a full disk from a killed recorder.

A follower (the .rrd parts, recording.rrd_parts) splits with the MCAP files: it is given
every call after the MCAP writer, and told of each new file (roll) before the record that
begins it, so its parts begin at the same steps. A follower that fails is dropped and said
through `warn`; the MCAP goes on.
"""
import dataclasses
import os

from ball_world.recording.bag import (claim_directory, file_name, reserve_space,
                                      write_metadata)
from ball_world.recording.mcap_writer import CHUNK_BYTES, McapRecordingError, McapSink
from ball_world.recording.resume import CommandsInForce, resume_metadata

#: Smallest chunk a split file is cut into: small files still compress well.
MIN_CHUNK_BYTES = 16 << 10


def split_chunk_bytes(max_bytes):
    """Chunks of at most an eighth of a file: a small file still has a few chunks to index.

    The size checked counts the open chunk uncompressed, so compression (zstd halves a
    chunk, lz4 barely shrinks poses) can only make a file end below max_bytes, by at most
    what the open chunk shrinks.
    """
    if not max_bytes:
        return CHUNK_BYTES
    return min(CHUNK_BYTES, max(MIN_CHUNK_BYTES, max_bytes // 8))


def splits(values):
    """Whether parameters ask for a split recording (record.max_bytes or max_seconds)."""
    return bool(values['record.max_bytes'] or values['record.max_seconds'])


def unused_max_files(values):
    """The warning line for record.max_files set where it cannot act, or None.

    Only split files are removed: without record.max_bytes or record.max_seconds the run
    is one file, which is never deleted, and the user asked for bounded disk.
    """
    if values['record.max_files'] and (values['record.mcap'] or values['record.rerun']) \
            and not splits(values):
        return (f"record.max_files {values['record.max_files']} has no effect: the recording "
                'is one file unless record.max_bytes or record.max_seconds is set')
    return None


def open_split_sink(values, report=None, warn=None):
    """The SplitMcapSink the record.* parameters describe (raises OSError naming the path)."""
    return SplitMcapSink(values['record.mcap'], values['record.max_bytes'],
                         values['record.max_seconds'], values['record.max_files'],
                         values['record.overwrite'], report, warn=warn)


class SplitRule:
    """When a split recording starts its next file (or part): past max_bytes, or past
    max_ns of log time since the file's first step; never before a file holds a step."""

    def __init__(self, max_bytes=0, max_seconds=0.0):
        self.max_bytes = int(max_bytes)
        self.max_ns = round(float(max_seconds) * 1e9)

    def due(self, steps, size, first_ns, log_time_ns):
        """steps: steps in the open file; size: its bytes; first_ns: its first step's log
        time; log_time_ns: the next record's (None at a segment start)."""
        if not steps:
            return False
        if self.max_bytes and size >= self.max_bytes:
            return True
        return bool(self.max_ns and log_time_ns is not None
                    and log_time_ns - first_ns >= self.max_ns)


class SplitMcapSink:
    """A Sink writing `<dir>/<name>_0.mcap`, `_1.mcap`, ... and `<dir>/metadata.yaml`.

    max_bytes, max_seconds: when to start the next file (0: never by that measure).
    max_files: how many files to keep (0: all). report(line): where removals are said;
    warn(line): where a follower's failure is said (report when None). The directory is
    claimed at once (recording.bag.claim_directory: an existing one is refused unless
    overwrite). Other keyword arguments go to each McapSink.
    """

    #: Each file after the first starts with the state of the step it follows, which in exact
    #: mode includes what that step hands the next: the Simulation puts it in every record.
    wants_carried_state = True

    def __init__(self, directory, max_bytes=0, max_seconds=0.0, max_files=0, overwrite=False,
                 report=None, warn=None, **options):
        self.path = os.fspath(directory)
        self.rule = SplitRule(max_bytes, max_seconds)
        self.max_bytes = self.rule.max_bytes
        self.max_ns = self.rule.max_ns
        self.max_files = int(max_files)
        self.report = report
        self.warn = warn or report
        self.follower = None
        options.setdefault('chunk_bytes', split_chunk_bytes(self.max_bytes))
        self._options = options
        self._claim = claim_directory(self.path, overwrite, 'set record.overwrite:=true')
        self._folder = self._claim.folder
        self._finished = []  # bag.FileSummary of each complete file kept, in order
        self._number = 0
        self._sink = None
        self._closed = False
        self._world = self._info = None  # the current segment's start
        self._last = None  # the segment's last StepRecord
        self._retired = set()  # names deleted in the segment so far
        self._commands = CommandsInForce()  # the agents' last commands in the segment
        self._tf_static = None  # the segment's last /tf_static, for each file's start
        self._file_steps = 0
        self._file_start_ns = None
        self._stopped = False  # a write error stopped it (said in metadata.yaml)
        try:
            reserve_space(self._folder)
            self._open()
        except OSError:
            self._claim.discard()
            raise

    @property
    def identity(self):
        """(device, inode) of the directory: another output of the run may not be it."""
        return self._claim.identity

    @property
    def number(self):
        """The number of the file being written."""
        return self._number - 1

    def discard(self):
        """Give up a recording that never began: as close(), which then removes it all."""
        self.close()

    @property
    def files(self):
        """Paths of the complete files kept so far, in order."""
        return [summary.path for summary in self._finished]

    # Sink protocol ----------------------------------------------------------------------

    def start_segment(self, world, info):
        self._check_open()
        if self._due(None):
            self._run(self._roll, None)
        self._world, self._info = world, info
        self._last = None
        self._retired = set()
        self._commands.restart()
        self._tf_static = None
        self._run(self._sink.start_segment, world, info)
        self._follow('start_segment', world, info)

    def write_step(self, record):
        self._check_open()
        if self._due(record.log_time_ns) and self._last is not None:
            self._run(self._roll, self._last)
            record = self._with_tf_static(record)
        self._run(self._sink.write_step, record)
        if record.agents is not None and record.agents.tf_static_cdr is not None:
            self._tf_static = record.agents.tf_static_cdr
        self._commands.follow(record)
        if self._file_start_ns is None:
            self._file_start_ns = record.log_time_ns
        self._file_steps += 1
        self._last = record
        self._retired.update(edit.name for edit in record.edits if edit.kind == 'delete')
        self._follow('write_step', record)

    def write_pending(self, events):
        """The segment's closing record (step_record.PendingEvents), into the open file.

        It belongs to the segment it closes, so it never begins a file: a file that began
        with it would hold edits and no step to check them against. The file's summary and
        so metadata.yaml count its messages and its log time, as any other.
        """
        self._check_open()
        self._run(self._sink.write_pending, events)
        self._retired.update(edit.name for edit in events.edits if edit.kind == 'delete')
        self._commands.follow(events)
        if hasattr(self.follower, 'write_pending'):
            self._follow('write_pending', events)

    def flush(self):
        self._check_open()
        self._run(self._sink.flush)
        self._follow('flush')

    def close(self):
        """Finish the open file and metadata.yaml; a second call does nothing.

        A recording closed before anything was recorded leaves no directory it created.
        """
        if self._closed:
            return
        self._closed = True
        try:
            if self._sink is not None:
                self._finish(self.max_files or None)
        finally:
            self._close_follower()
            if self._finished:
                self._claim.release()
            else:
                self._claim.discard()

    # Implementation ---------------------------------------------------------------------

    def _check_open(self):
        if self._closed:
            raise ValueError(f'{self.path}: the recording is closed')

    def _run(self, action, *args):
        """Run action; any error finishes this sink (the files already complete stay, and
        metadata.yaml says what stopped it)."""
        try:
            action(*args)
        except Exception as error:
            self._closed = True
            failed, self._sink = self._sink, None
            self._record_stop(failed, error)
            self._close_follower()
            self._claim.release()
            raise

    def _record_stop(self, failed, error):
        """metadata.yaml once more, with what stopped the recorder (best effort, once)."""
        if self._stopped:
            return
        self._stopped = True
        if failed is not None:
            failed.abandon()
        name = os.path.basename(failed.path) if failed is not None else 'metadata.yaml'
        reason = getattr(error, 'strerror', None) or str(error)
        try:
            write_metadata(self._folder, self._finished,
                           stopped=f'{name} could not be written: {reason}')
        except OSError:
            pass  # the error itself is what the caller reports

    def _follow(self, name, *args):
        """Hand a call on to the follower; one that fails is dropped and said, once."""
        if self.follower is None:
            return
        try:
            getattr(self.follower, name)(*args)
        except Exception as error:  # noqa: B902 - the follower's failure is its own
            follower, self.follower = self.follower, None
            if self.warn is not None:
                self.warn(f'{_one_line(error)}; the .rrd parts stop, {self.path} goes on')
            _close_quietly(follower)

    def _close_follower(self):
        follower, self.follower = self.follower, None
        if follower is None:
            return
        try:
            follower.close()
        except Exception as error:  # noqa: B902 - reported, the MCAP is closed regardless
            if self.warn is not None:
                self.warn(f'{_one_line(error)}')

    def _due(self, log_time_ns):
        if self._sink is None:
            return False
        return self.rule.due(self._file_steps, self._sink.bytes_written, self._file_start_ns,
                             log_time_ns)

    def _open(self):
        name = file_name(self.path, self._number)
        claim = self._folder.claim(name)
        self._sink = McapSink(claim, **self._options)
        self._number += 1
        self._file_steps = 0
        self._file_start_ns = None

    def _finish(self, keep):
        """Close the open file, keep its summary and at most `keep` files (None: all), and
        rewrite metadata.yaml."""
        sink, self._sink = self._sink, None
        try:
            sink.close()
        except Exception as error:
            self._record_stop(sink, error)
            raise
        if sink.removed:
            return  # it held no segment: McapSink removed it
        self._finished.append(sink.summary())
        while keep is not None and len(self._finished) > keep:
            oldest = self._finished.pop(0)
            self._folder.remove(os.path.basename(oldest.path))
            if self.report is not None:
                self.report(f'record.max_files {self.max_files}: removed the oldest split '
                            f'file {oldest.path}')
        metadata = os.path.join(self.path, 'metadata.yaml')
        try:
            size = write_metadata(self._folder, self._finished)
            reserve_space(self._folder, size)
        except OSError as error:
            raise McapRecordingError(error.errno, error.strerror or str(error),
                                     metadata) from None

    def _with_tf_static(self, record):
        """The first record of a file that continues a segment, with the segment's /tf_static
        (the bytes the node latched) when it has agents: a reader of the file alone needs
        the frames, and a latched message comes once."""
        frame = record.agents
        if frame is None or frame.tf_static_cdr is not None or self._tf_static is None:
            return record
        return dataclasses.replace(record, agents=dataclasses.replace(
            frame, tf_static_cdr=self._tf_static))

    def _roll(self, resume_from):
        """Finish the open file and begin the next; resume_from: the StepRecord it follows.

        The limit on kept files counts the file being begun, so at most max_files exist.
        """
        self._finish(self.max_files - 1 if self.max_files else None)
        self._open()
        if resume_from is not None:
            record = resume_from
            world = dataclasses.replace(
                self._world, radii=record.radii, masses=record.masses,
                positions=record.positions, velocities=record.velocities, names=record.names)
            info = dataclasses.replace(self._info,
                                       resume=resume_metadata(record, self._retired,
                                                              self._commands.commands))
            self._sink.start_segment(world, info)
        self._follow('roll', self.number)


def _one_line(error):
    return ' '.join(str(error).split()) or type(error).__name__


def _close_quietly(sink):
    try:
        sink.close()
    except Exception:  # noqa: B902 - its failure was reported already
        pass
