"""A bag directory in rosbag2's layout: metadata.yaml beside `<name>_0.mcap`, `<name>_1.mcap`...

Why rosbag2's layout: `ros2 bag info/play` and the `rosbags` library take such a directory
as one recording, and users already know it from `ros2 bag record --max-bag-size`. The
files are named after the directory (a trailing '.mcap' dropped: `run.mcap/run_0.mcap`).

metadata.yaml is what rosbag2 Jazzy writes (version 9): storage `mcap`, the relative file
paths, duration and starting time, message counts per topic with each topic's type, `cdr`,
offered QoS (as a list, version 9's form) and type description hash, and per file its path,
starting time, duration and message count. It lists only complete files (finished, or
repaired): it is rewritten, through a temporary file and a rename, each time a file is
finished and when the recording closes, so a crash leaves the last good one.

The directory is claimed like a file (recording.files): an existing one is refused unless
overwrite (then its bag files are removed, nothing else), and it stays locked (flock on the
directory) while it is recorded, so a second recorder is refused at once.
"""
from dataclasses import dataclass
import errno
import fcntl
import os
import re
import stat
from typing import Optional

import yaml

from ball_world.recording.files import FileRefused

METADATA_FILE = 'metadata.yaml'
#: rosbag2 Jazzy's metadata version.
METADATA_VERSION = 9
#: Largest metadata.yaml read back (a day of one-minute files lists about 1,500).
MAX_METADATA_BYTES = 16 << 20


def file_stem(directory):
    """The name split files start with: the directory's own name, '.mcap' dropped."""
    name = os.path.basename(os.path.normpath(os.fspath(directory)))
    return name[:-len('.mcap')] if name.endswith('.mcap') and len(name) > 5 else name


def file_name(directory, number):
    return f'{file_stem(directory)}_{number}.mcap'


def numbered_files(directory):
    """The split files present in a directory, as (number, name), in order."""
    pattern = re.compile(re.escape(file_stem(directory)) + r'_([0-9]{1,9})\.mcap')
    found = []
    for name in os.listdir(directory):
        match = pattern.fullmatch(name)
        if match:
            found.append((int(match.group(1)), name))
    return sorted(found)


class DirectoryClaim:
    """A bag directory created (or emptied of its bag files) for recording, locked."""

    def __init__(self, path, fd, created):
        self.path = path
        self.created = created
        self._fd = fd
        status = os.fstat(fd)
        self.identity = (status.st_dev, status.st_ino)

    def release(self):
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def discard(self):
        """Release, and remove the directory if it was created here and is empty."""
        self.release()
        if self.created:
            try:
                os.rmdir(self.path)
            except OSError:
                pass  # it holds something: not ours to remove


def lock_directory(path):
    """Open the directory `path` and lock it (flock) for this process; return the descriptor.

    One lock for the recorder and for repair in place, so each refuses the other. Raises
    FileRefused naming the path when another process holds the lock.
    """
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise FileRefused(errno.EBUSY, 'is being recorded by another process (it is locked)',
                          path) from None
    return fd


def claim_directory(path, overwrite=False, hint=''):
    """Create the bag directory `path` (or, with overwrite, reuse one), locked.

    Raises FileRefused naming the path: it exists (without overwrite), is not a directory,
    or another process records into it.
    """
    path = os.fspath(path)
    created = True
    try:
        os.mkdir(path)
    except FileExistsError:
        if not overwrite:
            advice = f'; {hint} to replace it' if hint else ''
            raise FileRefused(errno.EEXIST, f'already exists{advice}', path) from None
        created = False
        mode = os.lstat(path).st_mode
        if stat.S_ISREG(mode):  # a single-file recording of the same name is replaced
            os.unlink(path)
            os.mkdir(path)
            created = True
        elif not stat.S_ISDIR(mode):
            raise FileRefused(errno.EINVAL, 'is not a directory or a regular file', path)
    except OSError as error:
        raise FileRefused(error.errno, error.strerror, path) from None
    fd = lock_directory(path)
    if not created:
        for _, name in numbered_files(path):
            os.unlink(os.path.join(path, name))
        metadata = os.path.join(path, METADATA_FILE)
        if os.path.lexists(metadata):
            os.unlink(metadata)
    return DirectoryClaim(path, fd, created)


def _qos_list(text):
    """offered_qos_profiles as version 9 writes it: the list the channel's YAML holds."""
    try:
        profiles = yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return []
    return profiles if isinstance(profiles, list) else []


@dataclass(frozen=True)
class FileSummary:
    """What metadata.yaml says of one complete file (a Recording's counts, without indexes)."""

    path: str
    start_ns: Optional[int]
    end_ns: Optional[int]
    message_count: int
    topics: dict  # topic -> mcap_reader.TopicInfo


def summarize(recording):
    """The FileSummary of an mcap_reader.Recording: small enough to keep for days."""
    return FileSummary(path=recording.path, start_ns=recording.start_ns,
                       end_ns=recording.end_ns, message_count=recording.message_count,
                       topics=dict(recording.topics))


def bag_metadata(recordings):
    """The metadata.yaml document for complete files (FileSummary or Recording), in order."""
    topics = {}
    files = []
    for recording in recordings:
        for info in recording.topics.values():
            entry = topics.setdefault(info.topic, [info, 0])
            entry[1] += info.message_count
        start = recording.start_ns or 0
        end = recording.end_ns if recording.end_ns is not None else start
        files.append({'path': os.path.basename(recording.path),
                      'starting_time': {'nanoseconds_since_epoch': start},
                      'duration': {'nanoseconds': end - start},
                      'message_count': recording.message_count})
    starts = [r.start_ns for r in recordings if r.start_ns is not None]
    ends = [r.end_ns for r in recordings if r.end_ns is not None]
    start = min(starts, default=0)
    return {'rosbag2_bagfile_information': {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': max(ends, default=start) - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(r.message_count for r in recordings),
        'topics_with_message_count': [
            {'topic_metadata': {'name': info.topic, 'type': info.type,
                                'serialization_format': 'cdr',
                                'offered_qos_profiles': _qos_list(info.offered_qos_profiles),
                                'type_description_hash': info.type_hash},
             'message_count': count}
            for info, count in topics.values()],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file['path'] for file in files],
        'files': files,
        'custom_data': {},
        'ros_distro': 'jazzy',
    }}


def write_metadata(directory, recordings):
    """Write metadata.yaml for `recordings` atomically (a temporary file, then a rename)."""
    text = yaml.safe_dump(bag_metadata(recordings), sort_keys=False,
                          default_flow_style=False)
    target = os.path.join(directory, METADATA_FILE)
    temporary = target + '.tmp'
    with open(temporary, 'w', encoding='utf-8') as stream:
        stream.write(text)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(temporary, target)


def missing_metadata(directory):
    """What a directory without metadata.yaml is, for the one line that refuses it."""
    if numbered_files(directory):
        return (f'has no {METADATA_FILE}: its recorder was killed before it finished a '
                f'file; ball_world_repair {directory} writes it')
    return f'is a directory without {METADATA_FILE}, not a bag of split files'


def listed_files(directory, load):
    """The file names metadata.yaml lists, in order (ValueError says what is wrong).

    load(text, what, limit): the caller's bounded YAML parser for untrusted text. A name
    must be a plain file name inside the directory.
    """
    path = os.path.join(directory, METADATA_FILE)
    try:
        with open(path, 'rb') as stream:
            data = stream.read(MAX_METADATA_BYTES + 1)
    except FileNotFoundError:
        raise ValueError(missing_metadata(directory)) from None
    document = load(data.decode('utf-8', 'replace'), METADATA_FILE, MAX_METADATA_BYTES)
    information = document.get('rosbag2_bagfile_information') \
        if isinstance(document, dict) else None
    names = information.get('relative_file_paths') if isinstance(information, dict) else None
    if not isinstance(names, list) or not names:
        raise ValueError(f'{METADATA_FILE} lists no files (relative_file_paths)')
    for name in names:
        if not isinstance(name, str) or name in ('', '.', '..') or '/' in name \
                or '\0' in name:
            raise ValueError(f'{METADATA_FILE} lists {repr(name)[:60]}, which is not a file '
                             'name in the directory')
    return names
