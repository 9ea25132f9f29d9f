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

The reader's step roles (agent_role) are cmd_vel, odom and /tf; scans, ground truth and
bumpers are read as topics of their own (AGENT_MESSAGE_KINDS), beside the steps.
"""
import re

import numpy as np

from ball_world.core.orientation import quaternion_to_yaw
from ball_world.msgs.agent_cdr import decode_odometry
from ball_world.msgs.twist_cdr import decode_twist, decode_twist_stamped
from ball_world.step_record import AgentFrame

COMMAND = 'cmd_vel'
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
         BUMPER: 'geometry_msgs/msg/Vector3Stamped'}
STAMPED_COMMAND = 'geometry_msgs/msg/TwistStamped'
_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*')
_AGENT_TOPIC = re.compile(r'(?P<namespace>.*)/(?P<name>[A-Za-z][A-Za-z0-9_]*)/'
                          r'(?P<kind>cmd_vel|odom)')


def namespace_of(topics):
    """The node's namespace in a segment's topics ('' at the root)."""
    return topics['balls'].rpartition('/')[0]


def command_type(parameters):
    return STAMPED_COMMAND if parameters.get('agent.cmd_vel_stamped') else TYPES[COMMAND]


def before_step(record, namespace, parameters):
    """(topic, type, role, bytes) of the commands taken before this step, in order."""
    kind = command_type(parameters)
    return [(f'{namespace}/{command.name}/{COMMAND}', kind, COMMAND, command.cdr)
            for command in record.commands]


def after_step(record, namespace):
    """(topic, type, role, bytes) of the agents' odom, ground truth, /tf, /tf_static,
    bumpers and scans of this step."""
    frame = record.agents
    if frame is None:
        return []
    messages = [(f'{namespace}/{name}/{ODOM}', TYPES[ODOM], ODOM, data)
                for name, data in zip(frame.names, frame.odom_cdr)]
    messages += [(f'{namespace}/{name}/{GROUND_TRUTH}', TYPES[GROUND_TRUTH], GROUND_TRUTH,
                  data) for name, data in zip(frame.names, frame.ground_truth_cdr)]
    messages.append((TF_TOPIC, TYPES[TF], TF, frame.tf_cdr))
    if frame.tf_static_cdr is not None:
        messages.append((TF_STATIC_TOPIC, TYPES[TF_STATIC], TF_STATIC, frame.tf_static_cdr))
    messages += [(f'{namespace}/{bumper.name}/{BUMPER}', TYPES[BUMPER], BUMPER, bumper.cdr)
                 for bumper in frame.bumpers]
    messages += [(f'{namespace}/{scan.name}/{SCAN}', TYPES[SCAN], SCAN, scan.cdr)
                 for scan in frame.scans]
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


def recorded_frame(odom, names):
    """The AgentFrame a recorded step's odom gives ({agent: bytes} in recorded order), or None.

    For the sinks fed from a recording (ball_world_to_rrd draws the headings): each agent's
    row is found by name among the step's balls `names`; ValueError for odom that does not
    decode or whose orientation is not a rotation about z (an untrusted file).
    """
    if not odom:
        return None
    row_of = {name: row for row, name in enumerate(names)}
    agents = [name for name in odom if name in row_of]
    decoded = [decode_odometry(odom[name]) for name in agents]
    yaws = quaternion_to_yaw(np.array([d.pose[3:7] for d in decoded]).reshape(-1, 4))
    twists = np.array([(d.twist[0], d.twist[1], d.twist[5]) for d in decoded]).reshape(-1, 3)
    return AgentFrame(names=tuple(agents),
                      indices=np.array([row_of[name] for name in agents], dtype=np.int64),
                      yaws=np.asarray(yaws, dtype=np.float64).reshape(-1), twists=twists,
                      odom_frames=tuple(d.frame_id for d in decoded),
                      base_frames=tuple(d.child_frame_id for d in decoded),
                      odom_cdr=tuple(odom[name] for name in agents), tf_cdr=b'')
