"""ball_world_info for Rerun recordings: an .rrd file, or the parts of a split one.

What `rerun rrd verify` says of each file (a part whose writer was killed has no footer),
which recordings it holds and the steps of the balls in it, read through Rerun's own reader
(recording.rrd_reading). Given the name of a split .rrd whose parts `<name>_<i>.rrd` lie
beside it (recording.rrd_parts), every part is described, in order, with the steps it
begins and ends at, so a gap between parts shows; look-alikes the recorder does not name
are said and left out.
"""
import os
import re

from ball_world.recording.files import open_regular
from ball_world.recording.mcap_reader import RecordingError
from ball_world.recording.rrd_parts import part_names, part_stem
from ball_world.recording.rrd_reading import ball_steps, verify


def _describe_file(path):
    """(size, verify problem or '', ball step spans) of one .rrd; RecordingError if Rerun
    cannot read it at all."""
    with open_regular(path) as stream:  # a FIFO or a device is refused, never waited on
        size = os.fstat(stream.fileno()).st_size
    problem = verify(path)
    try:
        recordings, _, spans = ball_steps(path)
    except Exception as error:  # noqa: B902 - whatever the SDK's reader raises
        if problem:  # cut short (no footer, a torn message): repair reads what is there
            return size, problem, None
        raise RecordingError(f'Rerun cannot read it: {" ".join(str(error).split())}') from None
    if not recordings:
        raise RecordingError('no recording of ball_world in it: not a ball_world .rrd')
    return size, problem, spans


def _spans_text(spans):
    if spans is None:
        return "steps not known (Rerun's reader stops in it)"
    return '; '.join(f'steps {span[0]}-{span[1]}' if span else 'no ball positions'
                     for span in spans)


def describe(path):
    """The report as lines: one .rrd, or every part of a split one named `path`."""
    if os.path.lexists(path) or not part_names(path):
        size, problem, spans = _describe_file(path)
        return [f'file:        {path} ({size:,} bytes)',
                f"verify:      {'passes' if not problem else f'FAILS: {problem}'}"
                + (f'; ball_world_repair {path} mends it' if problem else ''),
                f'balls:       {_spans_text(spans)}']
    folder = os.path.dirname(path) or '.'
    parts = part_names(path)
    lines = [f'parts:       {len(parts)} parts of {path} '
             f'({part_stem(path)}_<i>.rrd, each a complete recording)']
    failing = 0
    for _, name in parts:
        part = os.path.join(folder, name)
        try:
            size, problem, spans = _describe_file(part)
        except RecordingError as error:
            failing += 1
            lines.append(f'  {name}: CANNOT BE READ: {error}')
            continue
        failing += bool(problem)
        lines.append(f'  {name}: {size:,} bytes, {_spans_text(spans)}, '
                     + ('verifies' if not problem else f'FAILS: {problem}'))
    lookalike = re.compile(re.escape(part_stem(path)) + r'_[0-9]+\.rrd')
    canonical = {name for _, name in parts}
    for name in sorted(os.listdir(folder)):
        if lookalike.fullmatch(name) and name not in canonical:
            lines.append(f'  left out: {name}: not a name the recorder gives a part')
    if failing:
        lines.append(f'  {failing} part(s) do not verify: ball_world_repair {path} mends them')
    return lines
