"""ball_world_score's benchmark: a tracker over many simulated scenes, on every core.

A scene is a world (the node's parameters: by default the default world with random.seed
set to the scene's seed) with one scanning agent driven by a constant command (default a
circle: 0.5 m/s forward turning at 0.4 rad/s), simulated headless without ROS (the
Simulation class the node wraps) as fast as the machine goes, for `--duration` simulated
seconds. At each scan the tracker is given what a ROS tracker gets, the LaserScan (from
its message bytes) and the scanner's pose from /tf, and its tracks are scored against
the balls that scan could see from the agent's true pose (past walls and a map's cells: /tf
drifts with agent.odom.noise), exactly as a recording of that scene would be scored
(tools.score_recording and tools.score_frames do both). A tracker is the example one or any
class `update(scan, pose) -> rows (id, x, y, ...)` (tools.tracker.ScanTracker), made anew
for each scene with no arguments (and given the scene's map first when it has `use_map(grid)`).

Scenes run in worker processes (one per core by default), each scene alone in one and all
of its numbers its own, and results are gathered in scene order: the report is the same
bit for bit whatever the number of processes or the machine's load. Each figure is given
as its mean over scenes with a 95% confidence interval (scoring.scenes), with the scenes
pooled as TrackEval combines sequences, and the worst scenes by HOTA.

`--worlds FILE.yaml` lists worlds instead (docs/scoring.md):

    duration: 30             # simulated seconds per scene (optional)
    agent: ball_0            # the scanning agent (optional)
    cmd_vel: [0.5, 0.0, 0.4] # vx, vy (m/s), wz (rad/s) in the agent's frame (optional)
    worlds:
      - name: gas
        seeds: 0:10          # one scene per seed (optional; default: the world's own)
        parameters: {random.count: 20}
      - name: crowd
        parameters: {random.count: 60, arena: [0.0, 0.0, 12.0, 12.0]}
"""
from dataclasses import dataclass
import importlib
import importlib.util
import math
import multiprocessing
import os
import sys
import time

#: Most scenes one benchmark runs.
MAX_SCENES = 100_000
#: Longest scene, simulated seconds.
MAX_DURATION = 3600.0
#: Largest worlds file read.
MAX_WORLDS_BYTES = 1 << 20
DEFAULT_COMMAND = (0.5, 0.0, 0.4)
EXAMPLE = 'the example tracker'


class BenchError(ValueError):
    """A benchmark that cannot run; the message says why in one line."""


@dataclass(frozen=True)
class Scene:
    """One world to simulate and score."""

    label: str
    parameters: dict  # the node's parameters (over the defaults)
    agent: str
    command: tuple  # (vx, vy, wz) every step
    steps: int


def add_arguments(parser):
    group = parser.add_argument_group('benchmark over many scenes')
    group.add_argument('--seeds', metavar='A:B',
                       help='simulate the default world with random.seed A .. B-1 (or 0 .. '
                            'N-1 for N), one scene each')
    group.add_argument('--worlds', metavar='FILE.yaml',
                       help='simulate the worlds this file lists (docs/scoring.md)')
    group.add_argument('--scenes', metavar='DIR',
                       help='score recorded scenes: the directories ball_world_score_scenes '
                            'made (world and tracks of a tracker node, one per scene)')
    group.add_argument('--duration', type=float, default=None, metavar='S',
                       help='simulated seconds per scene (default 30)')
    group.add_argument('--tracker', metavar='MODULE:CLASS',
                       help='a tracker class (update(scan, pose) -> rows (id, x, y, ...)), '
                            'from an importable module or a file path.py:CLASS (default: '
                            'the example tracker)')
    group.add_argument('--jobs', type=int, default=None, metavar='N',
                       help='worker processes (default: every core this process may use)')
    group.add_argument('--worst', type=int, default=5, metavar='K',
                       help='how many worst scenes to name (default 5)')


def check_arguments(parser, args):
    given = [name for name in ('seeds', 'worlds', 'scenes') if getattr(args, name) is not None]
    if len(given) > 1:
        parser.error(f"give one of --seeds, --worlds, --scenes, not {' and '.join(given)}")
    if args.tracks or args.csv or args.rerun or args.per_track:
        parser.error('--tracks, --csv, --rerun and --per-track score one recording, not a '
                     'benchmark')
    if args.duration is not None and not (math.isfinite(args.duration)
                                          and 0.0 < args.duration <= MAX_DURATION):
        parser.error(f'--duration must be in (0, {MAX_DURATION:g}] s')
    if args.jobs is not None and not 1 <= args.jobs <= 1024:
        parser.error('--jobs must be in [1, 1024]')
    if not 0 <= args.worst <= MAX_SCENES:
        parser.error('--worst must be >= 0')
    if args.seeds is not None:
        try:
            args.seed_range = parse_seeds(args.seeds)
        except ValueError as error:
            parser.error(f'--seeds: {error}')
    if args.scenes is not None and (args.tracker or args.duration is not None):
        parser.error('--tracker and --duration make scenes; --scenes scores recorded ones')


def parse_seeds(text):
    """range of 'A:B' (A .. B-1) or 'N' (0 .. N-1); ValueError for anything else."""
    parts = text.split(':')
    try:
        if len(parts) == 1:
            first, last = 0, int(parts[0])
        elif len(parts) == 2:
            first, last = int(parts[0]), int(parts[1])
        else:
            raise ValueError
    except ValueError:
        raise ValueError(f'expected A:B or N (whole numbers), got {text!r}') from None
    if not 0 <= first < last <= 2 ** 63:
        raise ValueError(f'expected 0 <= A < B, got {text!r}')
    if last - first > MAX_SCENES:
        raise ValueError(f'{last - first:,} scenes; at most {MAX_SCENES:,}')
    return range(first, last)


# Scenes ------------------------------------------------------------------------------------

def _scene(label, parameters, agent, command, duration):
    from ball_world.core.parameters import checked, ParameterError
    from ball_world.core.scenario import step_duration_ns
    try:
        merged = checked({**parameters, 'agents': [agent]})
        for name in parameters:
            from ball_world.core.parameters import check
            check(name, parameters[name])
        dt_ns = step_duration_ns(merged)
    except ParameterError as error:
        raise BenchError(f'{label}: {error}') from None
    if int(merged['agent.scan.samples']) == 0:
        raise BenchError(f'{label}: agent.scan.samples is 0: the agent does not scan')
    steps = max(1, round(duration * 1e9 / dt_ns))
    return Scene(label, merged, agent, tuple(float(v) for v in command), steps)


def seed_scenes(seeds, duration):
    return [_scene(f'seed {seed}', {'random.seed': seed}, 'ball_0', DEFAULT_COMMAND, duration)
            for seed in seeds]


def world_scenes(path, duration_override):
    """The scenes a worlds file lists (BenchError naming what is wrong)."""
    from ball_world.recording.files import open_regular
    from ball_world.recording.mcap_reader import load_untrusted, RecordingError
    try:
        with open_regular(path) as stream:
            text = stream.read(MAX_WORLDS_BYTES + 1).decode('utf-8')
        document = load_untrusted(text, path, MAX_WORLDS_BYTES, json_text=False)
    except (OSError, UnicodeDecodeError, RecordingError) as error:
        raise BenchError(f'{path}: {getattr(error, "strerror", None) or error}') from None
    if not isinstance(document, dict) or not isinstance(document.get('worlds'), list) \
            or not document['worlds']:
        raise BenchError(f'{path}: expected a mapping with a non-empty list `worlds`')
    unknown = set(document) - {'duration', 'agent', 'cmd_vel', 'worlds'}
    if unknown:
        raise BenchError(f'{path}: unknown key {sorted(unknown)[0]!r} (duration, agent, '
                         'cmd_vel, worlds)')
    duration = _number(document.get('duration', 30.0), path, 'duration')
    if duration_override is not None:
        duration = duration_override
    if not 0.0 < duration <= MAX_DURATION:
        raise BenchError(f'{path}: duration must be in (0, {MAX_DURATION:g}] s')
    agent = document.get('agent', 'ball_0')
    if not isinstance(agent, str) or not agent:
        raise BenchError(f'{path}: agent must be an entity name')
    command = document.get('cmd_vel', list(DEFAULT_COMMAND))
    if not isinstance(command, list) or len(command) != 3:
        raise BenchError(f'{path}: cmd_vel must be [vx, vy, wz]')
    command = [_number(v, path, 'cmd_vel') for v in command]
    scenes = []
    for position, world in enumerate(document['worlds']):
        if not isinstance(world, dict) or set(world) - {'name', 'seeds', 'parameters'}:
            raise BenchError(f'{path}: world {position}: expected name, seeds, parameters')
        name = str(world.get('name', f'world {position}'))
        parameters = world.get('parameters', {}) or {}
        if not isinstance(parameters, dict):
            raise BenchError(f'{path}: {name}: parameters must be a mapping')
        seeds = [None]
        if 'seeds' in world:
            try:
                seeds = parse_seeds(str(world['seeds']))
            except ValueError as error:
                raise BenchError(f'{path}: {name}: seeds: {error}') from None
        for seed in seeds:
            values = dict(parameters) if seed is None else {**parameters, 'random.seed': seed}
            label = name if seed is None else f'{name} seed {seed}'
            scenes.append(_scene(label, values, agent, command, duration))
            if len(scenes) > MAX_SCENES:
                raise BenchError(f'{path}: more than {MAX_SCENES:,} scenes')
    return scenes


def _number(value, path, key):
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise BenchError(f'{path}: {key} must be a finite number, got {value!r}')
    return float(value)


# The tracker ---------------------------------------------------------------------------------

def load_tracker_class(spec):
    """The class `spec` names: 'module:Class' or 'path/to/file.py:Class' (BenchError)."""
    if spec is None:
        from ball_world.tools.tracker import ScanTracker
        return ScanTracker
    module_name, _, class_name = spec.rpartition(':')
    if not module_name or not class_name:
        raise BenchError(f'--tracker {spec!r}: expected MODULE:CLASS or FILE.py:CLASS')
    try:
        if module_name.endswith('.py'):
            if not os.path.isfile(module_name):
                raise BenchError(f'--tracker: {module_name} is not a file')
            loaded = importlib.util.spec_from_file_location(
                f'ball_world_user_tracker_{abs(hash(module_name))}', module_name)
            module = importlib.util.module_from_spec(loaded)
            loaded.loader.exec_module(module)
        else:
            module = importlib.import_module(module_name)
    except BenchError:
        raise
    except Exception as error:  # noqa: B902 - a user's module may raise anything on import
        from ball_world.tools.user_code import describe_exception
        raise BenchError(f'--tracker: importing {module_name} failed: '
                         f'{describe_exception(error)}') from None
    tracker_class = getattr(module, class_name, None)
    if tracker_class is None or not callable(tracker_class):
        raise BenchError(f'--tracker: {module_name} has no class {class_name}')
    return tracker_class


def _new_tracker(tracker_class, spec):
    try:
        tracker = tracker_class()
    except Exception as error:  # noqa: B902 - user code
        from ball_world.tools.user_code import describe_exception
        raise BenchError(f'--tracker {spec}: making one failed: '
                         f'{describe_exception(error)}') from None
    if not callable(getattr(tracker, 'update', None)):
        raise BenchError(f'--tracker {spec}: it has no update(scan, pose) method')
    return tracker


# One scene, in a worker -----------------------------------------------------------------------

def simulated_scans(scene):
    """The agent's scans of a scene (tools.score_recording.RecordedScan), simulated."""
    from ball_world.msgs.agent_cdr import decode_laser_scan
    from ball_world.scoring.planar_tf import PlanarTransforms
    from ball_world.simulation import Simulation
    from ball_world.tools.score_recording import add_transforms, scan_at, true_pose
    from ball_world.core.agents import frames as agent_frames

    simulation = Simulation(scene.parameters)
    world_frame = simulation.frame_id
    scan_frame = agent_frames(scene.parameters['frame_prefix'], scene.agent)[1]
    transforms = PlanarTransforms()
    record = simulation.last_record
    scans = []
    vx, vy, wz = scene.command
    for step in range(scene.steps + 1):
        if step:
            simulation.command(scene.agent, vx, vy, wz)
            record, _ = simulation.step()
        agents = record.agents
        if agents.tf_static_cdr is not None:
            add_transforms(transforms, agents.tf_static_cdr, static=True)
        for scan in agents.scans:
            if scan.name != scene.agent:
                continue
            add_transforms(transforms, agents.tf_cdr)
            message = decode_laser_scan(scan.cdr)
            pose = transforms.lookup(world_frame, scan_frame, message.stamp_ns)
            index = simulation.index_of[scene.agent]
            # Ground truth from the true pose, as a recording of the scene has it (its
            # ground_truth bytes), never from /tf, which drifts with agent.odom.noise.
            truth = true_pose(agents.ground_truth_cdr[agents.names.index(scene.agent)],
                              scan_frame, message.stamp_ns)
            world = simulation.world
            scans.append(scan_at(step, message, pose, truth, record.names, record.positions,
                                 record.radii, (world.walls, world.static.scan_grid), index,
                                 scene.parameters))
    return scans


def _scene_map(scene):
    """The scene's map (core.occupancy_map), for a tracker's use_map, or None."""
    if not scene.parameters.get('map'):
        return None
    from ball_world.simulation import load_map
    return load_map(scene.parameters)


def run_scene(job):
    """Score one scene: (position, label, SequenceScore without its frames) or the one-line
    error of a tracker that failed. Runs in a worker process."""
    position, scene, spec, gate = job
    from ball_world.scoring import figures
    from ball_world.scoring.frames import DuplicateTrack
    from ball_world.tools.score_frames import frames_with_tracker, FramesError
    try:
        tracker = _new_tracker(load_tracker_class(spec), spec or EXAMPLE)
        scans = simulated_scans(scene)
        try:
            frames = frames_with_tracker(scans, tracker, spec or EXAMPLE, _scene_map(scene))
        except FramesError:
            raise
        except Exception as error:  # noqa: B902 - a user's tracker may raise anything
            from ball_world.tools.user_code import describe_exception
            raise BenchError(f'{spec or EXAMPLE} failed on {scene.label}: '
                             f'{describe_exception(error)}') from None
        score = figures.score_tracks(frames, gate)
    except DuplicateTrack as error:
        return position, scene.label, None, f'{spec or EXAMPLE} on {scene.label}: {error}'
    except (BenchError, FramesError) as error:
        return position, scene.label, None, str(error)
    score.sequence = score.matches = None  # not sent back: large, and not needed
    return position, scene.label, score, None


# The benchmark ------------------------------------------------------------------------------

def available_cores():
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def run(args):
    """The report of a benchmark of simulated scenes (a dict; BenchError when it cannot
    run)."""
    duration = 30.0 if args.duration is None else args.duration
    if args.seeds is not None:
        scenes = seed_scenes(args.seed_range, duration)
        what = f'seeds {args.seed_range.start}:{args.seed_range.stop}, {duration:g} s each'
    else:
        scenes = world_scenes(args.worlds, args.duration)
        what = f'worlds of {args.worlds}'
    tracker_class = load_tracker_class(args.tracker)  # fail here, once, not in every worker
    _new_tracker(tracker_class, args.tracker or EXAMPLE)
    jobs = min(args.jobs or available_cores(), len(scenes))
    began = time.perf_counter()
    work = [(position, scene, args.tracker, args.gate) for position, scene in
            enumerate(scenes)]
    results = [None] * len(scenes)
    if jobs == 1:
        outcomes = map(run_scene, work)
        pool = None
    else:
        pool = multiprocessing.get_context('spawn').Pool(jobs, initializer=_worker_start,
                                                         initargs=(sys.path,))
        outcomes = pool.imap_unordered(run_scene, work)
    try:
        for position, label, score, error in outcomes:
            if error is not None:
                raise BenchError(error)
            results[position] = (label, score)
    finally:
        if pool is not None:
            pool.terminate()
            pool.join()
    seconds = time.perf_counter() - began
    return summarize(results, what, args.tracker or EXAMPLE, args.gate, jobs, seconds,
                     args.worst)


def _worker_start(path):
    """A spawned worker: the parent's import path (a tracker module beside the user)."""
    sys.path[:] = path


def summarize(results, what, tracker, gate, jobs, seconds, worst_count):
    """The benchmark's report from [(label, SequenceScore)] in scene order."""
    from ball_world.scoring import figures as metrics
    from ball_world.scoring import scenes as stats
    labels = [label for label, _ in results]
    rows = [score.figures() for _, score in results]
    kind = results[0][1].kind
    names = metrics.TRACK_FIGURES if kind == 'tracks' else metrics.DETECTION_FIGURES
    names = names + ('mean_distance_m',)
    summary = {name: interval.as_dict()
               for name, interval in stats.summarize(rows, names).items()}
    pooled = metrics.combine([score for _, score in results]).figures()
    by = 'HOTA' if kind == 'tracks' else 'DetA'
    return {'scenes': len(results), 'what': what, 'tracker': tracker, 'kind': kind,
            'gate': gate, 'jobs': jobs, 'seconds': seconds, 'summary': summary,
            'pooled': pooled, 'worst_by': by,
            'worst': stats.worst(rows, labels, by, worst_count),
            'per_scene': [dict(scene=label, **row) for label, row in zip(labels, rows)]}
