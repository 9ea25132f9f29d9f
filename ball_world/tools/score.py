"""ball_world_score: how well tracks follow the balls a scanner could see.

Scores a tracker the way the field does (TrackEval's CLEAR-MOT, identity and HOTA metrics,
equal to TrackEval's on the same frames), against ground truth only a simulator has: at
each scan of an agent, every ball and whether that scan could see it. docs/scoring.md says
what each figure means and how to read them. Two uses:

- one recording (`ball_world_score run.mcap`): the example tracker run on its scans, or
  `--tracks MCAP TOPIC` a tracker's recorded output (MarkerArray with ids, or PoseArray
  scored as detections), paired with the scans by stamp;
- a benchmark over many scenes (`ball_world_score --seeds 0:100`, or `--worlds FILE.yaml`):
  the worlds simulated headless on every core with the example tracker or
  `--tracker module:Class`, each figure's mean with a 95% confidence interval and the worst
  scenes; or `--scenes DIR`: recordings of scenes made with a tracker node
  (ball_world_score_scenes), scored the same way.

The mathematics is in ball_world.scoring (no ROS, no files); this module reads the inputs
and prints. Every bad input is one line on stderr and exit status 1 (2 for bad arguments).
"""
import argparse
import json
import math
import sys

PROG = 'ball_world_score'
EXAMPLES = """examples:
  ball_world_score run.mcap                                  the example tracker on a recording
  ball_world_score run.mcap --tracks mine /ball_0/my_tracks  your tracker's recorded output
  ball_world_score --seeds 0:100                             100 simulated scenes, every core
  ball_world_score --seeds 0:100 --tracker my_tracker.py:MyTracker
  ball_world_score --scenes DIR                              scenes ball_world_score_scenes made

docs/scoring.md: ground truth, the gate, don't-care, stamps, the metrics, the CSV."""


def _positive(text):
    value = float(text)
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f'expected a number > 0, got {text!r}')
    return value


def _tolerance(text):
    value = float(text)
    if not (math.isfinite(value) and 0.0 <= value <= 3600.0):
        raise argparse.ArgumentTypeError(f'expected seconds in [0, 3600], got {text!r}')
    return value


def parse_args(argv):
    from ball_world.tools import score_bench
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description='How well tracks follow the balls a scanner could see: HOTA (DetA, '
                    'AssA, LocA), IDF1 and CLEAR-MOT,\n'
                    "equal to TrackEval's on the same frames, on one recording or over many "
                    'simulated scenes.',
        epilog=EXAMPLES)
    parser.add_argument('recording', nargs='?',
                        help='a ball_world MCAP (or bag directory) recorded with a scanning '
                             'agent')
    parser.add_argument('--agent', default='ball_0', help='the scanning agent (default ball_0)')
    parser.add_argument('--gate', type=_positive, default=0.5,
                        help='distance within which a track matches a ball, m (similarity '
                             '0.5; default 0.5)')
    parser.add_argument('--tracks', nargs=2, metavar=('MCAP', 'TOPIC'),
                        help='score these tracks (visualization_msgs/MarkerArray with track '
                             'ids, or geometry_msgs/PoseArray: detections) instead of the '
                             'example tracker; MCAP may be a rosbag2 directory')
    parser.add_argument('--stamp-tolerance', type=_tolerance, default=0.0, metavar='S',
                        help='pair a track message with the nearest scan within S seconds '
                             '(default 0: equal stamps only)')
    parser.add_argument('--per-track', action='store_true',
                        help='also a breakdown per ball and per track')
    parser.add_argument('--json', action='store_true',
                        help='print the report as JSON (for scripts and CI)')
    parser.add_argument('--csv', metavar='FILE',
                        help='write the scored frames (ground truth with visibility, and '
                             'tracks) to a CSV file (docs/scoring.md: the format)')
    parser.add_argument('--rerun', metavar='FILE.rrd',
                        help='log the scored run to a Rerun file: balls, tracks, misses and '
                             'false positives over time')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing --csv or --rerun file')
    score_bench.add_arguments(parser)
    args = parser.parse_args(argv)
    benchmark = args.seeds is not None or args.worlds is not None or args.scenes is not None
    if benchmark == (args.recording is not None):
        parser.error('give a recording, or one of --seeds, --worlds, --scenes')
    if benchmark:
        score_bench.check_arguments(parser, args)
    elif args.tracker is not None:
        parser.error('--tracker runs on simulated scenes: give it with --seeds or --worlds')
    elif args.ray is not None:
        parser.error('--ray runs simulated scenes: give it with --seeds or --worlds')
    if args.stamp_tolerance and not (args.tracks or args.scenes):
        parser.error('--stamp-tolerance pairs recorded track messages: give --tracks')
    return args


def score_recording(args):
    """The report of the recording the arguments name (a dict) and the scores behind it."""
    from ball_world.tools.score_one import breakdown, score_files
    report, segments, scores = score_files(
        args.recording, args.agent, args.gate, args.tracks, args.stamp_tolerance)
    if args.per_track:
        report['per_ball'], report['per_track'] = breakdown(scores)
    return report, segments, scores


def _json_ready(value):
    """The report with nan as null (JSON has no nan) and every key a string."""
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, 'item'):
        return _json_ready(value.item())
    return value


def _write_outputs(args, segments, scores):
    if args.csv:
        from ball_world.tools import score_export
        score_export.write_csv(args.csv, segments, scores, args.force)
    if args.rerun:
        from ball_world.tools import score_rerun
        score_rerun.write_rrd(args.rerun, segments, scores, args.force)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the tool is, so that its workers end with it (a `with` of the
    pool kills them) and their notes are removed, as on a Ctrl-C."""


def _terminate(signum, frame):
    raise Terminated


def _on_sigterm(handler):
    """Install `handler` for SIGTERM (from the main thread only); the one it replaces."""
    import signal
    import threading
    if handler is None or threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, handler)


def main(argv=None):
    from ball_world.recording.mcap_reader import RecordingError
    from ball_world.scoring.frames import DuplicateTrack
    from ball_world.tools.score_frames import FramesError
    from ball_world.tools.score_one import ScoreError
    from ball_world.tools.score_tracks import TracksError

    args = parse_args(sys.argv[1:] if argv is None else argv)
    previous = _on_sigterm(_terminate)
    try:
        if args.scenes is not None:
            from ball_world.tools import score_scenes
            report = score_scenes.score_directory(args)
            lines_of = 'bench_lines'
        elif args.recording is None:
            from ball_world.tools import score_bench
            report = score_bench.run(args)
            lines_of = 'bench_lines'
        else:
            report, segments, scores = score_recording(args)
            _write_outputs(args, segments, scores)
            lines_of = 'recording_lines'
    except (ScoreError, RecordingError, TracksError, FramesError, DuplicateTrack,
            OSError, ValueError) as error:
        text = getattr(error, 'strerror', None) if isinstance(error, OSError) else None
        if isinstance(error, OSError) and error.filename and text:
            text = f'{error.filename}: {text}'
        print(f'{PROG}: {text or error}', file=sys.stderr)
        return 1
    except Terminated:
        print(f'{PROG}: terminated', file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted', file=sys.stderr)
        return 130
    finally:
        _on_sigterm(previous)
    if args.json:
        print(json.dumps(_json_ready(report), indent=1))
    else:
        from ball_world.scoring import report as text
        print('\n'.join(getattr(text, lines_of)(report)))
    note = (report.get('stamps') or {}).get('note')
    if args.json and note:
        print(f'{PROG}: warning: {note}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
