"""Reading a ball_world .rrd from outside: Rerun's own checks and what steps it holds.

For the tools that look at .rrd files (ball_world_repair, ball_world_info): `rerun rrd
verify` through the Rerun CLI that ships with rerun-sdk, and the steps of the balls' positions
through the SDK's reader, read chunk by chunk. rerun is imported only when a file is read
(its import takes a second).
"""
from pathlib import Path
import subprocess
import warnings

from ball_world.recording.mcap_reader import RecordingError
from ball_world.recording.rerun_log import APPLICATION_ID, BALLS, STEP


def rerun_binary():
    """The Rerun CLI of the installed rerun-sdk (the `rerun` script only runs it)."""
    try:
        import rerun_cli
    except ImportError:
        raise RecordingError('reading an .rrd needs the Rerun CLI of rerun-sdk (pip install '
                             'rerun-sdk)') from None
    return Path(rerun_cli.__file__).parent / 'rerun'


def run_rerun(arguments, **options):
    """The Rerun CLI run with `arguments` (subprocess.run's result, text)."""
    return subprocess.run([str(rerun_binary()), *map(str, arguments)], text=True, **options)


def last_line(text):
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else 'no message'


def verify(path):
    """'' when `rerun rrd verify` passes the file, else the line saying what is wrong."""
    done = run_rerun(['rrd', 'verify', path], capture_output=True)
    return '' if done.returncode == 0 else verify_error(done)


def verify_error(done):
    """The line of `rerun rrd verify`'s output that says what is wrong."""
    lines = [line.strip() for line in (done.stdout + done.stderr).splitlines()
             if line.strip() and not line.startswith('Error: Verification failed')]
    if not lines:
        return f'rerun rrd verify failed (exit code {done.returncode})'
    quoted, _, said = lines[-1].partition('": ')  # '"PATH": what is wrong'
    return f'rerun rrd verify: {said if quoted.startswith(chr(34)) and said else lines[-1]}'


def ball_steps(path):
    """(recordings, blueprints, [(first, last) step of the balls per recording]) of an .rrd.

    Recordings are those of ball_world's application id; a recording without ball
    positions gives None. Raises what the SDK's reader raises for a file it cannot read.
    """
    import rerun as rr
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
