"""An .rrd file written by a child process, so that the node's own memory stays flat.

Why: the Rerun SDK's file sink keeps metadata of every chunk it has written (the manifest
that the footer at the end of the file holds) for as long as the file is open. At 1,000
balls and 100 Hz that is about 1 MB of native memory a minute (docs/reliability.md: about
600 chunks a minute). `rerun.save(..., write_footer=False)` keeps memory flat, but then
`rerun rrd verify` refuses the file ("no RRD manifests"), and concatenated streams each with
a footer are refused too ("more than one RRD manifest"): a single valid file needs one
writer holding the whole index. So that writer lives in a child process (`python -m
ball_world.recording.rerun_process`): the node's memory stays flat and the index grows in
the child, which frees it with the file.

ProcessStream stands in for the RecordingStream of an Outlet.file (rerun_outlet), which
already runs every call on a worker thread with bounded waits: each SDK call made on it is
pickled to the child's stdin, in order; flush and disconnect wait for the child's answer, so
a write error (a full disk) is raised where the in-process stream raises it. A child that
died is raised as an OSError saying how, and the Outlet reports it once.

A split .rrd (recording.rrd_parts) moves to its next part with next_file(claim, blueprint):
the child finishes the part (footer included), answers, and saves the next, given to it as
an open descriptor (sent over a socket, SCM_RIGHTS) and opened as /proc/self/fd/N, so it
writes the very file the node claimed. The SDK never frees a file sink's threads and some
of its memory (rerun issue #2116: about 1.3 MB and two threads per file), so a child that
has written for WRITER_SECONDS hands over, at the next part, to a spare started in advance
(ProcessStream(spare=True)), and finishes its own part and exits: memory stays flat however
many parts a run makes, and no part waits for a child to start.

The child runs in a process group of its own and ignores SIGINT: a Ctrl-C in a terminal,
which reaches the whole foreground group, stops the node, and the node closes the file when
it stops. If the node dies first (SIGKILL, the OOM killer), the child reads the end of its
input, finishes the file, footer included, and exits; it never lingers more than
FINISH_SECONDS after that.
"""
import io
import os
import pickle
import select
import signal
import socket
import subprocess
import sys
import time

import pyarrow as pa
from rerun_bindings import ComponentDescriptor

#: The SDK calls an Outlet.file makes on its stream; anything else is a programming error.
CALLS = frozenset(('save', 'log', 'send_columns', 'set_time', 'flush', 'disconnect'))
#: Calls the child answers (None: done; else the error, one line) before the next is sent.
ANSWERED = frozenset(('new', 'flush', 'disconnect', 'save_fd', 'part'))
#: Longest wait for the child to have started (imported the SDK) and made its stream. It
#: starts with the sink, so this wait usually overlaps the node's own start-up.
STARTUP_SECONDS = 60.0
#: Longest wait for an answer beyond the call's own timeout (the child may be busy writing
#: what was queued before it).
ANSWER_MARGIN = 3.0
#: Longest wait for the child's answer to disconnect (the footer is written then), and to a
#: move to the next part (the last part's footer, then the next file).
DISCONNECT_SECONDS = 8.0
#: From the end of its input or a disconnect on, the child is ended by its own alarm
#: (SIGALRM) if still running this long.
FINISH_SECONDS = 30
#: The child gathers an entity's columns (send_columns) for this long of wall time...
GATHER_SECONDS = 5.0
#: ...or up to this many bytes, and sends them as one chunk: the index the SDK keeps per
#: chunk then grows by one entry per entity per 5 s, not ten a second (the node sends
#: each second what it has).
GATHER_BYTES = 4 << 20
#: A child that has written parts this long (wall time) hands over to its spare at the next
#: part: each file the SDK writes leaves threads and memory behind (see the module).
WRITER_SECONDS = 30.0
#: What a child writes once it has imported the SDK and can take calls.
READY = 'ready'
#: Where the child finds the descriptors it is sent (Linux); elsewhere it is sent paths.
_PROC_FDS = '/proc/self/fd'


class _Pickler(pickle.Pickler):
    """Pickles what the SDK's objects hold that pickle alone gets wrong or refuses.

    Arrow arrays go as Arrow IPC: pickle drops the non-null flag of a fixed-size list's
    items (Points2D positions), and the SDK then takes the column for another type
    (`rerun rrd compare` sees it). ComponentDescriptor (in a ComponentColumn) has no pickle
    support of its own.
    """

    def reducer_override(self, obj):
        if isinstance(obj, pa.Array):
            batch = pa.record_batch([obj], names=['column'])
            sink = pa.BufferOutputStream()
            with pa.ipc.new_stream(sink, batch.schema) as writer:
                writer.write_batch(batch)
            return _array, (sink.getvalue().to_pybytes(),)
        if isinstance(obj, ComponentDescriptor):
            return _descriptor, (obj.component, obj.archetype, obj.component_type)
        return NotImplemented


def _array(ipc):
    return pa.ipc.open_stream(ipc).read_next_batch().column(0)


def _descriptor(component, archetype, component_type):
    return ComponentDescriptor(component, archetype=archetype, component_type=component_type)


def _pickled(message):
    buffer = io.BytesIO()
    _Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(message)
    return buffer.getvalue()


class _Child:
    """One writer process: its pipes, the socket its descriptors go through, its age."""

    def __init__(self):
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            # The SDK's own log lines (several, coloured, per failure) stay out of the
            # node's terminal unless asked for (RUST_LOG): the node reports a failure itself.
            self.process = subprocess.Popen(
                [sys.executable, '-m', __name__, str(theirs.fileno())], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, close_fds=True, pass_fds=(theirs.fileno(),),
                process_group=0, env={**os.environ, 'RUST_LOG': os.environ.get('RUST_LOG',
                                                                               'off')})
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        self.socket = ours
        self.pid = self.process.pid
        self.began = time.monotonic()
        self.ready = False
        self.failure = None

    def poll_ready(self, timeout=0.0):
        """Whether the child has imported the SDK (its READY read), waiting up to timeout."""
        if not self.ready:
            readable, _, _ = select.select([self.process.stdout], [], [], timeout)
            if readable:
                said = self._load()
                if said != READY:
                    self.failure = said or self._ended()
                    raise OSError(self.failure)
                self.ready = True
        return self.ready

    def call(self, name, args, kwargs, descriptor=None):
        """Send one call (a descriptor first, if any); wait for its answer if it has one."""
        if self.failure is not None:
            raise OSError(self.failure)
        if name in ANSWERED and not self.poll_ready(STARTUP_SECONDS):
            raise RuntimeError(f'the .rrd writer process (pid {self.pid}) did not start '
                               f'within {STARTUP_SECONDS:g} s')
        try:
            if descriptor is not None:
                socket.send_fds(self.socket, [b'f'], [descriptor])
            self.process.stdin.write(_pickled((name, args, kwargs)))
            self.process.stdin.flush()
        except (BrokenPipeError, ConnectionError, ValueError):
            self._died()
        if name == 'new':
            self._answer(STARTUP_SECONDS)
        elif name == 'flush':
            self._answer(kwargs.get('timeout_sec', 0.0) + ANSWER_MARGIN)
        elif name in ('disconnect', 'part'):
            self._answer(DISCONNECT_SECONDS + ANSWER_MARGIN)
        elif name == 'save_fd':
            self._answer(ANSWER_MARGIN)

    def _load(self):
        try:
            return pickle.load(self.process.stdout)
        except (EOFError, pickle.UnpicklingError, OSError, ValueError):
            return None

    def _answer(self, timeout):
        """Wait for the child's answer to the call just sent; raise its error if any."""
        readable, _, _ = select.select([self.process.stdout], [], [], timeout)
        if not readable:
            raise RuntimeError(f'the .rrd writer process (pid {self.pid}) timed out: '
                               f'no answer for {timeout:g} s')
        try:
            error = pickle.load(self.process.stdout)
        except (EOFError, pickle.UnpicklingError):
            self._died()
        if error is not None:
            self.failure = error
            raise OSError(error)

    def _ended(self):
        """How the child ended, as one line."""
        try:
            code = self.process.wait(timeout=ANSWER_MARGIN)
        except subprocess.TimeoutExpired:
            code = None
        if code is not None and code < 0:
            return (f'the .rrd writer process (pid {self.pid}) was killed by '
                    f'{signal.Signals(-code).name}')
        return (f'the .rrd writer process (pid {self.pid}) ended '
                + ('(exit status unknown)' if code is None else f'(exit {code})'))

    def _died(self):
        """Raise how the child ended (its own error line if it wrote one)."""
        said = None
        try:
            said = pickle.load(self.process.stdout)
        except Exception:  # noqa: B902 - nothing (or a torn answer) from a dead child
            pass
        self.failure = said if said and said != READY else self._ended()
        raise OSError(self.failure)

    def end(self):
        """Close its input (it finishes what it has and exits) and wait for it, bounded."""
        for pipe in (self.process.stdin, self.process.stdout, self.socket):
            try:
                pipe.close()
            except OSError:
                pass
        try:
            self.process.wait(timeout=ANSWER_MARGIN)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


class ProcessStream:
    """The calls of a RecordingStream, run by a child process that owns the real one.

    Made in two steps: ProcessStream() starts the child, which then imports the SDK while
    its owner goes on; open() takes the arguments of rerun_outlet.new_stream and waits for
    the child's stream. Then used from one thread at a time (an Outlet's worker).
    spare=True (a split .rrd) keeps a second child started, to take over at a part once
    the first has written for WRITER_SECONDS.
    """

    def __init__(self, spare=False):
        self._child = _Child()
        self._spare = _Child() if spare else None
        self._wants_spare = spare
        self._opened = None  # the arguments of open(), for a spare that takes over
        self._failure = None
        self._descriptor = None  # the claimed file being written, when given one

    @property
    def pid(self):
        return self._child.pid

    def open(self, application_id, recording_id, flush_seconds=None):
        """The child's stream made; self. A failure is kept and raised by the first call
        (Outlet.file's save), so the Outlet reports it as any other."""
        self._opened = (application_id, recording_id, flush_seconds)
        try:
            self._child.call('new', self._opened, {})
        except (OSError, RuntimeError) as error:
            self._failure = self._failure or _one_line(error)
        return self

    def __getattr__(self, name):
        if name.startswith('_') or name not in CALLS:
            raise AttributeError(name)
        return lambda *args, **kwargs: self._call(name, args, kwargs)

    def _call(self, name, args, kwargs):
        if self._failure is not None:
            raise OSError(self._failure)
        try:
            self._child.call(name, args, kwargs)
        finally:
            if name == 'disconnect':
                self._end()
        if name == 'flush' and self._spare is not None:
            self._spare_ready()  # noted now (a second's flush), taken at the next part

    def save_file(self, claim, blueprint):
        """Write the claimed file (recording.files.OutputClaim): its descriptor is sent."""
        if self._failure is not None:
            raise OSError(self._failure)
        if not os.path.isdir(_PROC_FDS):
            self._child.call('save', (claim.path,), {'default_blueprint': blueprint})
            return
        self._child.call('save_fd', (), {'default_blueprint': blueprint},
                         descriptor=claim.fileno())

    def next_file(self, claim, blueprint):
        """Finish the file being written (footer included) and go on in the claimed one.

        A child that has written for WRITER_SECONDS hands over to its spare when the spare
        is ready: the spare's stream is made and saves the new file, the old child finishes
        and exits, and a new spare starts. Returns when the old file is complete.
        """
        if self._failure is not None:
            raise OSError(self._failure)
        spare = self._spare
        if spare is not None and time.monotonic() - self._child.began >= WRITER_SECONDS \
                and self._spare_ready():
            old, self._child, self._spare = self._child, spare, None
            try:
                old.call('disconnect', (), {})
            finally:
                old.end()
            self._child.call('new', self._opened, {})
            self.save_file(claim, blueprint)
            self._spare = _Child()
            return
        if not os.path.isdir(_PROC_FDS):
            self._child.call('part', (claim.path,), {'default_blueprint': blueprint})
        else:
            self._child.call('part', (), {'default_blueprint': blueprint},
                             descriptor=claim.fileno())

    def _spare_ready(self):
        """Whether the spare can take over now; a spare that died is replaced (the child
        writing goes on meanwhile)."""
        try:
            return self._spare.poll_ready()
        except OSError:
            self._spare.end()
            self._spare = _Child()
            return False

    def _end(self):
        self._child.end()
        if self._spare is not None:
            self._spare.end()
            self._spare = None


def _one_line(error):
    return ' '.join(str(error).split()) or type(error).__name__


class _Index:
    """A merged time column, as send_columns reads one (TimeColumnLike)."""

    def __init__(self, name, array):
        self.name, self.array = name, array

    def timeline_name(self):
        return self.name

    def as_arrow_array(self):
        return self.array


class _Column:
    """A merged component column, as send_columns reads one."""

    def __init__(self, descriptor, array):
        self.descriptor, self.array = descriptor, array

    def component_descriptor(self):
        return self.descriptor

    def as_arrow_array(self):
        return self.array


class Gathered:
    """send_columns calls held per entity and sent merged, GATHER_SECONDS or GATHER_BYTES at
    a time: rows, times and data as they came, in fewer chunks.

    Held data is safe from the node's death (this process sends it when its input ends);
    only this process's own death loses it, and that leaves a file to repair anyway.
    """

    def __init__(self, stream, clock=time.monotonic):
        self.stream = stream
        self.clock = clock
        self.held = {}  # entity -> [layout, since, bytes, [(times, components)]]

    def add(self, entity, indexes, columns):
        times = [(index.timeline_name(), index.as_arrow_array()) for index in indexes]
        components = [(column.component_descriptor(), column.as_arrow_array())
                      for column in columns]
        layout = (tuple(name for name, _ in times),
                  tuple(descriptor.component for descriptor, _ in components))
        held = self.held.get(entity)
        if held is not None and held[0] != layout:
            self.send(entity)
            held = None
        if held is None:
            held = self.held[entity] = [layout, self.clock(), 0, []]
        held[2] += sum(array.nbytes for _, array in components)
        held[3].append((times, components))
        if held[2] >= GATHER_BYTES:
            self.send(entity)

    def send_due(self):
        now = self.clock()
        for entity in [e for e, held in self.held.items() if now - held[1] >= GATHER_SECONDS]:
            self.send(entity)

    def send_all(self):
        for entity in list(self.held):
            self.send(entity)

    def send(self, entity):
        _, _, _, parts = self.held.pop(entity)
        times = [_Index(name, pa.concat_arrays([part[0][i][1] for part in parts]))
                 for i, (name, _) in enumerate(parts[0][0])]
        components = [_Column(descriptor, pa.concat_arrays([part[1][i][1] for part in parts]))
                      for i, (descriptor, _) in enumerate(parts[0][1])]
        self.stream.send_columns(entity, times, components)


#: How a finished .rrd ends (rerun-sdk 0.41): its footer's magic, then 4 bytes.
FOOTER_MAGIC = b'RRF2FOOT'


def _check_finished(descriptor):
    """Raise OSError unless the file written through `descriptor` ends with its footer.

    The SDK's file writer can die on a write error (a full disk, EFBIG) and disconnect then
    return as if all went well: the file, read back, says whether it was finished.
    """
    if descriptor is None:
        return
    with open(f'{_PROC_FDS}/{descriptor}', 'rb') as written:
        size = os.fstat(written.fileno()).st_size
        head = written.read(4)
        written.seek(max(0, size - 12))
        tail = written.read(12)
    if head == b'RRF2' and tail[:8] != FOOTER_MAGIC:
        raise OSError(f'the file was left unfinished (no footer after {size:,} bytes): the '
                      'writer could not write it')


def _receive(channel):
    """A descriptor sent by the node (SCM_RIGHTS) over `channel`."""
    _, descriptors, _, _ = socket.recv_fds(channel, 1, 1)
    if not descriptors:
        raise OSError('no file descriptor came with the call')
    return descriptors[0]


def serve(source, answers, channel=None):
    """Run the calls read from `source` on a RecordingStream, answering what ANSWERED names.

    send_columns calls are gathered (Gathered); a flush writes what the stream has, the
    end (disconnect, or the end of the input) sends everything first. save_fd and part
    take a descriptor from `channel` (a socket): the file is written as /proc/self/fd/N.
    The first error is written to `answers` and ends the child: the parent fails the
    outlet on it, as it would on the in-process stream's error.
    """
    from ball_world.recording.rerun_outlet import new_stream
    stream = gathered = None
    descriptor = None
    while True:
        try:
            name, args, kwargs = pickle.load(source)
        except (EOFError, pickle.UnpicklingError):
            break  # the node is gone (or dropped the outlet): finish the file
        try:
            if name == 'new':
                stream = new_stream(*args)
                gathered = Gathered(stream)
            elif name == 'send_columns':
                gathered.add(*args, **kwargs)
            elif name in ('save_fd', 'part'):
                if name == 'part':
                    signal.alarm(FINISH_SECONDS)  # a part the disk cannot take ends it
                    gathered.send_all()
                    stream.flush(timeout_sec=float(FINISH_SECONDS))
                    stream.disconnect()
                    signal.alarm(0)
                    _check_finished(descriptor)
                    if descriptor is not None:
                        os.close(descriptor)
                        descriptor = None
                if args:  # a path: where /proc/self/fd is not
                    stream.save(args[0], **kwargs)
                else:
                    descriptor = _receive(channel)
                    stream.save(f'{_PROC_FDS}/{descriptor}', **kwargs)
            else:
                if name == 'disconnect':
                    # The SDK's disconnect waits for good on a file whose writer thread
                    # died (a full disk): the alarm ends this process then.
                    signal.alarm(FINISH_SECONDS)
                    gathered.send_all()
                getattr(stream, name)(*args, **kwargs)
                if name == 'disconnect':
                    _check_finished(descriptor)
            if gathered is not None:
                gathered.send_due()
        except Exception as error:  # noqa: B902 - any SDK failure ends this file only
            pickle.dump(_one_line(error), answers)
            answers.flush()
            return 1
        if name in ANSWERED:
            pickle.dump(None, answers)
            answers.flush()
            if name == 'disconnect':
                return 0
    if stream is not None:
        signal.alarm(FINISH_SECONDS)  # a writer that hangs (its disk gone) ends anyway
        gathered.send_all()
        stream.flush(timeout_sec=float(FINISH_SECONDS))
        stream.disconnect()
    return 0


def main():
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    channel = None
    if len(sys.argv) > 1:
        channel = socket.socket(fileno=int(sys.argv[1]))
    import rerun  # noqa: F401 - the SDK loaded before READY: a spare is then quick to take over
    pickle.dump(READY, sys.stdout.buffer)
    sys.stdout.buffer.flush()
    try:
        code = serve(sys.stdin.buffer, sys.stdout.buffer, channel)
    except OSError:  # the node closed its end first (it gave up waiting): it reports that
        code = 1
    # The SDK's at-exit hook would flush again; the file is finished or failed by now.
    os._exit(code)


if __name__ == '__main__':
    main()
