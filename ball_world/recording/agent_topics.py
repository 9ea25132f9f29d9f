"""What a recording holds of the agents (core.agents): which topics, types and bytes.

Why a module of its own: the writer and the reader must agree on these names, and neither
should grow agent knowledge inline. A world without agents records none of this, so its
files are what they were before agents existed.

Per step, with `<ns>` the node's namespace (that of `balls`):
- before the step's `balls`: every command an agent took, as received, on
  `<ns>/<name>/cmd_vel` (Twist, or TwistStamped with agent.cmd_vel_stamped), at the log time
  of the first step it acted on;
- after it: `<ns>/<name>/odom` and `<ns>/<name>/ground_truth` of every agent, `/tf`, and
  `/tf_static` when the set of agents changed (a segment's first step included; never with
  agent.odom.tf_static false), as the node publishes them; `<ns>/<name>/bumper` of every
  agent hit in the step; at a scan step, `<ns>/<name>/scan` of every agent with a scanner
  (ball_world.scans).

With agent.topics none (a swarm) there are no per-agent topics: the commands taken before
a step go, all of them, into one message at its log time, `<ns>/agent_commands`
(std_msgs/msg/Float64MultiArray, rows (ball, vx, vy, wz), ball the row in the step's
`balls`, msgs.agent_cdr.encode_command_rows). With agent.odom.rate_hz, odom, ground truth
and /tf are recorded at the steps that send them.

The drives' impulses (an agent's cmd_vel turned into an impulse before each step it
accelerates, AppliedImpulse.drive) are not recorded, with either agent.topics: neither on
`impulse`, which keeps every other impulse, nor anywhere else. The commands are, and the
drive is a function of them and of the state recorded at the step before, so
re-simulation makes the drives again (as it always did) and compares everything they
move, and a recording fed to sinks gets them again from recording.remade_drives. Why:
1,000 robots at 100 Hz drive up to 100,000 times a second, which an MCAP writer in Python
cannot keep up with (docs/performance.md); 10,000 a swarm's. The segment metadata says so
(DRIVES_KEY). Recordings made before kept every drive on `impulse` and, from when drives
were recorded apart, again on `<ns>/<name>/drive` (geometry_msgs/msg/Vector3Stamped, the
same bytes), from which the reader marks them; a recording older still has its drives on
`impulse` alone, read as pushes, as they always were. Both re-simulate as before.

The reader's step roles (agent_role) are cmd_vel, agent_commands, drive (older files), odom
and /tf; scans, ground truth and bumpers are read as topics of their own
(AGENT_MESSAGE_KINDS), beside the steps, and handed to the sinks fed from a recording
(recorded_frame) when they draw them.
"""
import re
from typing import NamedTuple

import numpy as np

from ball_world.core.lidar import Fan
from ball_world.core.orientation import quaternion_to_yaw
from ball_world.msgs.agent_cdr import (decode_laser_scan, decode_odometry,
                                       encode_command_rows)
from ball_world.msgs.cdr import decode_pose_orientations, decode_vector3_stamped
from ball_world.msgs.twist_cdr import decode_twist, decode_twist_stamped
from ball_world.step_record import AgentFrame, Bumper

COMMAND = 'cmd_vel'
COMMANDS = 'agent_commands'
DRIVE = 'drive'
ODOM = 'odom'
TF = 'tf'
TF_STATIC = 'tf_static'
SCAN = 'scan'
GROUND_TRUTH = 'ground_truth'
BUMPER = 'bumper'
#: Per-agent topics a re-simulation compares byte for byte, read beside the steps.
AGENT_MESSAGE_KINDS = (SCAN, GROUND_TRUTH, BUMPER)
TF_TOPIC = '/tf'
TF_STATIC_TOPIC = '/tf_static'
TYPES = {COMMAND: 'geometry_msgs/msg/Twist', ODOM: 'nav_msgs/msg/Odometry',
         TF: 'tf2_msgs/msg/TFMessage', TF_STATIC: 'tf2_msgs/msg/TFMessage',
         SCAN: 'sensor_msgs/msg/LaserScan', GROUND_TRUTH: 'nav_msgs/msg/Odometry',
         BUMPER: 'geometry_msgs/msg/Vector3Stamped', DRIVE: 'geometry_msgs/msg/Vector3Stamped',
         COMMANDS: 'std_msgs/msg/Float64MultiArray'}
STAMPED_COMMAND = 'geometry_msgs/msg/TwistStamped'
#: The segment metadata entry (all values strings) that says a segment's drive impulses are
#: not recorded; files written before it have none (drives_recorded).
DRIVES_KEY = 'agent_drives'
DRIVES_NOT_RECORDED = 'made from the commands'
_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*')
_AGENT_TOPIC = re.compile(r'(?P<namespace>.*)/(?P<name>[A-Za-z][A-Za-z0-9_]*)/'
                          r'(?P<kind>cmd_vel|drive|odom)')


class RecordedScan(NamedTuple):
    """A recorded scan as the views take one (the fields of scans.AgentScan they read)."""

    name: str
    frame_id: str
    ranges: np.ndarray  # float64 (the message's float32, widened exactly)
    fan: Fan
    cdr: bytes


def namespace_of(topics):
    """The node's namespace in a segment's topics ('' at the root)."""
    return topics['balls'].rpartition('/')[0]


def command_type(parameters):
    return STAMPED_COMMAND if parameters.get('agent.cmd_vel_stamped') else TYPES[COMMAND]


def swarm(parameters):
    """Whether the agents of a segment with these parameters are a swarm (agent.topics
    none: no per-agent topics)."""
    return parameters.get('agent.topics', 'each') == 'none'


def recorded_impulses(impulses):
    """The impulses of a step that go on `impulse`: all but the drives'."""
    if hasattr(impulses, 'pushes'):  # step_record.AppliedImpulses: drives batched
        impulses = impulses.pushes()
    return tuple(impulse for impulse in impulses if not impulse.drive)


def before_step(record, namespace, parameters):
    """(topic, type, role, bytes) of the commands taken before this step, in order; a
    swarm's as one message."""
    frame = record.agents
    if frame is not None and not frame.topics:
        rows = frame.command_rows
        if rows is None or not len(rows):
            return []
        return [(f'{namespace}/{COMMANDS}', TYPES[COMMANDS], COMMANDS,
                 encode_command_rows(rows))]
    kind = command_type(parameters)
    return [(f'{namespace}/{command.name}/{COMMAND}', kind, COMMAND, command.cdr)
            for command in record.commands]


def drives_recorded(metadata, parameters):
    """Whether a segment's drive impulses are on `impulse` (files written before they were
    left out, but a swarm's), from its metadata values; ValueError for a value not known."""
    value = metadata.get(DRIVES_KEY)
    if value is None:
        return not swarm(parameters)
    if value != DRIVES_NOT_RECORDED:
        raise ValueError(f"'{DRIVES_KEY}' is {value[:64]!r}, not {DRIVES_NOT_RECORDED!r}")
    return False


class AgentMessages(NamedTuple):
    """One kind of a step's agent messages: data[i] goes on agent_topic(namespace, names[i],
    role), each agent's own topic; with names None, every one on `topic` (/tf, /tf_static).

    Why by kind and not a (topic, type, role, bytes) each: 1,000 robots record 2,000 odom and
    ground truth messages at each odometry step, and their writer finds each one's channel
    from the kind's names, the same tuple step after step, not from 2,000 topic strings.
    """

    role: str
    type_name: str
    data: tuple
    names: tuple = None
    topic: str = ''


def agent_topic(namespace, name, role):
    """An agent's own topic of a kind: `<ns>/<name>/<role>`."""
    return f'{namespace}/{name}/{role}'


def after_step(record):
    """The agents' odom, ground truth, /tf, /tf_static, bumpers and scans of this step, as
    AgentMessages in the order they are recorded."""
    frame = record.agents
    if frame is None or not frame.topics:
        return []
    names = tuple(frame.names)
    messages = []
    if len(frame.odom_cdr):  # not at a step agent.odom.rate_hz skips
        messages.append(AgentMessages(ODOM, TYPES[ODOM], tuple(frame.odom_cdr), names))
    if len(frame.ground_truth_cdr):
        messages.append(AgentMessages(GROUND_TRUTH, TYPES[GROUND_TRUTH],
                                      tuple(frame.ground_truth_cdr), names))
    if frame.tf_cdr:  # not at a step agent.odom.rate_hz skips
        messages.append(AgentMessages(TF, TYPES[TF], (frame.tf_cdr,), topic=TF_TOPIC))
    if frame.tf_static_cdr is not None:
        messages.append(AgentMessages(TF_STATIC, TYPES[TF_STATIC], (frame.tf_static_cdr,),
                                      topic=TF_STATIC_TOPIC))
    if frame.bumpers:
        messages.append(AgentMessages(BUMPER, TYPES[BUMPER],
                                      tuple(bumper.cdr for bumper in frame.bumpers),
                                      tuple(bumper.name for bumper in frame.bumpers)))
    if frame.scans:
        messages.append(AgentMessages(SCAN, TYPES[SCAN], tuple(scan.cdr for scan in frame.scans),
                                      tuple(scan.name for scan in frame.scans)))
    return messages


def agent_message(topic):
    """(kind, agent name) of a recorded scan, ground truth or bumper topic, or None."""
    head, _, kind = topic.rpartition('/')
    name = head.rpartition('/')[2]
    if kind in AGENT_MESSAGE_KINDS and _NAME.fullmatch(name):
        return kind, name
    return None


def agent_role(topic, namespaces):
    """(kind, agent name) of a recorded agent topic under one of `namespaces`, or None."""
    if topic == TF_TOPIC:
        return (TF, '')
    namespace, _, last = topic.rpartition('/')
    if last == COMMANDS and namespace in namespaces:
        return (COMMANDS, '')
    match = _AGENT_TOPIC.fullmatch(topic)
    if match is None or match['namespace'] not in namespaces:
        return None
    return (match['kind'], match['name'])


def decode_command(data, type_name):
    """(vx, vy, wz) of a recorded cmd_vel message of type `type_name` (ValueError if bad)."""
    if type_name == STAMPED_COMMAND:
        values = decode_twist_stamped(data)[2]
    else:
        values = decode_twist(data)
    return values[0], values[1], values[5]


def recorded_frame(odom, names, messages=None):
    """The AgentFrame a recorded step gives the sinks fed from a recording, or None.

    odom: {agent: bytes} in recorded order; names: the step's balls; messages: the step's
    scans, ground truth and bumpers {(kind, agent): bytes} (mcap_reader's
    RecordedStep.agent_messages), or None. ball_world_to_rrd draws what the live view draws
    from the same run: each agent at its true heading (its ground truth: with
    agent.odom.noise the odometry drifts; a recording without ground truth had no noise,
    so its odom is the truth), its bumper hits and its scans. Each agent's row is found by
    name among `names`; ValueError for a message that does not decode or an orientation
    that is not a rotation about z (an untrusted file).
    """
    if not odom:
        return None
    messages = messages or {}
    row_of = {name: row for row, name in enumerate(names)}
    agents = [name for name in odom if name in row_of]
    decoded = [decode_odometry(odom[name]) for name in agents]
    truth = [messages.get((GROUND_TRUTH, name)) for name in agents]
    poses = [decode_odometry(data) if data is not None else odometry
             for data, odometry in zip(truth, decoded)]
    yaws = quaternion_to_yaw(np.array([d.pose[3:7] for d in poses]).reshape(-1, 4))
    twists = np.array([(d.twist[0], d.twist[1], d.twist[5]) for d in poses]).reshape(-1, 3)
    return AgentFrame(names=tuple(agents),
                      indices=np.array([row_of[name] for name in agents], dtype=np.int64),
                      yaws=np.asarray(yaws, dtype=np.float64).reshape(-1), twists=twists,
                      odom_frames=tuple(d.frame_id for d in decoded),
                      base_frames=tuple(d.child_frame_id for d in decoded),
                      odom_cdr=tuple(odom[name] for name in agents), tf_cdr=b'',
                      scans=_recorded_scans(agents, messages),
                      ground_truth_cdr=tuple(truth) if all(t is not None for t in truth)
                      else (),
                      bumpers=_recorded_bumpers(agents, messages))


class SwarmAgents:
    """Which balls of a swarm's recorded segment are agents, step by step: a swarm has no
    per-agent topics to say so (agent.topics none), so they are the segment's `agents`
    parameter, then each spawn of an agent added and each deletion taken away, as the
    node made them. A split file's later part starts from the agents its parameters name
    that are still there (agents spawned in an earlier part are not known there)."""

    def __init__(self, parameters, names):
        present = set(names)
        self.names = [name for name in parameters.get('agents', []) if name in present]

    def follow(self, edits):
        for edit in edits:
            if edit.kind == 'spawn' and edit.agent:
                self.names.append(edit.name)
            elif edit.kind == 'delete' and edit.name in self.names:
                self.names.remove(edit.name)

    def frame(self, balls_cdr, names):
        """The AgentFrame of a recorded swarm step: each agent's row and heading (its
        orientation in `balls`, which gives a swarm's agents theirs), for the views; None
        without agents. ValueError for an orientation that is no rotation about z."""
        row_of = {name: row for row, name in enumerate(names)}
        agents = tuple(name for name in self.names if name in row_of)
        if not agents:
            return None
        rows = np.array([row_of[name] for name in agents], dtype=np.int64)
        yaws = quaternion_to_yaw(decode_pose_orientations(balls_cdr)[rows])
        count = len(agents)
        return AgentFrame(names=agents, indices=rows,
                          yaws=np.asarray(yaws, dtype=np.float64).reshape(-1),
                          twists=np.zeros((count, 3)), odom_frames=('',) * count,
                          base_frames=('',) * count, odom_cdr=(), tf_cdr=b'', topics=False)


def _recorded_bumpers(agents, messages):
    """step_record.Bumper of each recorded `<name>/bumper` of the step, agent order."""
    bumpers = []
    for name in agents:
        data = messages.get((BUMPER, name))
        if data is not None:
            _, frame_id, x, y, _ = decode_vector3_stamped(data)
            bumpers.append(Bumper(name, frame_id, x, y, data))
    return tuple(bumpers)


def _recorded_scans(agents, messages):
    """scans.AgentScan-like rows (name, frame_id, ranges, fan, cdr) of each recorded
    `<name>/scan` of the step, agent order: what a view draws of a scan."""
    scans = []
    for name in agents:
        data = messages.get((SCAN, name))
        if data is not None:
            scan = decode_laser_scan(data)
            fan = Fan(scan.angle_min, scan.angle_increment, len(scan.ranges), scan.range_min,
                      scan.range_max)
            scans.append(RecordedScan(name, scan.frame_id,
                                      np.asarray(scan.ranges, dtype=np.float64), fan, data))
    return tuple(scans)
