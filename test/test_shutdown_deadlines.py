"""No shutdown waits on a peer without a deadline (issue 33, item 4).

A launcher killed outright (SIGKILL) takes its Rerun server with it, and its world is told
to stop (SIGTERM) at the same moment: the world's close must not wait for a viewer that is
gone, nor for the full close timeout of a destination whose last call failed. The figures
(how long each child of a killed launcher lives on) are measured, not asserted here:
docs/reliability.md. What is asserted is the mechanism, in process, with fake streams whose
calls would block for good; the deadlines below only catch a close that hangs.
"""
import socket
import threading
import time

import pytest

from ball_world.recording import rerun_outlet
from ball_world.recording.rerun_outlet import finish_view, Outlet, OutletFailed
from ball_world.tools.processes import Children

#: Longer than any close may take here; only a close that waits for its peer reaches it.
GENEROUS = 60.0


class BlockingStream:
    """A stream whose flush and disconnect never return (a viewer that died mid-call), or
    raise `error` (the SDK's "gRPC connection severed")."""

    def __init__(self, error=None):
        self.error = error
        self.calls = []
        self.release = threading.Event()

    def log(self, *args, **kwargs):
        self.calls.append('log')

    def flush(self, timeout_sec):
        self.calls.append('flush')
        if self.error is not None:
            raise RuntimeError(self.error)
        self.release.wait()

    def disconnect(self):
        self.calls.append('disconnect')
        self.release.wait()


def closed_port():
    """A local port nobody listens on."""
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


def view_outlet(stream, port):
    target = f'rerun+http://127.0.0.1:{port}/proxy'
    return Outlet(f'live view at {target}', stream, connect=lambda: None,
                  probe=lambda: rerun_outlet._probe(('127.0.0.1', port), 'the viewer is gone'))


def test_a_view_whose_viewer_is_gone_is_closed_without_a_word_to_it():
    stream = BlockingStream()
    outlet = view_outlet(stream, closed_port())
    try:
        outlet.call('log', 'a')
        began = time.monotonic()
        with pytest.raises(OutletFailed, match='the viewer is gone'):
            outlet.close(timeout=GENEROUS)
        assert time.monotonic() - began < GENEROUS / 2  # not the timeout: at once
        assert stream.calls == ['log']  # neither flushed nor disconnected
    finally:
        stream.release.set()


def test_a_close_whose_call_fails_returns_at_once_not_at_its_timeout():
    # Before: a failure while closing left the worker waiting for more calls, and close()
    # waited its whole timeout (10 s: the world of a killed ball_world_demo lived 10 s on).
    stream = BlockingStream(error='gRPC connection severed')
    outlet = Outlet('file a.rrd', stream, connect=lambda: None)
    began = time.monotonic()
    with pytest.raises(OutletFailed, match='gRPC connection severed'):
        outlet.close(timeout=GENEROUS)
    assert time.monotonic() - began < GENEROUS / 2


def test_a_view_whose_viewer_does_not_answer_is_left_after_its_close_timeout(monkeypatch):
    monkeypatch.setattr(rerun_outlet, 'VIEW_CLOSE_TIMEOUT', 0.2)
    stream = BlockingStream()
    with socket.socket() as viewer:  # accepts connections, never reads: a frozen viewer
        viewer.bind(('127.0.0.1', 0))
        viewer.listen()
        outlet = view_outlet(stream, viewer.getsockname()[1])
        try:
            with pytest.raises(OutletFailed, match='did not finish within 0.2 s'):
                outlet.close()  # a view's own timeout, not a file's CLOSE_TIMEOUT
            assert stream.calls == ['flush']
        finally:
            stream.release.set()


def test_a_tools_own_view_is_ended_without_waiting_for_a_viewer_that_is_gone():
    stream = BlockingStream()
    try:
        assert not finish_view(stream, f'rerun+http://127.0.0.1:{closed_port()}/proxy',
                               timeout=GENEROUS)
        assert stream.calls == []
    finally:
        stream.release.set()


def test_a_tools_own_view_ends_in_bounded_time_when_its_viewer_hangs():
    stream = BlockingStream()
    with socket.socket() as viewer:
        viewer.bind(('127.0.0.1', 0))
        viewer.listen()
        try:
            assert not finish_view(
                stream, f'rerun+http://127.0.0.1:{viewer.getsockname()[1]}/proxy', timeout=0.2)
            assert stream.calls == ['flush']
        finally:
            stream.release.set()


TRAPPING = """trap 'echo "$1" >> "$2"; exit 0' INT
echo ready >> "$2.ready"
while :; do sleep 0.05; done"""
DEAF = """trap '' INT TERM
echo ready >> "$2.ready"
while :; do sleep 0.05; done"""


def test_a_launcher_stops_its_clients_together_then_the_server_and_escalates(tmp_path):
    log = tmp_path / 'stopped.txt'
    children = Children()
    children.start('server', ['sh', '-c', TRAPPING, 'sh', 'server', log], log=False)
    children.start('world', ['sh', '-c', TRAPPING, 'sh', 'world', log], log=False)
    children.start('deaf', ['sh', '-c', DEAF, 'sh', 'deaf', log], log=False)
    children.start('tracker', ['sh', '-c', TRAPPING, 'sh', 'tracker', log], log=False)
    processes = [child.process for child in children.started]
    deadline = time.monotonic() + GENEROUS
    while not (log.with_name(log.name + '.ready').exists() and len(
            log.with_name(log.name + '.ready').read_text().split()) == 4):
        assert time.monotonic() < deadline, 'the children to start'
        time.sleep(0.05)
    children.stop(seconds=0.3)  # the deaf one: SIGINT, SIGTERM, SIGKILL, 0.3 s apart
    assert all(process.poll() is not None for process in processes)
    order = log.read_text().split()
    assert sorted(order[:2]) == ['tracker', 'world'] and order[2:] == ['server'], order
    assert processes[2].returncode == -9
