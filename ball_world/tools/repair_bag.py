"""ball_world_repair on a bag directory: repair its split files, then rewrite metadata.yaml.

A recorder killed while writing a split recording leaves its last file without summary
and unlisted (metadata.yaml lists only finished files), or, killed right after starting a
file, a file with nothing in it. Each split file of the directory without summary is
repaired in place (tools.repair: every complete record kept); a file with no complete
record at all holds nothing to lose and is removed; then metadata.yaml is written again
from the files present, as the recorder writes it. A directory being recorded (locked) is
refused. Files metadata.yaml listed that are gone are named in the report, not invented.
"""
import os

from mcap.records import Message

from ball_world.recording.bag import (listed_files, lock_directory, METADATA_FILE,
                                      missing_metadata, numbered_files, summarize,
                                      write_metadata)
from ball_world.recording.files import open_regular
from ball_world.recording.mcap_reader import load_untrusted, Recording, RecordingError, Scan
from ball_world.tools import repair as repair_file


def _holds_messages(path):
    size = os.path.getsize(path)
    with open_regular(path) as stream:
        try:
            return any(isinstance(record, Message) for record in Scan(stream, size).records())
        except RecordingError:
            return size > 0


def _previously_listed(directory):
    try:
        return listed_files(directory, lambda text, what, limit: load_untrusted(
            text, what, limit, json_text=False))
    except (ValueError, RecordingError, OSError):
        return []


def check_bag(directory):
    """Refuse (RecordingError) a directory that is no bag of split files."""
    if not numbered_files(directory):
        raise RecordingError(missing_metadata(directory) if not os.path.exists(
            os.path.join(directory, METADATA_FILE)) else 'holds no split file to repair')


def repair_bag(directory, stream=None):
    """Repair every split file of `directory` that needs it and rewrite metadata.yaml.

    Returns the report as lines. Raises RecordingError when no file is left to list, or
    OSError (FileRefused: the directory is being recorded).
    """
    check_bag(directory)
    fd = lock_directory(directory)
    try:
        lines = []
        listed = _previously_listed(directory)
        present = [name for _, name in numbered_files(directory)]
        for name in listed:
            if name not in present:
                lines.append(f'{name}: listed in {METADATA_FILE} but gone; left out')
        kept = []
        for name in present:
            path = os.path.join(directory, name)
            try:
                recording = Recording(path)
                if not recording.has_summary:
                    report = repair_file.repair(path, path, force=True, stream=stream)
                    lines.extend(repair_file.describe(report, path, path).splitlines())
                    recording = Recording(path)
            except RecordingError as error:
                if not _holds_messages(path):
                    os.unlink(path)
                    lines.append(f'{name}: removed, it held no complete message ({error})')
                    continue
                lines.append(f'{name}: left out, it cannot be read: {error}')
                continue
            kept.append(summarize(recording))
        if not kept:
            raise RecordingError('holds no readable split file')
        write_metadata(directory, kept)
        lines.append(f'wrote {os.path.join(directory, METADATA_FILE)}: {len(kept)} files, '
                     f'{sum(s.message_count for s in kept)} messages')
        return lines
    finally:
        os.close(fd)
