"""The Ray executor: jobs as tasks on an existing Ray cluster, failing as the local pool
fails, in one line.

`RayPool(address, jobs, most, deadline_s, deadline_text)` has the executor's methods
(user_code's docstring): `jobs` tasks in flight at most (default: the cluster's CPUs),
map_unordered yields (position, result) as tasks end, close() cancels what still runs.
`address` is a cluster's 'host:port' or 'auto' (the cluster `ray start` runs on this
machine). ray is imported here alone, so nothing else pays its import.

Why each task runs its job in a supervised worker (user_code.workers.LocalPool of one,
kept by the Ray worker between tasks): a tracker that calls os._exit, crashes the
interpreter or hangs is then seen, timed out and named exactly as on this machine ("the
worker for seed 17 was killed by SIGSEGV (at bad.py:7)"), the Ray worker itself never
dies, and the line comes back as the task's result. A Ray worker or node that dies all
the same (out of memory, a node lost) is JobFailed too, with Ray's reason in one line.
Tasks are never retried (max_retries=0): a failure is the run's end, and close() cancels
every task still running with ray.cancel(force=True), which kills its worker (and the
supervised worker with it: it dies with its parent).

The results are bit for bit the local ones when the workers have the same ball_world and
numpy (docs/scoring.md): each job's numbers are its own and the caller orders them.
"""
import atexit
import logging
import os
import signal
import socket
import threading

from ball_world.user_code.describe import UserCodeError
from ball_world.user_code.workers import JobFailed, LocalPool

#: Seconds to reach the cluster (a TCP connection to ADDRESS, then ray.init's own).
CONNECT_S = 15.0


class ClusterError(UserCodeError):
    """A Ray cluster that cannot be used; the message is one line."""


def _one_line(error):
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[0] if lines else type(error).__name__


def _probe(address, connect_s, given=None):
    """ClusterError unless something listens at 'host:port' (ray.init itself would retry
    for ever, logging to the terminal). `given`: what the user gave, for the message."""
    given = given or address
    host, _, port = address.removeprefix('ray://').rpartition(':')  # ray://: Ray Client
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ClusterError(f"--ray {given}: expected HOST:PORT (the head node's GCS "
                           'address, e.g. 10.0.0.5:6379) or auto')
    try:
        socket.create_connection((host.strip('[]'), int(port)), timeout=connect_s).close()
    except OSError as error:
        reason = error.strerror or _one_line(error) or 'timed out'
        raise ClusterError(f'--ray {given}: no Ray cluster answers there ({reason})') \
            from None


def _probe_auto(connect_s):
    """Probe the cluster 'auto' means (RAY_ADDRESS, or the last `ray start` on this
    machine, which may be long gone: ray.init would then retry for ever)."""
    try:
        from ray._private.services import get_ray_address_from_environment
    except ImportError:  # Ray's private helper moved: ray.init finds it alone
        return
    try:
        found = get_ray_address_from_environment('auto', None)
    except Exception as error:  # noqa: B902 - none found; each kind is one line
        raise ClusterError(f'--ray auto: no Ray cluster runs on this machine '
                           f'({_one_line(error)})') from None
    if found and found != 'auto':
        _probe(found, connect_s, f'auto (the cluster at {found})')


def connect(address, connect_s=CONNECT_S):
    """The ray module, connected to the cluster at `address` (ClusterError, one line)."""
    if not _connected() and address != 'auto':
        _probe(address, connect_s)  # before importing ray: an unreachable address is quick
    # gRPC's C core logs errors of its own shutdown on stderr at the process's exit
    # ("backup_poller.cc ... Timer list shutdown"), which is the tool's report channel: it is
    # told to keep quiet before Ray loads it (a user's own setting is kept).
    os.environ.setdefault('GRPC_VERBOSITY', 'NONE')
    try:
        import ray
    except ImportError:
        raise ClusterError('--ray needs the ray package (pip install ray==2.60.0)') from None
    if ray.is_initialized():
        return ray
    if address == 'auto':
        _probe_auto(connect_s)
    # ray.init replaces the SIGTERM handler (with one that exits at once): the tool's own
    # (one line, tasks cancelled) is put back.
    main = threading.current_thread() is threading.main_thread()
    handler = signal.getsignal(signal.SIGTERM) if main else None
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR,
                 configure_logging=True)
    except Exception as error:  # noqa: B902 - Ray raises many kinds; each is one line
        raise ClusterError(f'--ray {address}: could not connect to a Ray cluster: '
                           f'{_one_line(error)}') from None
    finally:
        if handler is not None:
            signal.signal(signal.SIGTERM, handler)
    return ray


def _connected():
    try:
        import ray
    except ImportError:
        return False
    return ray.is_initialized()


# On a Ray worker ------------------------------------------------------------------------------

_pools = {}


def _close_pools():
    for pool in _pools.values():
        pool.close(abort=True)
    _pools.clear()


def run_supervised(task):
    """A Ray task: (True, function(argument)) run in this Ray worker's supervised worker, or
    (False, the one line of its failure)."""
    function, argument, label, deadline_s, deadline_text = task
    key = (deadline_s, deadline_text)
    pool = _pools.get(key)
    if pool is None:
        if not _pools:
            atexit.register(_close_pools)
        pool = _pools[key] = LocalPool(1, deadline_s, deadline_text)
    try:
        for _, result in pool.map_unordered(function, [argument], [label]):
            return True, result
    except JobFailed as error:
        del _pools[key]
        pool.close(abort=True)
        return False, str(error)


# On the driver -------------------------------------------------------------------------------

def _failure(ray, error, label):
    """The one line of a task that raised in Ray itself (its worker or node died)."""
    if isinstance(error, ray.exceptions.TaskCancelledError):
        return f'the Ray task for {label} was cancelled'
    if isinstance(error, ray.exceptions.RayTaskError):  # in Ray's code around the task
        cause = getattr(error, 'cause', None) or error
        hint = (' (ball_world must be importable on every node: docs/scoring.md)'
                if isinstance(cause, ImportError) else '')
        return (f'the Ray task for {label} failed: {type(cause).__name__}: '
                f'{_one_line(cause)}{hint}')
    if isinstance(error, ray.exceptions.WorkerCrashedError):
        return f'the Ray worker for {label} died: {_one_line(error)}'
    return f'the Ray task for {label} failed: {type(error).__name__}: {_one_line(error)}'


class RayPool:
    """The executor of jobs as Ray tasks (see the module's docstring)."""

    def __init__(self, address, jobs=None, most=None, deadline_s=None,
                 deadline_text='its deadline', connect_s=CONNECT_S):
        # A driver already connected (the caller's own ray.init) stays connected at close.
        self._connected_here = not _connected()
        self.ray = connect(address, connect_s)
        if jobs is None:
            jobs = int(self.ray.cluster_resources().get('CPU', 1))
        self.jobs = max(1, min(int(jobs), most or int(jobs)))
        self.deadline_s = deadline_s
        self.deadline_text = deadline_text
        self._task = self.ray.remote(num_cpus=1, max_retries=0)(run_supervised)
        self._running = {}

    def __enter__(self):
        return self

    def __exit__(self, kind, error, trace):
        self.close(abort=kind is not None)

    def map_unordered(self, function, arguments, labels):
        ray = self.ray
        arguments = list(arguments)
        waiting = list(range(len(arguments)))[::-1]
        running = self._running
        try:
            while waiting or running:
                while waiting and len(running) < self.jobs:
                    position = waiting.pop()
                    task = (function, arguments[position], labels[position],
                            self.deadline_s, self.deadline_text)
                    running[self._task.remote(task)] = position
                done = self._wait(list(running))
                for reference in done:
                    position = running.pop(reference)
                    try:
                        ok, value = ray.get(reference)
                    except ray.exceptions.RayError as error:
                        raise JobFailed(_failure(ray, error, labels[position])) from None
                    if not ok:
                        raise JobFailed(value)
                    yield position, value
        finally:
            self._cancel()

    def _wait(self, references):
        """ray.wait for the first to end. A signal handler's exception raised while Ray
        waits (the tool's SIGTERM: 'terminated', exit 143) comes out of Ray as a plain
        KeyboardInterrupt: the handler is run again here to raise its own."""
        main = threading.current_thread() is threading.main_thread()
        handler = signal.getsignal(signal.SIGTERM) if main else None
        if not callable(handler):
            return self.ray.wait(references, num_returns=1)[0]
        received = []

        def noting(signum, frame):
            received.append(signum)
            handler(signum, frame)

        signal.signal(signal.SIGTERM, noting)
        try:
            return self.ray.wait(references, num_returns=1)[0]
        except KeyboardInterrupt:
            if received:
                handler(received[0], None)
            raise
        finally:
            signal.signal(signal.SIGTERM, handler)

    def _cancel(self):
        running, self._running = self._running, {}
        for reference in running:
            try:
                self.ray.cancel(reference, force=True)
            except Exception:  # noqa: B902 - it ended meanwhile
                pass

    def close(self, abort=False):
        """Cancel (force: kill) every task still running and leave the cluster."""
        self._cancel()
        if self._connected_here and self.ray.is_initialized():
            self.ray.shutdown()
