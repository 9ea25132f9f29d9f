"""Record a run to MCAP the way `ros2 bag record` (rosbag2 Jazzy, mcap storage) would.

Why by hand and not through rosbag2: the node already holds every message as CDR bytes, and
rosbag2's Python API is not in the ROS wheels. Writing the same records rosbag2 writes
('ros2' profile, complete 'ros2msg' schemas, 'cdr' channels with offered_qos_profiles and
topic_type_hash) lets `ros2 bag info/play`, Foxglove, mcap_ros2 and rosbags open the file.

Besides the messages, every segment (start, and each reset) gets a metadata record named
'ball_world' with the effective parameters, so a recording is enough to re-simulate its run.
World edits (spawn, delete, set_state) are recorded on `edits` as the node publishes them
(std_msgs/String, one JSON object each: step_record.AppliedEdit.text), at the log time of
the step they were applied before, interleaved with that step's impulses in the order both
were applied (each edit's impulses_before says so too); with the parameters they make the
run re-simulable through any number of spawns, deletions and state sets.

A world with a map (`map`) keeps the map in the recording: its YAML and image as MCAP
attachments, under the names the run gave them, once per file (each split file carries
them), with the segment metadata naming them and their SHA-256 (MAP_KEYS), so resim, info
and to_rrd need no map file; and `map`, the nav_msgs/OccupancyGrid the node latched, at each
segment (and split file) start, transient local, for `ros2 bag play` and Foxglove.

Two topics are recorded for viewers and players only (the tools never read them back):
`markers`, the MarkerArray the node publishes for RViz (a sphere per ball sized by its
radius, the walls as a line list), so Foxglove's 3D panel shows the world from the file
alone; and `/clock` when `publish_clock` is on, as the node publishes it. Markers are written
when a segment starts and at the first step after a spawn or deletion (each time after a
DELETEALL, so a reset or an edit clears the old balls), and then every MARKERS_PERIOD_NS of
simulated time, not every step: see MARKERS_PERIOD_NS for the cost.

The file is claimed first (recording.files): an existing file is refused unless
overwrite=True, and the file stays locked until the sink is closed.

The records are written by recording.mcap_records, the messages of a step in one call: the
`mcap` package's Writer took about 9 us a message, and 1,000 robots with their own topics
record 30,000 messages a second (docs/performance.md). The records are those its Writer
wrote, so every MCAP reader reads these files as before.

Crash safety: chunks are cut only between steps, and flush() closes the open chunk and hands
it to the OS. After a SIGKILL the file has no summary, but every chunk before the last
flush() is complete; `ball_world_repair` turns such a file into a complete one.
"""
import array
import dataclasses
import hashlib
import json
import os

from mcap import __version__ as MCAP_VERSION
import numpy as np
import yaml

from ball_world import __version__
from ball_world.msgs.cdr import encode_clock, encode_string
from ball_world.msgs.definitions import message_definition, type_hash
from ball_world.recording import agent_topics, mcap_records
from ball_world.recording.bag import FileSummary, TopicCount
from ball_world.recording.files import claim_output, OutputClaim
from ball_world.recording.mcap_records import McapRecords
from ball_world.recording.resume import RESUME_STEP
from ball_world.step_record import PACKAGE_NAME

#: Compression of the MCAP chunks. lz4 is the default because writing competes with stepping
#: (the node writes on a background thread, but the Python parts share the GIL): measured per
#: step (write_step + a flush every 60 steps), lz4 costs 0.12 ms
#: at 1,000 balls and 0.9 ms at 10,000 (p99 2.2 ms), zstd 0.23 ms and 3.6 ms (p99 9.5 ms,
#: more than the 7 ms the 10,000-ball physics step takes). zstd files are 2-2.6x smaller
#: (19 vs 49 kB per step at 1,000 balls, 260 vs 505 kB at 10,000): choose it for archives.
COMPRESSIONS = tuple(mcap_records.COMPRESSIONS)
DEFAULT_COMPRESSION = 'lz4'

#: Uncompressed bytes after which the open chunk is closed (at the end of a step). The writer
#: keeps an index entry per chunk for the summary (mcap's Writer: about 800 bytes as objects;
#: mcap_records: its record's bytes, about 100 and 10 per channel in the chunk), so larger
#: chunks keep memory flatter: at 1,000 balls and 100 Hz, 1 MiB chunks grew it by 0.41 MB a
#: minute with mcap's Writer. The one-second flush still bounds what a SIGKILL can lose.
CHUNK_BYTES = 4 << 20

#: What each logical topic carries: the messages of every step, which the tools read back.
#: A new kind of recorded event is one more entry here and in EVENT_ROLES.
STEP_TOPICS = {
    'balls': 'geometry_msgs/msg/PoseArray',
    'state': 'std_msgs/msg/Float64MultiArray',
    'stats': 'std_msgs/msg/Float64MultiArray',
    'impulse': 'geometry_msgs/msg/Vector3Stamped',
    'edits': 'std_msgs/msg/String',
}
#: Roles of which a step may hold any number of messages (the others hold one each).
EVENT_ROLES = ('impulse', 'edits')
#: Roles whose channel is declared at its first message, not at the segment start: a run
#: without world edits records no `edits` topic, so its file holds the topics it held
#: before edits were recorded (and `ball_world_replay --wait-for-subscribers` waits for
#: no subscriber of a topic that has nothing to play).
LAZY_ROLES = ('edits',)
#: Topics for viewers and players only: the tools never read them back.
VIEW_TOPICS = {
    'markers': 'visualization_msgs/msg/MarkerArray',
    'clock': 'rosgraph_msgs/msg/Clock',
    'map': 'nav_msgs/msg/OccupancyGrid',
}
TOPIC_TYPES = {**STEP_TOPICS, **VIEW_TOPICS}
#: The clock topic is absolute, whatever the node's namespace (as the node publishes it).
CLOCK_TOPIC = '/clock'

#: Simulated time between two recorded MarkerArrays (one is also written at every segment
#: start). Foxglove draws the latest marker of each id, so the spheres move at this rate (10
#: Hz, the node's live markers.rate_hz), while `balls`, recorded every step, has the exact
#: positions. Measured (lz4, 60 Hz; sizes relative to a file without markers): every step
#: +0.79x at 20 balls and +0.87x at 10,000, and about 6 ms of writer CPU per step at 10,000
#: balls; 30 Hz +0.41x and +0.44x; 10 Hz +0.16x at 20, 1,000 and 10,000 balls (zstd:
#: +0.07x to +0.27x) and about 0.2 ms of writer CPU per step at 10,000 balls.
MARKERS_PERIOD_NS = 100_000_000

#: Name of the per-segment metadata record, and the node name of its parameters document.
METADATA_NAME = PACKAGE_NAME
NODE_NAME = PACKAGE_NAME
#: The Header's library: the `mcap` package's version too, as when its Writer wrote the records
#: (recording.mcap_records writes the same ones; topic_bag's files still use its Writer).
LIBRARY = f'{PACKAGE_NAME} {__version__} (mcap-python {MCAP_VERSION})'

#: Parameters whose recorded value is '' so that running with a recording's parameters
#: never overwrites that recording.
NOT_REPEATED = ('record.mcap', 'record.rerun')

#: offered_qos_profiles of the node's publishers in the YAML rosbag2 Jazzy writes (metadata
#: version 9: policy names, infinite durations as sec 9223372036 / nsec 854775807, yaml-cpp's
#: block style, no trailing newline).
_INFINITE = '    sec: 9223372036\n    nsec: 854775807'


def offered_qos_profiles(depth, reliability='reliable', durability='volatile'):
    """One publisher's offered QoS as rosbag2 records it."""
    return ('- history: keep_last\n'
            f'  depth: {depth}\n'
            f'  reliability: {reliability}\n'
            f'  durability: {durability}\n'
            f'  deadline:\n{_INFINITE}\n'
            f'  lifespan:\n{_INFINITE}\n'
            '  liveliness: automatic\n'
            f'  liveliness_lease_duration:\n{_INFINITE}\n'
            '  avoid_ros_namespace_conventions: false')


#: The node's step publishers: reliable, volatile, keep_last 10.
OFFERED_QOS_PROFILES = offered_qos_profiles(10)
#: What each role's publisher offers in the node (edits: depth 1000 for a burst of spawns;
#: markers: transient local for late RViz and Foxglove subscribers; /clock: best effort,
#: depth 1).
ROLE_QOS = {
    **{role: OFFERED_QOS_PROFILES for role in STEP_TOPICS},
    'edits': offered_qos_profiles(1000),
    'markers': offered_qos_profiles(1, durability='transient_local'),
    'clock': offered_qos_profiles(1, reliability='best_effort'),
    # The map: as nav2_map_server offers it (transient local), so `ros2 bag play` latches it.
    'map': offered_qos_profiles(1, durability='transient_local'),
    # The agents' topics (recording.agent_topics), as ros/agents.py offers them.
    agent_topics.COMMAND: offered_qos_profiles(100),
    agent_topics.ODOM: offered_qos_profiles(10),
    agent_topics.TF: offered_qos_profiles(100),
    agent_topics.TF_STATIC: offered_qos_profiles(1, durability='transient_local'),
    agent_topics.SCAN: offered_qos_profiles(10),
    agent_topics.GROUND_TRUTH: offered_qos_profiles(10),
    agent_topics.BUMPER: offered_qos_profiles(10),
    agent_topics.COMMANDS: offered_qos_profiles(10),  # a swarm's commands, recorded only
}


class _ParamsDumper(yaml.SafeDumper):
    """Block-style maps with one-line lists: how parameter files are written by hand."""


_ParamsDumper.add_representer(
    list, lambda dumper, value: dumper.represent_sequence('tag:yaml.org,2002:seq', value,
                                                          flow_style=True))


class McapRecordingError(OSError):
    """An MCAP file that cannot be created or written; str() is '<path>: <reason>'."""

    def __str__(self):
        return f'{self.filename}: {self.strerror}'


def _recording_error(path, error):
    reason = error.strerror or str(error)
    return McapRecordingError(error.errno, reason, path)


def plain(value):
    """A parameter value as plain Python (rclpy hands out array.array, numpy scalars...)."""
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        return [plain(item) for item in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def parameters_document(parameters):
    """The params-file dict {'ball_world': {'ros__parameters': {...}}} for `parameters`.

    Dotted names nest ('balls.x' -> balls: {x: ...}), as users write them, except under a
    name that has a value itself ('map': '...', 'map.unknown_solid': ...). Empty lists are
    kept: rcl reads them as unset, which the node takes as the (empty) default.
    """
    tree = {}
    for name in sorted(parameters):
        value = '' if name in NOT_REPEATED else plain(parameters[name])
        node = tree
        parts = name.split('.')
        # A name that is also another's prefix ('map' and 'map.unknown_solid') keeps the
        # rest of the longer one as a dotted key, as rcl reads it: sorted, the shorter
        # comes first and is a value, not a mapping to nest into.
        while len(parts) > 1 and isinstance(node.get(parts[0], {}), dict):
            node = node.setdefault(parts.pop(0), {})
        node['.'.join(parts)] = value
    return {NODE_NAME: {'ros__parameters': tree}}


def flatten_parameters(document):
    """The inverse of parameters_document: {'balls.x': [...], ...} from the params dict."""
    flat = {}

    def walk(prefix, node):
        for key, value in node.items():
            name = f'{prefix}.{key}' if prefix else str(key)
            if isinstance(value, dict):
                walk(name, value)
            else:
                flat[name] = value

    walk('', document[NODE_NAME]['ros__parameters'])
    return flat


def segment_topics(info, clock, has_map=False):
    """The recorded topic of each role in a segment: step roles, markers, /clock if on, and
    `map` in a world with a map.

    A role the run does not name (markers, or edits in runs fed from recordings made before
    edits were recorded) lives beside `balls`, as the node names them all relatively.
    """
    namespace = info.topics['balls'].rpartition('/')[0]
    topics = {role: info.topics.get(role, f'{namespace}/{role}')
              for role in (*STEP_TOPICS, 'markers', *(('map',) if has_map else ()))}
    if clock:
        topics['clock'] = CLOCK_TOPIC
    return topics


#: The map's files are kept as MCAP attachments, named as the run named them; the segment's
#: metadata names them (these keys) with the SHA-256 of their bytes.
MAP_KEYS = ('map_yaml', 'map_image', 'map_yaml_sha256', 'map_image_sha256')
#: Media types of the attachments, by the image's first bytes.
_IMAGE_MEDIA_TYPES = {b'P2': 'image/x-portable-graymap', b'P5': 'image/x-portable-graymap',
                      b'P3': 'image/x-portable-pixmap', b'P6': 'image/x-portable-pixmap',
                      b'\x89P': 'image/png'}
YAML_MEDIA_TYPE = 'application/yaml'


def map_metadata(files):
    """The segment metadata values that name a map's attachments (core MapFiles)."""
    return {'map_yaml': files.yaml_name, 'map_image': files.image_name,
            'map_yaml_sha256': hashlib.sha256(files.yaml_bytes).hexdigest(),
            'map_image_sha256': hashlib.sha256(files.image_bytes).hexdigest()}


def map_attachments(files):
    """(name, media type, bytes) of the attachments that keep a map's files."""
    image_type = _IMAGE_MEDIA_TYPES.get(bytes(files.image_bytes[:2]),
                                        'application/octet-stream')
    return ((files.yaml_name, YAML_MEDIA_TYPE, files.yaml_bytes),
            (files.image_name, image_type, files.image_bytes))


def segment_metadata(world, info, topics):
    """The 'ball_world' metadata record of one segment: all values are strings."""
    document = parameters_document(info.parameters)
    occupancy_map = getattr(world, 'occupancy_map', None)
    return {
        'segment': str(info.segment),
        'log_offset_ns': str(info.log_offset_ns),
        'dt_ns': str(world.dt_ns),
        'frame_id': world.frame_id,
        'package_version': info.package_version,
        # Which backend stepped it; both give the same bits, so re-simulation may use either.
        'backend': info.backend,
        'parameters': yaml.dump(document, Dumper=_ParamsDumper, sort_keys=False),
        'parameters_json': json.dumps(document),
        'topics': json.dumps(topics),
        # The agents' drive impulses are left out (recording.agent_topics): say so, for the
        # readers of files from before that kept them.
        agent_topics.DRIVES_KEY: agent_topics.DRIVES_NOT_RECORDED,
        **(map_metadata(occupancy_map.files) if occupancy_map is not None else {}),
        **(info.resume or {}),
    }


def segment_start_ns(world, info):
    """Log time of what a segment start writes: its step 0, or in a split file that
    continues the segment (recording.resume), the file's first step."""
    if info.resume:
        return info.log_offset_ns + (int(info.resume[RESUME_STEP]) + 1) * world.dt_ns
    return info.log_offset_ns


class _Markers:
    """The markers of the current world as the node publishes them, and when they are due.

    rclpy (through msgs.markers) is imported only when a sink records markers.
    """

    def __init__(self, period_ns):
        from rclpy.serialization import serialize_message
        from ball_world.msgs.markers import MarkerBuilder
        self.period_ns = period_ns
        self.builder = MarkerBuilder()
        self.delete_all = serialize_message(self.builder.delete_all())
        self.next_ns = 0

    def reset(self, world):
        """A new world (segment start): its markers are due at its next step."""
        self.builder.reset(world.radii, world.walls, world.frame_id)
        self.next_ns = 0

    def due(self, stamp_ns):
        return stamp_ns >= self.next_ns

    def build(self, record):
        self.next_ns = (record.stamp_ns // self.period_ns + 1) * self.period_ns
        return self.builder.build(record.positions, record.stamp_ns)


class McapSink:
    """A Sink writing a rosbag2-compatible MCAP file (see the module docstring).

    output is a path, claimed here (an existing file is refused unless overwrite=True), or
    an OutputClaim the caller took. Opening fails at once (McapRecordingError or
    files.FileRefused, naming the path) when the file cannot be claimed, created or
    written. Any later write error raises McapRecordingError from the call that hit it and
    closes the file; the sink is then finished and close() does nothing. fsync=True makes
    flush() also fsync, for power loss (SIGKILL does not need it). markers_period_ns=None
    records no markers.
    """

    def __init__(self, output, compression=DEFAULT_COMPRESSION, chunk_bytes=CHUNK_BYTES,
                 fsync=False, overwrite=False, markers_period_ns=MARKERS_PERIOD_NS):
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}, got "
                             f'{compression!r}')
        claim = output if isinstance(output, OutputClaim) else claim_output(output, overwrite)
        self._claim = claim
        self._segments = 0
        self.path = claim.path
        self.compression = compression
        self.chunk_bytes = int(chunk_bytes)
        self.fsync = fsync
        self._schemas = {}  # type name -> schema id
        self._channels = {}  # topic -> channel id
        self._roles = {}  # logical name -> channel id, for the current segment
        self._topics = {}  # logical name -> recorded topic, for the current segment
        self._channel_info = {}  # channel id -> (topic, type name, role)
        self._agent_kinds = {}  # (namespace, role) -> the last agents' names, their channels
        # The messages of the step being written (channel ids, bytes): one call writes them.
        self._batch_channels = []
        self._batch_data = []
        self.removed = False  # closed before any segment: the file was removed
        self._last_log_ns = None
        self._clock = False  # whether this segment records /clock
        self._agent_parameters = {}  # the segment's parameters (agent.cmd_vel_stamped)
        self._world = None  # the segment's WorldSnapshot: its walls and frame for markers
        self._markers = None if markers_period_ns is None else _Markers(markers_period_ns)
        self._attached = set()  # (YAML bytes, image bytes) of the maps attached to this file
        self._file = claim.writer()
        self._closed = False
        # Chunks are cut here, between steps, never in the middle of one.
        self._records = McapRecords(self._file, compression)
        try:
            self._guard(self._start)
        except McapRecordingError:
            claim.discard()  # nothing was recorded: leave no empty file behind
            raise

    def _start(self):
        self._records.start(profile='ros2', library=LIBRARY)
        self._file.flush()  # a full disk or read-only file fails here, at start

    @property
    def bytes_written(self):
        """Bytes handed to the file so far plus the open chunk's (uncompressed): about the
        size of the file were it finished now, less its summary."""
        return self._records.position + self._records.pending

    # Sink protocol ----------------------------------------------------------------------

    def start_segment(self, world, info):
        self._check_open()
        self._segments += 1
        self._clear_batch()
        self._guard(self._start_segment, world, info)

    def write_step(self, record):
        self._check_open()
        if self._last_log_ns is not None and record.log_time_ns < self._last_log_ns:
            raise ValueError(f'log time went back from {self._last_log_ns} to '
                             f'{record.log_time_ns} ns')
        self._clear_batch()
        self._guard(self._write_step, record)

    def write_pending(self, events):
        """Record edits (and the impulses they applied) made after the segment's last step.

        They go at the log time of the step they would have preceded, as that step's impulse
        and edit messages would, with no balls, state or stats: a closing record, which the
        reader and the tools take for what it is (mcap_reader.RecordedStep.closing).
        """
        self._check_open()
        if self._last_log_ns is not None and events.log_time_ns <= self._last_log_ns:
            raise ValueError(f'log time went back from {self._last_log_ns} to '
                             f'{events.log_time_ns} ns')
        self._clear_batch()
        self._guard(self._write_events, events.log_time_ns, events.impulses, events.edits)
        self._guard(self._write_batch, events.log_time_ns)
        self._last_log_ns = events.log_time_ns

    def flush(self):
        self._check_open()
        self._guard(self._flush)

    def close(self):
        """Write the summary and footer and close the file; a second call does nothing.

        A file closed before any segment began holds nothing: it is removed if this sink
        created it (a start that failed leaves no file to refuse the next start).
        """
        if self._closed:
            return
        self._guard(self._finish)
        self._closed = True
        if not self._segments:
            self._claim.discard()
            self.removed = True
        else:
            self._claim.release()

    def abandon(self):
        """After a write error: close what is left of the file, keep it, drop the claim."""
        self._closed = True
        try:
            self._file.close()
        except OSError:
            pass  # the bytes it held cannot be written either
        self._claim.release()

    def summary(self):
        """What metadata.yaml says of this file (recording.bag.FileSummary), from what was
        written: no need to read the file back."""
        topics = {}
        counts = self._records.counts()
        for channel, count in sorted(counts.items()):
            topic, type_name, role = self._channel_info[channel]
            topics[topic] = TopicCount(topic=topic, type=type_name, message_count=count,
                                       offered_qos_profiles=ROLE_QOS[role],
                                       type_hash=type_hash(type_name))
        return FileSummary(path=self.path, start_ns=self._records.start_time,
                           end_ns=self._records.end_time,
                           message_count=self._records.message_count, topics=topics)

    # Implementation ---------------------------------------------------------------------

    def _start_segment(self, world, info):
        self._world = world
        self._clock = bool(info.parameters.get('publish_clock'))
        self._agent_parameters = info.parameters
        occupancy_map = world.occupancy_map
        topics = segment_topics(info, self._clock, occupancy_map is not None)
        self._topics = topics
        self._roles = {role: self._channel(topic, role) for role, topic in topics.items()
                       if role not in LAZY_ROLES}
        # Close the previous segment's chunk first, so that in file order the metadata
        # record sits between the two segments' messages.
        self._records.flush()
        start_ns = segment_start_ns(world, info)
        if occupancy_map is not None:
            self._attach_map(occupancy_map.files, start_ns)
        self._records.metadata(METADATA_NAME, segment_metadata(world, info, topics))
        self._restart_markers(world, start_ns)
        if occupancy_map is not None and world.map_cdr is not None:
            # /map as the node latched it, at the segment's (or this file's) first log time,
            # so `ros2 bag play` and Foxglove have the map from the file alone.
            self._add('map', start_ns, world.map_cdr)
        self._write_batch(start_ns)

    def _attach_map(self, files, log_time_ns):
        """Keep the map's files in this file as attachments, once per file per map.

        Each file of a split recording has its own copy: each stands alone.
        """
        key = (files.yaml_bytes, files.image_bytes)
        if key in self._attached:
            return
        for name, media_type, data in map_attachments(files):
            self._records.attachment(log_time=log_time_ns, create_time=0, name=name,
                                     media_type=media_type, data=data)
        self._attached.add(key)

    def _restart_markers(self, world, log_time_ns):
        """Clear the old world in viewers and record the new one's markers at its next step.

        Called at every segment start, and at the first step after a spawn or a deletion
        (with the balls' new radii): marker ids follow pose order, so after an edit the old
        set must go before the new one is drawn.
        """
        if self._markers is not None:
            self._markers.reset(world)
            self._add('markers', log_time_ns, self._markers.delete_all)

    def _channel(self, topic, role, type_name=None):
        type_name = type_name or TOPIC_TYPES[role]
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get(type_name)
            if schema is None:
                schema = self._records.schema(
                    type_name, 'ros2msg', message_definition(type_name).encode('utf-8'))
                self._schemas[type_name] = schema
            channel = self._records.channel(
                topic, 'cdr', schema, metadata={'offered_qos_profiles': ROLE_QOS[role],
                                                'topic_type_hash': type_hash(type_name)})
            self._channels[topic] = channel
            self._channel_info[channel] = (topic, type_name, role)
        return channel

    def _add(self, role, log_time_ns, data):
        """A message of the batch being made (all at log_time_ns: _write_batch writes it)."""
        channel = self._roles.get(role)
        if channel is None:  # a LAZY_ROLES topic's first message
            channel = self._roles[role] = self._channel(self._topics[role], role)
        self._batch_channels.append(channel)
        self._batch_data.append(data)

    def _add_agents(self, messages):
        """Agent messages (recording.agent_topics' (topic, type, role, bytes)) into the batch;
        a topic's channel is made at its first message. A list at a time: 1,000 robots
        record up to 3,000 messages a step."""
        if not messages:
            return
        channels = self._channels
        self._batch_channels += [channels.get(topic) or self._channel(topic, role, type_name)
                                 for topic, type_name, role, _ in messages]
        self._batch_data += [message[3] for message in messages]

    def _add_kind(self, namespace, messages):
        """One kind of agent message (agent_topics.AgentMessages) into the batch."""
        if messages.names is None:
            self._add_agents([(messages.topic, messages.type_name, messages.role, data)
                              for data in messages.data])
            return
        self._batch_channels += self._agent_channels(namespace, messages)
        self._batch_data += messages.data

    def _agent_channels(self, namespace, messages):
        """The channel of each agent's topic of messages.role, made at its first message.

        The last names of each kind are kept with their channels: the agents are mostly the
        same step after step (one tuple, compared by identity), so 1,000 robots' odometry
        needs no topic strings.
        """
        key = (namespace, messages.role)
        names, channels = self._agent_kinds.get(key, ((), []))
        if names != messages.names:
            known, role = self._channels, messages.role
            channels = []
            for name in messages.names:
                topic = agent_topics.agent_topic(namespace, name, role)
                channels.append(known.get(topic)
                                or self._channel(topic, role, messages.type_name))
            self._agent_kinds[key] = (messages.names, channels)
        return channels

    def _write_batch(self, log_time_ns):
        """The messages added since the last batch, at their log time, in order."""
        channels, data = self._batch_channels, self._batch_data
        self._batch_channels, self._batch_data = [], []
        self._records.messages(log_time_ns, channels, data)

    def _clear_batch(self):
        """Forget a batch a failed call left half made (a write error ends the sink)."""
        self._batch_channels, self._batch_data = [], []

    def _write_events(self, log_time_ns, impulses, edits):
        """Impulses and edits in the order they were applied (each edit's impulses_before)."""
        done = 0
        for edit in edits:
            for impulse in impulses[done:edit.impulses_before]:
                self._add('impulse', log_time_ns, impulse.cdr)
            done = max(done, edit.impulses_before)
            self._add('edits', log_time_ns, encode_string(edit.text))
        for impulse in impulses[done:]:
            self._add('impulse', log_time_ns, impulse.cdr)

    def _write_step(self, record):
        log_time_ns = record.log_time_ns
        # Impulses and edits come first, in the order they were applied: all of them were
        # applied before the step whose stamp they carry.
        self._write_events(log_time_ns, agent_topics.recorded_impulses(record.impulses),
                           record.edits)
        namespace = agent_topics.namespace_of(self._topics)
        self._add_agents(agent_topics.before_step(record, namespace, self._agent_parameters))
        if record.world_changed:
            self._restart_markers(dataclasses.replace(self._world, radii=record.radii),
                                  log_time_ns)
        self._add('balls', log_time_ns, record.balls_cdr)
        self._add('state', log_time_ns, record.state_cdr)
        self._add('stats', log_time_ns, record.stats_cdr)
        for messages in agent_topics.after_step(record):
            self._add_kind(namespace, messages)
        if self._clock:
            self._add('clock', log_time_ns, encode_clock(record.stamp_ns))
        if self._markers is not None and self._markers.due(record.stamp_ns):
            self._add('markers', log_time_ns, self._markers.build(record))
        self._write_batch(log_time_ns)
        self._last_log_ns = log_time_ns
        if self._records.pending >= self.chunk_bytes:
            self._records.flush()

    def _flush(self):
        # Close the open chunk (with its message indexes), write it and flush the Python
        # buffer to the OS; fsync only when asked.
        self._records.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def _finish(self):
        self._records.finish()
        self._file.close()

    def _check_open(self):
        if self._closed:
            raise ValueError(f'{self.path}: the recording is closed')

    def _guard(self, action, *args):
        """Run action; on an OS error close the file and raise it as McapRecordingError."""
        try:
            action(*args)
        except OSError as error:
            self._closed = True
            try:
                self._file.close()
            except OSError:
                pass  # the buffered bytes cannot be written either; the first error says why
            self._claim.release()
            raise _recording_error(self.path, error) from error
