"""ball_world_cli record: any topics into a rosbag2 bag directory of MCAP, as
`ros2 bag record -s mcap -o DIR TOPIC...` makes one (DIR/metadata.yaml, DIR/DIR_0.mcap).

The ROS side only: each topic's type and offered QoS are read from the graph, a raw
subscription per topic hands over the CDR bytes with their send and receive times, and
recording.topic_bag writes them with the node's own file rules (an existing DIR refused
unless --overwrite, a symlinked DIR refused, the directory locked while recorded). The
output is claimed before the graph is asked anything, so a refused path fails at once.

Every topic named must be on the graph within --timeout (else nothing is recorded and no
directory is left). The recording is flushed every second (a SIGKILL loses at most that;
ball_world_repair completes the file) and ends at Ctrl-C, SIGTERM or --for with a complete
file that ball_world_info, rosbags and mcap read.
"""
import time

from ball_world.tools import print_report
from ball_world.tools.cli_client import Failure, message_class, offered_qos, one_line

#: Seconds between two flushes of the recording: what a SIGKILL can lose at most.
FLUSH_PERIOD = 1.0


def record(client, args):
    from ball_world.recording.files import FileRefused
    from ball_world.recording.mcap_writer import McapRecordingError
    from ball_world.recording.topic_bag import TopicBag
    resolved = []
    for name in args.topics:  # every name checked before anything is made
        absolute = client.resolve(name)
        if absolute not in resolved:
            resolved.append(absolute)
    try:
        bag = TopicBag(args.output, args.overwrite, 'pass --overwrite')
    except (FileRefused, McapRecordingError) as error:
        raise Failure(f'record: {one_line(error)}') from None
    subscriptions = []
    try:
        try:
            subscriptions = _subscribe(client, bag, resolved)
        except (Failure, KeyboardInterrupt):
            bag.discard()
            raise
        until = 'Ctrl-C' if args.seconds is None else f'--for {args.seconds:g} s or Ctrl-C'
        print_report(f"recording {', '.join(resolved)} to {bag.file_path} until {until}")
        count = _record(client, bag, args.seconds)
    except McapRecordingError as error:
        raise Failure(f'record: {one_line(error)}') from None
    finally:
        for subscription in subscriptions:
            client.node.destroy_subscription(subscription)
        try:
            bag.close()
        except McapRecordingError as error:
            raise Failure(f'record: {one_line(error)}') from None
    print_report(f'recorded {count} messages of {len(resolved)} topics to {bag.path} '
                 f'({bag.file_path} and metadata.yaml)')
    return 0


def _subscribe(client, bag, resolved):
    """A raw subscription per topic, once each is on the graph with one type."""
    types = {}
    for topic in resolved:
        types[topic] = client.topic_type(topic)[1]
    subscriptions = []
    for topic in resolved:
        cls = message_class(types[topic])
        qos, profiles, topic_hash = offered_qos(client.node, topic)
        try:
            channel = bag.add_topic(topic, types[topic], profiles, topic_hash)
        except LookupError as error:
            raise Failure(f'record: cannot record {topic}: {one_line(error)}') from None

        def heard(data, info, channel=channel):
            received = info.get('received_timestamp') or time.time_ns()
            bag.write(channel, received, info.get('source_timestamp') or received, data)

        subscriptions.append(client.node.create_subscription(cls, topic, heard, qos, raw=True))
    return subscriptions


def _record(client, bag, seconds):
    """Spin, flushing every FLUSH_PERIOD, until --for or Ctrl-C; the messages recorded."""
    end = None if seconds is None else time.monotonic() + seconds
    flushed = time.monotonic()
    try:
        while end is None or time.monotonic() < end:
            client.spin(0.05)
            if time.monotonic() - flushed >= FLUSH_PERIOD:
                bag.flush()
                flushed = time.monotonic()
    except KeyboardInterrupt:
        pass
    return bag.message_count
