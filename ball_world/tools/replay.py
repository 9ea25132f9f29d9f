"""ball_world_replay: publish a recording again, with its timing and QoS, like `ros2 bag play`.

Why not `ros2 bag play`: it is not in the ROS wheels, and a recording is enough to rebuild
the run. The recorded CDR bytes are published as they are (no decode, no re-encode), at the
recorded log-time spacing divided by --rate, on the recorded topics with the reliability,
durability and depth their publishers offered. --clock publishes /clock with the recorded
log time before each step, so nodes with use_sim_time follow the replay. Topics recorded
as transient local (the map, /tf_static, markers) are published so again; with
--start-offset, their last message before the offset is published first, so the map is
there from the start.

One thread: between messages the executor waits (spin_once with the time left as timeout),
so services such as the parameter ones answer and Ctrl-C / SIGTERM end the replay at once,
with exit status 0, as does the end of the recording unless --loop.

The recording is untrusted: it is read with the reader's checks (bounded chunks, checked
metadata, QoS text without YAML aliases), and a file found corrupt while playing stops the
replay with one line and exit status 2. A recording that holds /clock (the node's, when
publish_clock was on) plays it like any topic, unless --clock publishes the log time
instead: then the recorded /clock is left out, so there is one clock.
"""
import argparse
import importlib
from pathlib import Path
import sys
import time

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from ball_world.msgs.cdr import encode_clock
from ball_world.msgs.definitions import message_definition
from ball_world.recording.mcap_reader import load_untrusted, MAX_SMALL_TEXT, RecordingError
from ball_world.recording.mcap_writer import CLOCK_TOPIC
from ball_world.recording.recording_set import open_recording
from ball_world.ros.rcl_init import creating_node
from ball_world.ros.stopping import stopped_by_signal

DEFAULT_DEPTH = 10
#: Recordings larger than this (bytes) take a while to index: the replay says it is reading.
LARGE_FILE = 64 << 20
CLOCK_TYPE = 'rosgraph_msgs/msg/Clock'
#: Seconds to wait at the end for reliable subscribers to acknowledge the last messages.
ACK_TIMEOUT = 2.0
#: Seconds between checks while waiting for subscribers.
MATCH_POLL = 0.05
#: Recorded policy (rosbag2 >= Jazzy writes names, older bags the rmw enum values) -> rclpy.
_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE, 1: ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT,
                2: ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
               1: DurabilityPolicy.TRANSIENT_LOCAL, 'volatile': DurabilityPolicy.VOLATILE,
               2: DurabilityPolicy.VOLATILE}


def message_class(type_name):
    """'geometry_msgs/msg/PoseArray' -> the generated Python class (ImportError if absent).

    The name comes from the recording: only a message whose .msg definition is installed
    is imported, so a crafted type name can never import an arbitrary Python module.
    """
    try:
        message_definition(type_name)
        package, namespace, name = type_name.split('/')
    except (LookupError, ValueError):
        raise ImportError(f'{type_name!r} is not an installed ROS message type') from None
    if namespace != 'msg':
        raise ImportError(f'{type_name!r} is not a message type')
    module = importlib.import_module(f'{package}.{namespace}')
    try:
        return getattr(module, name)
    except AttributeError:
        raise ImportError(f'{module.__name__} has no message {name}') from None


def qos_profile(offered_qos_profiles):
    """The QoS to publish a topic with: what its recorded publisher offered.

    As ros2 bag play does: reliability and durability are the recorded ones, history is
    keep_last with the recorded depth (10 when unknown). Accepts rosbag2's YAML with policy
    names (metadata version 9, Jazzy) or the rmw enum numbers of older bags.
    """
    profile = QoSProfile(depth=DEFAULT_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
    try:
        offered = load_untrusted(offered_qos_profiles, 'offered_qos_profiles',
                                 MAX_SMALL_TEXT, json_text=False) or []
        first = dict(offered[0])
    except (RecordingError, IndexError, KeyError, TypeError, ValueError):
        return profile
    reliability = _RELIABILITY.get(first.get('reliability'))
    if reliability is not None:
        profile.reliability = reliability
    durability = _DURABILITY.get(first.get('durability'))
    if durability is not None:
        profile.durability = durability
    depth = first.get('depth')
    if first.get('history') in ('keep_last', 1) and isinstance(depth, int) and depth > 0:
        profile.depth = depth
    return profile


class Player:
    """Publishes a Recording's messages on an rclpy node with the recorded timing."""

    def __init__(self, node, executor, recording, topics, rate=1.0, start_offset=0.0,
                 clock=False, prefix=''):
        self.node = node
        self.executor = executor
        self.recording = recording
        self.topics = list(topics)
        self.rate = rate
        self.begin_ns = (recording.start_ns or 0) + round(start_offset * 1e9)
        self.publishers = {}
        self.latched = set()  # topics recorded as transient local (the map, /tf_static)
        for topic in self.topics:
            info = recording.topics[topic]
            profile = qos_profile(info.offered_qos_profiles)
            self.publishers[topic] = node.create_publisher(
                message_class(info.type), prefix + topic, profile)
            if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL:
                self.latched.add(topic)
        self.clock = None
        if clock:
            self.clock = node.create_publisher(message_class(CLOCK_TYPE), '/clock',
                                               QoSProfile(depth=1))

    def sleep_until(self, deadline):
        """Wait for a monotonic time, serving the node's callbacks meanwhile."""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            if not self.node.context.ok():
                raise ExternalShutdownException()
            self.executor.spin_once(timeout_sec=left)

    def wait_for_subscribers(self):
        """Block until every topic's publisher has a matched subscription."""
        while any(publisher.get_subscription_count() == 0
                  for publisher in self.publishers.values()):
            self.sleep_until(time.monotonic() + MATCH_POLL)

    def play_once(self):
        """Publish every selected message once; returns how many were published."""
        start = None
        last_clock = None
        published = 0
        held = {}  # latched topics' last message before --start-offset: played first
        for message in self.recording.messages(self.topics):
            if message.log_time_ns < self.begin_ns:
                if message.topic in self.latched:
                    held[message.topic] = message
                continue
            if start is None:
                start = time.monotonic()
                for earlier in held.values():  # /map, /tf_static: what a late joiner needs
                    self.publishers[earlier.topic].publish(earlier.data)
                    published += 1
            self.sleep_until(start + (message.log_time_ns - self.begin_ns) / 1e9 / self.rate)
            if self.clock is not None and message.log_time_ns != last_clock:
                self.clock.publish(encode_clock(message.log_time_ns))
                last_clock = message.log_time_ns
            self.publishers[message.topic].publish(message.data)
            published += 1
        return published

    def wait_for_acks(self):
        deadline = time.monotonic() + ACK_TIMEOUT
        for publisher in [*self.publishers.values(), self.clock]:
            if publisher is not None:
                left = max(0.0, deadline - time.monotonic())
                publisher.wait_for_all_acked(Duration(nanoseconds=round(left * 1e9)))


def argument_parser():
    parser = argparse.ArgumentParser(
        prog='ball_world_replay',
        description='Publish a ball_world MCAP recording with its recorded timing and QoS, '
                    'like ros2 bag play. ROS arguments go after --ros-args.')
    parser.add_argument('file', help='the .mcap recording, or a bag directory of split files')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='playback speed factor (default 1: recorded timing)')
    parser.add_argument('--loop', action='store_true', help='start over at the end')
    parser.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                        help='skip the first S seconds of the recording')
    parser.add_argument('--topics', nargs='+', metavar='T',
                        help='only these recorded topics (default: all)')
    parser.add_argument('--clock', action='store_true',
                        help='publish /clock with the recorded log time')
    parser.add_argument('--remap-prefix', default='', metavar='NS',
                        help="publish every topic under this prefix ('/replay': /replay/balls)")
    parser.add_argument('--wait-for-subscribers', action='store_true',
                        help='start only once every topic has a subscriber')
    parser.add_argument('--delay', type=float, default=0.0, metavar='S',
                        help='wait S seconds before playing (after --wait-for-subscribers)')
    return parser


def _check(args, recording):
    """Argument errors that need the recording; returns an error line or None."""
    if not args.rate > 0:
        return f'--rate must be > 0, got {args.rate}'
    if args.start_offset < 0 or args.delay < 0:
        return '--start-offset and --delay must be >= 0'
    if args.remap_prefix and not args.remap_prefix.startswith('/'):
        return f"--remap-prefix must start with '/', got {args.remap_prefix!r}"
    unknown = [t for t in args.topics or () if t not in recording.topics]
    if unknown:
        return (f"no such topic in the recording: {', '.join(unknown)} (it has "
                f"{', '.join(recording.topics)})")
    if args.clock and CLOCK_TOPIC in (args.topics or ()):
        return f'--clock publishes {CLOCK_TOPIC} itself: leave it out of --topics'
    for topic in played_topics(args, recording):
        try:
            message_class(recording.topics[topic].type)
        except (ImportError, ValueError) as error:
            return f'cannot publish {topic} ({recording.topics[topic].type}): {error}'
    return None


def played_topics(args, recording):
    """The recorded topics to play: --topics, or all but a recorded /clock under --clock."""
    if args.topics:
        return list(args.topics)
    return [topic for topic in recording.topics if not (args.clock and topic == CLOCK_TOPIC)]


def _size(path):
    """Bytes of a recording (a file, or a bag directory's files); 0 when unknown."""
    try:
        path = Path(path)
        files = [path] if path.is_file() else list(path.iterdir()) if path.is_dir() else []
        return sum(f.stat().st_size for f in files if f.is_file())
    except OSError:
        return 0


def say(text):
    """A line on stderr, at once: what the replay is doing (stdout stays free)."""
    print(f'ball_world_replay: {text}', file=sys.stderr, flush=True)


def plan_line(args, recording, topics):
    """What is about to be played: messages, topics, recorded and wall-clock length."""
    count = sum(recording.topics[topic].message_count for topic in topics)
    start = (recording.start_ns or 0) + round(args.start_offset * 1e9)
    length = max(0.0, ((recording.end_ns or 0) - start) * 1e-9)
    pace = f', {length / args.rate:.1f} s at --rate {args.rate:g}' if args.rate != 1.0 else ''
    return (f'playing {count:,} messages on {len(topics)} topics ({", ".join(topics)}): '
            f'{length:.1f} s of recording{pace}; Ctrl-C stops')


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    args = argument_parser().parse_args(remove_ros_args(['ball_world_replay', *argv])[1:])
    if _size(args.file) > LARGE_FILE:
        say(f'reading {args.file} ({_size(args.file) / 2**20:,.0f} MiB)')
    try:
        recording = open_recording(args.file)
    except RecordingError as error:
        print(f'ball_world_replay: {args.file}: {error}', file=sys.stderr)
        return 2
    problem = _check(args, recording)
    if problem:
        print(f'ball_world_replay: {problem}', file=sys.stderr)
        return 2
    topics = played_topics(args, recording)
    say(plan_line(args, recording, topics))
    rclpy.init(args=['ball_world_replay', *argv])
    node = executor = None
    finished = False
    try:
        with stopped_by_signal():
            with creating_node('ball_world_replay'):
                node = rclpy.create_node('ball_world_replay')
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            player = Player(node, executor, recording, topics,
                            rate=args.rate, start_offset=args.start_offset, clock=args.clock,
                            prefix=args.remap_prefix.rstrip('/'))
            if args.wait_for_subscribers:
                say('waiting for a subscriber on every topic (--wait-for-subscribers)')
                player.wait_for_subscribers()
            if args.delay:
                say(f'starting in {args.delay:g} s (--delay)')
            player.sleep_until(time.monotonic() + args.delay)
            started = time.monotonic()
            played = 0
            while True:
                count = player.play_once()
                played += count
                if not args.loop or count == 0:
                    break
            player.wait_for_acks()
            finished = True
            say(f'played {played:,} messages in {time.monotonic() - started:.1f} s')
    except RecordingError as error:
        print(f'ball_world_replay: {args.file}: {error}', file=sys.stderr)
        return 2
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if not finished:
        print('ball_world_replay: stopped', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
