"""A split Rerun recording: parts `<name>_0.rrd`, `<name>_1.rrd`, ... beside the named .rrd.

Why: one .rrd of a long run grows without bound (49 MB a minute at 1,000 balls and 100 Hz,
about 70 GB a day), and so does the memory of its writer, which keeps an index entry per
chunk until the file is finished. With a split parameter set (record.max_bytes or
record.max_seconds), record.rerun names the parts instead of one file: record.rerun
`/data/run.rrd` makes `/data/run_0.rrd`, `/data/run_1.rrd`, ... in /data, where the user
looks for it (the MCAP's parts go in a bag directory because rosbag2 says so; Rerun has no
such layout, and `rerun /data/run_*.rrd` opens them together, as one recording: every
part has the run's recording id). record.max_files keeps the newest parts, the oldest
removed and said, as for the MCAP files; existing parts of the name are refused unless
record.overwrite (then removed).

Each part is a complete file (`rerun rrd verify` passes) that opens on its own: the arena's
transform, the plots' styles, the segment's walls and scale, the blueprint, the balls'
looks and the impulses on screen are logged in it again (rerun_log.RerunSink.next_part),
and its first step is always logged. It is written by the same writer process as the rest
(rerun_process, with a spare that takes over every WRITER_SECONDS), and finished (footer)
before the next one begins, so the writer's memory is freed at each part.

With record.mcap split too, the parts follow the MCAP files (split_writer.SplitMcapSink's
follower): part i begins at the same step as `<bag>_i.mcap`. Alone, they split by the
same rule (split_writer.SplitRule: log time, or the part's own size in bytes).

Every part is made and removed in the folder of the named .rrd (recording.files.Folder):
never through a symlink, never elsewhere.
"""
import errno
import os
import re
import threading

from ball_world.recording.files import FileRefused, Folder, split_path
from ball_world.recording.rerun_log import RerunSink


def part_stem(path):
    """What the parts of `path` are named after: its name without '.rrd'."""
    name = os.path.basename(os.fspath(path))
    return name[:-len('.rrd')] if name.endswith('.rrd') and len(name) > 4 else name


def part_name(path, number):
    return f'{part_stem(path)}_{number}.rrd'


def part_names(path, names=None):
    """The parts of the .rrd `path` present beside it, as (number, name), in order.

    Only canonical names count (`run_3.rrd`, never `run_003.rrd`). names: the folder's
    entries when already listed.
    """
    if names is None:
        try:
            names = os.listdir(os.path.dirname(os.fspath(path)) or '.')
        except OSError:
            return []
    pattern = re.compile(re.escape(part_stem(path)) + r'_(0|[1-9][0-9]{0,8})\.rrd')
    found = []
    for name in names:
        match = pattern.fullmatch(name)
        if match:
            found.append((int(match.group(1)), name))
    return sorted(found)


class _Part:
    """One part: its number, its claim, whether it is complete, whether it is to go."""

    def __init__(self, number, claim):
        self.number = number
        self.claim = claim
        self.finished = False
        self.doomed = False


class RrdParts:
    """A Sink writing the parts of a split .rrd (see the module docstring).

    rule: a split_writer.SplitRule to split by on its own, or None to follow (roll()).
    max_files: how many parts to keep (0: all). report(line): where removals are said.
    Other keyword arguments go to each part's RerunSink (every, velocities,
    trail_seconds, clock, report, file_process). Raises FileRefused naming the path when
    the parts cannot be claimed.
    """

    def __init__(self, path, rule=None, max_files=0, overwrite=False, report=None,
                 hint='set record.overwrite:=true', **sink_options):
        self.path = os.fspath(path)
        self.rule = rule
        self.max_files = int(max_files)
        self.report = report
        folder_path, _ = split_path(self.path)
        self.folder = Folder(folder_path)
        self._lock = threading.Lock()
        self._parts = []
        self._closed = False
        self._segments = 0
        self._steps = 0
        self._first_ns = None
        try:
            self._clear(overwrite, hint)
            claim = self.folder.claim(part_name(self.path, 0))
            self._current = _Part(0, claim)
            self._parts.append(self._current)
            sink_options.setdefault('file_process', True)
            self.sink = RerunSink(claim, spare=sink_options['file_process'], **sink_options)
        except BaseException:
            for part in self._parts:
                part.claim.discard()
            self.folder.close()
            raise

    def _clear(self, overwrite, hint):
        existing = part_names(self.path, self.folder.names())
        if existing and not overwrite:
            advice = f'; {hint} to replace them' if hint else ''
            raise FileRefused(errno.EEXIST, f'has parts already ({existing[0][1]}, ...)'
                                            f'{advice}', self.path)
        for _, name in existing:
            self.folder.refuse_symlink(name)  # not one of ours: never removed, said
        for _, name in existing:
            self.folder.remove(name)

    @property
    def identity(self):
        """(device, inode) of the part being written."""
        return self._current.claim.identity

    @property
    def files(self):
        """Paths of the parts kept so far (the one being written last), in order."""
        with self._lock:
            return [part.claim.path for part in self._parts if not part.doomed]

    # Sink protocol ----------------------------------------------------------------------

    def start_segment(self, world, info):
        if self.rule is not None and self._due(None):
            self.roll()
        self._segments += 1
        self.sink.start_segment(world, info)

    def write_step(self, record):
        if self.rule is not None and self._due(record.log_time_ns):
            self.roll()
        self.sink.write_step(record)
        self._steps += 1
        if self._first_ns is None:
            self._first_ns = record.log_time_ns

    def write_pending(self, events):
        """A closing record has no step of its own: nothing of it is drawn."""

    def flush(self):
        self.sink.flush()

    def roll(self, number=None):
        """Finish the part being written and begin the next (numbered `number`, by default
        the next one): the part a split MCAP file of that number begins with."""
        number = self._current.number + 1 if number is None else number
        claim = self.folder.claim(part_name(self.path, number))
        old = self._current
        self._current = _Part(number, claim)
        with self._lock:
            self._parts.append(self._current)
        self._steps = 0
        self._first_ns = None
        try:
            self.sink.next_part(claim, done=lambda: self._finished(old))
        finally:
            self._keep()

    def close(self):
        """Finish the last part; release every claim; keep at most max_files parts."""
        if self._closed:
            return
        self._closed = True
        try:
            self.sink.close()
            self._finished(self._current)
        finally:
            with self._lock:
                parts, self._parts = self._parts, [p for p in self._parts if not p.doomed]
            for part in parts:
                if not self._segments:
                    part.claim.discard()  # nothing was recorded: no file left behind
                elif part.doomed:
                    part.claim.release()
                    self._remove(part)
                else:
                    part.claim.release()
            self.folder.close()

    # Implementation ---------------------------------------------------------------------

    def _due(self, log_time_ns):
        return self.rule.due(self._steps, self._current.claim.size(), self._first_ns,
                             log_time_ns)

    def _finished(self, part):
        """A part's file is complete (called on the writer's thread): release it, and
        remove it if the limit took it meanwhile."""
        with self._lock:
            part.finished = True
            remove = part.doomed and part in self._parts
            if remove:
                self._parts.remove(part)
        part.claim.release()
        if remove:
            self._remove(part)

    def _keep(self):
        """At most max_files parts, the one being written counted: the oldest go, each
        once it is complete."""
        if not self.max_files:
            return
        doomed = []
        with self._lock:
            alive = [part for part in self._parts if not part.doomed]
            for part in alive[:max(0, len(alive) - self.max_files)]:
                part.doomed = True
                if part.finished:
                    self._parts.remove(part)
                    doomed.append(part)
        for part in doomed:
            self._remove(part)

    def _remove(self, part):
        try:
            self.folder.remove(part.claim.name, part.claim.identity)
        except OSError as error:
            if self.report is not None:
                self.report(f'record.max_files {self.max_files}: could not remove the oldest '
                            f'.rrd part {part.claim.path}: {error.strerror or error}')
            return
        if self.report is not None:
            self.report(f'record.max_files {self.max_files}: removed the oldest .rrd part '
                        f'{part.claim.path}')
