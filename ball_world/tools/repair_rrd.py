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
"""
from dataclasses import dataclass
import os
from pathlib import Path
import subprocess
import warnings

from ball_world.recording.files import open_regular, PartialOutput, same_path
from ball_world.recording.mcap_reader import RecordingError
from ball_world.recording.rerun_log import BALLS, STEP

#: The application id the node's Rerun streams are logged under.
APPLICATION_ID = 'ball_world'


@dataclass
class RrdReport:
    """What a repair of an .rrd found and wrote."""

    source_bytes: int = 0
    problem: str = ''  # what `rerun rrd verify` said of the input ('' when it passed)
    target_bytes: int = 0
    recordings: int = 0
    blueprints: int = 0
    steps: list = None  # for each recording, (first, last) step with ball positions, or None


def rerun_binary():
    """The Rerun CLI of the installed rerun-sdk (the `rerun` script only runs it)."""
    try:
        import rerun_cli
    except ImportError:
        raise RecordingError('repairing an .rrd needs the Rerun CLI of rerun-sdk (pip install '
                             'rerun-sdk)') from None
    return Path(rerun_cli.__file__).parent / 'rerun'


def _run(arguments, **options):
    return subprocess.run([str(rerun_binary()), *map(str, arguments)], text=True, **options)


def _last_line(text):
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else 'no message'


def _ball_steps(path):
    """(recordings, blueprints, [(first, last) step of the balls per recording]) of an .rrd."""
    import rerun as rr  # its import takes a second: only when an .rrd is repaired
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', 'RRD file has no footer')
        reader = rr.chunk.RrdReader(path)
    recordings = [store for store in reader.recordings()
                  if store.application_id == APPLICATION_ID]
    spans = []
    for store in recordings:
        steps = []
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if chunk.entity_path == f'/{BALLS}' and 'Points2D:positions' in batch.schema.names:
                steps += batch.column(STEP).to_pylist()
        spans.append((min(steps), max(steps)) if steps else None)
    return len(recordings), len(reader.blueprints()), spans


def repair_rrd(source, target, force=False):
    """Write every complete chunk of the .rrd `source` into a complete .rrd at `target`.

    Raises RecordingError (not a Rerun recording of ball_world, or Rerun could not read it)
    or OSError (files.FileRefused included); then nothing is written.
    """
    with open_regular(source) as stream:  # refuses a FIFO or a device, like the MCAP repair
        report = RrdReport(source_bytes=os.fstat(stream.fileno()).st_size)
    checked = _run(['rrd', 'verify', source], capture_output=True)
    report.problem = '' if checked.returncode == 0 else _last_error(checked)
    output = PartialOutput(target, force or same_path(source, target), 'pass --force')
    try:
        with output.claim.writer() as written:
            merged = _run(['rrd', 'merge', '--continue-on-error', source], stdout=written,
                          stderr=subprocess.PIPE)
        if merged.returncode != 0:
            raise RecordingError(f'Rerun could not read it: {_last_line(merged.stderr)}')
        verified = _run(['rrd', 'verify', output.path], capture_output=True)
        if verified.returncode != 0:
            raise RecordingError(f'the copy does not verify: {_last_error(verified)}')
        report.recordings, report.blueprints, report.steps = _ball_steps(output.path)
        if not report.recordings:
            raise RecordingError(f"no recording of '{APPLICATION_ID}' in it: not a ball_world "
                                 '.rrd')
        report.target_bytes = os.path.getsize(output.path)
        output.commit()
    except BaseException:
        output.discard()
        raise
    return report


def _last_error(done):
    """The line of `rerun rrd verify`'s output that says what is wrong."""
    lines = [line.strip() for line in (done.stdout + done.stderr).splitlines()
             if line.strip() and not line.startswith('Error: Verification failed')]
    if not lines:
        return f'rerun rrd verify failed (exit code {done.returncode})'
    quoted, _, said = lines[-1].partition('": ')  # '"PATH": what is wrong'
    return f'rerun rrd verify: {said if quoted.startswith(chr(34)) and said else lines[-1]}'


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
