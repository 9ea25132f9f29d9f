"""The agents' ROS topics: <name>/cmd_vel in; <name>/odom, <name>/ground_truth, <name>/bumper,
<name>/scan, /tf, /tf_static out; and bumper_markers (RViz arrows of the hits).

The node creates one AgentTopics and calls it at four points: sync() when the set of balls
changes, drain() before each step, publish() after it, and report() for the progress line.
Nothing here decides anything: commands go to Simulation.command (core.agents checks them),
and the odom, ground truth, bumper and /tf bytes are the StepRecord's, made once for the
publishers and the recording alike (raw CDR, like `balls`).

Names are relative (`<name>/cmd_vel` resolves under the node's namespace, so `-r __ns:=/sim2`
gives /sim2/ball_0/cmd_vel); /tf and /tf_static are absolute, as tf2 listens on them, and
frames carry frame_prefix so two worlds on one graph do not clash.

A flood of commands (thousands a second, NaN, 1e308) costs one decode and one check per
message: a refusal is counted, and a warning is logged at most once per WARN_PERIOD without
formatting anything in between.

The per-agent subscriptions and publishers belong to a second node of the same process,
`<node name>_agents` in the same namespace (made with the first agent), that no executor
spins: the world node drains
the subscriptions itself before each step (take_message), and publishers need no spinning.
Why: rclpy's executor walks every subscription and event handler of its nodes on every wait
and takes one message per wait, so 100 agents under a stream of commands took most of the
node's time (measured 2026-12-01 at 10,000 balls, 100 Hz, 100 agents commanded at 10 Hz, on
a loaded 2-core machine: real-time factor 0.45 against 0.91 without agents). They are also
made without rclpy's default QoS-event handlers (warnings about an incompatible QoS), which
only an executor would run. That node takes no command-line arguments (a `__node:=` rename
must not give two nodes one name): its namespace is the world node's.

A per-agent topic nobody subscribes to costs nothing (INTERFACE.md, "Many robots"): each
step looks at the subscriber count of SURVEY_PER_STEP publishers in turn (every one within
publishers / SURVEY_PER_STEP steps; /tf and bumper_markers every step), publishes only to
those that have subscribers, and tells the Simulation's agents which kinds of message
someone takes (AgentPart.encode), so the others are not even encoded, unless the node
records (an MCAP takes every one). With agent.topics none there are no per-agent topics
and no /tf at all: this class makes nothing.
"""
from dataclasses import dataclass
import time

from geometry_msgs.msg import Twist, TwistStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from ball_world.agents import frames as kinds
from ball_world.core.agents import CommandRejected
from ball_world.msgs.bumper_markers import bumper_markers
from ball_world.msgs.twist_cdr import decode_twist, decode_twist_stamped

#: cmd_vel messages a subscription holds between two steps (the node drains them all).
CMD_VEL_DEPTH = 100
#: Seconds between two warnings about refused commands.
WARN_PERIOD = 5.0
#: Agents whose topics take long enough to make (or leave) that the node says so first.
MANY_AGENTS = 200
#: Wall seconds between two looks at the graph for cmd_vel of another type (check_types).
TYPE_CHECK_PERIOD = 2.0
#: Publishers whose subscriber count is looked at per step (rcl's matched count: about a
#: microsecond each).
SURVEY_PER_STEP = 256
#: Wall seconds the node spends leaving the graph entity by entity when it stops; what is
#: left then goes with the process (see destroy).
LEAVE_BUDGET = 5.0

CMD_VEL_QOS = QoSProfile(depth=CMD_VEL_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
ODOM_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: tf2's own profiles: /tf as tf2_ros.TransformBroadcaster, /tf_static latched.
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
TF_STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


@dataclass
class _AgentEntities:
    """One agent's subscription and publishers."""

    cmd_vel: object
    odom: object
    ground_truth: object
    bumper: object
    scan: object = None  # when agents have scanners

    def all(self):
        return [entity for entity in (self.odom, self.ground_truth, self.bumper, self.scan)
                if entity is not None]

    def by_kind(self):
        """(kind, publisher) of each publisher (agents.frames' kinds)."""
        return [(kind, entity) for kind, entity in (
            (kinds.ODOM, self.odom), (kinds.GROUND_TRUTH, self.ground_truth),
            (kinds.BUMPER, self.bumper), (kinds.SCAN, self.scan)) if entity is not None]


class AgentTopics:
    """Subscriptions and publishers of every agent of the node's Simulation."""

    def __init__(self, node, stamped, recording=False):
        self.node = node
        # Whether an MCAP takes every agent message (then each is made whoever listens).
        self.recording = recording
        self.each = node.simulation.agents.each  # agent.topics, read at start only
        # kind -> names of the agents whose publisher of that kind has subscribers
        self._listened = {kind: set() for kind in (kinds.ODOM, kinds.GROUND_TRUTH,
                                                   kinds.BUMPER, kinds.SCAN)}
        self._survey = None  # [(name, kind, publisher's handle)], made again when they change
        self._cursor = 0
        self._drains = None  # _CommandWaits of the cmd_vel subscriptions, made after sync()
        self._io = None  # the node of the per-agent entities, made with the first agent
        self.stamped = stamped
        self._message_type = TwistStamped if stamped else Twist
        self._decode = self._decode_stamped if stamped else decode_twist
        self._topics = {}  # agent name -> _AgentEntities
        self._tf = None
        self._tf_static = None
        self._warned_at = -WARN_PERIOD
        self._hinted = set()  # (topic, type) pairs already named in a hint
        self.sync()

    @property
    def simulation(self):
        return self.node.simulation

    @staticmethod
    def _decode_stamped(data):
        return decode_twist_stamped(data)[2]

    def sync(self):
        """Topics for the agents the world has now: new agents get theirs, gone ones lose them.

        A world without agents creates nothing, not even /tf: it speaks as before; nor does
        a swarm (agent.topics none).
        """
        if not self.each:
            return
        self._survey = None
        self._drop_drains()
        names = self.simulation.agents.names
        if names and self._io is None:
            world = self.node
            self._io = Node(f'{world.get_name()}_agents', namespace=world.get_namespace(),
                            context=world.context, use_global_arguments=False,
                            start_parameter_services=False)
        node = self._io
        for name in [name for name in self._topics if name not in names]:
            entities = self._topics.pop(name)
            node.destroy_subscription(entities.cmd_vel)
            for publisher in entities.all():
                node.destroy_publisher(publisher)
        scanning = self.simulation.parameters['agent.scan.samples'] > 0
        new = [name for name in names if name not in self._topics]
        started = time.monotonic()
        if len(new) >= MANY_AGENTS:
            self.node.get_logger().info(
                f'making the topics of {len(new):,} agents (cmd_vel, odom, ground_truth, '
                f"bumper{', scan' if scanning else ''}): DDS announces each, which takes a "
                'while')
        for name in new:
            subscription = node.create_subscription(
                self._message_type, f'{name}/cmd_vel',
                lambda data, name=name: self.take(name, data), CMD_VEL_QOS, raw=True,
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
            self._topics[name] = _AgentEntities(
                subscription, self._publisher(Odometry, f'{name}/odom'),
                self._publisher(Odometry, f'{name}/ground_truth'),
                self._publisher(Vector3Stamped, f'{name}/bumper'),
                self._publisher(LaserScan, f'{name}/scan') if scanning else None)
        if len(new) >= MANY_AGENTS:
            self.node.get_logger().info(f'made the topics of {len(new):,} agents in '
                                        f'{time.monotonic() - started:.1f} s')
        if names and self._tf is None:
            self._bumper_markers = self.node.create_publisher(MarkerArray, 'bumper_markers',
                                                              ODOM_QOS)
            self._tf = self.node.create_publisher(TFMessage, '/tf', TF_QOS)
            self._tf_static = self.node.create_publisher(TFMessage, '/tf_static',
                                                         TF_STATIC_QOS)

    def check_types(self):
        """Say once, for each agent's cmd_vel and each other type seen on it, that commands
        of that type never arrive, and which setting takes them.

        Why: DDS matches a publisher only with subscriptions of its own type, so a
        TwistStamped sent to a world that takes Twist (Jazzy's diff_drive_controller takes
        only TwistStamped, Nav2 sends it with enable_stamped_cmd_vel, teleop_twist_keyboard
        sends Twist) is dropped without a word on either side. One graph query a period
        (all topics and their types) covers every agent.
        """
        if self._io is None:
            return
        expected = self._message_type.__module__.split('.')[0] + '/msg/' + \
            self._message_type.__name__
        wanted = {self._io.resolve_topic_name(f'{name}/cmd_vel'): name for name in self._topics}
        for topic, types in self._io.get_topic_names_and_types():
            if topic not in wanted:
                continue
            for other in types:
                if other == expected or (topic, other) in self._hinted:
                    continue
                self._hinted.add((topic, other))
                setting = 'true' if other.endswith('TwistStamped') else 'false'
                self.node.get_logger().warning(
                    f'{topic} has a {other} endpoint, but this world takes {expected} there: '
                    f'those commands never reach agent {wanted[topic]} (start the world with '
                    f'-p agent.cmd_vel_stamped:={setting} to take {other})')

    def _publisher(self, message_type, topic):
        return self._io.create_publisher(
            message_type, topic, ODOM_QOS,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))

    def destroy(self, budget=LEAVE_BUDGET):
        """Leave the graph (the world node is closing), within `budget` wall seconds.

        Entity by entity, the subscriptions first (they are what publishers of cmd_vel look
        for), then the publishers. Why a budget: with FastDDS each destruction costs in
        proportion to the entities left in the participant (measured 2026-12-02: 1,000
        agents' 4,000 entities took 23-44 s publishers first, 8 s subscriptions first; see
        docs/agents.md), so stopping at 10,000 agents took minutes. What is left when the
        budget is spent goes with the process: the node is exiting, and its participant's
        end tells the other participants (at the latest when its lease runs out).
        """
        if self._io is None:
            return
        self._drop_drains()
        self._survey = None
        deadline = time.monotonic() + budget
        node = self._io
        entities = self._topics.values()
        work = ([(node.destroy_subscription, e.cmd_vel) for e in entities]
                + [(node.destroy_publisher, p) for e in entities for p in e.all()])
        for done, (destroy, entity) in enumerate(work):
            if time.monotonic() > deadline:
                self.node.get_logger().info(
                    f'stopping: {len(work) - done:,} agent topics left to the process exit '
                    f'(over {budget:g} s leaving the graph one by one)')
                self._io = None
                return
            destroy(entity)
        self._topics = {}
        node.destroy_node()
        self._io = None

    def names(self):
        """The resolved topic names of the agents' topics."""
        node = self._io
        if node is None:
            return []
        return [node.resolve_topic_name(f'{name}/{topic}') for name in self._topics
                for topic in ('cmd_vel', 'odom', 'ground_truth', 'bumper')]

    def take(self, name, data):
        """One cmd_vel message for agent `name`: decoded, checked, given to the Simulation."""
        try:
            try:
                linear_x, linear_y, _, _, _, angular_z = self._decode(data)
            except ValueError as error:
                self.simulation.count_rejection('cmd_vel_malformed_message')
                raise CommandRejected('malformed_message', f'undecodable cmd_vel: {error}')
            self.simulation.command(name, linear_x, linear_y, angular_z, bytes(data))
        except CommandRejected as rejection:
            now = time.monotonic()
            if now - self._warned_at >= WARN_PERIOD:
                self._warned_at = now
                counts = self.simulation.rejected
                total = sum(v for k, v in counts.items() if k.startswith('cmd_vel_'))
                self.node.get_logger().warning(
                    f'refused cmd_vel for {name} ({rejection.reason}; {total} refused so far):'
                    f' {rejection}')

    def drain(self):
        """Take every waiting command, in arrival order per agent, before a step.

        As the node does for impulses: the executor hands over one message per wait, too
        few for a flood; take_message is what it calls itself (rclpy Jazzy). Which
        subscriptions hold a message is asked of one rcl wait set (waited on with a zero
        timeout, without the GIL) rather than by a take from each: at 1,000 robots every
        step looked at 1,000 subscriptions, and the empty takes (about 2 us each while DDS
        is busy) made the drain half of the node's main thread; the wait set costs a third
        less (py-spy of the node, 2026-12-08, docs/performance.md). Handles are used without
        rclpy's `with handle:` guard, which keeps another thread from destroying one
        meanwhile: only sync() and destroy() destroy them, on this thread, and they drop
        the wait set first.
        """
        if self._io is None:
            return
        if self._drains is None:
            self._drains = _CommandWaits(self._io.context, (
                (name, entities.cmd_vel) for name, entities in self._topics.items()))
        take = self.take
        for name, handle, message_type in self._drains.ready():
            taken = handle.take_message(message_type, True)
            while taken is not None:
                take(name, taken[0])
                taken = handle.take_message(message_type, True)

    def _drop_drains(self):
        if self._drains is not None:
            self._drains.close()
            self._drains = None

    def publish(self, record, tf=True):
        """Publish a step's odom and ground truth of every agent, its bumpers, scans and /tf,
        and /tf_static when it changed. tf False holds /tf back (the node publishes it
        later, publish_tf: a reset's first /tf waits for its /clock, see ros/node.py)."""
        frame = record.agents
        if frame is None or not frame.topics:
            return
        if self._tf is None or len(self._topics) != len(frame.names) or any(
                name not in self._topics for name in frame.names):
            self.sync()
        topics = self._topics
        for scan in frame.scans:
            entities = topics[scan.name]
            if entities.scan is None:  # scanners turned on by a reset
                entities.scan = self._publisher(LaserScan, f'{scan.name}/scan')
                self._survey = None
        self._look_at_subscribers()
        listened = self._listened
        for kind, messages in ((kinds.ODOM, frame.odom_cdr),
                               (kinds.GROUND_TRUTH, frame.ground_truth_cdr)):
            wanted = listened[kind]
            if wanted and messages:
                for name, data in zip(frame.names, messages):
                    if name in wanted:
                        getattr(topics[name], kind).publish(data)
        bumped = listened[kinds.BUMPER]
        if bumped:  # (a step's Bumpers are made only when someone reads them)
            for bumper in frame.bumpers:
                if bumper.name in bumped:
                    topics[bumper.name].bumper.publish(bumper.cdr)
        if self._bumper_markers.get_subscription_count():
            markers = bumper_markers(record, self.simulation.frame_id)
            if markers is not None:
                self._bumper_markers.publish(markers)
        for scan in frame.scans:
            if scan.name in listened[kinds.SCAN]:
                topics[scan.name].scan.publish(scan.cdr)
        if frame.tf_static_cdr is not None:
            self._tf_static.publish(frame.tf_static_cdr)
        if tf:
            self.publish_tf(record)
        self._tell_what_is_taken()

    def _look_at_subscribers(self):
        """Look at the subscriber counts of the next SURVEY_PER_STEP per-agent publishers."""
        if self._survey is None:
            # The publishers' rcl handles, asked without rclpy's `with handle:` guard (as
            # drain takes): only sync() and destroy() destroy them, on this thread, and they
            # drop this list first.
            self._survey = [(name, kind, publisher.handle)
                            for name, entities in self._topics.items()
                            for kind, publisher in entities.by_kind()]
            self._cursor = 0
            for names in self._listened.values():
                names.intersection_update(self._topics)
        survey = self._survey
        if not survey:
            return
        count = len(survey)
        for offset in range(min(count, SURVEY_PER_STEP)):
            name, kind, handle = survey[(self._cursor + offset) % count]
            if handle.get_subscription_count():
                self._listened[kind].add(name)
            else:
                self._listened[kind].discard(name)
        self._cursor = (self._cursor + SURVEY_PER_STEP) % count

    def _tell_what_is_taken(self):
        """The kinds of agent message the next step must make: all when recording, else
        those someone subscribes to (AgentPart.encode)."""
        agents = self.simulation.agents
        if self.recording:
            agents.encode = None
            return
        taken = {kind for kind, names in self._listened.items() if names}
        if self._tf is not None and self._tf.get_subscription_count():
            taken.add(kinds.TF)
        agents.encode = frozenset(taken)

    def publish_tf(self, record):
        """Publish a step's /tf (every odom -> base_link), if it has one."""
        if record.agents is not None and record.agents.tf_cdr and self._tf is not None:
            self._tf.publish(record.agents.tf_cdr)


class _CommandWaits:
    """The cmd_vel subscriptions of the agents, and the rcl wait set that tells which hold a
    message (AgentTopics.drain)."""

    def __init__(self, context, subscriptions):
        self._entries = [(name, subscription.handle, subscription.msg_type)
                         for name, subscription in subscriptions]
        self._by_pointer = {handle.pointer: (name, handle, message_type)
                            for name, handle, message_type in self._entries}
        with context.handle:
            self._wait_set = rclpy_implementation.WaitSet(len(self._entries), 0, 0, 0, 0, 0,
                                                          context.handle)

    def ready(self):
        """[(name, handle, message type)] of the subscriptions holding a message now, in
        agent order (none without agents: rcl refuses to wait on nothing)."""
        if not self._entries:
            return []
        wait_set = self._wait_set
        wait_set.clear_entities()
        add = wait_set.add_subscription
        for _, handle, _ in self._entries:
            add(handle)
        wait_set.wait(0)
        by_pointer = self._by_pointer
        return [by_pointer[pointer] for pointer in wait_set.get_ready_entities('subscription')]

    def close(self):
        """Let the wait set go (before its subscriptions or the context do)."""
        self._wait_set.clear_entities()
        self._wait_set.destroy_when_not_in_use()
        self._entries = []
        self._by_pointer = {}
