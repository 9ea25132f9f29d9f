"""ball_world_cli's topic commands: drive (ros2 topic pub -r), echo (ros2 topic echo) and hz
(ros2 topic hz), for any topic and any message type the graph shows.

The type of a topic is read from the graph and its Python class imported by name
(tools.cli_client.message_class), so these commands work on any topic a world or another
node publishes, as the ros2 commands do, not only on ball_world's own. A subscription takes
the QoS the publishers offer (reliable when all are, transient local when all are: a latched
message such as entity_names or map is heard), as `ros2 topic echo` chooses it.

Each runs until Ctrl-C (or SIGTERM) or its --for, and exits 0 then: that is how these
commands end. A topic that is not on the graph within --timeout is one line and exit 1.
"""
import collections
import math
import signal
import time

from ball_world.tools import print_report
from ball_world.tools.cli_client import Failure, message_class, offered_qos, shown

#: Items of an array, or characters of a string, that echo prints (ros2 topic echo's default
#: --truncate-length); --full-length prints all.
TRUNCATE = 128
#: Seconds between two lines of hz (ros2 topic hz prints once a second).
HZ_PERIOD = 1.0
#: The types an agent's cmd_vel takes (agent.cmd_vel_stamped chooses).
TWIST = 'geometry_msgs/msg/Twist'
TWIST_STAMPED = 'geometry_msgs/msg/TwistStamped'
#: Seconds drive waits, after the agent matched, for the other subscribers of its cmd_vel.
MATCH_OTHERS_SECONDS = 2.0


def _run_until(client, seconds, done=lambda: False):
    """Spin until `seconds` have passed (None: no end), done() holds, or Ctrl-C; returns
    whether Ctrl-C (or SIGTERM) ended it."""
    end = None if seconds is None else time.monotonic() + seconds
    try:
        while not done():
            now = time.monotonic()
            if end is not None and now >= end:
                break
            client.spin(0.1 if end is None else min(0.1, end - now))
    except KeyboardInterrupt:
        return True
    return False


# echo -------------------------------------------------------------------------------------

def plain(value, truncate=TRUNCATE):
    """A message as plain data (dicts in field order, lists, numbers, strings), as ros2
    topic echo shows it: arrays and strings longer than `truncate` cut, '...' after them."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {field: plain(getattr(value, field), truncate)
                for field in value.get_fields_and_field_types()}
    if hasattr(value, 'tolist'):  # numpy arrays and scalars
        value = value.tolist()
    if isinstance(value, (bytes, bytearray)):
        value = list(value)
    if isinstance(value, (list, tuple)) or type(value).__name__ == 'array':
        kept = value if truncate is None else value[:truncate]
        items = [plain(item, truncate) for item in kept]
        return items + (['...'] if truncate is not None and len(value) > truncate else [])
    if isinstance(value, str) and truncate is not None and len(value) > truncate:
        return value[:truncate] + '...'
    return value


def message_text(message, truncate=TRUNCATE):
    """A message in the YAML that ros2 topic echo prints (block style, fields in order)."""
    import yaml
    return yaml.safe_dump(plain(message, truncate), sort_keys=False, default_flow_style=False,
                          width=math.inf, allow_unicode=True).rstrip('\n')


def echo(client, args):
    resolved, type_name = client.topic_type(args.topic)
    cls = message_class(type_name)
    qos, _, _ = offered_qos(client.node, resolved)
    truncate = None if args.full_length else TRUNCATE
    state = {'printed': 0, 'closed': False}

    def show(message):
        if state['closed'] or (args.once and state['printed']):
            return
        if not print_report(message_text(message, truncate) + '\n---'):
            state['closed'] = True  # the reader went away (| head): done
        state['printed'] += 1

    subscription = client.node.create_subscription(cls, resolved, show, qos)
    try:
        if args.once:
            try:
                client.wait(lambda: state['printed'], f'no message on {resolved} within '
                            f'{client.timeout:g} s ({_publishers(client, resolved)})')
            except KeyboardInterrupt:
                pass
            return 0
        _run_until(client, args.seconds, lambda: state['closed'])
        return 0
    finally:
        client.node.destroy_subscription(subscription)


def _publishers(client, resolved):
    count = client.node.count_publishers(resolved)
    if not count:
        return 'it has no publisher now'
    return (f'{count} publisher{"s" if count > 1 else ""}; a paused world publishes '
            'nothing: resume or step it')


# hz ---------------------------------------------------------------------------------------

class Rate:
    """Arrival times of a topic's messages and what ros2 topic hz says of them."""

    def __init__(self, window):
        self.times = collections.deque(maxlen=window + 1)
        self.new = 0

    def heard(self, now):
        self.times.append(now)
        self.new += 1

    def line(self):
        """The lines ros2 topic hz prints for the window, or 'no new messages'."""
        if not self.new or len(self.times) < 2:
            self.new = 0
            return 'no new messages'
        self.new = 0
        times = list(self.times)
        gaps = [later - earlier for earlier, later in zip(times, times[1:])]
        mean = sum(gaps) / len(gaps)
        deviation = math.sqrt(sum((gap - mean) ** 2 for gap in gaps) / len(gaps))
        rate = 1.0 / mean if mean > 0 else math.inf
        return (f'average rate: {rate:.3f}\n\tmin: {min(gaps):.3f}s max: {max(gaps):.3f}s '
                f'std dev: {deviation:.5f}s window: {len(gaps) + 1}')


def hz(client, args):
    resolved, type_name = client.topic_type(args.topic)
    cls = message_class(type_name)
    qos, _, _ = offered_qos(client.node, resolved)
    rate = Rate(args.window)
    # raw: the bytes are not decoded, so a large message costs nothing to count.
    subscription = client.node.create_subscription(
        cls, resolved, lambda data: rate.heard(time.monotonic()), qos, raw=True)
    end = None if args.seconds is None else time.monotonic() + args.seconds
    try:
        while end is None or time.monotonic() < end:
            due = time.monotonic() + HZ_PERIOD
            if end is not None:
                due = min(due, end)
            if _run_until(client, due - time.monotonic()):
                break
            if not print_report(rate.line()):
                break
        return 0
    finally:
        client.node.destroy_subscription(subscription)


# drive ------------------------------------------------------------------------------------

def _command(cls, node, args, zero=False):
    """The command message: body-frame vx, vy and yaw rate wz (all 0 for the stop)."""
    message = cls()
    twist = message.twist if hasattr(message, 'twist') else message
    if hasattr(message, 'header'):
        message.header.stamp = node.get_clock().now().to_msg()
    if not zero:
        twist.linear.x, twist.linear.y, twist.angular.z = args.vx, args.vy, args.wz
    return message


def _match_the_others(client, publisher, resolved):
    """Wait for the agent, then up to MATCH_OTHERS_SECONDS for the rest of the graph.

    The others (a recorder, a plot, RViz) match within moments, so they hear the first command
    as the agent does; the graph is read again meanwhile, as discovery may show more of them
    late. One of incompatible QoS never matches: it is not waited for longer.
    """
    client.wait(lambda: publisher.get_subscription_count() > 0,
                f'{resolved}: the agent did not match this publisher within '
                f'{client.timeout:g} s')
    node = client.node
    deadline = time.monotonic() + min(MATCH_OTHERS_SECONDS, client.timeout)
    while (publisher.get_subscription_count() < node.count_subscribers(resolved)
           and time.monotonic() < deadline):
        client.spin(0.05)


def drive(client, args):
    """cmd_vel to an agent at --rate until --for or Ctrl-C, then one zero command.

    The agent is whatever subscribes to NAME/cmd_vel: the graph names its type (Twist, or
    TwistStamped in a world with agent.cmd_vel_stamped), and that type is sent: DDS drops a
    publisher of the other type without a word. The world does not answer commands: what
    this reports is that each was delivered (reliable, acknowledged), not how the agent
    moved (echo NAME/odom shows that).
    """
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    resolved = client.resolve(f'{args.agent}/cmd_vel')
    node = client.node
    found = []

    def subscribed():
        found[:] = node.get_subscriptions_info_by_topic(resolved)
        return bool(found)

    client.wait(subscribed, f'no agent {shown(args.agent)}: nothing subscribes to {resolved} '
                            f'within {client.timeout:g} s (agents are the balls in the '
                            "world's `agents` parameter, or spawned with agent: true)")
    types = sorted({info.topic_type for info in found})
    if len(types) != 1 or types[0] not in (TWIST, TWIST_STAMPED):
        raise Failure(f'{resolved} takes {", ".join(types)}: drive sends {TWIST} or '
                      f'{TWIST_STAMPED}, one type to one agent')
    cls = message_class(types[0])
    publisher = node.create_publisher(
        cls, resolved, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    if args.matching is not None:
        client.wait(lambda: publisher.get_subscription_count() >= args.matching,
                    f'{resolved}: fewer than the {args.matching} subscriptions asked for '
                    f'(-w) matched within {client.timeout:g} s')
    else:
        _match_the_others(client, publisher, resolved)
    period = 1.0 / args.rate
    started = time.monotonic()
    # --for S ends the command S s after it started (as `timeout S` would), not S s after the
    # first command: joining the graph (Python and rclpy, a DDS participant, finding the
    # agent) took 2-4 s under load, and `--for 5` ran for 8.8 s.
    begun = getattr(args, 'started', started)
    end = None if args.seconds is None else begun + args.seconds
    sent = 0
    interrupted = False
    try:
        due = started
        first = True  # one command at least, however long joining took
        while first or end is None or time.monotonic() < end:
            first = False
            now = time.monotonic()
            if now >= due:
                publisher.publish(_command(cls, node, args))
                sent += 1
                due = max(due + period, now)
            wait = due - time.monotonic()
            if end is not None:
                wait = min(wait, end - time.monotonic())
            if wait > 0:
                client.spin(wait)
    except KeyboardInterrupt:
        interrupted = True
    # How long it drove: the zero command's acknowledgement below is not driving (it took up
    # to 1.4 s on a quiet machine, and the report said 'for 6.02 s until --for 5 s').
    elapsed = time.monotonic() - started
    # The last command stops the agent; a second Ctrl-C may not cut it off.
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        publisher.publish(_command(cls, node, args, zero=True))
        acked = publisher.wait_for_all_acked(Duration(seconds=client.timeout))
    finally:
        signal.signal(signal.SIGINT, previous)
    short = types[0].rsplit('/', 1)[1]
    ended = 'Ctrl-C' if interrupted else f'--for {args.seconds:g} s'
    if not acked:
        raise Failure(f'{resolved}: the zero command was not acknowledged within '
                      f'{client.timeout:g} s; the agent stops by itself after '
                      'agent.cmd_timeout without commands')
    print_report(f'drove {args.agent}: {sent} {short} commands (vx {args.vx:g} m/s, vy '
                 f'{args.vy:g} m/s, wz {args.wz:g} rad/s) at {args.rate:g} Hz on {resolved} '
                 f'for {elapsed:.2f} s until {ended}, then a zero command (delivered); '
                 f'joining the graph took {started - begun:.2f} s before')
    return 0
