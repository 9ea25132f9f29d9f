"""ball_world_cli's connection to the graph, and the checks every argument passes first.

Why a module of its own: the world's commands (tools.cli), the topic commands (tools.
cli_topics) and the recorder (tools.cli_record) share one client and one set of argument
rules, and none of them may import the others.

Every argument is checked before anything is sent, so that bad input is one line on stderr
and a non-zero exit, never rclpy's traceback or a message the world then refuses:
- numbers are finite ('nan', 'inf' and '1e400', which Python reads as inf, are refused);
- integers fit the field of the message they go into (uint64 for a step count: 2**64 is
  refused here, not by rclpy's SystemError);
- names have no control characters and a bounded length;
- durations and rates are finite, positive and bounded, so no wait is endless.

Imports of ROS are made inside the functions that need them: `--help` and every usage error
answer without loading rclpy, and each command loads only its own message types.
"""
import argparse
import math
import os
import signal
import sys
import threading
import time

PROG = 'ball_world_cli'
#: The world node whose services are called, relative to the namespace.
WORLD_NODE = 'ball_world'
#: Seconds to wait for the world to be discovered and for each answer, unless --timeout.
DEFAULT_TIMEOUT = 10.0
#: Longest --timeout: an hour. A wait that long is a mistake, not a plan; a command that
#: runs longer (drive, echo, hz, record, a long step) runs as long as it makes progress.
MAX_TIMEOUT = 3600.0
#: Longest --for, s (about 11.6 days): any finite run a user means, never an endless one.
MAX_DURATION = 1e6
#: Highest --rate, Hz: faster than any controller sends cmd_vel; more only floods the world.
MAX_RATE = 1000.0
#: Most subscriptions `drive -w` waits for: more than any graph of one agent has.
MAX_MATCHING = 1000
#: Longest name (ball, agent, parameter) taken: the world's own limit (core.limits).
MAX_NAME = 256
#: Longest topic name taken (rcl's own limit is about 255 characters per name token).
MAX_TOPIC = 1024
#: Characters of a bad argument quoted in an error line.
QUOTED = 60
#: Characters of an error line at most (argparse quotes whatever was typed).
MAX_LINE = 400


class Failure(Exception):
    """The command could not be done; the message is the one line to print (exit 1)."""


class UsageError(Exception):
    """Arguments that parse but make no request; the message is the line to print (exit 2)."""


def shown(text, limit=QUOTED):
    """`text` fit for one line of an error: quoted, control characters escaped, cut short."""
    text = str(text)
    cut = text[:limit]
    return repr(cut) + (f'... ({len(text):,} characters)' if len(text) > limit else '')


def one_line(message):
    """Any message as one printable line of at most MAX_LINE characters."""
    text = ''.join(c if c.isprintable() else repr(c)[1:-1] for c in str(message))
    return text if len(text) <= MAX_LINE else text[:MAX_LINE] + '...'


# Argument types: each raises argparse.ArgumentTypeError with the line to print. --------------

def finite(text):
    """A finite float ('nan', 'inf', '1e400' refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {shown(text)}') from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a finite number, got {shown(text)}')
    return value


def _positive(text, limit, unit):
    value = finite(text)
    if not 0.0 < value <= limit:
        raise argparse.ArgumentTypeError(f'must be more than 0 and at most {limit:g} {unit}, '
                                         f'got {shown(text)}')
    return value


def timeout(text):
    return _positive(text, MAX_TIMEOUT, 's')


def duration(text):
    return _positive(text, MAX_DURATION, 's')


def rate(text):
    return _positive(text, MAX_RATE, 'Hz')


def integer(text):
    """An integer as typed (its range is checked against its message field later)."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an integer: {shown(text)}') from None


def count(text):
    """A count of subscriptions to wait for: 1 to MAX_MATCHING."""
    value = integer(text)
    if not 1 <= value <= MAX_MATCHING:
        raise argparse.ArgumentTypeError(f'{value} is not a count from 1 to {MAX_MATCHING}')
    return value


def name(text):
    """A ball, agent or parameter name: printable, at most MAX_NAME characters."""
    if len(text) > MAX_NAME:
        raise argparse.ArgumentTypeError(f'a name of {len(text):,} characters is longer than '
                                         f'the {MAX_NAME} the world takes')
    if not text.isprintable():
        raise argparse.ArgumentTypeError(f'a name may not hold control characters: '
                                         f'{shown(text)}')
    return text


def topic(text):
    """A topic name as typed (relative to --ns unless it starts with '/')."""
    if len(text) > MAX_TOPIC:
        raise argparse.ArgumentTypeError(f'a topic name of {len(text):,} characters is longer '
                                         f'than the {MAX_TOPIC} taken')
    if not text.isprintable():
        raise argparse.ArgumentTypeError(f'a topic name may not hold control characters: '
                                         f'{shown(text)}')
    return text


_INTEGER_RANGES = {f'{sign}int{bits}': ((0, 2 ** bits - 1) if sign else
                                        (-2 ** (bits - 1), 2 ** (bits - 1) - 1))
                   for sign in ('u', '') for bits in (8, 16, 32, 64)}


def fits(message_type, field, value, what):
    """value, if the integer field `field` of `message_type` can hold it; else UsageError.

    The range is the field's own (get_fields_and_field_types), so a message is never built
    with a value rclpy would refuse with a SystemError.
    """
    kind = message_type.get_fields_and_field_types()[field]
    low, high = _INTEGER_RANGES[kind]
    if not low <= value <= high:
        raise UsageError(f'{what} must be between {low} and {high} (a {kind}), got '
                         f'{shown(value)}')
    return value


def check_ros_name(validate, value, option):
    """UsageError unless rclpy's validator takes value (a namespace, node or topic name)."""
    from rclpy.exceptions import InvalidTopicNameException, NameValidationException
    try:
        validate(value)
    except (NameValidationException, InvalidTopicNameException) as error:
        reason = str(error).splitlines()[0].rstrip(':')
        raise UsageError(f'{option} {shown(value)}: {one_line(reason)}') from None


# Signals ------------------------------------------------------------------------------------

#: Set by Ctrl-C or SIGTERM; Client.spin turns it into KeyboardInterrupt.
_INTERRUPTED = threading.Event()


def interrupt_on_signals():
    """Ctrl-C and SIGTERM (a service manager, `timeout`) end a command in the same orderly
    way: drive's last zero command, record's complete file, simulate's cancelled goal.

    The handler only notes the signal, and the next spin raises KeyboardInterrupt where each
    command expects it. Raised from the handler itself, it landed wherever the main thread
    was, inside rclpy's executor too, which could lose it: `echo` of a busy topic went on
    printing after Ctrl-C. A spin lasts at most 0.1 s, so a signal ends a command at once.
    """
    def note(signum, frame):
        _INTERRUPTED.set()

    signal.signal(signal.SIGINT, note)
    signal.signal(signal.SIGTERM, note)


def _raise_if_interrupted():
    if _INTERRUPTED.is_set():
        _INTERRUPTED.clear()  # one KeyboardInterrupt per signal: a cancel may spin after it
        raise KeyboardInterrupt


# The client ---------------------------------------------------------------------------------

class Client:
    """One node in its own context; every wait is bounded by `timeout`."""

    def __init__(self, args, argv):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from ball_world.ros.rcl_init import creating_node
        self.timeout = args.timeout
        self.context = rclpy.Context()
        # rcl reads only the --ros-args parts of the command line. No signal handlers of
        # rclpy's: Ctrl-C is the CLI's own (interrupt_on_signals), which each command turns
        # into its own orderly end (drive's last zero command, record's complete file).
        rclpy.init(args=[PROG, *argv], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        options = {} if args.ns is None else {'namespace': args.ns}
        # A unique name: two commands run at once are two nodes of the graph.
        with creating_node(PROG):
            self.node = rclpy.create_node(f'{PROG}_{os.getpid()}', context=self.context,
                                          start_parameter_services=False, **options)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.world = args.node

    def close(self):
        import rclpy
        self.executor.shutdown(timeout_sec=0.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def spin(self, seconds):
        _raise_if_interrupted()
        self.executor.spin_once(timeout_sec=seconds)
        _raise_if_interrupted()

    def wait(self, predicate, what, timeout=None, progress=None):
        """Spin until predicate() holds; Failure(what) after `timeout` s (default --timeout)
        without it (`what` may be a function, called then: a message of the state at the
        end). progress(): a value that changes while the world works on the request (steps
        done): each change gives the wait `timeout` s more."""
        limit = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + limit
        last = progress() if progress is not None else None
        while not predicate():
            if progress is not None:
                now = progress()
                if now != last:
                    last, deadline = now, time.monotonic() + limit
            if time.monotonic() > deadline:
                raise Failure(what() if callable(what) else what)
            self.spin(0.05)

    def no_world(self, name):
        namespace = self.node.get_namespace()
        return (f'no world answers {name} within {self.timeout:g} s: is ball_world running '
                f"in namespace {namespace} (--ns), named '{self.world}' (--node)?")

    def service_name(self, service):
        return self.node.resolve_service_name(f'{self.world}/{service}')

    def call(self, srv_type, service, request, progress=None, gone=None):
        """The response of the world's service `service` (relative to the world node).

        progress: see wait(). gone(): whether the world has gone (an answer it could not
        send before it left): the call then returns None instead of failing.
        """
        return self.call_many([(srv_type, service, request)], progress, gone)[0]

    def call_many(self, calls, progress=None, gone=None):
        """Responses of several (type, service, request), sent together once all are ready:
        one wait for discovery and one for the answers, not one each."""
        clients = [self.node.create_client(srv_type, f'{self.world}/{service}')
                   for srv_type, service, _ in calls]
        try:
            for client in clients:
                name = self.node.resolve_service_name(client.srv_name)
                self.wait(client.service_is_ready, self.no_world(name))
            futures = [client.call_async(request)
                       for client, (_, _, request) in zip(clients, calls)]
            names = ', '.join(self.service_name(service) for _, service, _ in calls)
            answered = lambda: all(future.done() for future in futures)  # noqa: E731
            if gone is None:
                self.wait(answered, f'{names} did not answer within {self.timeout:g} s',
                          progress=progress)
            else:
                self.wait(lambda: answered() or gone(), f'{names} did not answer within '
                          f'{self.timeout:g} s, and the world is still on the graph',
                          progress=progress)
            return [future.result() if future.done() else None for future in futures]
        finally:
            for client in clients:
                self.node.destroy_client(client)

    def names(self):
        """The world's balls in pose order, from its latched `entity_names`."""
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String
        heard = []
        subscription = self.node.create_subscription(
            String, 'entity_names', lambda msg: heard.append(msg.data),
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        try:
            self.wait(lambda: heard, self.no_world(subscription.topic_name))
        finally:
            self.node.destroy_subscription(subscription)
        return heard[-1].split('\n') if heard[-1] else []

    def world_present(self):
        """Whether the world node is on the graph (by name, in its namespace)."""
        namespace = self.node.get_namespace()
        return (self.world, namespace) in self.node.get_node_names_and_namespaces()

    def resolve(self, topic_name):
        """The topic's absolute name (relative to --ns), or UsageError naming the problem."""
        from rclpy.validate_topic_name import validate_topic_name
        check_ros_name(validate_topic_name, topic_name, 'topic')
        return self.node.resolve_topic_name(topic_name)

    def topic_type(self, topic_name):
        """(absolute name, type name) of a topic once the graph has it; Failure after the
        deadline, naming a few topics that are there."""
        resolved = self.resolve(topic_name)
        found = {}

        def present():
            found.update(self.node.get_topic_names_and_types())
            return resolved in found

        try:
            self.wait(present, '')
        except Failure:
            others = sorted(found)
            listed = ', '.join(others[:8]) + (', ...' if len(others) > 8 else '')
            raise Failure(f'no topic {resolved} on the graph within {self.timeout:g} s '
                          f"(it has {len(others)}{': ' + listed if others else ''})") from None
        types = found[resolved]
        if len(types) != 1:
            raise Failure(f'{resolved} has {len(types)} types on the graph ({", ".join(types)});'
                          ' a subscriber can take only one')
        return resolved, types[0]


def message_class(type_name):
    """The Python class of a message type named 'pkg/msg/Type', imported by its name.

    Failure when the name is malformed or the package is not installed in this environment.
    """
    import importlib
    parts = type_name.split('/')
    if len(parts) != 3 or parts[1] != 'msg' or not all(p.isidentifier() for p in parts):
        raise Failure(f'{shown(type_name)} is not a message type name (pkg/msg/Type)')
    package, _, kind = parts
    try:
        module = importlib.import_module(f'{package}.msg')
        cls = getattr(module, kind)
    except (ImportError, AttributeError):
        raise Failure(f'the type {type_name} is not installed in this environment '
                      f'({sys.prefix}); install its package to read it') from None
    return cls


def offered_qos(node, resolved, reliable_only=False):
    """A subscription QoS that matches every publisher of the topic, as ros2 topic echo and
    ros2 bag record choose it: reliable if all offer reliable, transient local if all offer
    it (a latched message is then heard), else best effort / volatile; and the publishers'
    (depth, reliability, durability) as rosbag2 records them."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    infos = node.get_publishers_info_by_topic(resolved)
    profiles = [info.qos_profile for info in infos]
    reliable = bool(profiles) and all(
        p.reliability == ReliabilityPolicy.RELIABLE for p in profiles)
    latched = bool(profiles) and all(
        p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
    qos = QoSProfile(depth=1000 if reliable_only else 100,
                     reliability=ReliabilityPolicy.RELIABLE if reliable
                     else ReliabilityPolicy.BEST_EFFORT,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                     else DurabilityPolicy.VOLATILE)
    recorded = [(p.depth, 'reliable' if p.reliability == ReliabilityPolicy.RELIABLE
                 else 'best_effort',
                 'transient_local' if p.durability == DurabilityPolicy.TRANSIENT_LOCAL
                 else 'volatile') for p in profiles]
    hashes = [str(getattr(info, 'topic_type_hash', '') or '') for info in infos]
    return qos, recorded, next((h for h in hashes if h.startswith('RIHS01_')), '')
