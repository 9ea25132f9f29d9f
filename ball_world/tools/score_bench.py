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

Scenes run in worker processes (one per core by default; or with --ray as tasks on a Ray
cluster: `executor`, user_code.ray_pool), each scene alone in one and all of its numbers its
own, and results are gathered in scene order: the report is the same bit for bit whatever
the number of processes or the machine's load. The tracker, user code, runs only there
(with --jobs 1 too): the workers are supervised (user_code.workers), so however it ends (an
exception, SystemExit, os._exit, a segfault, a signal, a call past --timeout) the run stops
with one line and no process left. Each figure is given as its mean over scenes with a 95%
confidence interval (scoring.scenes), with the scenes pooled as TrackEval combines
sequences, and the worst scenes by HOTA.

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
import math
import os
import time

#: Most scenes one benchmark runs.
MAX_SCENES = 100_000
#: Longest scene, simulated seconds.
MAX_DURATION = 3600.0
#: Default and largest --timeout: wall seconds one call of the tracker may take.
DEFAULT_TIMEOUT = 60.0
MAX_TIMEOUT = 86400.0
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
    group.add_argument('--duration', type=given_float, default=None, metavar='S',
                       help='simulated seconds per scene (default 30)')
    group.add_argument('--tracker', metavar='MODULE:CLASS',
                       help='a tracker class (update(scan, pose) -> rows (id, x, y, ...)), '
                            'from an importable module or a file path.py:CLASS (default: '
                            'the example tracker)')
    group.add_argument('--jobs', type=int, default=None, metavar='N',
                       help='worker processes (default: every core this process may use)')
    group.add_argument('--ray', metavar='ADDRESS',
                       help='run the scenes as tasks on the Ray cluster at ADDRESS (its '
                            "head node's host:port, or auto for the one on this machine; "
                            '--jobs: tasks at once, default its CPUs); the report is the '
                            'local one (docs/scoring.md)')
    group.add_argument('--timeout', type=given_float,
                       default=given_float(f'{DEFAULT_TIMEOUT:g}'), metavar='S',
                       help='wall seconds one call of the tracker (import, making one, one '
                            'update) may take before its worker is stopped and the run '
                            f'fails (default {DEFAULT_TIMEOUT:g})')
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
        parser.error(f'--duration is {_given(args.duration)}; it must be in '
                     f'(0, {MAX_DURATION:g}] s')
    if args.jobs is not None and not 1 <= args.jobs <= 1024:
        parser.error(f'--jobs is {args.jobs}; it must be in [1, 1024]')
    if not (math.isfinite(args.timeout) and 0.0 < args.timeout <= MAX_TIMEOUT):
        parser.error(f'--timeout is {_given(args.timeout)}; it must be in '
                     f'(0, {MAX_TIMEOUT:g}] s')
    args.timeout = float(args.timeout)
    if args.duration is not None:
        args.duration = float(args.duration)
    if not 0 <= args.worst <= MAX_SCENES:
        parser.error(f'--worst is {args.worst}; it must be in [0, {MAX_SCENES}]')
    if args.seeds is not None:
        try:
            args.seed_range = parse_seeds(args.seeds)
        except ValueError as error:
            parser.error(f'--seeds: {error}')
    if args.ray is not None and args.scenes is not None:
        parser.error('--ray runs simulated scenes (--seeds, --worlds); --scenes scores the '
                     'recorded ones here')
    if args.ray is not None and not args.ray.strip():
        parser.error("--ray is empty; give the head node's HOST:PORT or auto")
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
        raise ValueError(f'expected A:B or N (whole numbers), got {_given(text)}') from None
    if not 0 <= first < last <= 2 ** 63:
        raise ValueError(f'expected 0 <= A < B <= 2**63, got {_given(text)}')
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


class _Number(float):
    """A float read from YAML that remembers how it was written (for messages)."""

    text = ''


def _yaml_loader():
    """A YAML loader for the scorer's files: YAML 1.2's numbers, no aliases.

    PyYAML reads YAML 1.1, where `1e308` is a string (its floats need a dot), `017` is 15
    (octal), `5:10` is 310 (base 60: `seeds: 5:10` would be 310 scenes) and `no` is False.
    Here, as in YAML 1.2, an int is decimal digits, a float a decimal with an optional
    exponent (or .inf, .nan), a bool true or false, and anything else is text. Aliases are
    refused: a few hundred bytes of them expand to gigabytes."""
    import re
    import yaml

    class Loader(yaml.SafeLoader):
        context = 'this file'

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise yaml.YAMLError(f'YAML aliases (*name) are not accepted in '
                                     f'{self.context} (line {mark.line + 1}): write the '
                                     'value out')
            return super().compose_node(parent, index)

    int_tag, float_tag = 'tag:yaml.org,2002:int', 'tag:yaml.org,2002:float'
    bool_tag = 'tag:yaml.org,2002:bool'
    Loader.yaml_implicit_resolvers = {
        first: [(tag, regex) for tag, regex in resolvers
                if tag not in (int_tag, float_tag, bool_tag)]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
    Loader.add_implicit_resolver(bool_tag, re.compile(
        r'^(?:true|True|TRUE|false|False|FALSE)$'), list('tTfF'))
    Loader.add_implicit_resolver(int_tag, re.compile(r'^[-+]?[0-9]+$'), list('-+0123456789'))
    Loader.add_implicit_resolver(float_tag, re.compile(
        r'^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?'
        r'|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$'), list('-+0123456789.'))

    def integer(loader, node):
        return int(loader.construct_scalar(node))

    def number(loader, node):
        text = loader.construct_scalar(node)
        lowered = text.lower().lstrip('+')
        value = _Number(float(lowered.replace('.inf', 'inf').replace('.nan', 'nan')))
        value.text = text
        return value

    Loader.add_constructor(int_tag, integer)
    Loader.add_constructor(float_tag, number)
    return Loader


def load_yaml(text, what, context):
    """The document of YAML `text` (BenchError naming `what` in one line); `context` says
    where aliases were refused ('a --worlds file')."""
    import yaml
    loader = _yaml_loader()(text)
    loader.context = context
    try:
        return loader.get_single_data()
    except RecursionError:
        raise BenchError(f'{what} nests too deeply') from None
    except (ValueError, yaml.YAMLError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise BenchError(f'{what} does not parse: {reason}') from None
    finally:
        loader.dispose()


def _plain(value):
    """The document with _Number as plain floats (what the world's parameters take)."""
    if isinstance(value, _Number):
        return float(value)
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_plain(item) for item in value]
    return value


def given_float(text):
    """float(text) that remembers `text` (argparse's type: messages say what was given)."""
    import argparse
    try:
        value = _Number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {_given(text)}') from None
    value.text = text
    return value


def _given(value):
    """A value as the file or command line gave it."""
    from ball_world.user_code.describe import shown
    return getattr(value, 'text', '') or shown(value)


def world_scenes(path, duration_override):
    """The scenes a worlds file lists (BenchError naming what is wrong)."""
    from ball_world.recording.files import open_regular
    try:
        with open_regular(path) as stream:
            data = stream.read(MAX_WORLDS_BYTES + 1)
        if len(data) > MAX_WORLDS_BYTES:
            raise BenchError(f'{path} is larger than {MAX_WORLDS_BYTES:,} bytes, the most '
                             'a --worlds file may hold')
        text = data.decode('utf-8')
    except UnicodeDecodeError as error:
        raise BenchError(f'{path} is not UTF-8 text (byte {error.start})') from None
    except OSError as error:
        raise BenchError(f'{path}: {error.strerror or error}') from None
    document = load_yaml(text, path, 'a --worlds file')
    if not isinstance(document, dict) or not isinstance(document.get('worlds'), list) \
            or not document['worlds']:
        raise BenchError(f'{path}: expected a mapping with a non-empty list `worlds`, got '
                         f'{_shown_kind(document)}')
    unknown = set(document) - {'duration', 'agent', 'cmd_vel', 'worlds'}
    if unknown:
        raise BenchError(f'{path}: unknown key {_given(sorted(unknown, key=str)[0])} '
                         '(duration, agent, cmd_vel, worlds)')
    duration = _number(document.get('duration', 30.0), path, 'duration')
    if duration_override is not None:
        duration = duration_override
    elif not 0.0 < duration <= MAX_DURATION:
        raise BenchError(f'{path}: duration is {_given(document["duration"])}; it must be '
                         f'in (0, {MAX_DURATION:g}] s')
    agent = document.get('agent', 'ball_0')
    if not isinstance(agent, str) or not agent:
        raise BenchError(f'{path}: agent is {_given(agent)}; it must be an entity name '
                         '(text, e.g. ball_0)')
    command = document.get('cmd_vel', list(DEFAULT_COMMAND))
    if not isinstance(command, list) or len(command) != 3:
        raise BenchError(f'{path}: cmd_vel is {_given(command)}; it must be [vx, vy, wz]')
    command = [_number(v, path, 'cmd_vel') for v in command]
    scenes = []
    for position, world in enumerate(document['worlds']):
        if not isinstance(world, dict):
            raise BenchError(f'{path}: world {position} is {_given(world)}; expected a '
                             'mapping of name, seeds, parameters')
        extra = set(world) - {'name', 'seeds', 'parameters'}
        if extra:
            raise BenchError(f'{path}: world {position}: unknown key '
                             f'{_given(sorted(extra, key=str)[0])} (name, seeds, parameters)')
        name = str(world.get('name', f'world {position}'))
        parameters = world.get('parameters', {}) or {}
        if not isinstance(parameters, dict):
            raise BenchError(f'{path}: {name}: parameters is {_given(parameters)}; it must be '
                             'a mapping')
        parameters = _plain(parameters)
        seeds = [None]
        if 'seeds' in world:
            try:
                seeds = parse_seeds(world['seeds'] if isinstance(world['seeds'], str)
                                    else _given(world['seeds']))
            except ValueError as error:
                raise BenchError(f'{path}: {name}: seeds: {error}') from None
        for seed in seeds:
            values = dict(parameters) if seed is None else {**parameters, 'random.seed': seed}
            label = name if seed is None else f'{name} seed {seed}'
            scenes.append(_scene(label, values, agent, command, duration))
            if len(scenes) > MAX_SCENES:
                raise BenchError(f'{path}: more than {MAX_SCENES:,} scenes')
    return scenes


def _shown_kind(document):
    if isinstance(document, dict):
        return (f"`worlds: {_given(document['worlds'])}`" if 'worlds' in document
                else 'no `worlds`')
    return f'a {type(document).__name__}' if document is not None else 'an empty document'


def _number(value, path, key):
    if isinstance(value, float) and math.isnan(value):
        raise BenchError(f'{path}: {key} is {_given(value)}; it must be a number, not nan')
    if isinstance(value, float) and math.isinf(value):
        raise BenchError(f'{path}: {key} is {_given(value)}, beyond the largest float '
                         '(1.8e308); it must be finite')
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BenchError(f'{path}: {key} is {_given(value)}; it must be a number')
    return float(value)


# The tracker ---------------------------------------------------------------------------------

def load_tracker_class(spec):
    """The class `spec` names: 'module:Class' or 'path/to/file.py:Class' (UserCodeError).
    Runs the user's module: call it in a worker (user_code.workers), never in the tool."""
    if spec is None:
        from ball_world.tools.tracker import ScanTracker
        return ScanTracker
    from ball_world.user_code.loading import load_class
    return load_class(spec, '--tracker')


def _new_tracker(tracker_class, spec):
    from ball_world.user_code.calls import call
    tracker = call(f'--tracker {spec}: making one', tracker_class)
    if not callable(getattr(tracker, 'update', None)):
        raise BenchError(f'--tracker {spec}: it has no update(scan, pose) method')
    return tracker


def check_tracker(spec):
    """Load and make one tracker (a job: in a worker), so that a bad one is one line once,
    before any scene."""
    _end([_new_tracker(load_tracker_class(spec), spec or EXAMPLE)], spec, 'a check')
    return True


def _end(held, spec, where):
    """Let go of the tracker in `held` (a list) under the deadline: its __del__ is user code
    too, and a __del__ that hangs would hold its worker past every deadline."""
    from ball_world.user_code.calls import call
    call(f'{spec or EXAMPLE} on {where}: its end', held.clear)


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
    """Score one scene: (label, SequenceScore without its frames). Runs in a worker; a
    tracker that fails or returns what cannot be scored raises one line (UserCodeError,
    FramesError, DuplicateTrack: ValueErrors)."""
    position, scene, spec, gate = job
    from ball_world.scoring import figures
    from ball_world.scoring.frames import DuplicateTrack
    from ball_world.tools.score_frames import frames_with_tracker
    tracker = _new_tracker(load_tracker_class(spec), spec or EXAMPLE)
    scans = simulated_scans(scene)
    frames = frames_with_tracker(scans, tracker, spec or EXAMPLE, _scene_map(scene),
                                 scene.label)
    held = [tracker]
    del tracker
    _end(held, spec, scene.label)
    try:
        score = figures.score_tracks(frames, gate)
    except DuplicateTrack as error:
        raise DuplicateTrack(f'{spec or EXAMPLE} on {scene.label}: {error}') from None
    score.sequence = score.matches = None  # not sent back: large, and not needed
    return scene.label, score


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
    jobs = min(args.jobs or available_cores(), len(scenes))
    began = time.perf_counter()
    work = [(position, scene, args.tracker, args.gate) for position, scene in
            enumerate(scenes)]
    results = [None] * len(scenes)
    with executor(args, jobs, len(scenes)) as pool:
        jobs = pool.jobs
        if args.tracker is not None:  # a bad tracker: one line, once, not one per worker
            for _ in pool.map_unordered(check_tracker, [args.tracker],
                                        [f'--tracker {args.tracker}']):
                pass
        for position, result in pool.map_unordered(run_scene, work,
                                                   [scene.label for scene in scenes]):
            results[position] = result
    seconds = time.perf_counter() - began
    return summarize(results, what, args.tracker or EXAMPLE, args.gate, jobs, seconds,
                     args.worst)


def executor(args, jobs, count=None):
    """Where the jobs run (user_code's executor seam): the local pool of `jobs` supervised
    workers, or with --ray tasks on a Ray cluster (--jobs of them at once, or as many as it
    has CPUs, at most `count`). Every user call has --timeout s."""
    text = f'the --timeout of {args.timeout:g} s'
    if getattr(args, 'ray', None) is not None:
        from ball_world.user_code.ray_pool import RayPool
        return RayPool(args.ray.strip(), args.jobs, count, args.timeout, text)
    from ball_world.user_code.workers import LocalPool
    return LocalPool(jobs, args.timeout, text)


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
