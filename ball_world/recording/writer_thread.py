"""Run a sink on its own thread, so compression and file I/O never hold up stepping.

At 10,000 balls a step's MCAP record is about 1.2 MB before compression: writing it on the
stepping thread costs about 2 ms of a 10 ms period, with spikes when the OS flushes. lz4
compression and file writes release the GIL, so on a worker thread they run beside the
physics on the second core. Calls run in order, so the file is the same as if written
inline. The queue is bounded: if the disk cannot keep up, stepping slows down (back-pressure)
rather than dropping anything or growing memory without limit.
"""
import queue
import threading
import time

#: Steps that may wait for the writer; about 0.6 s at 100 Hz, about 0.8 GB at 10,000 balls.
MAX_PENDING = 64


class BackgroundSink:
    """Wraps a Sink; its calls return at once and run, in order, on a worker thread.

    A failure of the wrapped sink is raised from the next call made on the stepping thread
    (so the Simulation drops the sink and reports it once); the calls queued behind the
    failure are discarded, since the file they were for is already broken.
    """

    def __init__(self, sink, max_pending=MAX_PENDING):
        self.sink = sink
        self.waited = 0.0  # seconds the stepping thread waited for the writer, in all
        self._queue = queue.Queue(maxsize=max_pending)
        self._error = None
        self._closed = False
        self._thread = threading.Thread(
            target=self._work, name=f'{type(sink).__name__}-writer', daemon=True)
        self._thread.start()

    @property
    def wants_carried_state(self):
        """Whether the wrapped sink wants exact mode's carried state in each record."""
        return getattr(self.sink, 'wants_carried_state', False)

    def _work(self):
        while True:
            call, args = self._queue.get()
            if call is None:
                return
            if self._error is None:
                try:
                    call(*args)
                except Exception as error:  # noqa: B902 - handed to the stepping thread
                    self._error = error

    def _submit(self, call, *args):
        if self._error is not None:
            raise self._error
        try:
            self._queue.put_nowait((call, args))
        except queue.Full:  # the writer is behind: stepping waits for it (back-pressure)
            began = time.monotonic()
            self._queue.put((call, args))
            self.waited += time.monotonic() - began

    def start_segment(self, world, info):
        self._submit(self.sink.start_segment, world, info)

    def write_step(self, record):
        self._submit(self.sink.write_step, record)

    def write_pending(self, events):
        if hasattr(self.sink, 'write_pending'):
            self._submit(self.sink.write_pending, events)

    def flush(self):
        self._submit(self.sink.flush)

    def close(self):
        """Finish the queued work and the file; waits for the worker."""
        if self._closed:
            return
        self._closed = True
        self._queue.put((self.sink.close, ()))
        self._queue.put((None, ()))
        self._thread.join()
        if self._error is not None:
            raise self._error
