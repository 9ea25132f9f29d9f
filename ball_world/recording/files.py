"""Claiming a file to record into: never destroy a recording by accident, never hang on one.

Why one module: the node's two recorders (MCAP and Rerun) and the tools that write files
(ball_world_to_rrd, ball_world_repair) must follow the same rules, and each rule has a trap
that is easy to get wrong in one of four places:

- An existing path is refused unless the caller says to overwrite (rosbag2 likewise refuses
  an existing output). A symlink counts as existing, whatever it points to: O_EXCL refuses it.
- Only a regular file is ever written. A FIFO would block open() until a reader comes, and a
  directory or device is no recording, so the file is opened with O_NONBLOCK and its type is
  read from the open descriptor (fstat), never checked first and opened later.
- The file is locked (flock, exclusive, non-blocking) for as long as it is recorded, so a
  second recorder (another node, a tool) is refused at once instead of interleaving with the
  first. An existing file is truncated only once the lock is held.
- Two outputs of one run may not be one file: paths are compared resolved (symlinks and
  relative parts), and the open files by device and inode (hard links).

A recording closed before anything was recorded into it (the start failed) removes the file
its claim created, so correcting a typo and starting again is not refused for a file that
holds nothing.

Tools that write a whole file (ball_world_to_rrd, ball_world_repair) write it beside its
target under a locked temporary name and move it into place only when it is complete
(PartialOutput): a failed run leaves the target as it was, and the temporary file of a run
that was killed is removed by the next run for the same target.

Reading has the same trap: a recording handed to a tool is opened with open_regular, which
refuses a FIFO or device instead of waiting on it.
"""
import errno
import fcntl
import glob
import io
import os
import stat

#: What a non-regular file is, for the refusal message.
_KINDS = (
    (stat.S_ISDIR, 'a directory'),
    (stat.S_ISFIFO, 'a FIFO'),
    (stat.S_ISCHR, 'a character device'),
    (stat.S_ISBLK, 'a block device'),
    (stat.S_ISSOCK, 'a socket'),
)

_OPEN_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC


class FileRefused(OSError):
    """A file that may not or cannot be written or read; str() is '<path>: <reason>'."""

    def __str__(self):
        return f'{self.filename}: {self.strerror}'


def _kind(mode):
    for test, name in _KINDS:
        if test(mode):
            return name
    return 'not a regular file'


def _not_regular(path, mode):
    return FileRefused(errno.EINVAL, f'is {_kind(mode)}, not a regular file', path)


class OutputClaim:
    """A regular file created or truncated for writing, locked until released.

    writer() hands the descriptor over as a buffered binary file: closing that file releases
    the lock. Otherwise release() does. discard() releases and removes a file this claim
    created (nothing was recorded into it).
    """

    def __init__(self, path, fd, created):
        self.path = path
        self.created = created
        self._fd = fd
        status = os.fstat(fd)
        self.identity = (status.st_dev, status.st_ino)
        self._writer = None

    def writer(self):
        """The file as a buffered binary writer (the lock goes with it)."""
        if self._writer is None:
            self._writer = io.open(self._fd, 'wb', closefd=True)
        return self._writer

    def release(self):
        """Close the file and so drop the lock; a second call does nothing."""
        if self._writer is not None:
            try:
                self._writer.close()
            except OSError:
                pass  # the recorder reported its own write error already
        elif self._fd is not None:
            os.close(self._fd)
        self._fd = None

    def discard(self):
        """Release, and remove the file if this claim created it and it is still there."""
        self.release()
        if self.created:
            try:
                status = os.lstat(self.path)
                if (status.st_dev, status.st_ino) == self.identity:
                    os.unlink(self.path)
            except OSError:
                pass  # already gone or replaced: nothing of ours to remove


def same_path(first, second):
    """Whether two paths name one file once symlinks and relative parts are resolved."""
    return os.path.realpath(first) == os.path.realpath(second)


def claim_output(path, overwrite=False, hint='', others=()):
    """Create (or, with overwrite, truncate) `path` for recording, locked: an OutputClaim.

    hint completes the refusal of an existing file ('set record.overwrite:=true', 'pass
    --force'). others: (label, OutputClaim) pairs already held by the same run, which this
    one must not share a file with. Raises FileRefused, whose message names the path.
    """
    path = os.fspath(path)
    for label, other in others:
        if same_path(path, other.path):
            raise FileRefused(errno.EEXIST, f'is the same file as {label}', path)
    created = True
    try:
        fd = os.open(path, _OPEN_FLAGS | os.O_EXCL, 0o666)
    except FileExistsError:
        if not overwrite:
            raise _refuse_existing(path, hint) from None
        created = False
        fd = _open_existing(path)
    except OSError as error:
        raise FileRefused(error.errno, error.strerror, path) from None
    try:
        return _lock(path, fd, created, others)
    except FileRefused as error:
        os.close(fd)
        # A file we created but another recorder locked first is that recorder's now.
        if created and error.errno != errno.EBUSY:
            os.unlink(path)
        raise


def _refuse_existing(path, hint):
    try:
        mode = os.stat(path).st_mode  # follows a symlink: say what it points to
    except OSError:
        mode = stat.S_IFLNK  # a dangling symlink
    if not stat.S_ISREG(mode) and not stat.S_ISLNK(mode):
        return _not_regular(path, mode)
    advice = f'; {hint} to replace it' if hint else ''
    return FileRefused(errno.EEXIST, f'already exists{advice}', path)


def _open_existing(path):
    try:
        return os.open(path, _OPEN_FLAGS)
    except OSError as error:
        # A FIFO without a reader answers ENXIO and a directory EISDIR: say what it is.
        try:
            mode = os.stat(path).st_mode
        except OSError:
            mode = stat.S_IFREG
        if not stat.S_ISREG(mode):
            raise _not_regular(path, mode) from None
        raise FileRefused(error.errno, error.strerror, path) from None


def _lock(path, fd, created, others):
    status = os.fstat(fd)
    if not stat.S_ISREG(status.st_mode):
        raise _not_regular(path, status.st_mode)
    for label, other in others:
        if (status.st_dev, status.st_ino) == other.identity:
            raise FileRefused(errno.EEXIST, f'is the same file as {label}', path)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FileRefused(errno.EBUSY, 'is being recorded by another process (it is locked)',
                          path) from None
    if not created:
        os.ftruncate(fd, 0)
    os.set_blocking(fd, True)
    return OutputClaim(path, fd, created)


def open_regular(path):
    """Open a file to read it, refusing anything but a regular file without blocking.

    A recording given to a tool may be a FIFO (open() would wait for a writer forever) or a
    device (endless bytes): opened non-blocking, its type is read from the descriptor.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise _not_regular(path, mode)
        os.set_blocking(fd, True)
        return io.open(fd, 'rb', closefd=True)
    except BaseException:
        os.close(fd)
        raise


def _locked(fd):
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    return False


def is_locked(path):
    """Whether another open file holds the recording lock on `path` (False if none is there).

    For tools that replace a file whole (repair in place): a file being recorded is refused.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        return _locked(fd)
    finally:
        os.close(fd)


def _pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's process
    return True


class PartialOutput:
    """A file written as `<target>.partial-<pid>` and moved onto `target` once complete.

    The target is checked first: an existing one is refused unless overwrite (hint says how
    to allow it), as are a non-regular one and one another process is recording (locked).
    Temporary files of earlier runs for the same target whose process is gone (dead pid,
    lock free) are removed. The temporary file is claimed (created, locked) like any
    recording; commit() moves it into place, without replacing a target that appeared
    meanwhile unless overwrite; discard() removes it.
    """

    def __init__(self, target, overwrite=False, hint=''):
        self.target = os.fspath(target)
        self.overwrite = overwrite
        self.hint = hint
        self._check_target()
        remove_stale_partials(self.target)
        self.claim = claim_output(f'{self.target}.partial-{os.getpid()}')
        self.path = self.claim.path

    def _check_target(self):
        try:
            mode = os.stat(self.target).st_mode
        except FileNotFoundError:
            if os.path.lexists(self.target) and not self.overwrite:
                raise _refuse_existing(self.target, self.hint) from None
            return
        except OSError as error:
            raise FileRefused(error.errno, error.strerror, self.target) from None
        if not stat.S_ISREG(mode):
            raise _not_regular(self.target, mode)
        if not self.overwrite:
            raise _refuse_existing(self.target, self.hint)
        if is_locked(self.target):
            raise FileRefused(errno.EBUSY, 'is being recorded by another process (it is '
                                           'locked)', self.target)

    def commit(self):
        """Put the complete file in place of the target and release it."""
        try:
            if self.overwrite:
                os.replace(self.path, self.target)
            else:
                try:
                    os.link(self.path, self.target)
                except FileExistsError:
                    raise _refuse_existing(self.target, self.hint) from None
                os.unlink(self.path)
        except OSError:
            self.claim.discard()
            raise
        self.claim.release()

    def discard(self):
        self.claim.discard()


def remove_stale_partials(target):
    """Remove `<target>.partial-<pid>` files left by runs that were killed; returns them.

    One is stale when its process is gone and nothing holds its lock (a pid that was
    reused by another process keeps its file until that process ends too).
    """
    removed = []
    for path in glob.glob(glob.escape(target) + '.partial-*'):
        pid = path.rpartition('.partial-')[2]
        # One named with this process's pid is from a dead process that had the same pid.
        if not pid.isdigit() or (int(pid) != os.getpid() and _pid_alive(int(pid))):
            continue
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            if stat.S_ISREG(os.fstat(fd).st_mode) and not _locked(fd):
                os.unlink(path)
                removed.append(path)
        finally:
            os.close(fd)
    return removed


class ClaimedSink:
    """A Sink whose output file is held by a claim, released when the sink is closed.

    For recorders that open their file by path themselves (the Rerun SDK does): the claim
    is taken first (refusing existing, shared, locked and non-regular files) and held, with
    its lock, for the life of the recording. Closed before any segment began (the start
    failed), the sink leaves no file behind if the claim created it, as rosbag2 removes an
    output folder it created and recorded nothing into.
    """

    def __init__(self, sink, claim):
        self.sink = sink
        self.claim = claim
        self._segments = 0

    def start_segment(self, world, info):
        self._segments += 1
        self.sink.start_segment(world, info)

    def write_step(self, record):
        self.sink.write_step(record)

    def write_pending(self, events):
        if hasattr(self.sink, 'write_pending'):
            self.sink.write_pending(events)

    def flush(self):
        self.sink.flush()

    def close(self):
        try:
            self.sink.close()
        finally:
            if self._segments:
                self.claim.release()
            else:
                self.claim.discard()
