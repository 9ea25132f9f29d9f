"""Convert a ball_world MCAP recording to a Rerun .rrd file (or, with --split, to parts).

The recording is replayed through the same RerunSink the node logs with (via
recording.feed_sinks), so a converted file has the same layout, timelines and blueprint as
one logged live. A recording cut off by a crash converts up to its last complete step. A
bag directory of split files converts as one run; with --split, into one part per MCAP
file, `OUT_<n>.rrd` for `<bag>_<n>.mcap`, each complete and opening on its own, as the node
writes the parts of a split .rrd (recording.rrd_parts). A set with a gap (a file missing or
cut short) converts what it holds, picked up again from the state the next file resumes
from, and says which steps are not in the output.

Every .rrd is written beside its target under a temporary name and moved into place when
complete (recording.files.PartialOutput): an existing file is never replaced without
--force, never written through a symlink, and a conversion that fails (a corrupt recording)
leaves no file behind.
"""
import argparse
import os
from pathlib import Path
import re
import sys

from ball_world.recording.files import same_path

PROG = 'ball_world_to_rrd'


def parse_args(argv):
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument('input', type=Path, help='ball_world MCAP recording (IN.mcap), or a '
                        'bag directory of split files')
    parser.add_argument('-o', '--output', type=Path,
                        help='Rerun file to write (default: IN with the suffix .rrd); with '
                             '--split, the name of the parts OUTPUT_<n>.rrd')
    parser.add_argument('--force', action='store_true',
                        help='replace the output file(s) if they exist')
    parser.add_argument('--every', type=int, default=1, metavar='K',
                        help='log every K-th step (steps with impulses and the first and '
                             'last step of each segment are always logged; default 1)')
    parser.add_argument('--split', action='store_true',
                        help='a bag directory: one .rrd part per MCAP file, OUTPUT_<n>.rrd '
                             'for <bag>_<n>.mcap, as the node splits a .rrd')
    args = parser.parse_args(argv)
    if args.every < 1:
        parser.error(f'--every must be >= 1, got {args.every}')
    if args.output is None:
        args.output = args.input.with_suffix('.rrd')
    if same_path(args.output, args.input) or (
            args.output.exists() and args.input.exists()
            and os.path.samefile(args.output, args.input)):
        parser.error(f'the output {str(args.output)!r} would overwrite the input')
    if args.split and not args.input.is_dir():
        parser.error('--split needs a bag directory of split files')
    return args


def convert(args, passed_over):
    """Write the .rrd (or its parts); returns (steps, recording, outputs).

    Raises RecordingError or ScenarioError for the input, OSError for the output.
    passed_over: a list that gets the steps a jump inside a segment made unreadable.
    """
    # Imported here: rerun takes a while to import, and --help should not wait for it.
    from ball_world.recording.mcap_reader import RecordingError
    from ball_world.recording.recording_set import open_recording

    recording = open_recording(args.input)
    balls = recording.topics.get(recording.topic_of('balls'))
    if balls is None or balls.message_count == 0:
        raise RecordingError('holds no step to convert')
    files = recording.files if args.split else [recording]
    names = [_part_name(args.output, f, index) for index, f in enumerate(files)] \
        if args.split else [args.output]
    return (*_write(args, recording, files, names, balls.message_count, passed_over), names)


def _part_name(output, recording, index):
    """OUTPUT_<n>.rrd for the MCAP file <bag>_<n>.mcap (its position when not so named)."""
    match = re.search(r'_(0|[1-9][0-9]*)\.mcap$', os.path.basename(recording.path))
    number = int(match.group(1)) if match else index
    stem = output.name[:-len('.rrd')] if output.name.endswith('.rrd') else output.name
    return output.with_name(f'{stem}_{number}.rrd')


def _write(args, recording, files, names, total, passed_over):
    from ball_world.recording.files import PartialOutput
    from ball_world.recording.mcap_reader import feed_sinks, RecordingError
    from ball_world.recording.rerun_log import RerunSink
    from ball_world.tools.progress import StepProgress

    outputs = []
    progress = StepProgress(total, PROG)
    sink = None
    try:
        outputs.append(PartialOutput(names[0], args.force, 'pass --force'))
        sink = RerunSink(outputs[0].claim, every=args.every)
        steps = 0
        for index, source in enumerate(files):
            if index:
                outputs.append(PartialOutput(names[index], args.force, 'pass --force'))
                sink.next_part(outputs[-1].claim)
            steps += feed_sinks(source, [sink, progress], close=False,
                                passed_over=passed_over)
        sink.close()
        if steps == 0:
            raise RecordingError('holds no complete step to convert')
        for output in outputs:
            output.commit()
    except BaseException:
        progress.abandon()
        _close_quietly(sink)
        for output in outputs:
            output.discard()
        raise
    progress.finish()
    return steps, recording


def _close_quietly(sink):
    """Close a sink after a failure: the failure is what gets reported, not this."""
    if sink is None:
        return
    try:
        sink.close()
    except Exception:  # noqa: B902 - the conversion already failed; its error is reported
        pass


def main(argv=None):
    args = parse_args(argv)
    from ball_world.core.scenario import ScenarioError
    from ball_world.recording.mcap_reader import RecordingError
    passed_over = []
    try:
        steps, recording, outputs = convert(args, passed_over)
    except (RecordingError, ScenarioError) as error:
        print(f'{PROG}: error: {args.input}: {error}', file=sys.stderr)
        return 2
    except OSError as error:  # the output: its message names it
        print(f'{PROG}: error: {error}', file=sys.stderr)
        return 2
    if recording.problem:
        print(f'{PROG}: warning: {args.input} is incomplete ({recording.problem}); '
              'converted what it holds', file=sys.stderr)
    for gap in getattr(recording, 'gaps', ()):
        print(f'{PROG}: warning: {gap.describe()}', file=sys.stderr)
    for segment, first, last in passed_over:
        print(f'{PROG}: warning: segment {segment}: steps {first}-{last} not converted (they '
              'follow steps missing from the recording, with no state to go on from)',
              file=sys.stderr)
    for name, why in getattr(recording, 'strays', ()):
        print(f'{PROG}: note: {name} left out: {why}', file=sys.stderr)
    written = ', '.join(str(output) for output in outputs)
    segments = len({segment.index for segment in recording.segments})
    print(f'{PROG}: wrote {written}: {steps} steps, {segments} segment(s)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
