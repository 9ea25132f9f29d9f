"""BackgroundSink: calls run in order on a worker, failures come back, close waits."""
import threading

import pytest

from ball_world.recording.writer_thread import BackgroundSink


class Log:
    """A sink that records its calls and the thread they ran on; can be told to fail."""

    def __init__(self, fail_at=None):
        self.calls = []
        self.threads = set()
        self.fail_at = fail_at

    def _note(self, call):
        self.threads.add(threading.get_ident())
        if call == self.fail_at:
            raise OSError(28, 'No space left on device')
        self.calls.append(call)

    def start_segment(self, world, info):
        self._note(('start', world))

    def write_step(self, record):
        self._note(('step', record))

    def flush(self):
        self._note(('flush',))

    def close(self):
        self._note(('close',))


def test_calls_run_in_order_on_another_thread_and_close_waits_for_them():
    log = Log()
    sink = BackgroundSink(log, max_pending=4)  # small: the producer must wait, not drop
    sink.start_segment(0, None)
    for k in range(500):
        sink.write_step(k)
        if k % 100 == 0:
            sink.flush()
    sink.close()
    expected = [('start', 0)]
    for k in range(500):
        expected.append(('step', k))
        if k % 100 == 0:
            expected.append(('flush',))
    assert log.calls == expected + [('close',)]
    assert log.threads and threading.get_ident() not in log.threads
    sink.close()  # a second close is harmless
    assert log.calls[-1] == ('close',) and log.calls.count(('close',)) == 1


def test_a_failure_is_raised_on_a_later_call_and_nothing_after_it_runs():
    log = Log(fail_at=('step', 3))
    sink = BackgroundSink(log)
    sink.start_segment(0, None)
    with pytest.raises(OSError, match='No space left'):
        for k in range(10_000):
            sink.write_step(k)
    with pytest.raises(OSError):
        sink.close()
    assert log.calls == [('start', 0), ('step', 0), ('step', 1), ('step', 2)]
