"""Supervised worker processes: user code runs in them, and however one ends, the
supervisor says so in one line and leaves no process behind.

multiprocessing.Pool never notices a worker that dies (os._exit, a segfault, SIGKILL): the
map waits for ever. Here each worker is one spawned process with a pipe of its own, and the
supervisor waits on the pipes and the process sentinels together, so a death is seen at
once, named with the job it held ("the worker for seed 17 was killed by SIGSEGV (at
bad.py:7)") and raised as JobFailed; every other worker is then killed.

In a worker (`_worker_main`):
- SIGINT is ignored and the worker leads a session of its own: a terminal's Ctrl-C reaches
  the tool alone, which kills the workers (a KeyboardInterrupt in a worker can only be the
  user code's own, and is one line like any exception);
- the kernel kills it when the tool dies (PR_SET_PDEATHSIG), so none outlives a SIGKILL
  of the tool;
- faulthandler writes the stack of a fatal signal, and of a call that outlives its
  deadline (user_code.calls), to a notes file the supervisor reads after the death; a call
  of os._exit writes its caller there first: the line then says where;
- the user's prints go to stderr (fd 1 is made fd 2): stdout is the tool's report.

A job is (function, argument), the function importable by name (spawn pickles it by
reference); it returns a picklable result or raises. A ValueError's text (the tools' own
one-line errors, and UserCodeError) is passed on as it is; any other exception as
user_code.describe's one line.
"""
import faulthandler
import multiprocessing
import multiprocessing.connection
import os
import shutil
import signal
import sys
import tempfile

from ball_world.user_code.calls import supervise
from ball_world.user_code.describe import (describe_exception, describe_exit, EXIT_NOTE,
                                           parse_notes, UserCodeError, where)

#: Seconds an idle worker gets to end when asked, before it is killed.
GRACE_S = 2.0


class JobFailed(UserCodeError):
    """A job that raised, or whose worker died; the message is one line."""


# In the worker -------------------------------------------------------------------------------

def _die_with_parent(parent_pid):
    """Have the kernel SIGKILL this process when its parent ends (Linux; elsewhere the
    closed pipe ends an idle worker)."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:  # the parent ended before prctl took effect
        os._exit(1)


def _note_exits(notes):
    """os._exit that first writes where it was called from to the notes."""
    real = os._exit

    def _exit(status):
        frames, frame = [], sys._getframe(1)
        while frame is not None:
            frames.append(f'  File "{frame.f_code.co_filename}", line {frame.f_lineno} in '
                          f'{frame.f_code.co_name}')
            frame = frame.f_back
        try:
            notes.write(f'{EXIT_NOTE}{status!r}) called\n' + '\n'.join(frames) + '\n')
            notes.flush()
        finally:
            real(status)

    os._exit = _exit


def _one_line(error):
    if isinstance(error, ValueError) and str(error):
        return ' '.join(str(error).split())
    return describe_exception(error)


def _worker_main(connection, notes_path, path, deadline_s, parent_pid):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        os.setsid()
    except OSError:
        pass
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    _die_with_parent(parent_pid)
    sys.path[:] = path
    os.dup2(2, 1)
    notes = open(notes_path, 'w')
    faulthandler.enable(file=notes, all_threads=False)
    supervise(deadline_s, notes)
    _note_exits(notes)
    while True:
        try:
            message = connection.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        position, function, argument = message
        try:
            result = function(argument)
        except BaseException as error:  # noqa: B902 - one line for anything, then go on
            # Sent before the error is let go: that frees the user's objects, whose __del__
            # may hang; the supervisor has its answer by then.
            connection.send((position, False, _one_line(error)))
            continue
        try:
            connection.send((position, True, result))
        except Exception as error:  # noqa: B902 - an unpicklable result
            connection.send((position, False, f'its result could not be sent back: '
                                              f'{describe_exception(error)}'))


# In the supervisor ----------------------------------------------------------------------------

class _Worker:
    """One worker process, its pipe, its notes file and the job it holds."""

    def __init__(self, context, notes_path, deadline_s):
        self.notes_path = notes_path
        self.connection, child_end = context.Pipe()
        self._child_end = child_end
        self.process = context.Process(
            target=_worker_main, name='ball_world user code', daemon=True,
            args=(child_end, notes_path, list(sys.path), deadline_s, os.getpid()))
        self.job = None  # (position, label) held

    def start(self):
        # The child starts with SIGINT blocked (the mask survives exec) until it ignores it:
        # a Ctrl-C while it starts is the tool's alone.
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            self.process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
            self._child_end.close()

    def send(self, message):
        self.connection.send(message)

    def death(self, label, deadline_text):
        """The one line of this worker's death while it held `label`."""
        self.process.join(GRACE_S)
        try:
            with open(self.notes_path, encoding='utf-8', errors='replace') as notes:
                what, locations = parse_notes(notes.read(1 << 20))
        except OSError:
            what, locations = '', []
        at = where(locations)
        if what.startswith('Timeout'):
            return (f'{label}: user code ran past {deadline_text}{at}; its worker was '
                    'stopped')
        exit_text = describe_exit(self.process.exitcode)
        if what.startswith(EXIT_NOTE):
            exit_text += f': {what.split(" called")[0]}'
        elif self.process.exitcode == -signal.SIGKILL:
            exit_text += ' (sent by another process, or by the kernel when memory ran out)'
        verb = 'was ' if exit_text.startswith('killed') else ''
        return f'the worker for {label} {verb}{exit_text}{at}'

    def kill(self):
        """SIGKILL the worker and its process group (what user code started in it)."""
        self.connection.close()
        if self.process.pid is None:  # never started
            return
        for kill in (lambda: os.killpg(self.process.pid, signal.SIGKILL),
                     self.process.kill):
            try:
                kill()
            except (ProcessLookupError, PermissionError, OSError, AttributeError):
                pass
        self.process.join()

    def stop(self):
        """Ask an idle worker to end; kill it if it does not within the grace."""
        if self.process.pid is not None:
            try:
                self.connection.send(None)
            except (OSError, ValueError):
                pass
            self.process.join(GRACE_S)
        self.kill()


#: A pool's notes folder in the temporary directory: NOTES_PREFIX<pid of its process>_<random>.
NOTES_PREFIX = 'ball_world_workers_'


def notes_folder():
    """A new folder for a pool's notes, named after this process, having removed those of
    processes that are gone. Why: a pool kept for a process's life (ray_pool's, one per Ray
    worker) is never closed when Ray kills that process, and would leave its folder behind
    on every run."""
    root = tempfile.gettempdir()
    try:
        names = os.listdir(root)
    except OSError:
        names = []
    for name in names:
        pid = name[len(NOTES_PREFIX):].split('_', 1)[0]
        if name.startswith(NOTES_PREFIX) and pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(os.path.join(root, name), ignore_errors=True)
    return tempfile.mkdtemp(prefix=f'{NOTES_PREFIX}{os.getpid()}_')


def _alive(pid):
    """Whether process `pid` exists (one of another user counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: it exists
        return True
    return True


class LocalPool:
    """The local executor: `jobs` supervised worker processes on this machine.

    map_unordered(function, arguments, labels) yields (position, result) as jobs end and
    raises JobFailed (one line) at the first that fails; leaving the `with` block (normally,
    by an error or a KeyboardInterrupt) ends every worker: idle ones are asked, busy ones
    killed at once.
    """

    def __init__(self, jobs, deadline_s=None, deadline_text='its deadline'):
        self.jobs = max(1, int(jobs))
        self.deadline_s = deadline_s
        self.deadline_text = deadline_text
        self._context = multiprocessing.get_context('spawn')
        self._notes = notes_folder()
        self._workers = []

    def __enter__(self):
        return self

    def __exit__(self, kind, error, trace):
        self.close(abort=kind is not None)

    def _new_worker(self):
        worker = _Worker(self._context, os.path.join(
            self._notes, f'worker_{len(self._workers)}.txt'), self.deadline_s)
        self._workers.append(worker)  # before it starts: close() ends it whatever happens
        worker.start()
        return worker

    def map_unordered(self, function, arguments, labels):
        arguments = list(arguments)
        waiting = list(range(len(arguments)))[::-1]
        idle = [w for w in self._workers if w.job is None and w.process.is_alive()]
        while len(self._workers) < self.jobs:  # all at once: they start side by side
            idle.append(self._new_worker())
        busy = []
        while waiting or busy:
            while waiting and idle:
                worker = idle.pop()
                position = waiting.pop()
                worker.job = (position, labels[position])
                busy.append(worker)
                try:
                    worker.send((position, function, arguments[position]))
                except (OSError, ValueError):
                    pass  # it died: its sentinel says so below
            ready = multiprocessing.connection.wait(
                [w.connection for w in busy] + [w.process.sentinel for w in busy])
            for worker in list(busy):
                if worker.connection not in ready and worker.process.sentinel not in ready:
                    continue
                position, label = worker.job
                reply = None
                try:
                    if worker.connection.poll():
                        reply = worker.connection.recv()
                except (EOFError, OSError):
                    reply = None
                if reply is None:
                    if worker.process.is_alive() and worker.process.sentinel not in ready:
                        continue
                    raise JobFailed(worker.death(label, self.deadline_text))
                busy.remove(worker)
                worker.job = None
                idle.append(worker)
                _, ok, value = reply
                if not ok:
                    raise JobFailed(value)
                yield position, value

    def close(self, abort=False):
        """End every worker (killed at once when abort) and remove the notes."""
        workers, self._workers = self._workers, []
        for worker in workers:
            if abort or worker.job is not None:
                worker.kill()
            else:
                worker.stop()
        shutil.rmtree(self._notes, ignore_errors=True)


def _make(argument):
    spec, option, args = argument
    from ball_world.user_code.calls import call
    from ball_world.user_code.loading import load_class
    found = load_class(spec, option)
    _held['object'] = call(f'{option} {spec}: making one', found, *args)
    return True


def _invoke(argument):
    method, args = argument
    from ball_world.user_code.calls import call
    held = _held['object']
    function = getattr(held, method, None)
    if not callable(function):
        raise UserCodeError(f'{type(held).__name__} has no method {method}')
    return call(f'{type(held).__name__}.{method}', function, *args)


_held = {}


class Remote:
    """One user object (a controller) living in a supervised worker of its own.

    Remote(spec, option, args) loads the class `spec` names and makes one with `args` in
    the worker; remote.call(method, *args) calls a method there and returns its result
    (pickled both ways: numpy arrays travel as they are); a failure of any kind raises
    JobFailed in one line, and the worker is then gone. close() ends it.
    """

    def __init__(self, spec, option='--controller', args=(), deadline_s=None,
                 deadline_text='its deadline'):
        self._pool = LocalPool(1, deadline_s, deadline_text)
        self.label = f'{option} {spec}'
        try:
            self._request(_make, (spec, option, tuple(args)))
        except BaseException:
            self.close()
            raise

    def _request(self, function, argument):
        for _, result in self._pool.map_unordered(function, [argument], [self.label]):
            return result

    def call(self, method, *args):
        try:
            return self._request(_invoke, (method, args))
        except BaseException:
            self.close()
            raise

    def close(self):
        self._pool.close()

    def __enter__(self):
        return self

    def __exit__(self, kind, error, trace):
        self.close()
