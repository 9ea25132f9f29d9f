"""Convert a ball_world MCAP recording to a Rerun .rrd file.

The recording is replayed through the same RerunSink the node logs with (via
recording.feed_sinks), so a converted file has the same layout, timelines and blueprint as
one logged live. A recording cut off by a crash converts up to its last complete step.

The .rrd is written beside its target under a temporary name and moved into place when
complete: an existing file is never replaced without --force, and a conversion that fails
(a corrupt recording) leaves no file behind.
"""
import argparse
import os
from pathlib import Path
import sys

from ball_world.recording.files import same_path

PROG = 'ball_world_to_rrd'


def parse_args(argv):
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument('input', type=Path, help='ball_world MCAP recording (IN.mcap), or a '
                        'bag directory of split files')
    parser.add_argument('-o', '--output', type=Path,
                        help='Rerun file to write (default: IN with the suffix .rrd)')
    parser.add_argument('--force', action='store_true',
                        help='replace the output file if it exists')
    parser.add_argument('--every', type=int, default=1, metavar='K',
                        help='log every K-th step (steps with impulses and the first and '
                             'last step of each segment are always logged; default 1)')
    args = parser.parse_args(argv)
    if args.every < 1:
        parser.error(f'--every must be >= 1, got {args.every}')
    if args.output is None:
        args.output = args.input.with_suffix('.rrd')
    if same_path(args.output, args.input) or (
            args.output.exists() and args.input.exists()
            and os.path.samefile(args.output, args.input)):
        parser.error(f'the output {str(args.output)!r} would overwrite the input')
    return args


def convert(args):
    """Write the .rrd; returns (steps, recording).

    Raises RecordingError or ScenarioError for the input, OSError for the output.
    """
    # Imported here: rerun takes a while to import, and --help should not wait for it.
    from ball_world.recording.files import ClaimedSink, PartialOutput
    from ball_world.recording.mcap_reader import feed_sinks, RecordingError
    from ball_world.recording.recording_set import open_recording
    from ball_world.recording.rerun_log import RerunSink
    from ball_world.tools.progress import StepProgress

    recording = open_recording(args.input)
    balls = recording.topics.get(recording.topic_of('balls'))
    if balls is None or balls.message_count == 0:
        raise RecordingError('holds no step to convert')
    output = PartialOutput(args.output, args.force, 'pass --force')
    progress = StepProgress(balls.message_count, PROG)
    sink = None
    try:
        sink = ClaimedSink(RerunSink(output.claim, every=args.every), output.claim)
        steps = feed_sinks(recording, [sink, progress], close=False)
        sink.close()
        if steps == 0:
            raise RecordingError('holds no complete step to convert')
        output.commit()
    except BaseException:
        progress.abandon()
        _close_quietly(sink)
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
    try:
        steps, recording = convert(args)
    except (RecordingError, ScenarioError) as error:
        print(f'{PROG}: error: {args.input}: {error}', file=sys.stderr)
        return 2
    except OSError as error:  # the output: its message names it
        print(f'{PROG}: error: {error}', file=sys.stderr)
        return 2
    if recording.problem:
        print(f'{PROG}: warning: {args.input} is incomplete ({recording.problem}); '
              'converted up to its last complete step', file=sys.stderr)
    print(f'{PROG}: wrote {args.output}: {steps} steps, {len(recording.segments)} '
          f'segment(s)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
