"""ball_world_repair on a bag directory: mend its split files, then rewrite metadata.yaml.

What belongs to the set is decided first (recording.bag): the files metadata.yaml lists,
and after them the recorder's next files, which it had not listed yet when it stopped:
canonical names (`run_<n>.mcap`) numbered after the last listed file whose log times go on
after it. Anything else that looks like a split file is a stray (a copy such as
`run_000.mcap`, a file numbered before the last listed one but not listed, a file whose
log times go back into the run): it is named in the report and left exactly as it is,
never repaired, removed or listed. Repair never makes a set worse.

Every file of the set is read whole, every chunk decompressed and checked, so damage that a
valid summary hides (a corrupt chunk) is found too. A file without summary, or with damage,
is repaired in place (tools.repair_mcap: every readable record kept, what was lost named
with its log times). The recorder's next file when it held nothing at all (killed as it
began) is removed; the recorder's temporary and reserved files are removed too. Then
metadata.yaml is written again from the set, as the recorder writes it.

Whatever repair cannot mend is said and makes `lost` true (ball_world_repair then exits 1):
data lost in a damaged file, a listed file that is gone, a listed file that cannot be read
at all (left in place, no longer listed). A directory being recorded (locked) is refused.
"""
from dataclasses import dataclass, field
import os

from mcap.records import Message

from ball_world.recording.bag import (classify_names, METADATA_FILE, missing_metadata,
                                      numbered_files, open_bag, read_listing, refuse_links,
                                      RESERVE_FILE, summarize, write_metadata)
from ball_world.recording.files import open_regular
from ball_world.recording.mcap_reader import (load_untrusted, MAGIC, Recording,
                                              RecordingError, Scan)
from ball_world.tools import repair_mcap


@dataclass
class BagReport:
    """What a bag repair found and did, as lines, and whether data was lost for good."""

    lines: list = field(default_factory=list)
    lost: bool = False


def _load_yaml(text, what, limit):
    return load_untrusted(text, what, limit, json_text=False)


def _listing(directory):
    """(names metadata.yaml lists, what stopped the recorder) or (None, None) without one."""
    try:
        listing = read_listing(directory, _load_yaml)
    except (ValueError, RecordingError, OSError):
        return None, None
    return listing.names, listing.stopped


def check_bag(directory):
    """Refuse (RecordingError) a directory that is no bag of split files."""
    if not numbered_files(directory) and not os.path.exists(
            os.path.join(directory, METADATA_FILE)):
        raise RecordingError(missing_metadata(directory))


@dataclass
class FileState:
    """One file read whole: its size, whether it is an MCAP, the log times of its messages,
    the damage a scan skipped, and whether its data section ends properly."""

    size: int
    is_mcap: bool = False
    first_ns: int = None
    last_ns: int = None
    damage: list = field(default_factory=list)
    finished: bool = False


def file_state(path):
    """The FileState of one file, every chunk decompressed and checked."""
    state = FileState(os.path.getsize(path))
    with open_regular(path) as stream:
        if stream.read(len(MAGIC)) != MAGIC:
            return state
        scan = Scan(stream, state.size, go_on=True)
        state.is_mcap = True
        try:
            for record in scan.records():
                if isinstance(record, Message):
                    time = record.log_time
                    state.first_ns = time if state.first_ns is None else min(state.first_ns,
                                                                             time)
                    state.last_ns = time if state.last_ns is None else max(state.last_ns, time)
        except RecordingError:
            state.is_mcap = False
        state.damage = scan.damage
        state.finished = scan.finished
    return state


def repair_bag(directory, stream=None):
    """Mend every file of the set in `directory` that needs it and rewrite metadata.yaml.

    Returns a BagReport. Raises RecordingError when no file is left to list, or OSError
    (FileRefused: the directory is being recorded, or is a symlink).
    """
    check_bag(directory)
    folder = open_bag(directory)
    try:
        return _repair(directory, folder, stream)
    finally:
        folder.close()


def _repair(directory, folder, stream):
    report = BagReport()
    refuse_links(folder, directory)
    listed, stopped = _listing(directory)
    if stopped:
        report.lines.append(f'{METADATA_FILE} says the recorder stopped: {stopped}')
    names = folder.names()
    members = listed or []
    candidates, strays = classify_names(directory, names, listed)
    kept = []
    last_end = None
    for name in members:
        if name not in names:
            report.lines.append(f'{name}: listed in {METADATA_FILE} but gone; its steps are '
                                'lost (a gap in the set)')
            report.lost = True
            continue
        summary = _mend(directory, folder, name, report, stream)
        if summary is not None:
            kept.append(summary)
            last_end = summary.end_ns if summary.end_ns is not None else last_end
    for name in candidates:
        state = file_state(os.path.join(directory, name))
        if state.size == 0 or (state.is_mcap and state.first_ns is None):
            folder.remove(name)
            report.lines.append(f'{name}: removed, it held no complete message (its recorder '
                                'stopped as it began it)')
            continue
        if not state.is_mcap:
            strays.append((name, 'not an MCAP file'))
            continue
        if last_end is not None and state.first_ns <= last_end:
            strays.append((name, f'its log times begin at {state.first_ns / 1e9:.9g} s, not '
                                 f'after the set before it ({last_end / 1e9:.9g} s): not part '
                                 'of this run'))
            continue
        summary = _mend(directory, folder, name, report, stream, candidate=True)
        if summary is not None:
            kept.append(summary)
            last_end = summary.end_ns if summary.end_ns is not None else last_end
    for name, why in strays:
        report.lines.append(f'{name}: left alone, {why}')
    for name in names:
        if name == RESERVE_FILE or name.startswith(f'{METADATA_FILE}.tmp-'):
            folder.remove(name)  # the recorder's own, left by a recorder that was killed
    if not kept:
        raise RecordingError('holds no readable split file'
                             + (f' (the recorder stopped: {stopped})' if stopped else ''))
    write_metadata(folder, kept)
    report.lines.append(f'wrote {os.path.join(directory, METADATA_FILE)}: {len(kept)} files, '
                        f'{sum(s.message_count for s in kept)} messages'
                        + ('; NOT ALL DATA COULD BE KEPT (see above)' if report.lost else ''))
    return report


def _mend(directory, folder, name, report, stream, candidate=False):
    """Check one file of the set whole and repair it in place if it needs it: its
    bag.FileSummary, or None when it cannot be read at all (left in place, not listed)."""
    path = os.path.join(directory, name)
    try:
        state = file_state(path)
        recording = Recording(path) if state.is_mcap and not state.damage else None
        if recording is None or not recording.has_summary or not state.finished:
            repaired = repair_mcap.repair(path, name, force=True, stream=stream,
                                          folder=folder)
            report.lines.extend(repair_mcap.describe(repaired, path, path).splitlines())
            report.lost = report.lost or repaired.lost_data
            if not candidate and repaired.problem:
                # listed: its recorder had finished it, so what is missing was cut off since
                report.lines.append(f'  DAMAGED: {name} was finished by its recorder (it is '
                                    f'listed in {METADATA_FILE}); its end is gone, lost')
                report.lost = True
            recording = Recording(path)
    except RecordingError as error:
        report.lines.append(f'{name}: left in place and no longer listed, it cannot be read: '
                            f'{error}' if not candidate else
                            f'{name}: left alone, it cannot be read: {error}')
        report.lost = report.lost or not candidate
        return None
    return summarize(recording)
