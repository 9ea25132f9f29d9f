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
overwrite (then its bag files are removed, nothing else), a symlink is refused whatever it
points to, and it stays locked (flock on the directory) while it is recorded, so a second
recorder is refused at once. Every file in it is made, replaced and removed relative to the
directory's descriptor (recording.files.Folder): never through a symlink, never elsewhere.

The recorder's files are named canonically, `<name>_<n>.mcap` with n written without
leading zeros: a copy such as `run_000.mcap` is never taken for one of them (it is a stray
file, which the tools name and leave alone).

When the disk fills, the recorder still says so: it keeps RESERVE_FILE, a few blocks set
aside, and writes the last metadata.yaml into them, with what stopped it in custom_data
(STOPPED_KEY), so ball_world_info can tell a full disk from a killed recorder.
"""
from dataclasses import dataclass
import errno
import functools
import json
import os
import re
import stat
from typing import Optional

import yaml

from ball_world.recording.files import FileRefused, Folder, split_path

METADATA_FILE = 'metadata.yaml'
#: rosbag2 Jazzy's metadata version.
METADATA_VERSION = 9
#: Largest metadata.yaml read back (a day of one-minute files lists about 1,500).
MAX_METADATA_BYTES = 16 << 20
#: Blocks set aside in the bag directory for the metadata.yaml written when the disk is full.
RESERVE_FILE = '.metadata.yaml.reserve'
#: The least space set aside, and how much more than the current metadata.yaml.
RESERVE_BYTES = 64 << 10
#: custom_data key saying what stopped the recorder (a write error), when it was stopped.
STOPPED_KEY = 'ball_world.stopped'
#: YAML written by libyaml when it is there (a hundred times faster for a long listing).
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)
_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def file_stem(directory):
    """The name split files start with: the directory's own name, '.mcap' dropped."""
    name = os.path.basename(os.path.normpath(os.fspath(directory)))
    return name[:-len('.mcap')] if name.endswith('.mcap') and len(name) > 5 else name


def file_name(directory, number):
    return f'{file_stem(directory)}_{number}.mcap'


def _numbered(directory, names, canonical):
    digits = r'(0|[1-9][0-9]{0,8})' if canonical else r'([0-9]+)'
    pattern = re.compile(re.escape(file_stem(directory)) + '_' + digits + r'\.mcap')
    found = []
    for name in names:
        match = pattern.fullmatch(name)
        if match:
            found.append((int(match.group(1)), name))
    return sorted(found)


def numbered_files(directory, names=None):
    """The recorder's split files present in a directory, as (number, name), in order.

    Only canonical names count (`run_3.mcap`, never `run_003.mcap`). names: the directory's
    entries when already listed (a Folder's names()).
    """
    return _numbered(directory, os.listdir(directory) if names is None else names, True)


def lookalike_files(directory, names=None):
    """Names that look like split files but are none the recorder writes (`run_000.mcap`)."""
    names = os.listdir(directory) if names is None else names
    canonical = {name for _, name in _numbered(directory, names, True)}
    return [name for _, name in _numbered(directory, names, False) if name not in canonical]


def classify_names(directory, names, listed):
    """(candidates, strays) among a bag directory's names, given the names metadata.yaml
    lists (None without one).

    candidates: canonical files after the last listed one (or every canonical file when
    nothing is listed), in order: the recorder's next files, not listed yet when it
    stopped; they belong to the set if their log times go on after it. strays: (name,
    why) of the other names that look like split files, which no tool takes for the set's.
    """
    canonical = numbered_files(directory, names)
    strays = [(name, 'not a name the recorder writes (it numbers its files without leading '
                     'zeros): a copy, not part of the set')
              for name in lookalike_files(directory, names)]
    listed = listed or []
    numbers = dict((name, number) for number, name in canonical)
    last = max((numbers[name] for name in listed if name in numbers), default=-1)
    candidates = []
    for number, name in canonical:
        if name in listed:
            continue
        if number > last:
            candidates.append(name)
        else:
            strays.append((name, f'numbered before {listed[-1]}, the last file '
                                 f'{METADATA_FILE} lists, but not listed: not written in '
                                 'this run'))
    return candidates, strays


class DirectoryClaim:
    """A bag directory created (or emptied of its bag files) for recording, locked.

    folder: the recording.files.Folder of the directory, in which every file is made.
    """

    def __init__(self, path, folder, created):
        self.path = path
        self.folder = folder
        self.created = created
        status = os.fstat(folder.fd)
        self.identity = (status.st_dev, status.st_ino)

    def release(self):
        if self.folder is not None:
            self.folder.remove(RESERVE_FILE)
            self.folder.close()
            self.folder = None

    def discard(self):
        """Release, and remove the directory if it was created here and is empty."""
        if self.folder is not None:
            self.folder.remove(RESERVE_FILE)
            self.folder.close()
            self.folder = None
        if self.created:
            try:
                os.rmdir(self.path)
            except OSError:
                pass  # it holds something: not ours to remove


def open_bag(path):
    """The bag directory `path` opened (not through a symlink) and locked for this process.

    One lock for the recorder and for repair in place, so each refuses the other. Raises
    FileRefused naming the path (a symlink, not a directory, locked by another process).
    """
    folder = Folder(_directory_path(path), follow=False)
    try:
        folder.lock()
    except BaseException:
        folder.close()
        raise
    return folder


def _directory_path(path):
    """A directory path without trailing slashes ('run/' is the directory 'run')."""
    path = os.fspath(path)
    stripped = path.rstrip('/')
    return stripped or path


def claim_directory(path, overwrite=False, hint=''):
    """Create the bag directory `path` (or, with overwrite, reuse one), locked.

    Raises FileRefused naming the path: it exists (without overwrite), is a symlink, is not
    a directory, or another process records into it. Reused, it loses the recorder's files
    (canonical split files, metadata.yaml): nothing else in it is touched.
    """
    path = _directory_path(path)
    parent_path, name = split_path(path)
    created = True
    with Folder(parent_path) as parent:
        try:
            os.mkdir(name, dir_fd=parent.fd)
        except FileExistsError:
            created = _reuse(parent, name, path, overwrite, hint)
        except OSError as error:
            raise FileRefused(error.errno, error.strerror, path) from None
        folder = parent.subfolder(name)
    try:
        folder.lock()
    except BaseException:
        folder.close()
        raise
    if not created:
        try:
            names = refuse_links(folder, path)
        except BaseException:
            folder.close()
            raise
        for _, old in numbered_files(path, names):
            folder.remove(old)
        for old in (METADATA_FILE, RESERVE_FILE):
            folder.remove(old)
    return DirectoryClaim(path, folder, created)


def ours(directory, name):
    """Whether `name` is one the recorder or repair writes, reads or removes in a bag
    directory: its split files (and look-alikes), metadata.yaml and its temporaries."""
    stem = re.escape(file_stem(directory))
    return bool(re.fullmatch(stem + r'_[0-9]+\.mcap(\.partial-[0-9]+)?', name)
                or name == METADATA_FILE or name.startswith(METADATA_FILE + '.')
                or name == RESERVE_FILE)


def refuse_links(folder, directory):
    """The folder's names, or FileRefused if a symlink stands where a bag's files go: it
    was not made by the recorder, and a writer that followed it would write elsewhere."""
    names = folder.names()
    for name in sorted(names):
        if ours(directory, name) and stat.S_ISLNK(folder.lstat(name).st_mode):
            raise FileRefused(errno.ELOOP, f'holds {name}, a symbolic link where the '
                                           "recorder's own files go; ball_world never writes "
                                           'through one: remove it', directory)
    return names


def _reuse(parent, name, path, overwrite, hint):
    """An existing entry where the bag directory goes: whether a new one was made."""
    parent.refuse_symlink(name)
    if not overwrite:
        advice = f'; {hint} to replace it' if hint else ''
        raise FileRefused(errno.EEXIST, f'already exists{advice}', path)
    mode = parent.lstat(name).st_mode
    if stat.S_ISREG(mode):  # a single-file recording of the same name is replaced
        parent.remove(name)
        os.mkdir(name, dir_fd=parent.fd)
        return True
    if not stat.S_ISDIR(mode):
        raise FileRefused(errno.EINVAL, 'is not a directory or a regular file', path)
    return False


@functools.lru_cache(maxsize=256)
def _qos_list_cached(text):
    try:
        profiles = yaml.load(text, Loader=_LOADER) if text else []
    except yaml.YAMLError:
        return ()
    return _freeze(profiles)[1] if isinstance(profiles, list) else ()


def _qos_list(text):
    """offered_qos_profiles as version 9 writes it: the list the channel's YAML holds."""
    return [_thaw(profile) for profile in _qos_list_cached(text)]


@dataclass(frozen=True)
class FileSummary:
    """What metadata.yaml says of one complete file (a Recording's counts, without indexes)."""

    path: str
    start_ns: Optional[int]
    end_ns: Optional[int]
    message_count: int
    topics: dict  # topic -> mcap_reader.TopicInfo


@dataclass(frozen=True)
class TopicCount:
    """A topic of a file as metadata.yaml lists it (mcap_reader.TopicInfo's fields)."""

    topic: str
    type: str
    message_count: int
    offered_qos_profiles: str
    type_hash: str


def summarize(recording):
    """The FileSummary of an mcap_reader.Recording: small enough to keep for days."""
    return FileSummary(path=recording.path, start_ns=recording.start_ns,
                       end_ns=recording.end_ns, message_count=recording.message_count,
                       topics=dict(recording.topics))


def bag_metadata(recordings, stopped=None):
    """The metadata.yaml document for complete files (FileSummary or Recording), in order.

    stopped: what stopped the recorder (a write error), kept in custom_data[STOPPED_KEY].
    """
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
        'custom_data': {STOPPED_KEY: stopped} if stopped else {},
        'ros_distro': 'jazzy',
    }}


def metadata_text(recordings, stopped=None):
    """bag_metadata(recordings, stopped) as YAML, rendered by hand: the same document
    yaml.dump writes (block style, keys in order), at a cost that does not grow with the
    work of a YAML emitter over every file of a long listing. Each file's entry and each
    topic's QoS block are rendered once and kept."""
    information = bag_metadata(recordings, stopped)['rosbag2_bagfile_information']
    out = ['rosbag2_bagfile_information:\n',
           f"  version: {information['version']}\n",
           f"  storage_identifier: {information['storage_identifier']}\n",
           f"  duration:\n    nanoseconds: {information['duration']['nanoseconds']}\n",
           '  starting_time:\n    nanoseconds_since_epoch: '
           f"{information['starting_time']['nanoseconds_since_epoch']}\n",
           f"  message_count: {information['message_count']}\n"]
    topics = information['topics_with_message_count']
    out.append('  topics_with_message_count:\n' if topics
               else '  topics_with_message_count: []\n')
    for entry in topics:
        topic = entry['topic_metadata']
        out.append(f"  - topic_metadata:\n      name: {_scalar(topic['name'])}\n"
                   f"      type: {_scalar(topic['type'])}\n"
                   '      serialization_format: cdr\n')
        out.append(_qos_block(_freeze(topic['offered_qos_profiles'])))
        out.append(f"      type_description_hash: {_scalar(topic['type_description_hash'])}\n"
                   f"    message_count: {entry['message_count']}\n")
    out.append("  compression_format: ''\n  compression_mode: ''\n")
    names = information['relative_file_paths']
    out.append('  relative_file_paths:\n' if names else '  relative_file_paths: []\n')
    out.extend(f'  - {_scalar(name)}\n' for name in names)
    files = information['files']
    out.append('  files:\n' if files else '  files: []\n')
    out.extend(_file_entry(entry['path'], entry['starting_time']['nanoseconds_since_epoch'],
                           entry['duration']['nanoseconds'], entry['message_count'])
               for entry in files)
    custom = information['custom_data']
    out.append('  custom_data:\n' if custom else '  custom_data: {}\n')
    out.extend(f'    {_scalar(key)}: {_scalar(value)}\n' for key, value in custom.items())
    out.append(f"  ros_distro: {information['ros_distro']}\n")
    return ''.join(out)


#: Strings written as they are; anything else is quoted (JSON's quoting is valid YAML).
_PLAIN = re.compile(r'[A-Za-z_/][A-Za-z0-9_./-]*')


def _scalar(text):
    text = str(text)
    reserved = ('null', 'true', 'false', 'yes', 'no', 'on', 'off', '~')
    if _PLAIN.fullmatch(text) and text.lower() not in reserved:
        return text
    return json.dumps(text)


@functools.lru_cache(maxsize=4096)
def _file_entry(path, start, duration, count):
    return (f'  - path: {_scalar(path)}\n    starting_time:\n      nanoseconds_since_epoch: '
            f'{start}\n    duration:\n      nanoseconds: {duration}\n    message_count: '
            f'{count}\n')


def _freeze(value):
    """A hashable copy of plain YAML data (lists and dicts as tuples), for the cache."""
    if isinstance(value, dict):
        return ('dict', tuple((key, _freeze(item)) for key, item in value.items()))
    if isinstance(value, list):
        return ('list', tuple(_freeze(item) for item in value))
    return value


def _thaw(value):
    if isinstance(value, tuple) and value and value[0] == 'dict':
        return {key: _thaw(item) for key, item in value[1]}
    if isinstance(value, tuple) and value and value[0] == 'list':
        return [_thaw(item) for item in value[1]]
    return value


@functools.lru_cache(maxsize=256)
def _qos_block(profiles):
    """offered_qos_profiles of a topic entry (frozen), at its indentation, as yaml.dump
    writes it."""
    value = _thaw(profiles)
    if not value:
        return '      offered_qos_profiles: []\n'
    text = yaml.dump(value, Dumper=_DUMPER, sort_keys=False, default_flow_style=False)
    return '      offered_qos_profiles:\n' + ''.join(
        f'      {line}\n' for line in text.splitlines())


def write_metadata(folder, recordings, stopped=None):
    """Write metadata.yaml for `recordings` atomically (a temporary file in the bag
    directory, then a rename) in `folder` (recording.files.Folder); when the disk is full,
    into the space set aside (reserve_space). Returns the bytes written."""
    data = metadata_text(recordings, stopped).encode('utf-8')
    folder.write_atomically(METADATA_FILE, data, spare=RESERVE_FILE)
    return len(data)


def reserve_space(folder, metadata_bytes=0):
    """Set aside room for the metadata.yaml of a recorder stopped by a full disk: twice the
    current one's size and at least RESERVE_BYTES (it lists one more file, and the reason).
    """
    folder.reserve(RESERVE_FILE, max(RESERVE_BYTES, 2 * metadata_bytes + 4096))


def what_stopped(stopped):
    """What a recorded write error means, when it says: ' (the disk filled up)', ..."""
    if 'No space left' in stopped or 'Disk quota' in stopped:
        return ' (the disk filled up)'
    if 'File too large' in stopped:
        return (" (the file reached the largest size allowed it: the process's file size "
                "limit, RLIMIT_FSIZE, or the file system's)")
    return ''


def missing_metadata(directory, stopped=None):
    """What a directory without a usable listing is, for the one line that refuses it.

    stopped: what metadata.yaml says stopped the recorder before it finished a file.
    """
    files = numbered_files(directory)
    repair = f'ball_world_repair {directory} keeps their complete records'
    if stopped:
        return (f'its recorder stopped before it finished a file: {stopped}'
                f'{what_stopped(stopped)}; {repair}')
    if files:
        return (f'has no {METADATA_FILE}: its recorder stopped before it finished a file '
                f'(it was killed, or could not write{_free_space(directory)}); {repair}')
    return f'is a directory without {METADATA_FILE}, not a bag of split files'


def _free_space(directory):
    """'; its file system has N bytes free now' when that is under 1 MiB (a full disk)."""
    try:
        status = os.statvfs(directory)
    except OSError:
        return ''
    free = status.f_bavail * status.f_frsize
    return f'; its file system has {free:,} bytes free now' if free < (1 << 20) else ''


@dataclass(frozen=True)
class Listing:
    """What metadata.yaml says: the files in order, and what stopped the recorder, if it was
    stopped by an error (None when it finished or was killed)."""

    names: list
    stopped: Optional[str]


def read_listing(directory, load):
    """The Listing of a bag directory's metadata.yaml (ValueError says what is wrong).

    load(text, what, limit): the caller's bounded YAML parser for untrusted text. A name
    must be a plain file name inside the directory. A listing of no files is accepted only
    when it says what stopped the recorder.
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
    custom = information.get('custom_data') if isinstance(information, dict) else None
    stopped = custom.get(STOPPED_KEY) if isinstance(custom, dict) else None
    stopped = stopped[:500] if isinstance(stopped, str) and stopped.isprintable() else None
    if not isinstance(names, list) or (not names and not stopped):
        raise ValueError(f'{METADATA_FILE} lists no files (relative_file_paths)')
    for name in names:
        if not isinstance(name, str) or name in ('', '.', '..') or '/' in name \
                or '\0' in name:
            raise ValueError(f'{METADATA_FILE} lists {repr(name)[:60]}, which is not a file '
                             'name in the directory')
    if len(set(names)) != len(names):
        raise ValueError(f'{METADATA_FILE} lists a file twice')
    return Listing(list(names), stopped)


def listed_files(directory, load):
    """The file names metadata.yaml lists, in order (read_listing's names)."""
    return read_listing(directory, load).names
