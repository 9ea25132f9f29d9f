"""The children of `ball_world_view` and `ball_world_demo`: started together, stopped together.

A launcher that dies must not leave a Rerun server holding its ports (killing `.venv/bin/rerun`,
a Python wrapper that runs the viewer binary as its child, did). So each child:

- runs in a session of its own: the terminal's Ctrl-C reaches the launcher alone, which stops
  the children in two waves: every program but the first started (the world and its
  clients, together, so the world closes its recordings and its view while the server
  still takes it), then the first (the Rerun server the others stream to);
- gets SIGTERM from the kernel the moment the launcher ends, however it ends (SIGKILL
  included: Linux's PR_SET_PDEATHSIG, set in the child between fork and exec); every
  program started here ends within a bounded time of SIGTERM, whatever its peers do (the
  world does not wait for a view whose server is gone: recording/rerun_outlet.py);
- is stopped with SIGINT (what Ctrl-C would send), then SIGTERM, then SIGKILL, each after
  a bounded wait, so stop() always returns.
"""
import ctypes
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time

#: prctl(2) option: the signal a child gets when its parent thread ends.
PR_SET_PDEATHSIG = 1
#: Seconds a child has after SIGINT, and again after SIGTERM, before the next signal.
STOP_SECONDS = 10.0
#: Longest wait for a port to accept connections (a server starting) or to be free.
PORT_SECONDS = 30.0


def _die_with_parent():
    """In the child, before exec: SIGTERM when the launcher ends, however it ends."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() == 1:  # the launcher is already gone: do not start at all
        os._exit(1)


def rerun_binary():
    """The Rerun viewer binary itself, not the `rerun` wrapper script in .venv/bin."""
    import rerun_cli
    return Path(rerun_cli.__file__).parent / 'rerun'


def port_open(port, host='127.0.0.1'):
    """Whether something accepts TCP connections on host:port."""
    try:
        socket.create_connection((host, port), timeout=0.5).close()
        return True
    except OSError:
        return False


def port_free(port, host='127.0.0.1'):
    """Whether host:port can be bound now (no server, no lingering listener)."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
            return True
        except OSError:
            return False


class Child:
    """One started program: its name (for messages), Popen and log file."""

    def __init__(self, name, process, log):
        self.name = name
        self.process = process
        self.log = log

    @property
    def running(self):
        return self.process.poll() is None


class Children:
    """Programs started in order and stopped in two waves, the first started last (see the
    module doc)."""

    def __init__(self, log_dir=None):
        self.log_dir = None if log_dir is None else Path(log_dir)
        self.started = []

    def start(self, name, command, log=True, env=None):
        """Start `command`; its output goes to <log_dir>/<name>.log (or to the terminal
        when log is False or there is no log_dir)."""
        output = None
        if log and self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            output = open(self.log_dir / f'{name}.log', 'wb')
        process = subprocess.Popen(
            [str(part) for part in command], stdin=subprocess.DEVNULL, stdout=output,
            stderr=subprocess.STDOUT if output else None, start_new_session=True,
            preexec_fn=_die_with_parent, env=env)
        child = Child(name, process, output)
        self.started.append(child)
        return child

    def first_ended(self):
        """The first child that has ended, or None."""
        return next((child for child in self.started if not child.running), None)

    def stop(self, seconds=STOP_SECONDS):
        """Stop every child: all but the first started together, then the first; each with
        SIGINT, then SIGTERM, then SIGKILL, `seconds` apart (see the module doc)."""
        _stop([child.process for child in self.started[1:]], seconds)
        _stop([child.process for child in self.started[:1]], seconds)
        for child in self.started:
            if child.log is not None:
                child.log.close()
        self.started = []


def _stop(processes, seconds):
    """Signal every process still running, wait for them all at most `seconds`, and go on
    to the next signal with those left."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        running = [process for process in processes if process.poll() is None]
        if not running:
            return
        for process in running:
            try:
                process.send_signal(sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + seconds
        for process in running:
            try:
                process.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                continue


def wait_for_port(port, child, seconds=PORT_SECONDS):
    """Wait until `port` accepts connections; False if `child` ended or time ran out."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if port_open(port):
            return True
        if not child.running:
            return False
        time.sleep(0.1)
    return False


class Stop(Exception):
    """A signal asked the launcher to stop (SIGINT, SIGTERM, SIGHUP)."""


def raise_on_signals():
    """Turn SIGINT, SIGTERM and SIGHUP into Stop in the main thread."""
    def handler(signum, _frame):
        raise Stop(signal.Signals(signum).name)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, handler)


def hold_signals():
    """From here on, stopping is under way: a second Ctrl-C must not cut it short."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)


def say(prog, text):
    print(f'{prog}: {text}', file=sys.stderr, flush=True)
