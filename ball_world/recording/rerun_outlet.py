"""Where a Rerun recording goes (an .rrd file, a live viewer), each on its own worker thread.

The Rerun SDK can block its caller for good: when the disk fills under an .rrd, the file
writer thread dies and `RecordingStream.flush` may wait forever for an answer that never
comes (seen with rerun-sdk 0.41); a gRPC sink whose viewer never answers waits 5 s on
`disconnect`. The simulation must step on and stop cleanly whatever the destination does,
so every SDK call of a destination runs on a thread of its own, fed by a bounded queue that
the stepping thread never waits on, and every wait on that thread is bounded:

- a call that raises (a write error, a flush of the file that times out) fails the outlet;
  a view's flushes may time out for VIEW_PATIENCE s (a slow viewer) before it fails;
- a call that has not returned after STALL_SECONDS fails it too, and so does a full queue:
  at once for a view, and for a file once no call has begun or ended for STALL_SECONDS (a
  file's writer slower than a burst of steps, on a loaded machine, holds the steps back
  instead of losing the recording); the stuck thread is abandoned (a daemon) with its
  stream, and the SDK's at-exit hook, which would wait on that stream for good, is dropped;
- a view is also failed when its viewer's port stops accepting connections: the SDK drops
  data silently once a viewer is gone, so only a probe can tell (a stalled viewer still
  accepts connections and is kept: the SDK drops what it cannot send, never blocking);
- closing a view waits at most VIEW_CLOSE_TIMEOUT, and not at all for a viewer that is
  gone: the SDK's flush and disconnect wait seconds on a peer that died (the viewer of
  `ball_world_view` ends with its launcher, when the world is told to stop too), and a view
  holds nothing that outlives the run, so the world's exit never waits on one.

Each outlet has its own RecordingStream with the same application and recording id, so the
file and the viewer hold one recording with the same content, and one can fail alone.
"""
import ctypes
import os
from pathlib import Path
import queue
import shutil
import socket
import sys
import threading
import time
from urllib.parse import urlsplit

import rerun as rr

#: A call still running after this long means the destination hangs: the outlet is dropped.
STALL_SECONDS = 5.0
#: Longest wait of a flush for the stream to write what was logged.
FLUSH_TIMEOUT = 2.0
#: A viewer may be too slow to take the data (its flushes time out) for this long before
#: the view is dropped; meanwhile the SDK holds what it could not send.
VIEW_PATIENCE = 10.0
#: Longest wait of close() for an outlet to finish its file.
CLOSE_TIMEOUT = 10.0
#: Longest wait of close() for a view to send what is left: its viewer keeps nothing the run
#: needs, and a process told to stop must not wait on a peer (see the module doc).
VIEW_CLOSE_TIMEOUT = 1.0
#: Calls that may wait for the worker (a logged step makes a few per 64 steps).
MAX_QUEUED_CALLS = 256
#: How often a step held back by a file's full queue looks whether its worker is stuck.
QUEUE_POLL_SECONDS = 0.1
#: Streams of failed outlets, never touched again and never destroyed (_keep_forever).
_ABANDONED = []
#: Longest wait for a viewer's port to accept the liveness probe.
PROBE_TIMEOUT = 1.0

SPAWN = 'spawn'
#: Port of the native viewer that `spawn` starts (the SDK's default).
SPAWN_PORT = 9876
#: URL schemes of a viewer. The port must be written out: without one, urllib (and a
#: reader) would take the scheme's 80 or 443, where no viewer listens.
VIEW_SCHEMES = ('rerun', 'rerun+http', 'rerun+https')


class OutletFailed(RuntimeError):
    """A destination stopped taking data; the message says which and why, in one line."""


def parse_view(value):
    """(host, port) of a view: 'spawn' or a rerun+http(s)://HOST:PORT/proxy URL.

    Raises ValueError with the accepted forms, so a typo is refused at start rather than
    found out as a view that never shows anything.
    """
    if value == SPAWN:
        return '127.0.0.1', SPAWN_PORT
    try:
        parts = urlsplit(value)
        port = parts.port
    except ValueError:
        parts, port = None, None
    if (parts is None or parts.scheme not in VIEW_SCHEMES or not parts.hostname
            or parts.path != '/proxy' or parts.query or parts.fragment or not port):
        raise ValueError(f"expected 'spawn' or a URL like rerun+http://127.0.0.1:9876/proxy, "
                         f'with a port from 1 to 65535, got {value!r}')
    return parts.hostname, port


def spawn_call(stream, blueprint, viewer=None):
    """(function, keyword arguments) that start a native viewer and connect `stream` to it.

    The viewer is the `rerun` beside this Python (the SDK's own, in the .venv) when there is
    one, else the first on PATH. Only the SDK's module-level rr.spawn takes
    `executable_path` (RecordingStream.spawn of rerun-sdk 0.41 has no such argument), and it
    connects the stream given as `recording`; test_rerun binds these arguments to the
    installed SDK's signature.
    """
    viewer = Path(sys.executable).parent / 'rerun' if viewer is None else Path(viewer)
    arguments = dict(port=SPAWN_PORT, default_blueprint=blueprint, recording=stream)
    if viewer.exists():
        arguments['executable_path'] = str(viewer)
    return rr.spawn, arguments


def new_stream(application_id, recording_id, flush_seconds=None):
    """A stream with the simulation's timelines only (no wall-clock log_time, no log_tick).

    flush_seconds: how long the SDK gathers logged rows into one chunk per entity before
    sending them (its default, 0.2 s, when None).
    """
    config = None if flush_seconds is None else rr.ChunkBatcherConfig(flush_tick=flush_seconds)
    stream = rr.RecordingStream(application_id, recording_id=recording_id,
                                send_properties=False, batcher_config=config)
    stream.set_log_time_enabled(False)
    stream.set_log_tick_enabled(False)
    return stream


class Outlet:
    """One destination: a RecordingStream whose calls run, in order, on a worker thread.

    call(name, *args) queues stream.<name>(*args) and returns at once, never raising: the
    stepping path stays free of failure handling. A failure is raised as OutletFailed, once,
    from the next flush() or close(); from then on the outlet drops every call (`failed`
    holds the reason).
    """

    #: A file's claim (recording.files.OutputClaim): the file being written.
    claim = None

    def __init__(self, description, stream, connect, probe=None, explain=None, claim=None):
        self.description = description
        self.stream = stream
        self.claim = claim
        if claim is not None and explain is None:
            explain = self._file_state
        self.failed = None
        self._probe = probe
        self._explain = explain
        self._late_since = None  # a view: when its flushes started timing out
        self._error = None
        self._reported = False
        self._busy_since = None
        self._progress = time.monotonic()  # when the worker last began or ended a call
        self._queue = queue.Queue(maxsize=MAX_QUEUED_CALLS)
        self._close_ended = threading.Event()  # the worker ran _close, well or not
        self._thread = threading.Thread(target=self._work, daemon=True,
                                        name=f'rerun-{description.split()[0]}')
        self._thread.start()
        self._put(connect, ())

    @classmethod
    def file(cls, claim, stream, blueprint):
        """Write the claimed file (recording.files.OutputClaim): the stream saves to its
        descriptor (OutputClaim.fd_path), never to a path that could have changed since."""
        return cls(f'file {str(claim.path)!r}', stream, lambda: _save(stream, claim, blueprint),
                   claim=claim)

    def next_file(self, claim, blueprint, done=None):
        """Queue the move to the next file of a split .rrd: the file being written is
        finished (its footer written) and the stream goes on in `claim`; done() is called
        on the worker once the old file is complete (not when the move failed)."""
        def move():
            stream = self.stream
            if hasattr(stream, 'next_file'):
                stream.next_file(claim, blueprint)
            else:
                stream.flush(timeout_sec=FLUSH_TIMEOUT)
                stream.disconnect()
                stream.save(claim.fd_path(), default_blueprint=blueprint)
            self.description = f'file {str(claim.path)!r}'
            self.claim = claim
            if done is not None:
                done()
        self._put(move, ())

    @classmethod
    def view(cls, target, stream, blueprint):
        """Stream to a viewer: target is 'spawn' or a URL (checked with parse_view)."""
        address = parse_view(target)
        if target == SPAWN:
            spawn, arguments = spawn_call(stream, blueprint)

            def connect():
                spawn(**arguments)
            description = f'live view in the viewer spawned on port {SPAWN_PORT}'
        else:
            def connect():
                _probe(address, 'no viewer listens there')
                stream.connect_grpc(target, default_blueprint=blueprint)
            description = f'live view at {target}'
        return cls(description, stream, connect,
                   probe=lambda: _probe(address, 'the viewer is gone'))

    # Caller's side ----------------------------------------------------------------------

    def call(self, name, *args, **kwargs):
        """Queue stream.<name>(*args, **kwargs), or drop it if the outlet failed."""
        method = getattr(self.stream, name)
        self._put(lambda: method(*args, **kwargs), ())

    def flush(self):
        """Raise OutletFailed once if the outlet failed; else queue a bounded flush.

        A view's flush also probes the viewer's port.
        """
        self.check()
        self._put(self._flush, ())

    def close(self, timeout=None):
        """Flush, finish the file or connection, and wait for it at most `timeout` s
        (CLOSE_TIMEOUT for a file, VIEW_CLOSE_TIMEOUT for a view).

        Raises OutletFailed if the outlet failed before or during the close and that was
        not reported yet.
        """
        if timeout is None:
            timeout = CLOSE_TIMEOUT if self._probe is None else VIEW_CLOSE_TIMEOUT
        if self.failed is None and self._error is None:
            self._put(self._close, ())
            if not self._close_ended.wait(timeout):
                self._fail(f'did not finish within {timeout:g} s')
        self._check()

    def check(self):
        """Raise OutletFailed once if the outlet failed or hangs."""
        busy_since = self._busy_since
        if self._error is None and busy_since is not None \
                and time.monotonic() - busy_since > STALL_SECONDS:
            self._fail(f'no answer for {STALL_SECONDS:g} s')
        self._check()

    def _check(self):
        if self._error is not None and not self._reported:
            self._reported = True
            self.failed = self._error
            self._abandon()
            raise OutletFailed(f'{self.description}: {self._error}')

    def _put(self, call, args):
        if self._error is not None:
            return
        try:
            self._queue.put_nowait((call, args))
            return
        except queue.Full:
            if self.claim is None:
                self._fail(f'no answer: {MAX_QUEUED_CALLS} calls waiting')
                return
        # A file: slow is not stuck. Wait for room while its worker makes progress.
        while self._error is None:
            try:
                self._queue.put((call, args), timeout=QUEUE_POLL_SECONDS)
                return
            except queue.Full:
                if time.monotonic() - self._progress > STALL_SECONDS:
                    self._fail(f'no answer: {MAX_QUEUED_CALLS} calls waiting, none begun or '
                               f'ended for {STALL_SECONDS:g} s')

    def _fail(self, error):
        if self._error is None:
            self._error = error
            if self._explain is not None:
                self._error += f' ({self._explain()})'

    def _abandon(self):
        """Drop the queued calls and let the worker end the stream, if it still can.

        The SDK's at-exit hook disconnects every stream, and on a stream whose file writer
        died that waits forever (the process then never exits, whatever the signal). Every
        outlet that still works is closed explicitly by its sink, so the hook is dropped.
        """
        rr.unregister_shutdown()
        while True:
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        try:
            self._queue.put_nowait((None, ()))
        except queue.Full:
            pass

    def _file_state(self):
        return _file_state(self.claim)

    # Worker's side ----------------------------------------------------------------------

    def _work(self):
        while True:
            call, args = self._queue.get()
            if call is None:
                # A failed stream is left as it is: disconnecting one whose file writer
                # died can abort the process (seen with rerun-sdk 0.41). It is kept alive
                # for good, so no destructor of it runs, not even at the process's end.
                _keep_forever(self.stream)
                return
            if self._error is not None:
                if call == self._close:
                    self._close_ended.set()  # failed before: nothing more to wait for
                continue
            self._busy_since = self._progress = time.monotonic()
            try:
                call(*args)
            except Exception as error:  # noqa: B902 - any SDK failure ends this outlet only
                self._fail(_one_line(error))
            finally:
                self._busy_since = None
                self._progress = time.monotonic()
            if call == self._close:
                self._close_ended.set()
                if self._error is None:
                    return

    def _flush(self):
        if self._probe is None:
            self.stream.flush(timeout_sec=FLUSH_TIMEOUT)
            return
        # A view: a timed-out flush is a slow viewer, which may catch up; a broken
        # connection, a closed port or VIEW_PATIENCE s of timeouts is a viewer gone.
        try:
            self.stream.flush(timeout_sec=FLUSH_TIMEOUT)
            self._late_since = None
        except RuntimeError as error:
            if 'timed out' not in str(error):
                raise
            now = time.monotonic()
            self._late_since = self._late_since or now
            if now - self._late_since >= VIEW_PATIENCE:
                raise RuntimeError(f'the viewer took no data for {VIEW_PATIENCE:g} s') from None
        self._probe()

    def _close(self):
        if self._probe is not None:
            # A view: a viewer that is gone is not waited for (the flush would time out
            # and the disconnect wait on it); the stream is left as a failed one is.
            self._probe()
            self.stream.flush(timeout_sec=VIEW_CLOSE_TIMEOUT)
        else:
            self.stream.flush(timeout_sec=FLUSH_TIMEOUT)
        self.stream.disconnect()


def finish_view(stream, target, timeout=VIEW_CLOSE_TIMEOUT):
    """End a live view's stream made on this thread (a tool's own view, not an Outlet):
    what is left is sent if the viewer at `target` is still there, waiting at most `timeout`
    s; a viewer that is gone, or a stream that fails or does not finish in time, is left as
    a failed outlet's is (never disconnected, never destroyed). Returns whether it finished."""
    def finish():
        try:
            _probe(parse_view(target), 'the viewer is gone')
            stream.flush(timeout_sec=timeout)
            stream.disconnect()
            done.set()
        except Exception:  # noqa: B902 - a view that fails at its end is simply left
            pass

    done = threading.Event()
    worker = threading.Thread(target=finish, daemon=True, name='rerun-view-end')
    worker.start()
    worker.join(timeout)
    if not done.is_set():
        rr.unregister_shutdown()  # the SDK's at-exit disconnect would wait on the viewer
        _keep_forever(stream)
    return done.is_set()


def _keep_forever(stream):
    """Keep the stream alive past the interpreter's teardown (one reference never given back).

    When the interpreter ends, it clears module globals, so a list alone would let the stream
    go: its __del__, and every other stream's, disconnects the SDK's orphaned recordings, and
    disconnecting one whose file writer died waits forever (a test process, once in many
    runs on a loaded machine, printed its last line and never exited).
    """
    _ABANDONED.append(stream)
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(stream))


def _probe(address, reason):
    """Raise OSError(reason) if nothing accepts a TCP connection at address."""
    try:
        socket.create_connection(address, timeout=PROBE_TIMEOUT).close()
    except OSError as error:
        raise OSError(f'{reason} ({error.strerror or error})') from None


def _save(stream, claim, blueprint):
    """Make the stream write the claimed file: a child is sent its descriptor."""
    if hasattr(stream, 'save_file'):
        stream.save_file(claim, blueprint)
    else:
        stream.save(claim.fd_path(), default_blueprint=blueprint)


def _file_state(claim):
    """How far a file got and the room left beside it: what a write error usually means."""
    try:
        size = claim.size()
        free = shutil.disk_usage(os.path.dirname(os.path.abspath(claim.path))).free
    except OSError as error:
        return error.strerror or str(error)
    return f'{size:,} bytes written, {free:,} bytes free on its file system'


def _one_line(error):
    text = ' '.join(str(error).split()) or type(error).__name__
    return text
