"""ball_world_repair for Rerun .rrd files: make a recording whose writer was killed complete.

A SIGKILLed node leaves its .rrd without the footer (the index of its chunks) that the Rerun
SDK writes when the stream is closed, possibly ending in a torn message; `rerun rrd verify`
then fails. Rerun's own CLI (shipped with rerun-sdk) reads such a file up to its last
complete message: `rerun rrd merge --continue-on-error` reads every complete chunk of every
store (the recording and its blueprint) and writes them out as a complete file with a
footer. This runs it into a temporary file, checks the result with `rerun rrd verify` and
that it holds a ball_world recording, and only then moves it into place
(recording.files.PartialOutput, as for MCAP): the input is never changed, and input that is
not a Rerun recording of ball_world writes nothing.

The parts of a split .rrd (recording.rrd_parts: `<name>_<i>.rrd` beside the name given) are
repaired in place by repair_parts: each part `rerun rrd verify` refuses is rewritten, a part
that holds nothing (its writer stopped as it began it) is removed, and anything that looks
like a part but is none the recorder names (`run_003.rrd`) is left alone, said.
"""
from dataclasses import dataclass, field
import os
import re
import subprocess

from ball_world.recording.files import Folder, open_regular, PartialOutput, same_path, split_path
from ball_world.recording.mcap_reader import RecordingError
from ball_world.recording.rerun_log import APPLICATION_ID
from ball_world.recording.rrd_parts import part_names, part_stem
from ball_world.recording.rrd_reading import (ball_steps, last_line, run_rerun, verify,
                                              verify_error)


@dataclass
class RrdReport:
    """What a repair of an .rrd found and wrote."""

    source_bytes: int = 0
    problem: str = ''  # what `rerun rrd verify` said of the input ('' when it passed)
    target_bytes: int = 0
    recordings: int = 0
    blueprints: int = 0
    steps: list = None  # for each recording, (first, last) step with ball positions, or None


def repair_rrd(source, target, force=False, folder=None):
    """Write every complete chunk of the .rrd `source` into a complete .rrd at `target`.

    folder: a recording.files.Folder in which `target` is a plain name. Raises
    RecordingError (not a Rerun recording of ball_world, or Rerun could not read it) or
    OSError (files.FileRefused included); then nothing is written.
    """
    with open_regular(source) as stream:  # refuses a FIFO or a device, like the MCAP repair
        report = RrdReport(source_bytes=os.fstat(stream.fileno()).st_size)
    report.problem = verify(source)
    in_place = same_path(source, folder.join(target) if folder is not None else target)
    output = PartialOutput(target, force or in_place, 'pass --force', folder=folder)
    try:
        with output.claim.writer() as written:
            merged = run_rerun(['rrd', 'merge', '--continue-on-error', source], stdout=written,
                               stderr=subprocess.PIPE)
        if merged.returncode != 0:
            raise RecordingError(f'Rerun could not read it: {last_line(merged.stderr)}')
        verified = run_rerun(['rrd', 'verify', output.path], capture_output=True)
        if verified.returncode != 0:
            raise RecordingError(f'the copy does not verify: {verify_error(verified)}')
        report.recordings, report.blueprints, report.steps = ball_steps(output.path)
        if not report.recordings:
            raise RecordingError(f"no recording of '{APPLICATION_ID}' in it: not a ball_world "
                                 '.rrd')
        report.target_bytes = os.path.getsize(output.path)
        output.commit()
    except BaseException:
        output.discard()
        raise
    return report


def describe(report, source, target):
    lines = [f'{source}: {report.source_bytes} bytes, '
             + (f'{report.problem}' if report.problem else 'it verified (rewritten anyway)')]
    for index, span in enumerate(report.steps):
        kept = f'steps {span[0]}-{span[1]} of the balls' if span else 'no ball positions'
        lines.append(f'  recording {index}: kept {kept}')
    blueprints = f"{report.blueprints} blueprint{'' if report.blueprints == 1 else 's'}"
    lines.append(f'  kept {blueprints}; the copy verifies ({report.target_bytes} bytes)')
    lines.append(f'wrote {target}')
    return '\n'.join(lines)


@dataclass
class PartsReport:
    """What a repair of a split .rrd's parts found and did, as lines; lost: a part that
    could not be read at all (left in place)."""

    lines: list = field(default_factory=list)
    lost: bool = False


def repair_parts(path):
    """Repair in place every part of the split .rrd named `path` that does not verify.

    Raises OSError (FileRefused) for the folder; returns a PartsReport.
    """
    folder_path, _ = split_path(path)
    report = PartsReport()
    with Folder(folder_path) as folder:
        names = folder.names()
        parts = part_names(path, names)
        lookalike = re.compile(re.escape(part_stem(path)) + r'_[0-9]+\.rrd')
        canonical = {name for _, name in parts}
        for name in sorted(names):
            if lookalike.fullmatch(name) and name not in canonical:
                report.lines.append(f'{folder.join(name)}: left alone, not a name the '
                                    'recorder gives a part (it numbers them without leading '
                                    'zeros)')
        verified = sum(_repair_part(folder, name, report) for _, name in parts)
    report.lines.append(f'{len(parts)} parts of {path}: {verified} verify'
                        + ('; NOT ALL COULD BE READ (see above)' if report.lost else ''))
    return report


def _repair_part(folder, name, report):
    """Check one part and repair it in place if it needs it; whether it verifies now."""
    path = folder.join(name)
    if folder.lstat(name).st_size == 0:
        folder.remove(name)
        report.lines.append(f'{path}: removed, it held nothing (its writer stopped as it '
                            'began it)')
        return False
    if not verify(path):
        report.lines.append(f'{path}: verifies')
        return True
    try:
        repaired = repair_rrd(path, name, force=True, folder=folder)
    except RecordingError as error:
        report.lost = True
        report.lines.append(f'{path}: left in place, it cannot be read: {error}')
        return False
    report.lines.extend(describe(repaired, path, path).splitlines())
    return True
