"""ball_world_score_scenes: record scenes with a tracker that runs as a ROS node, to score
them as the benchmark scores simulated ones (`ball_world_score --scenes DIR`).

For each seed it starts the world (`ball_world`, the default world with random.seed set,
one scanning agent, paused at step 0, recording DIR/seed_<k>/world.mcap, stopping after
--duration simulated seconds) and your tracker (the command after `--`), waits until the
tracker subscribes to the agent's scan and publishes its tracks topic, gives the agent
the benchmark's command (a circle, held), un-pauses the world, and records the tracks topic
(MarkerArray or PoseArray) to DIR/seed_<k>/tracks.mcap until the world stops; then it
stops the tracker (SIGINT) and goes on with the next seed. DIR/scenes.yaml says which
agent and topic, for the scoring:

    ball_world_score_scenes --seeds 0:20 --out scenes --tracks-topic /ball_0/tracks -- \\
        ros2 run my_pkg my_tracker --ros-args -p agent:=ball_0
    ball_world_score --scenes scenes

The world runs at its rate (60 Hz: real time; --rate to run it faster if your tracker keeps
up: a tracker that falls behind drops scans, and the score shows it). Runs in your
ROS_DOMAIN_ID: give each concurrent run its own.
"""
import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import time

PROG = 'ball_world_score_scenes'
SCENES_FILE = 'scenes.yaml'
#: Seconds to wait for the world and the tracker to meet on the graph.
DISCOVERY_SECONDS = 60.0


class ScenesError(Exception):
    """A scene that could not be recorded; the message says why."""


def parse_args(argv):
    from ball_world.tools.score_bench import (DEFAULT_COMMAND, given_float, MAX_DURATION,
                                              parse_seeds)
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n\n')[0],
                                     usage=f'{PROG} --seeds A:B --out DIR --tracks-topic '
                                           'TOPIC [options] -- TRACKER COMMAND ...')
    parser.add_argument('--seeds', required=True, metavar='A:B',
                        help='record scenes of random.seed A .. B-1 (or 0 .. N-1 for N)')
    parser.add_argument('--out', required=True, metavar='DIR',
                        help='directory for the scenes (made; must not hold them already)')
    parser.add_argument('--tracks-topic', required=True, metavar='TOPIC',
                        help="the tracker's output (MarkerArray or PoseArray)")
    parser.add_argument('--agent', default='ball_0', help='the scanning agent (default ball_0)')
    parser.add_argument('--duration', type=given_float, default=given_float('30'), metavar='S',
                        help='simulated seconds per scene (default 30)')
    parser.add_argument('--rate', type=given_float, default=given_float('60'), metavar='HZ',
                        help="the world's steps per second of wall time (default 60: real "
                             'time, dt 1/60 s either way)')
    parser.add_argument('--cmd-vel', type=float, nargs=3, default=list(DEFAULT_COMMAND),
                        metavar=('VX', 'VY', 'WZ'), help="the agent's command (default "
                        f"{' '.join(map(str, DEFAULT_COMMAND))}: a circle)")
    parser.add_argument('tracker', nargs=argparse.REMAINDER,
                        help='-- then the command that starts your tracker node')
    args = parser.parse_args(argv)
    command = args.tracker[1:] if args.tracker[:1] == ['--'] else args.tracker
    if not command:
        parser.error("give the tracker's command after --")
    args.tracker = command
    try:
        args.seed_range = parse_seeds(args.seeds)
    except ValueError as error:
        parser.error(f'--seeds: {error}')
    if not (math.isfinite(args.duration) and 0.0 < args.duration <= MAX_DURATION):
        parser.error(f'--duration is {args.duration.text}; it must be in '
                     f'(0, {MAX_DURATION:g}] s')
    if not (math.isfinite(args.rate) and 1.0 <= args.rate <= 10_000.0):
        parser.error(f'--rate is {args.rate.text}; it must be in [1, 10000] Hz')
    if not all(math.isfinite(v) for v in args.cmd_vel):
        parser.error(f"--cmd-vel is {' '.join(f'{v:g}' for v in args.cmd_vel)}; each must be "
                     'finite')
    args.duration, args.rate = float(args.duration), float(args.rate)
    if not args.tracks_topic.startswith('/'):
        args.tracks_topic = '/' + args.tracks_topic
    if shutil.which(args.tracker[0]) is None and not os.path.isfile(args.tracker[0]):
        parser.error(f'{args.tracker[0]}: no such command')
    return args


class _Recorder:
    """An rclpy node that meets the world and the tracker on the graph, drives the agent
    and keeps the tracks topic's messages as their bytes."""

    def __init__(self, args):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from ball_world.ros.rcl_init import creating_node
        self.rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context)
        with creating_node(PROG):
            self.node = rclpy.create_node('ball_world_score_scenes', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.args = args
        self.messages = []
        self.type_name = None
        self.subscription = None

    def spin(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(0.0, end - time.monotonic())))

    def wait_for(self, what, ready, processes):
        end = time.monotonic() + DISCOVERY_SECONDS
        while not ready():
            for name, process in processes:
                if process.poll() is not None:
                    raise ScenesError(f'{name} exited ({process.returncode}) before {what}')
            if time.monotonic() > end:
                raise ScenesError(f'gave up after {DISCOVERY_SECONDS:g} s waiting for {what}')
            self.spin(0.1)

    def tracks_type(self):
        for name, types in self.node.get_topic_names_and_types():
            if name == self.args.tracks_topic and types:
                return types[0]
        return None

    def subscribe(self):
        import importlib
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        self.type_name = self.tracks_type()
        package, _, name = self.type_name.rpartition('/')
        try:
            message_type = getattr(importlib.import_module(package.replace('/', '.')), name)
        except (ImportError, AttributeError):
            raise ScenesError(f'{self.args.tracks_topic} is a {self.type_name}, which this '
                              'Python cannot import') from None
        self.messages = []
        self.subscription = self.node.create_subscription(
            message_type, self.args.tracks_topic,
            lambda data: self.messages.append((time.time_ns(), data)),
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True)

    def unsubscribe(self):
        if self.subscription is not None:
            self.node.destroy_subscription(self.subscription)
            self.subscription = None

    def drive_and_start(self):
        from geometry_msgs.msg import Twist
        from std_srvs.srv import SetBool
        agent = self.args.agent
        publisher = self.node.create_publisher(Twist, f'/{agent}/cmd_vel', 10)
        self.wait_for(f"the world's /{agent}/cmd_vel subscription",
                      lambda: publisher.get_subscription_count() > 0, [])
        twist = Twist()
        twist.linear.x, twist.linear.y, twist.angular.z = self.args.cmd_vel
        publisher.publish(twist)
        self.spin(0.2)
        client = self.node.create_client(SetBool, '/ball_world/pause')
        self.wait_for('the /ball_world/pause service', client.service_is_ready, [])
        future = client.call_async(SetBool.Request(data=False))
        end = time.monotonic() + DISCOVERY_SECONDS
        while not future.done() and time.monotonic() < end:
            self.spin(0.05)
        self.node.destroy_client(client)
        self.node.destroy_publisher(publisher)
        if not future.done():
            raise ScenesError('the world did not answer ~/pause')

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def _write_tracks(path, topic, type_name, messages):
    """The recorded messages as an MCAP (ROS 2 profile), claimed like any output file."""
    from mcap.writer import CompressionType, Writer
    from ball_world.msgs.definitions import message_definition
    from ball_world.recording.files import PartialOutput
    output = PartialOutput(path)
    try:
        with output.claim.writer() as stream:
            writer = Writer(stream, compression=CompressionType.ZSTD)
            writer.start(profile='ros2', library=PROG)
            schema = writer.register_schema(type_name, 'ros2msg',
                                            message_definition(type_name).encode())
            channel = writer.register_channel(topic, 'cdr', schema)
            for sequence, (stamp, data) in enumerate(messages):
                writer.add_message(channel, stamp, bytes(data), stamp, sequence)
            writer.finish()
        output.commit()
    except BaseException:
        output.discard()
        raise


def _stop(process, seconds=10.0):
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGINT)
        except ProcessLookupError:
            pass
        try:
            process.wait(seconds)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def record_scene(recorder, args, seed, directory):
    """Record one scene into `directory` (made here)."""
    from ball_world.recording.files import claim_output
    os.mkdir(directory)
    steps = max(1, round(args.duration * 60.0))
    world_path = os.path.join(directory, 'world.mcap')
    log = claim_output(os.path.join(directory, 'processes.log')).writer()
    world_command = [shutil.which('ball_world') or os.path.join(
        os.path.dirname(sys.executable), 'ball_world'), '--ros-args',
        '-p', f'random.seed:={seed}', '-p', f"agents:=['{args.agent}']",
        '-p', f'max_steps:={steps}', '-p', 'start_paused:=true',
        '-p', f'rate_hz:={args.rate}', '-p', 'agent.cmd_timeout:=0.0',
        '-p', 'markers.rate_hz:=0.0', '-p', f'record.mcap:={world_path}']
    if args.rate != 60.0:  # keep dt at 1/60 s of simulated time whatever the pace
        world_command += ['-p', f'dt:={1.0 / 60.0!r}']
    world = subprocess.Popen(world_command, stdout=log, stderr=subprocess.STDOUT,
                             start_new_session=True)
    tracker = subprocess.Popen(args.tracker, stdout=log, stderr=subprocess.STDOUT,
                               start_new_session=True)
    processes = [('the world', world), ('the tracker', tracker)]
    scan_topic = f'/{args.agent}/scan'
    try:
        recorder.wait_for(f'the tracker to subscribe to {scan_topic} and publish '
                          f'{args.tracks_topic}',
                          lambda: recorder.node.count_subscribers(scan_topic) > 0
                          and recorder.node.count_publishers(scan_topic) > 0
                          and recorder.tracks_type() is not None, processes)
        recorder.subscribe()
        recorder.wait_for(f'{args.tracks_topic} to connect',
                          lambda: recorder.subscription.get_publisher_count() > 0, processes)
        recorder.drive_and_start()
        end = time.monotonic() + 3.0 * steps / args.rate + DISCOVERY_SECONDS
        while world.poll() is None:
            if time.monotonic() > end:
                raise ScenesError('the world did not finish its steps in time')
            recorder.spin(0.1)
        recorder.spin(1.0)  # the tracks of the last scans
        if world.returncode != 0:
            raise ScenesError(f'the world exited with {world.returncode} (see '
                              f'{directory}/processes.log)')
        if tracker.poll() is not None:
            raise ScenesError(f'the tracker exited ({tracker.returncode}) during the scene')
        _write_tracks(os.path.join(directory, 'tracks.mcap'), args.tracks_topic,
                      recorder.type_name, recorder.messages)
        return len(recorder.messages)
    finally:
        recorder.unsubscribe()
        for _, process in processes:
            _stop(process)
        log.close()


def _write_description(args):
    """DIR/scenes.yaml: which agent and topic the scenes hold, for the scoring (replaced
    whole, never written through a symlink: recording.files.PartialOutput)."""
    import yaml
    from ball_world.recording.files import PartialOutput
    text = yaml.safe_dump({'agent': args.agent, 'tracks_topic': args.tracks_topic,
                           'duration': args.duration, 'cmd_vel': list(args.cmd_vel),
                           'tracker': ' '.join(args.tracker)})
    output = PartialOutput(os.path.join(args.out, SCENES_FILE), overwrite=True)
    try:
        with output.claim.writer() as stream:
            stream.write(text.encode('utf-8'))
        output.commit()
    except BaseException:
        output.discard()
        raise


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        os.makedirs(args.out, exist_ok=True)
        taken = [f'seed_{s}' for s in args.seed_range
                 if os.path.lexists(os.path.join(args.out, f'seed_{s}'))]
        if taken:
            raise ScenesError(f'{args.out} already holds {taken[0]}: give another --out')
        recorder = _Recorder(args)
    except (OSError, ScenesError) as error:
        print(f'{PROG}: {getattr(error, "strerror", None) or error}', file=sys.stderr)
        return 1
    try:
        _write_description(args)
        for seed in args.seed_range:
            count = record_scene(recorder, args, seed, os.path.join(args.out, f'seed_{seed}'))
            print(f'{PROG}: seed {seed}: {count} track messages', flush=True)
    except (OSError, ScenesError) as error:
        print(f'{PROG}: {getattr(error, "strerror", None) or error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted', file=sys.stderr)
        return 130
    finally:
        recorder.close()
    print(f'{PROG}: score them with: ball_world_score --scenes {args.out}')
    return 0


# Scoring a directory of recorded scenes ------------------------------------------------------

def scene_directories(path):
    """[(label, world.mcap, tracks.mcap)] of a scenes directory, in seed order."""
    found = []
    for name in os.listdir(path):
        directory = os.path.join(path, name)
        world = os.path.join(directory, 'world.mcap')
        if os.path.isdir(directory) and os.path.isfile(world):
            number = name.rpartition('_')[2]
            key = (0, int(number), name) if number.isdigit() else (1, 0, name)
            found.append((key, name, world, os.path.join(directory, 'tracks.mcap')))
    return [(name, world, tracks) for _, name, world, tracks in sorted(found)]


def _score_scene(job):
    position, label, world, tracks, agent, topic, gate, tolerance = job
    from ball_world.recording.mcap_reader import RecordingError
    from ball_world.tools.score_one import score_files, ScoreError
    from ball_world.tools.score_frames import FramesError
    from ball_world.tools.score_tracks import TracksError
    try:
        report, _, scores = score_files(world, agent, gate, (tracks, topic), tolerance)
    except (RecordingError, TracksError, FramesError, ScoreError, OSError,
            ValueError) as error:
        return position, label, None, None, f'{label}: {error}'
    from ball_world.scoring import figures
    combined = figures.combine(scores)
    combined.sequence = combined.matches = None
    return position, label, combined, (report['stamps'] or {}).get('note'), None


def score_directory(args):
    """The benchmark report of a directory ball_world_score_scenes made."""
    from ball_world.recording.files import open_regular
    from ball_world.tools.score_bench import available_cores, BenchError, load_yaml, summarize
    path = args.scenes
    description = os.path.join(path, SCENES_FILE)
    try:
        with open_regular(description) as stream:
            text = stream.read(1 << 16).decode('utf-8', 'replace')
        scenes = scene_directories(path)
    except OSError as error:
        raise BenchError(f'{path}: {error.strerror or error} (a directory {PROG} '
                         'made)') from None
    described = load_yaml(text, description, f'{SCENES_FILE} of a scenes directory')
    if not isinstance(described, dict) or not isinstance(described.get('tracks_topic'), str):
        topic = described.get('tracks_topic') if isinstance(described, dict) else None
        raise BenchError(f'{description}: tracks_topic is {topic!r}; it must be a topic name '
                         f'(a directory {PROG} made has one)')
    if not scenes:
        raise BenchError(f'{path} holds no scene (seed_<k>/world.mcap)')
    agent = str(described.get('agent', 'ball_0'))
    jobs = min(args.jobs or available_cores(), len(scenes))
    work = [(position, label, world, tracks, agent, described['tracks_topic'], args.gate,
             args.stamp_tolerance) for position, (label, world, tracks) in enumerate(scenes)]
    began = time.perf_counter()
    results = [None] * len(scenes)
    notes = []
    from ball_world.user_code.workers import LocalPool
    with LocalPool(jobs) as pool:
        for _, (position, label, score, note, error) in pool.map_unordered(
                _score_scene, work, [label for label, _, _ in scenes]):
            if error is not None:
                raise BenchError(error)
            results[position] = (label, score)
            if note:
                notes.append(f'{label}: {note}')
    report = summarize(results, f'scenes of {path}', str(described.get('tracker', '?')),
                       args.gate, jobs, time.perf_counter() - began, args.worst)
    report['stamp_notes'] = notes
    return report


if __name__ == '__main__':
    sys.exit(main())
