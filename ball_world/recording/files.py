"""Writing a file: never destroy a recording by accident, never write through a symlink or
outside the folder given, never hang on a file that is not one.

Why one module: every file the package writes (the node's MCAP and .rrd and their split
parts, a bag directory's metadata.yaml, ball_world_repair's and ball_world_to_rrd's
outputs, the benchmarks' reports, the CLI's `record`, score exports) must follow the same
rules, and each rule has a trap that is easy to get wrong in one of many places:

- A file is made in a folder by a plain name only (no '/', '.', '..'): the folder is opened
  once (os.open with O_DIRECTORY) and every file in it is created, replaced or removed
  relative to that descriptor (dir_fd), so no name can lead out of it, and a folder renamed
  or swapped for a symlink meanwhile cannot redirect a write. The folder a user names may
  itself be reached through symlinks (a home on another disk): that is the user's choice.
  A folder the package makes and fills (a bag directory) is opened without following one.
- A symlink where a file is to be written is refused, whatever it points to and whether or
  not overwriting was asked for: open() would write through it (a link planted in a bag
  directory, or at a recording's name, would make an overwrite of any file the user may
  write). Every open for writing uses O_NOFOLLOW; every replacement is a rename, which
  replaces a name and never writes through it.
- An existing file is refused unless the caller says to overwrite (rosbag2 likewise refuses
  an existing output). A file with more than one name (hard links) is never truncated in
  place: the other names would change too.
- Only a regular file is ever written. A FIFO would block open() until a reader comes, and a
  directory or device is no recording, so the file is opened with O_NONBLOCK and its type is
  read from the open descriptor (fstat), never checked first and opened later.
- The file is locked (flock, exclusive, non-blocking) for as long as it is recorded, so a
  second recorder (another node, a tool) is refused at once instead of interleaving with the
  first. An existing file is truncated only once the lock is held.
- Two outputs of one run may not be one file: paths are compared resolved (symlinks and
  relative parts), and the open files by device and inode (hard links).
- Temporary files are made in the target's own folder with O_EXCL (never an existing name),
  then renamed onto the target: a failed run leaves the target as it was.

A recording closed before anything was recorded into it (the start failed) removes the file
its claim created, so correcting a typo and starting again is not refused for a file that
holds nothing.

A library that opens its file by path itself (the Rerun SDK) is given the claimed descriptor
as /proc/self/fd/N (OutputClaim.fd_path), so it writes the very file that was claimed.

Reading has the same trap: a recording handed to a tool is opened with open_regular, which
refuses a FIFO or device instead of waiting on it.

The API other branches use (see /work/wt/NOTES.md): claim_output, write_file, PartialOutput,
Folder, plain_name, open_regular, FileRefused.
"""
import errno
import fcntl
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
    (stat.S_ISLNK, 'a symbolic link'),
)

_WRITE_FLAGS = (os.O_WRONLY | os.O_CREAT | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
                | os.O_NOFOLLOW)
_PROBE_FLAGS = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC | os.O_NOFOLLOW
_FOLDER_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC
#: Where a process's open files can be named by path (Linux).
_PROC_FDS = '/proc/self/fd'


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


def _symlink(path, target=None):
    shown = f' (to {target})' if target else ''
    return FileRefused(errno.ELOOP, f'is a symbolic link{shown}; ball_world never writes '
                                    'through one: name the file itself or remove the link',
                       path)


def plain_name(name, folder=''):
    """`name` if it names a file inside its folder: not empty, '.' or '..', no '/' or NUL.

    Raises FileRefused otherwise (a name read from a file, or made from a user's, must not
    lead out of the folder it is written in).
    """
    if not isinstance(name, str) or name in ('', '.', '..') or '/' in name or '\0' in name:
        shown = repr(name)[:80]
        raise FileRefused(errno.EINVAL, 'is not a plain file name: it would lead out of its '
                                        'folder', os.path.join(folder, shown))
    return name


def split_path(path):
    """(folder, name) of a file path to write: its folder as given ('.' when none) and its
    last component, which must name a file (FileRefused for 'dir/', '.', '..')."""
    path = os.fspath(path)
    folder, name = os.path.split(path)
    if not name or name in ('.', '..'):
        raise FileRefused(errno.EISDIR, 'names a folder, not a file', path)
    return folder or '.', name


class Folder:
    """A directory opened once; files are made, replaced and removed in it by plain names.

    follow=False refuses a folder that is itself a symlink (a bag directory the package
    makes); the folder a user names is opened as named (follow=True). Raises FileRefused
    naming the path when it is no directory. Close it (or use it as a context manager)
    when done; the claims made in it keep their own reference.
    """

    def __init__(self, path, follow=True, parent=None):
        self.path = os.fspath(path) if parent is None else parent.join(path)
        flags = _FOLDER_FLAGS | (0 if follow else os.O_NOFOLLOW)
        try:
            if parent is None:
                self.fd = os.open(self.path, flags)
            else:
                self.fd = os.open(plain_name(path, parent.path), flags, dir_fd=parent.fd)
        except OSError as error:
            raise _folder_refusal(self.path, error) from None
        self._users = 1

    def subfolder(self, name, follow=False):
        """The folder `name` in this one, opened relative to it (not through a symlink
        unless follow)."""
        return Folder(name, follow, parent=self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _use(self):
        self._users += 1
        return self

    def close(self):
        """Drop one use of the descriptor; the last one closes it."""
        self._users -= 1
        if self._users == 0 and self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def join(self, name):
        """The path of `name` in this folder, for messages and readers."""
        return os.path.join(self.path, name)

    def lstat(self, name):
        """os.lstat of `name` in the folder (FileNotFoundError when there is none)."""
        return os.stat(plain_name(name, self.path), dir_fd=self.fd, follow_symlinks=False)

    def exists(self, name):
        try:
            self.lstat(name)
        except FileNotFoundError:
            return False
        return True

    def names(self):
        """The names in the folder."""
        return os.listdir(self.fd)

    def lock(self):
        """Lock the folder (flock on its descriptor) for this process, or FileRefused."""
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FileRefused(errno.EBUSY, 'is being recorded by another process (it is '
                                           'locked)', self.path) from None

    def remove(self, name, identity=None):
        """Remove the file `name` (a symlink: the link, never what it points to).

        identity: (device, inode) it must still have, else it is left (another file took
        its name). Returns whether it was removed; a directory is refused (FileRefused).
        """
        try:
            status = self.lstat(name)
        except FileNotFoundError:
            return False
        if stat.S_ISDIR(status.st_mode):
            raise _not_regular(self.join(name), status.st_mode)
        if identity is not None and (status.st_dev, status.st_ino) != identity:
            return False
        try:
            os.unlink(name, dir_fd=self.fd)
        except FileNotFoundError:
            return False
        return True

    def refuse_symlink(self, name):
        """FileRefused if `name` is a symlink in the folder (nothing is written through it)."""
        try:
            status = self.lstat(name)
        except FileNotFoundError:
            return
        if stat.S_ISLNK(status.st_mode):
            raise _symlink(self.join(name), _link_text(self, name))

    def claim(self, name, overwrite=False, hint='', others=()):
        """Create (or, with overwrite, truncate) `name` for recording, locked: an OutputClaim.

        hint completes the refusal of an existing file ('set record.overwrite:=true', 'pass
        --force'). others: (label, OutputClaim or anything with .path and .identity)
        already held by the same run, which this one must not share a file with. Raises
        FileRefused, whose message names the path.
        """
        path = self.join(plain_name(name, self.path))
        for label, other in others:
            if same_path(path, other.path):
                raise FileRefused(errno.EEXIST, f'is the same file as {label}', path)
        created = True
        try:
            fd = os.open(name, _WRITE_FLAGS | os.O_EXCL, 0o666, dir_fd=self.fd)
        except FileExistsError:
            created = False
            fd = self._open_existing(name, path, overwrite, hint)
        except OSError as error:
            raise FileRefused(error.errno, error.strerror, path) from None
        try:
            return _lock(self, name, path, fd, created, others)
        except FileRefused as error:
            os.close(fd)
            # A file we created but another recorder locked first is that recorder's now.
            if created and error.errno != errno.EBUSY:
                os.unlink(name, dir_fd=self.fd)
            raise

    def _open_existing(self, name, path, overwrite, hint):
        try:
            mode = self.lstat(name).st_mode
        except FileNotFoundError:  # removed meanwhile: treat as existing, the user decides
            mode = stat.S_IFREG
        if stat.S_ISLNK(mode):
            raise _symlink(path, _link_text(self, name))
        if not stat.S_ISREG(mode):
            raise _not_regular(path, mode)
        if not overwrite:
            advice = f'; {hint} to replace it' if hint else ''
            raise FileRefused(errno.EEXIST, f'already exists{advice}', path)
        try:
            return os.open(name, _WRITE_FLAGS, dir_fd=self.fd)
        except OSError as error:
            if error.errno == errno.ELOOP:  # swapped for a link since the look above
                raise _symlink(path) from None
            if error.errno in (errno.ENXIO, errno.EISDIR):
                raise _not_regular(path, stat.S_IFIFO if error.errno == errno.ENXIO
                                   else stat.S_IFDIR) from None
            raise FileRefused(error.errno, error.strerror, path) from None

    def write_atomically(self, name, data, spare=None):
        """Make `name` hold exactly `data` (bytes): a temporary file in this folder (O_EXCL),
        fsync'ed, renamed onto it, then the folder fsync'ed. A symlink at `name` is refused.

        spare: the name of a file set aside with reserve(); when the disk is full (ENOSPC,
        EDQUOT) the data is written into its blocks instead, which needs no new space.
        Raises OSError (FileRefused for a refusal) naming the path.
        """
        path = self.join(plain_name(name, self.path))
        self.refuse_symlink(name)
        temporary = f'{name}.tmp-{os.getpid()}'
        try:
            self._write_new(temporary, data)
        except OSError as error:
            self.remove(temporary)
            if spare is None or error.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise _named(error, path) from None
            temporary = self._write_spare(spare, data, path)
        try:
            os.replace(temporary, name, src_dir_fd=self.fd, dst_dir_fd=self.fd)
            os.fsync(self.fd)
        except OSError as error:
            raise _named(error, path) from None

    def _write_new(self, name, data):
        if self.exists(name):  # left by a dead process with this pid: ours to remove
            self.remove(name)
        fd = os.open(name, _WRITE_FLAGS | os.O_EXCL, 0o666, dir_fd=self.fd)
        try:
            _write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)

    def reserve(self, name, size):
        """Set `size` bytes aside in the file `name` (created if need be, never through a
        symlink), for write_atomically(spare=name) to write into when the disk is full."""
        fd = os.open(plain_name(name, self.path), _WRITE_FLAGS, 0o666, dir_fd=self.fd)
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise _not_regular(self.join(name), os.fstat(fd).st_mode)
            os.posix_fallocate(fd, 0, size)
        finally:
            os.close(fd)

    def _write_spare(self, spare, data, path):
        try:
            fd = os.open(spare, os.O_WRONLY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=self.fd)
        except OSError as error:
            raise _named(error, path) from None
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode) or os.fstat(fd).st_size < len(data):
                raise FileRefused(errno.ENOSPC, 'the disk is full and the space set aside '
                                                'for it is too small', path)
            os.lseek(fd, 0, os.SEEK_SET)
            _write_all(fd, data)
            os.ftruncate(fd, len(data))
            os.fsync(fd)
        except FileRefused:
            raise
        except OSError as error:
            raise _named(error, path) from None
        finally:
            os.close(fd)
        return spare


def _write_all(fd, data):
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]


def _named(error, path):
    if isinstance(error, FileRefused):
        return error
    return FileRefused(error.errno, error.strerror or str(error), path)


def _link_text(folder, name):
    try:
        return os.readlink(name, dir_fd=folder.fd)
    except OSError:
        return None


def _folder_refusal(path, error):
    if error.errno == errno.ELOOP:
        return _symlink(path, _readlink(path))
    if error.errno == errno.ENOTDIR:
        try:
            mode = os.lstat(path).st_mode
        except OSError:
            mode = stat.S_IFREG
        if stat.S_ISLNK(mode):
            return _symlink(path, _readlink(path))
        kind = 'a file' if stat.S_ISREG(mode) else _kind(mode)
        return FileRefused(errno.ENOTDIR, f'is {kind}, not a folder', path)
    return FileRefused(error.errno, error.strerror or str(error), path)


def _readlink(path):
    try:
        return os.readlink(path)
    except OSError:
        return None


class OutputClaim:
    """A regular file created or truncated for writing, locked until released.

    writer() hands the descriptor over as a buffered binary file: closing that file releases
    the lock. Otherwise release() does. discard() releases and removes a file this claim
    created (nothing was recorded into it). fd_path() names the claimed file for a library
    that opens it by path itself.
    """

    def __init__(self, folder, name, path, fd, created):
        self.folder = folder._use()
        self.name = name
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

    def fileno(self):
        return self._fd

    def fd_path(self):
        """/proc/self/fd/N of the claimed file where the system has it, else its path.

        Opened by that name, it is this file, whatever is done to its path meanwhile.
        """
        if self._fd is not None and os.path.isdir(_PROC_FDS):
            return f'{_PROC_FDS}/{self._fd}'
        return self.path

    def size(self):
        """Bytes in the file now (0 once released)."""
        return os.fstat(self._fd).st_size if self._fd is not None else 0

    def release(self):
        """Close the file and so drop the lock; a second call does nothing."""
        if self._writer is not None:
            try:
                self._writer.close()
            except OSError:
                pass  # the recorder reported its own write error already
            self._writer = None
        elif self._fd is not None:
            os.close(self._fd)
        if self._fd is not None:
            self._fd = None
            self.folder.close()

    def discard(self):
        """Release, and remove the file if this claim created it and it is still there."""
        folder = self.folder._use()
        try:
            self.release()
            if self.created:
                try:
                    folder.remove(self.name, self.identity)
                except OSError:
                    pass  # already gone or replaced: nothing of ours to remove
        finally:
            folder.close()


def _lock(folder, name, path, fd, created, others):
    status = os.fstat(fd)
    if not stat.S_ISREG(status.st_mode):
        raise _not_regular(path, status.st_mode)
    for label, other in others:
        if (status.st_dev, status.st_ino) == other.identity:
            raise FileRefused(errno.EEXIST, f'is the same file as {label}', path)
    if not created and status.st_nlink > 1:
        raise FileRefused(errno.EMLINK, f'has {status.st_nlink} names (hard links); '
                                        'overwriting it would change the others too', path)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FileRefused(errno.EBUSY, 'is being recorded by another process (it is locked)',
                          path) from None
    if not created:
        os.ftruncate(fd, 0)
    os.set_blocking(fd, True)
    return OutputClaim(folder, name, path, fd, created)


def same_path(first, second):
    """Whether two paths name one file once symlinks and relative parts are resolved."""
    return os.path.realpath(first) == os.path.realpath(second)


def claim_output(path, overwrite=False, hint='', others=()):
    """Create (or, with overwrite, truncate) the file `path` for recording, locked.

    The file is made in its folder as named (Folder.claim): never through a symlink, never
    a file with other names. Raises FileRefused, whose message names the path.
    """
    folder_path, name = split_path(path)
    with open_folder_of(path, folder_path) as folder:
        claim = folder.claim(name, overwrite, hint, others)
    claim.path = os.fspath(path)
    return claim


def open_folder_of(path, folder_path):
    """The Folder a file `path` is written in; a folder that is not there (or may not be
    entered) is refused naming the file, as the user wrote it."""
    try:
        return Folder(folder_path)
    except FileRefused as error:
        if error.errno in (errno.ENOENT, errno.EACCES):
            raise FileRefused(error.errno, error.strerror, os.fspath(path)) from None
        if error.errno == errno.ENOTDIR:
            raise FileRefused(error.errno, f'its folder {folder_path} {error.strerror}',
                              os.fspath(path)) from None
        raise


def write_file(path, data, overwrite=False, hint=''):
    """Write a whole small file (a report, an export) atomically: `path` holds `data` (bytes
    or str) or is left as it was. Refuses an existing file unless overwrite (which replaces
    the name, never writes through it), a symlink, a non-regular file, a locked one."""
    if isinstance(data, str):
        data = data.encode('utf-8')
    output = PartialOutput(path, overwrite, hint)
    try:
        with output.claim.writer() as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        output.commit()
    except BaseException:
        output.discard()
        raise


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


def is_locked(path, folder=None):
    """Whether another open file holds the recording lock on `path` (False if none is there).

    For tools that replace a file whole (repair in place): a file being recorded is refused.
    With `folder`, path is a name in it.
    """
    try:
        if folder is None:
            fd = os.open(path, _PROBE_FLAGS)
        else:
            fd = os.open(path, _PROBE_FLAGS, dir_fd=folder.fd)
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

    The target is a file path, or with `folder` a plain name in that Folder. It is checked
    first: a symlink is refused, an existing file is refused unless overwrite (hint says how
    to allow it), as are a non-regular one and one another process is recording (locked).
    Temporary files of earlier runs for the same target whose process is gone (dead pid,
    lock free) are removed. The temporary file is claimed (created, locked) like any
    recording, in the target's folder; commit() renames it onto the target, without
    replacing a target that appeared meanwhile unless overwrite; discard() removes it.
    """

    def __init__(self, target, overwrite=False, hint='', folder=None):
        if folder is None:
            self.target = os.fspath(target)
            folder_path, self.name = split_path(self.target)
            self.folder = open_folder_of(self.target, folder_path)
        else:
            self.name = plain_name(os.fspath(target), folder.path)
            self.target = folder.join(self.name)
            self.folder = folder._use()
        try:
            self.overwrite = overwrite
            self.hint = hint
            self._check_target()
            remove_stale_partials(self.name, self.folder)
            self.claim = self.folder.claim(f'{self.name}.partial-{os.getpid()}')
        except BaseException:
            self.folder.close()
            raise
        self.path = self.claim.path

    def _check_target(self):
        try:
            mode = self.folder.lstat(self.name).st_mode
        except FileNotFoundError:
            return
        except OSError as error:
            raise FileRefused(error.errno, error.strerror, self.target) from None
        if stat.S_ISLNK(mode):
            raise _symlink(self.target, _link_text(self.folder, self.name))
        if not stat.S_ISREG(mode):
            raise _not_regular(self.target, mode)
        if not self.overwrite:
            advice = f'; {self.hint} to replace it' if self.hint else ''
            raise FileRefused(errno.EEXIST, f'already exists{advice}', self.target)
        if is_locked(self.name, self.folder):
            raise FileRefused(errno.EBUSY, 'is being recorded by another process (it is '
                                           'locked)', self.target)

    def commit(self):
        """Put the complete file in place of the target (a rename) and release it."""
        fd = self.folder.fd
        temporary = self.claim.name
        try:
            if self.overwrite:
                self.folder.refuse_symlink(self.name)
                os.replace(temporary, self.name, src_dir_fd=fd, dst_dir_fd=fd)
            else:
                try:
                    os.link(temporary, self.name, src_dir_fd=fd, dst_dir_fd=fd,
                            follow_symlinks=False)
                except FileExistsError:
                    raise FileRefused(errno.EEXIST, 'already exists'
                                      + (f'; {self.hint} to replace it' if self.hint else ''),
                                      self.target) from None
                os.unlink(temporary, dir_fd=fd)
        except OSError:
            self.discard()
            raise
        self.claim.release()
        self.folder.close()

    def discard(self):
        if self.claim._fd is not None or self.claim.created:
            self.claim.discard()
        if self.folder.fd is not None:
            self.folder.close()


def remove_stale_partials(name, folder=None):
    """Remove `<name>.partial-<pid>` files left by runs that were killed; returns their
    paths. name: a plain name in `folder`, or without one a path.

    One is stale when its process is gone and nothing holds its lock (a pid that was
    reused by another process keeps its file until that process ends too). A symlink of
    that name is left alone.
    """
    if folder is None:
        folder_path, name = split_path(name)
        with Folder(folder_path) as folder:
            return remove_stale_partials(name, folder)
    removed = []
    prefix = f'{name}.partial-'
    for entry in folder.names():
        if not entry.startswith(prefix):
            continue
        pid = entry[len(prefix):]
        # One named with this process's pid is from a dead process that had the same pid.
        if not pid.isdigit() or (int(pid) != os.getpid() and _pid_alive(int(pid))):
            continue
        try:
            fd = os.open(entry, _PROBE_FLAGS, dir_fd=folder.fd)
        except OSError:
            continue
        try:
            status = os.fstat(fd)
            if stat.S_ISREG(status.st_mode) and not _locked(fd):
                if folder.remove(entry, (status.st_dev, status.st_ino)):
                    removed.append(folder.join(entry))
        finally:
            os.close(fd)
    return removed


class ClaimedSink:
    """A Sink whose output file is held by a claim, released when the sink is closed.

    For recorders that open their file by path themselves (the Rerun SDK does): the claim
    is taken first (refusing existing, shared, locked, linked and non-regular files) and
    held, with its lock, for the life of the recording. Closed before any segment began (the
    start failed), the sink leaves no file behind if the claim created it, as rosbag2
    removes an output folder it created and recorded nothing into.
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
