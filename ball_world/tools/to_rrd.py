"""Convert a ball_world MCAP recording to a Rerun .rrd file.

The recording is replayed through the same RerunSink the node logs with (via
recording.feed_sinks), so a converted file has the same layout, timelines and blueprint as
one logged live. A recording cut off by a crash converts up to its last complete step.
"""
import argparse
from pathlib import Path
import sys
import time

PROG = 'ball_world_to_rrd'


class ProgressBar:
    """A Sink that only counts steps and draws a text bar on a stream (stderr).

    On a terminal the bar redraws in place at most every `interval` seconds; elsewhere (a
    log file, CI) it prints one line per tenth so the output stays readable.
    """

    def __init__(self, total, stream=None, width=40, interval=0.1):
        self.total = max(int(total), 0)
        self.stream = sys.stderr if stream is None else stream
        self.width = width
        self.interval = interval
        self.done = 0
        self.tty = hasattr(stream, 'isatty') and stream.isatty()
        self._drawn_at = None
        self._tenths = -1
        self._printed = None

    def start_segment(self, world, info):
        pass

    def write_step(self, record):
        self.done += 1
        self._draw(final=False)

    def flush(self):
        pass

    def close(self):
        self._draw(final=True)

    def line(self):
        if self.total:
            fraction = min(self.done / self.total, 1.0)
            filled = round(fraction * self.width)
            bar = '#' * filled + '.' * (self.width - filled)
            return f'[{bar}] {fraction:4.0%} {self.done}/{self.total} steps'
        return f'{self.done} steps'

    def _draw(self, final):
        if self.tty:
            now = time.monotonic()
            if not final and self._drawn_at is not None \
                    and now - self._drawn_at < self.interval:
                return
            self._drawn_at = now
            self.stream.write('\r' + self.line() + ('\n' if final else ''))
        else:
            tenths = 10 * self.done // self.total if self.total else 0
            line = self.line()
            if tenths == self._tenths and not (final and line != self._printed):
                return
            self._tenths = tenths
            self._printed = line
            self.stream.write(line + '\n')
        self.stream.flush()

    def abandon(self):
        """End a bar drawn in place, so an error message starts on a line of its own."""
        if self.tty and self._drawn_at is not None:
            self.stream.write('\n')
            self.stream.flush()


def parse_args(argv):
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument('input', type=Path, help='ball_world MCAP recording (IN.mcap)')
    parser.add_argument('-o', '--output', type=Path,
                        help='Rerun file to write (default: IN with the suffix .rrd)')
    parser.add_argument('--every', type=int, default=1, metavar='K',
                        help='log every K-th step (steps with impulses and the first and '
                             'last step of each segment are always logged; default 1)')
    args = parser.parse_args(argv)
    if args.every < 1:
        parser.error(f'--every must be >= 1, got {args.every}')
    if args.output is None:
        args.output = args.input.with_suffix('.rrd')
    if args.output.resolve() == args.input.resolve():
        parser.error(f'the output {str(args.output)!r} would overwrite the input')
    return args


def main(argv=None):
    args = parse_args(argv)
    # Imported here: rerun takes a while to import, and --help should not wait for it.
    from ball_world.recording.mcap_reader import feed_sinks, Recording, RecordingError
    from ball_world.recording.rerun_log import RerunSink
    from ball_world.core.scenario import ScenarioError

    progress = sink = None
    try:
        recording = Recording(args.input)
        balls = recording.topics.get(recording.topic_of('balls'))
        progress = ProgressBar(balls.message_count if balls else 0)
        sink = RerunSink(args.output, every=args.every)
        steps = feed_sinks(recording, [sink, progress])
    except (RecordingError, ScenarioError, OSError) as error:
        if progress is not None:
            progress.abandon()
        print(f'{PROG}: error: {error}', file=sys.stderr)
        if sink is not None:
            sink.close()  # a valid file with the steps before the error
            print(f'{PROG}: {args.output} holds the {progress.done} steps read before it',
                  file=sys.stderr)
        return 1
    if recording.problem:
        print(f'{PROG}: warning: {args.input} is incomplete ({recording.problem}); '
              'converted up to its last complete step', file=sys.stderr)
    print(f'{PROG}: wrote {args.output}: {steps} steps, {len(recording.segments)} '
          f'segment(s)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
