"""rcl's start, with one line for the user when it cannot start.

rcl reports a bad `--ros-args` (a params file that is missing or is not valid YAML, a
malformed `-p`) by logging its own `[ERROR] ... [rcl]: Failed to parse global arguments`
straight to the process's stderr, then raising an exception whose text names C source
files. The node promises one clear line for bad input, so rcl's own output is held back
while it parses (file descriptor 2 goes to a temporary file), and the failure is told in
one line without the source locations. When rcl starts fine, what it wrote is passed on.

A node that never comes: the first node of a context makes its DDS participant, and Fast
DDS's shared-memory transport can spin there for good, inside a C call that holds the GIL
(docs/reliability.md). Every program of the package makes its nodes inside creating_node():
a watchdog process (ros/node_watchdog.py, which lives while the node is made; a process
that makes many, as a test's, keeps one) says after NODE_SECONDS why the node has not come
and what to do, and ends the process on Ctrl-C or SIGTERM, which the stuck process itself
can no longer act on.
"""
import contextlib
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading

import rclpy
from rclpy.signals import (get_current_signal_handlers_options, install_signal_handlers,
                           SignalHandlerOptions, uninstall_signal_handlers)

from ball_world.ros import node_watchdog

#: ", at /project/src/rcl/arguments.c:415" and the like: where in rcl, not what is wrong.
_SOURCE_LOCATION = re.compile(r',? at [^\s,]+\.c:\d+')


def init_quietly(args):
    """rclpy.init(args=args); None when it started, else the one line saying why not."""
    unreadable = _unreadable_params_file(sys.argv if args is None else args)
    if unreadable is not None:
        return unreadable
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as held:
            os.dup2(held.fileno(), 2)
            try:
                rclpy.init(args=args)
                failure = None
            except Exception as error:  # noqa: B902 - rcl reports bad arguments generically
                failure = error
            finally:
                os.dup2(saved, 2)
            if failure is None:
                held.seek(0)
                sys.stderr.write(held.read().decode('utf-8', errors='replace'))
                return None
    finally:
        os.close(saved)
    return describe(failure)


def _unreadable_params_file(argv):
    """Why a --params-file of the ROS arguments cannot be read (rcl says only "Error
    opening YAML file"), or None."""
    argv = list(argv)
    for flag, path in zip(argv, argv[1:]):
        if flag == '--params-file':
            try:
                with open(path, 'rb'):
                    pass
            except OSError as error:
                return f'params file {path!r}: {error.strerror or error}'
    return None


def describe(error):
    """rcl's exception text as one line, without its C source locations."""
    text = _SOURCE_LOCATION.sub('', ' '.join(str(error).split()))
    text = text.replace('failed to initialize rcl: ', '')
    return text.rstrip('. ') or type(error).__name__


#: Seconds a node may take to be made before the process says why it has not been.
NODE_SECONDS = 10.0
#: Seconds a process making its node has to act on SIGINT or SIGTERM before its watchdog
#: ends it (a process that is not stuck has made its node by then, and acts on it itself).
STUCK_GRACE = 1.0
#: The signals a stuck process is ended on.
STOPPING = (signal.SIGINT, signal.SIGTERM)
#: The watchdog kept for many nodes, by pid (a forked child starts its own).
_kept = {}


@contextlib.contextmanager
def creating_node(prog=None, seconds=NODE_SECONDS, grace=STUCK_GRACE, keep=False):
    """Make a node inside this: if it takes `seconds`, one line says why and what to do, and
    SIGINT or SIGTERM ends the process even while rcl holds it (see the module doc).

    A signal that comes while the node is made is held and raised again once it is made (in
    the main thread, where Python can take signals), so the program sees it as before.
    keep: the watchdog stays for this process's next nodes (a test process makes hundreds);
    else it ends with the node made, unless one is kept already (then that one watches,
    with its own prog and seconds).
    """
    prog = prog or os.path.basename(sys.argv[0]) or 'python'
    watchdog = _kept.get(os.getpid()) or _Watchdog.start(prog, seconds, grace)
    if keep and watchdog is not None:
        _kept[os.getpid()] = watchdog
    if watchdog is None:
        yield
        return
    caught = []
    swapped = None
    if threading.current_thread() is threading.main_thread():
        swapped = _take_signals(watchdog.fd, caught)
    watchdog.send(node_watchdog.ARM)
    try:
        yield
    finally:
        watchdog.send(node_watchdog.DISARM)
        try:
            if swapped is not None:
                _give_signals_back(swapped)  # before the pipe may close: no signal writes to it
        finally:
            if watchdog not in _kept.values():
                watchdog.end()
        for signum in dict.fromkeys(caught):  # as if they came now
            signal.raise_signal(signum)


class _Watchdog:
    """The running ros/node_watchdog.py of this process and the pipe to it."""

    def __init__(self, prog, seconds, grace):
        read, self.fd = os.pipe()
        os.set_blocking(self.fd, False)  # signal.set_wakeup_fd needs it
        try:
            self.process = subprocess.Popen(
                [sys.executable, '-I', '-S', node_watchdog.__file__, str(os.getpid()),
                 str(read), prog, repr(float(seconds)), repr(float(grace))],
                pass_fds=(read,), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                start_new_session=True)  # no terminal signals: its parent's come by the pipe
        finally:
            os.close(read)

    @classmethod
    def start(cls, prog, seconds, grace):
        """A new watchdog, or None when no process can be started (the node is made all the
        same, without one)."""
        try:
            return cls(prog, seconds, grace)
        except OSError:
            return None

    def send(self, byte):
        try:
            os.write(self.fd, byte)
        except OSError:  # it is gone (or far behind): the node is made all the same
            pass

    def end(self):
        """Stop it now and reap it, so that no process of it outlives the node's making."""
        os.close(self.fd)
        self.process.kill()
        self.process.wait()


def _take_signals(fd, caught):
    """While the node is made: SIGINT and SIGTERM are written to the watchdog's pipe by
    Python's C-level handler (rclpy's own handlers, which need the GIL, are set aside) and
    held in `caught`. Returns what _give_signals_back restores."""
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, STOPPING)
    try:
        options = get_current_signal_handlers_options()
        if options != SignalHandlerOptions.NO:
            uninstall_signal_handlers()
        previous = {}
        for sig in STOPPING:
            if signal.getsignal(sig) is not None:  # None: set outside Python, left alone
                previous[sig] = signal.signal(sig, lambda signum, _frame: caught.append(signum))
        wakeup = signal.set_wakeup_fd(fd, warn_on_full_buffer=False)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    return options, previous, wakeup


def _give_signals_back(swapped):
    options, previous, wakeup = swapped
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, STOPPING)
    try:
        signal.set_wakeup_fd(wakeup)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if options != SignalHandlerOptions.NO:
            install_signal_handlers(options)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
