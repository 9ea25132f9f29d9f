"""The ball_world node: a thin ROS 2 shell around a Simulation.

It owns no physics and no file format. It declares the parameters, steps the Simulation
on a steady-clock schedule, publishes each step's ready-made CDR bytes, turns impulse
messages into queued impulses (or counted rejections), serves ~/reset, ~/pause and
~/step, and hands every step to the recording sinks.
"""
import difflib
import math
import os
from pathlib import Path
import signal
import sys
import threading
import time

from geometry_msgs.msg import PoseArray, Vector3Stamped
from nav_msgs.msg import OccupancyGrid
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks
import rclpy.logging
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ball_world.core import parameters as table
from ball_world.core.agents import frame_clash
from ball_world.core.alloc import tune_allocator
from ball_world.core.exact import EventBudgetExceeded
from ball_world.core.impulses import check_impulse, ImpulseRejected
from ball_world.core.pacing import MAX_LAG, steps_due
from ball_world.core.scenario import describe, ScenarioError, step_duration_ns
from ball_world.core.stepping import SubstepLimitExceeded
from ball_world.msgs.cdr import decode_vector3_stamped, encode_clock
from ball_world.msgs.map_cdr import encode_occupancy_grid
from ball_world.msgs.markers import MarkerBuilder
from ball_world.recording.writer_thread import BackgroundSink
from ball_world.ros.agents import AgentTopics, TYPE_CHECK_PERIOD
from ball_world.ros.calls import SERVICE_QOS
from ball_world.ros.parameters import converted, current_values, declare_all, ParameterError
from ball_world.ros.rcl_init import creating_node, init_quietly
from ball_world.ros.sim_interfaces import ACTION, SimulationInterfaces
from ball_world.ros.stopping import stopped_by_signal
from ball_world.simulation import build, Simulation
from ball_world.user_code.controller import ControllerProcess
from ball_world.user_code.describe import UserCodeError

#: Seconds between the node's progress lines (achieved rate, real-time factor, impulses).
REPORT_PERIOD = 10.0
#: A step's publishing that takes this long (s) is said in the next progress line.
SLOW_PUBLISH = 0.25
#: Seconds between flushes of the recordings: what a SIGKILL can lose at most.
FLUSH_PERIOD = 1.0
#: Largest share of wall time the RViz markers may take (they are costly at 10,000 balls).
MARKERS_SHARE = 0.05
#: Impulses buffered by the subscription before DDS would have to drop any.
IMPULSE_QUEUE_DEPTH = 100_000
#: Impulses taken from the subscription before one step, at most: a flood (accepted or
#: rejected alike) delays a step by at most this many impulses' work; the rest wait, in
#: order, in the subscription's queue for the next steps (60,000/s at 60 Hz).
MAX_IMPULSES_PER_STEP = 1000
#: Seconds between two warnings about rejected impulses; the rejections in between are only
#: counted (and named in the next warning and in the progress line), which costs nothing.
REJECTION_WARNING_PERIOD = 5.0
#: Longest wait of the stepping timer, s: slower rates are kept by a due time, so any rate
#: down to 1e-300 Hz is a valid timer (rcl timers hold at most 2^63 ns).
MAX_TIMER_PERIOD = 0.1
#: Wall seconds a segment's first /clock (at start and after a reset) waits after the last
#: /tf, and its first /tf after that /clock, at least: the time jump must reach a
#: use_sim_time client (and clear its tf2 buffer) after the old timeline's transforms and
#: before the new one's. See _release_held and docs/clock_and_tf.md.
TF_HOLD = 0.05

STEP_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
MARKER_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
#: What nav2_map_server offers on map: reliable, transient local, so RViz, Foxglove and a
#: Nav2 costmap that subscribe late still get it.
MAP_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Edits are few and each matters: reliable, with room for a burst of spawns.
EDITS_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
IMPULSE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=IMPULSE_QUEUE_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE)

#: The node's own topics and services (relative names, resolved in the start-up line).
TOPICS_OUT = ('balls', 'state', 'stats', 'markers', 'edits', 'entity_names')
TOPICS_IN = ('impulse',)
SERVICES = ('~/reset', '~/pause', '~/step')

USAGE = """usage: ball_world [--ros-args -p NAME:=VALUE ... --params-file FILE -r __ns:=/NS]

An exact 2D elastic-collision world as a ROS 2 node. Publishes balls (PoseArray), state,
stats and markers; takes impulses (Vector3Stamped, header.frame_id = ball name) on impulse;
services ~/reset, ~/pause, ~/step. Parameters (ros2 param describe shows each in full):
"""


class StartupError(Exception):
    """The node cannot start; the message is the one line to print."""


def open_sinks(values):
    """The recording sinks the parameters ask for, opened now so a bad path fails at start.

    Each file is claimed first (recording.files): an existing one needs record.overwrite,
    and a symlink, one that is not a regular file, is being recorded by another process, or
    is the other recording's file is refused. With a split parameter set, record.mcap is a
    bag directory and record.rerun names the parts of a split .rrd, which follow the MCAP's
    files when both are recorded (recording.rrd_parts).
    """
    from ball_world.recording.files import claim_output, ClaimedSink
    from ball_world.recording.split_writer import open_split_sink, splits, unused_max_files
    logger = rclpy.logging.get_logger('ball_world')
    unused = unused_max_files(values)
    if unused:
        logger.warning(unused)
    split = splits(values)
    claims = []
    sinks = []
    name = None
    try:
        for name in ('record.mcap', 'record.rerun'):
            if not values[name]:
                continue
            if name == 'record.mcap' and split:
                # a bag directory of split files: the sink claims it (and is the claim)
                claims.append((name, open_split_sink(values, logger.info, logger.error)))
            elif split:
                claims.append((name, _rrd_parts(values, 'record.mcap' not in dict(claims))))
            else:
                claims.append((name, claim_output(values[name], values['record.overwrite'],
                                                  'set record.overwrite:=true', claims)))
        claimed = dict(claims)
        if 'record.mcap' in claimed:
            from ball_world.recording.mcap_writer import McapSink
            mcap = claimed['record.mcap']
            sinks.append(BackgroundSink(mcap if split else McapSink(mcap)))
        rerun_file = claimed.get('record.rerun')
        if split and rerun_file is not None:
            if 'record.mcap' in claimed:
                claimed['record.mcap'].follower = rerun_file  # split at the MCAP's steps
            else:
                sinks.append(rerun_file)
            rerun_file = None
        if rerun_file is not None or values['view.rerun']:
            from ball_world.recording.rerun_log import RerunSink
            name = 'record.rerun' if rerun_file else 'view.rerun'
            sink = RerunSink(
                rerun_file, view=values['view.rerun'] or None,
                view_recording_id=values['view.recording_id'] or None, **_rerun_options(values),
                file_process=True)  # the SDK's index of a long file grows: not in the node
            sinks.append(ClaimedSink(sink, rerun_file) if rerun_file else sink)
    except ValueError as error:  # the only value a RerunSink checks is the view
        _abandon_sinks(sinks, claims)
        raise StartupError(f"parameter 'view.rerun': {error}") from None
    except OSError as error:
        _abandon_sinks(sinks, claims)
        raise StartupError(f"parameter '{name}': cannot record to {error}") from None
    return sinks


def recording_line(values):
    """'recording to /abs/runs/scan.mcap and /abs/runs/scan.rrd' (where a run's files go,
    absolute: a newcomer finds them whatever the working directory), or None."""
    paths = [str(Path(values[name]).resolve()) for name in ('record.mcap', 'record.rerun')
             if values[name]]
    if not paths:
        return None
    from ball_world.recording.split_writer import splits
    split = ' (split: a bag directory and .rrd parts beside it)' if splits(values) else ''
    return f"recording to {' and '.join(paths)}{split}"


def _rerun_options(values):
    """The Rerun sink's options the parameters give (besides where it writes)."""
    return dict(every=values['record.rerun_every'], velocities=values['rerun.velocities'],
                trail_seconds=values['rerun.trail_seconds'], clock=time.monotonic,
                report=rclpy.logging.get_logger('ball_world').error)


def _rrd_parts(values, alone):
    """The parts of a split .rrd (recording.rrd_parts); alone: no split MCAP to follow."""
    from ball_world.recording.rrd_parts import RrdParts
    from ball_world.recording.split_writer import SplitRule
    rule = SplitRule(values['record.max_bytes'], values['record.max_seconds']) if alone \
        else None
    options = _rerun_options(values)
    del options['report']  # a file alone: its failure is the sink's, reported as any
    return RrdParts(values['record.rerun'], rule, values['record.max_files'],
                    values['record.overwrite'], rclpy.logging.get_logger('ball_world').info,
                    **options)


def _abandon_sinks(sinks, claims):
    """A start that failed: close what was opened (nothing recorded: each removes the file
    it created) and give up the claims not yet handed to a sink."""
    opened = set()
    for sink in sinks:
        opened.add(id(getattr(sink, 'sink', sink)))
        sink.close()
    for _, claim in claims:
        if id(claim) in opened:
            continue
        if hasattr(claim, 'discard'):
            claim.discard()
        else:
            claim.close()


class BallWorld(Node):
    """Steps the world at rate_hz and speaks ROS for it."""

    def __init__(self, **kwargs):
        self._sinks = []
        self._node_made = False
        self.controller = None  # user_code.controller.ControllerProcess, with `controller`
        self.exit_code = 0  # 1 when the controller failed
        try:
            self._start(**kwargs)
        except BaseException:
            self._abandon()
            raise

    def _abandon(self):
        """A start cut short (a signal, an error) leaves no stub behind: a recording that has
        its first segment is closed complete, one that has nothing yet is removed (as a bad
        path's is), so the next run is not refused for a file this one never wrote.

        The node is destroyed here too. Left to the garbage collector, it would be destroyed
        whenever a collection runs, on whatever thread holds the GIL then, and the last
        node of a context takes its DDS participant with it: Fast DDS then waits for the
        participant's listener, whose thread may be waiting for the GIL (a test process
        hung so)."""
        simulation = getattr(self, 'simulation', None)
        if simulation is not None:
            simulation.close()
        else:
            for sink in self._sinks:
                sink.close()
        if self.controller is not None:
            self.controller.close()
        if self._node_made:
            self.destroy_node()

    def _start(self, **kwargs):
        with creating_node('ball_world'):  # says why, if DDS never lets it join the graph
            super().__init__('ball_world', **kwargs)
        self._node_made = True
        try:
            # rclpy keeps the command line's and files' values here; they are converted and
            # checked against the parameter table before anything is declared.
            unknown = declare_all(self, self._parameter_overrides)
        except ParameterError as error:
            raise StartupError(str(error)) from None
        for name in unknown:
            close = difflib.get_close_matches(name, table.BY_NAME, n=1)
            self.get_logger().warning(f"ignoring unknown parameter '{name}'" + (
                f"; did you mean '{close[0]}'?" if close else ''))
        values = current_values(self)
        failures = []
        topics = {name: self.resolve_topic_name(name)
                  for name in ('balls', 'state', 'stats', 'impulse', 'edits', 'markers')}
        try:
            # The world first: a start refused for its parameters creates no file, and a
            # signal while a large world builds leaves none half-written.
            built = build(values)
        except ScenarioError as error:
            raise StartupError(str(error)) from None
        if values['controller']:
            # Before any file is opened: a controller that cannot be made records nothing.
            try:
                self.controller = ControllerProcess(values['controller'])
            except UserCodeError as error:
                raise StartupError(f"parameter 'controller': {error}") from None
        sinks = self._sinks = open_sinks(values)
        self.simulation = Simulation(values, sinks, topics=topics,
                                     on_sink_failure=failures.append, built=built,
                                     controller=self.controller)
        if failures:
            # A recording that fails on its first segment is a bad path, not a run-time fault.
            self.simulation.close()
            sink = getattr(failures[0].sink, 'sink', failures[0].sink)
            name = 'record.mcap' if type(sink).__name__ in ('McapSink', 'SplitMcapSink') \
                else 'record.rerun'
            raise StartupError(f"parameter '{name}': cannot record to {values[name]}: "
                               f'{failures[0].error}')
        self.simulation.on_sink_failure = self._on_sink_failure

        self.balls_pub = self.create_publisher(
            PoseArray, 'balls', STEP_QOS, event_callbacks=PublisherEventCallbacks(
                matched=self._on_balls_matched))
        self._slowest_publish = 0.0  # s, the longest publish of a step in this window
        self.state_pub = self.create_publisher(Float64MultiArray, 'state', STEP_QOS)
        self.stats_pub = self.create_publisher(Float64MultiArray, 'stats', STEP_QOS)
        self.markers_pub = self.create_publisher(MarkerArray, 'markers', MARKER_QOS)
        self.clock_pub = self.create_publisher(ClockMsg, '/clock', CLOCK_QOS)
        self.edits_pub = self.create_publisher(String, 'edits', EDITS_QOS)
        self.entities_pub = self.create_publisher(String, 'entity_names', MARKER_QOS)
        self.map_pub = None
        if self.simulation.occupancy_map is not None:
            self.map_pub = self.create_publisher(OccupancyGrid, 'map', MAP_QOS)
        self._impulse_sub = self.create_subscription(
            Vector3Stamped, 'impulse', self._on_impulse, IMPULSE_QOS, raw=True)
        # Calls that take long (a reset builds its world on a thread) run as coroutines in
        # their own group: while one waits, the default group's timers, subscription and
        # services go on (rclpy holds a whole mutually exclusive group while a coroutine of
        # it is pending). _wake resumes a waiting coroutine without waiting for a timer.
        self.long_calls = MutuallyExclusiveCallbackGroup()
        self._wake = self.create_guard_condition(lambda: None)
        self.create_service(Trigger, '~/reset', self._on_reset, qos_profile=SERVICE_QOS,
                            callback_group=self.long_calls)
        self.create_service(SetBool, '~/pause', self._on_pause, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, '~/step', self._on_step, qos_profile=SERVICE_QOS)
        self.interfaces = SimulationInterfaces(self)
        self.agent_topics = AgentTopics(self, values['agent.cmd_vel_stamped'],
                                        recording=bool(values['record.mcap']))
        self.add_pre_set_parameters_callback(converted)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._rejection_warning_due = 0.0
        self._rejections_unwarned = 0
        self.paused = values['start_paused']
        self.finished = False
        self.steps_done = 0
        self._resetting = False
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._markers = MarkerBuilder()
        self._markers_next = 0.0
        self._markers_timer = None
        self._world_edited()
        self._timer = None
        self._schedule(values['rate_hz'])
        self._set_markers_rate(values['markers.rate_hz'])
        self.create_timer(FLUSH_PERIOD, self.simulation.flush, clock=self._steady)
        self.create_timer(REPORT_PERIOD, self._report, clock=self._steady)
        self.create_timer(TYPE_CHECK_PERIOD, self.agent_topics.check_types, clock=self._steady)
        self._window = (time.monotonic(), 0)
        self._start_wall = time.monotonic()
        self._held = []  # ('clock' or 'tf', record) not published yet: see _release_held
        self._publish(self.simulation.last_record, first=True)
        self._publish_map()
        summary, names = self._startup_lines(values)
        self.get_logger().info(summary)
        recorded = recording_line(values)
        if recorded:
            self.get_logger().info(recorded)
        self.get_logger().debug(names)

    def _startup_lines(self, values):
        """Two lines: the world and the rate (info), and every name the node speaks on
        (debug: `--ros-args --log-level ball_world:=debug` shows it)."""
        simulation = self.simulation
        published = [self.resolve_topic_name(name) for name in TOPICS_OUT]
        if self.map_pub is not None:
            published.append(self.resolve_topic_name('map'))
        if values['publish_clock']:
            published.append('/clock')
        services = [self.resolve_service_name(name) for name in SERVICES]
        standard = ', '.join(self.interfaces.names)
        occupancy_map = simulation.occupancy_map
        map_text = '' if occupancy_map is None else f'; map {occupancy_map.describe()}'
        if self.controller is not None:
            driven = values['controller.agents'] or simulation.agents.names
            map_text += (f"; controller {values['controller']} at "
                         f"{values['controller.rate_hz']:g} Hz driving {len(driven):,} agents")
        summary = (f'world: {describe(simulation.world, simulation.dt_ns)}{map_text}; rate '
                   f"{values['rate_hz']:g} Hz{' (paused at step 0)' if self.paused else ''}; "
                   f'node {self.get_fully_qualified_name()}')
        names = (f"publishing {', '.join(published)}; subscribed to "
                 f"{', '.join(self.resolve_topic_name(name) for name in TOPICS_IN)}; services "
                 f"{', '.join(services)}; simulation_interfaces services "
                 f'{self.get_fully_qualified_name()}/{{{standard}}} and action '
                 f"{self.resolve_service_name('~/' + ACTION)}")
        return summary, names

    # Stepping ---------------------------------------------------------------------------

    def _schedule(self, rate_hz):
        """Step every 1 / rate_hz s of wall time (0: as fast as possible).

        Step k is due at a fixed time (core/pacing.py); each tick of the timer takes the
        steps due by then, so ticks missed while the process was busy are made up, up to
        pacing.MAX_LAG s; beyond that the lag is dropped and said so. Periods up to
        MAX_TIMER_PERIOD are the timer's own; longer ones are checked at that period, so a
        rate of 1e-300 Hz waits rather than crashing.
        """
        period = 0.0 if rate_hz == 0.0 else 1.0 / rate_hz
        self._step_period = period
        self._next_due = None  # the schedule starts at the next tick: start-up is no lag
        self._tick = min(period, MAX_TIMER_PERIOD)
        tick_ns = int(self._tick * 1e9)
        if self._timer is None:
            self._dropped_steps = 0
            self._timer = self.create_timer(tick_ns * 1e-9, self._on_timer, clock=self._steady)
        else:
            self._timer.timer_period_ns = tick_ns

    def _on_timer(self):
        if self._held and not self._release_held():
            return  # no step before the segment's first /clock and /tf are out
        if self.paused or self.finished:
            return
        now = time.monotonic()
        if self._next_due is None:  # the first tick: the first step is a period after start
            self._next_due = now + self._step_period - self._tick
        take, self._next_due, dropped = steps_due(
            now, self._next_due, self._step_period, self._tick)
        if dropped:
            self._dropped_steps += dropped
            self.get_logger().warning(
                f'more than {MAX_LAG:g} s behind the {1.0 / self._step_period:g} Hz schedule: '
                f'dropped {dropped} steps of wall time ({self._dropped_steps} so far); '
                'the world costs more than its rate or the machine is busy',
                throttle_duration_sec=REPORT_PERIOD, throttle_time_source_type=self._steady)
        for _ in range(take):
            if self.paused or self.finished:
                return
            self._drain_impulses()
            self.agent_topics.drain()
            self.step_once()

    def _drain_impulses(self):
        """Take the impulses waiting in the subscription, in arrival order, before a step.

        The executor hands over one message per wait, which caps a flood at a few thousand
        impulses a second; taking them here in a loop keeps up with tens of thousands, so
        none waits behind its step or is dropped. At most MAX_IMPULSES_PER_STEP are taken:
        a flood faster than that is spread over the next steps rather than holding this one
        back. take_message is what the executor itself calls (rclpy Jazzy).
        """
        subscription = self._impulse_sub
        with subscription.handle:
            for _ in range(MAX_IMPULSES_PER_STEP):
                taken = subscription.handle.take_message(subscription.msg_type, True)
                if taken is None:
                    return
                self._on_impulse(taken[0])

    def step_once(self):
        """Advance one step, publish it, stop at max_steps or at the end of ROS time."""
        while self._held:  # a step asked for: the segment's first /clock and /tf go first
            self._release_held(now=math.inf)
        simulation = self.simulation
        if simulation.out_of_time:
            self.get_logger().info(
                f'simulation time {simulation.stamp_ns / 1e9:.6g} s: one more step would pass '
                'the last time a ROS stamp can carry (2^31 s); stopping')
            self.finished = True
            return simulation.last_record
        elapsed = time.monotonic() - self._start_wall
        simulated = (simulation.step_index + 1) * simulation.dt_ns * 1e-9
        rtf = simulated / elapsed if elapsed > 0 else None
        try:
            record, rejected = simulation.step(real_time_factor=rtf)
        except UserCodeError as error:
            # The controller failed (agents/control.py): the run ends, its recording whole
            # up to the last step taken, and the node exits 1.
            self.get_logger().error(f'step {simulation.step_index + 1}: {error}; stopping')
            self.finished = True
            self.exit_code = 1
            return simulation.last_record
        except (SubstepLimitExceeded, EventBudgetExceeded) as error:
            # Only a world built to jam (a ball wedged between walls) gets here. Stepping
            # stops until a reset; the node stays up and keeps answering.
            self.get_logger().error(f'step {simulation.step_index + 1} cannot be taken: '
                                    f'{error}; paused (change the world and call ~/reset)')
            self.paused = True
            return simulation.last_record
        for rejection in rejected:
            self._warn_rejection(rejection)
        self._publish(record)
        self.steps_done += 1
        max_steps = self.get_parameter('max_steps').value
        if max_steps and simulation.step_index >= max_steps:
            self.get_logger().info(f'max_steps {max_steps} reached at t = '
                                   f'{record.stamp_ns / 1e9:.6g} s; stopping')
            self.finished = True
        return record

    def _publish(self, record, first=False):
        """Publish a step: /clock first, then the step's topics and /tf.

        A segment's first record (first: at start, after a reset) is the simulation time
        jumping back: its /clock and /tf are held (_release_held) so that a use_sim_time
        client handles the jump after every /tf of the old timeline and before any of the new.
        """
        began = time.monotonic()
        clock = self.get_parameter('publish_clock').value
        hold = first and clock and record.agents is not None
        if clock and not hold:
            self.clock_pub.publish(encode_clock(record.stamp_ns))
        self.balls_pub.publish(record.balls_cdr)
        self.state_pub.publish(record.state_cdr)
        self.stats_pub.publish(record.stats_cdr)
        self.agent_topics.publish(record, tf=not hold)
        # The /clock twice: a client that loses one (it takes /clock best effort, depth 1)
        # still sees the jump before the /tf.
        self._held = [('clock', record), ('clock', record), ('tf', record)] if hold else []
        self._held_due = time.monotonic() + TF_HOLD
        self._slowest_publish = max(self._slowest_publish, time.monotonic() - began)

    def _release_held(self, now=None):
        """Publish the held /clock, then the held /tf, each once its time has come; return
        whether nothing is held any more.

        Why: DDS does not order two topics, and a client's executor takes the subscriptions
        that are ready in an order of its own (rclpy: the node's first subscription first,
        which for a use_sim_time node is /clock). Sent together, the /clock that jumps back
        could be handled before the old timeline's last /tf, or after the new one's first:
        either way a use_sim_time tf2 buffer, which clears itself at the jump, ends up
        holding transforms of the other timeline (dropped as TF_OLD_DATA, or kept and
        looked up as the latest). Held TF_HOLD apart, and to timer ticks (no step is taken
        meanwhile), each goes out after the one before it has had time to arrive; the
        /clock twice, since clients take it best effort (rclpy's and rclcpp's TimeSource).
        """
        now = time.monotonic() if now is None else now
        while self._held and now >= self._held_due:
            kind, record = self._held.pop(0)
            if kind == 'clock':
                self.clock_pub.publish(encode_clock(record.stamp_ns))
            else:
                self.agent_topics.publish_tf(record)
            self._held_due = now + TF_HOLD
        return not self._held

    def _publish_map(self):
        """Publish the segment's /map (latched: transient local), if the world has a map.

        The bytes are the Simulation's, encoded once at the segment start, unless frame_id
        changed since: then the map goes out again in the new frame.
        """
        simulation = self.simulation
        if self.map_pub is None or simulation.map_cdr is None:
            return
        data = simulation.map_cdr
        if simulation.frame_id != simulation.parameters['frame_id']:
            data = encode_occupancy_grid(0, simulation.frame_id, simulation.occupancy_map)
        self.map_pub.publish(data)

    def _on_balls_matched(self, info):
        """A subscriber of `balls` came or went (DDS matched or unmatched it): said, so that
        a subscriber that stops hearing the world can tell whether the node still counts
        it (docs/reliability.md, "The probe that stopped hearing balls")."""
        change = info.current_count_change
        if change:
            what = 'a subscriber joined' if change > 0 else 'a subscriber left'
            self.get_logger().info(f'{self.balls_pub.topic_name}: {what} '
                                   f'({info.current_count} now)')

    # Markers ----------------------------------------------------------------------------

    def _rebuild_markers(self):
        world = self.simulation.world
        self._markers.reset(world.radii, world.walls.segments, self.simulation.frame_id)
        self.markers_pub.publish(self._markers.delete_all())

    def _publish_markers(self):
        """Publish the markers, unless that would take more than MARKERS_SHARE of the time.

        rclpy converts a MarkerArray of 10,000 spheres in about 0.2 s, so at the requested
        rate large worlds would starve stepping; the node then publishes less often.
        """
        now = time.monotonic()
        if now < self._markers_next:
            return
        simulation = self.simulation
        self.markers_pub.publish(self._markers.build(
            simulation.world.positions, simulation.stamp_ns))
        self._markers_next = now + (time.monotonic() - now) / MARKERS_SHARE

    def _set_markers_rate(self, rate_hz):
        if self._markers_timer is not None:
            self.destroy_timer(self._markers_timer)
            self._markers_timer = None
        if rate_hz > 0.0:
            self._publish_markers()
            self._markers_timer = self.create_timer(1.0 / rate_hz, self._publish_markers,
                                                    clock=self._steady)

    # Impulses ---------------------------------------------------------------------------

    def _on_impulse(self, data):
        simulation = self.simulation
        try:
            try:
                stamp_ns, frame_id, x, y, z = decode_vector3_stamped(data)
            except ValueError as error:
                raise ImpulseRejected('malformed_message', f'undecodable impulse: {error}')
            _, jx, jy = check_impulse(
                frame_id, x, y, z, simulation.index_of, stamp_ns, simulation.stamp_ns,
                time.time_ns())
        except ImpulseRejected as rejection:
            simulation.count_rejection(rejection.reason)
            self._warn_rejection(rejection)
            return
        simulation.queue_impulse(frame_id, jx, jy)

    def _warn_rejection(self, rejection):
        """Warn about a rejected impulse, at most once per REJECTION_WARNING_PERIOD.

        The throttle is checked before anything is formatted or handed to rclpy: its
        logger's own throttle costs about 0.7 ms a call even when it suppresses, which made
        a flood of bad impulses cost far more than a flood of good ones.
        """
        now = time.monotonic()
        if now < self._rejection_warning_due:
            self._rejections_unwarned += 1
            return
        self._rejection_warning_due = now + REJECTION_WARNING_PERIOD
        more, self._rejections_unwarned = self._rejections_unwarned, 0
        count = self.simulation.rejected.get(rejection.reason, 0)
        self.get_logger().warning(
            f'rejected impulse ({rejection.reason}, {count} so far): {rejection}'
            + (f'; {more:,} more rejected since the last warning' if more else ''))

    # Services ---------------------------------------------------------------------------

    async def _on_reset(self, request, response):
        response.success, response.message = await self.reset_world()
        return response

    async def reset_world(self):
        """Rebuild the world from the current parameters, back to step 0: (ok, message).

        The world is built on a worker thread (the largest takes about a second), so the
        node keeps stepping the old world and answering until the new one is ready; it is
        swapped in between two steps. Impulses queued for the old world are discarded and
        counted. Callers run in the long-calls group (see __init__).
        """
        if self._resetting:
            return False, 'a reset is already in progress'
        self._resetting = True
        try:
            built = await self._build_in_background(current_values(self))
        except ScenarioError as error:
            return False, f'reset refused, world unchanged: {error}'
        except Exception as error:  # noqa: B902 - a fault of the build must not kill the node
            message = f'reset failed, world unchanged: {error!r}'
            self.get_logger().error(message)
            return False, message
        finally:
            self._resetting = False
        record = self.simulation.reset(None, built=built)
        discarded = self.simulation.last_discarded
        self._start_wall = time.monotonic()
        self._next_due = None  # the new world's schedule starts at the next tick
        self._world_edited()
        self._publish(record, first=True)
        self._publish_map()
        message = (f'reset to step 0: {describe(self.simulation.world, self.simulation.dt_ns)}'
                   f"; discarded {discarded} queued impulse{'' if discarded == 1 else 's'}")
        self.get_logger().info(message)
        return True, message

    def edit(self, change):
        """Apply a world edit (a Simulation method, via `change`) and tell the world about it.

        change() returns (value, impulses rejected on the way); the value is returned. The
        edit goes out on `edits` at once; a change of the set of balls also goes out on
        `entity_names` and in the markers.
        """
        simulation = self.simulation
        names = simulation.names
        done = len(simulation.pending_edits)
        value, rejected = change()
        for rejection in rejected:
            self._warn_rejection(rejection)
        for applied in simulation.pending_edits[done:]:
            self.edits_pub.publish(String(data=applied.text))
        if simulation.names is not names:
            self._world_edited()
        return value

    def _world_edited(self):
        """Balls appeared or went (or a reset): names and markers follow."""
        self.entities_pub.publish(String(data='\n'.join(self.simulation.names)))
        self.agent_topics.sync()
        self._rebuild_markers()
        if self._markers_timer is not None:
            self._markers_next = 0.0
            self._publish_markers()

    def set_paused(self, paused):
        """Pause or resume stepping; returns whether it was paused before."""
        was = self.paused
        self.paused = bool(paused)
        if not self.paused and was:
            # Resume the real-time factor and the schedule from now, not from before.
            simulated = self.simulation.step_index * self.simulation.dt_ns * 1e-9
            self._start_wall = time.monotonic() - simulated
            self._next_due = time.monotonic()
        return was

    def quit(self, reason):
        """End the run as max_steps does: the main loop stops and closes the recordings."""
        self.get_logger().info(f'{reason}: stopping at step {self.simulation.step_index}')
        self.finished = True

    def wake(self):
        """Make the executor look again at once (resumes a waiting long call)."""
        self._wake.trigger()

    def _build_in_background(self, values):
        """An rclpy Future of build(values), computed on a worker thread.

        The thread wakes the executor when it is done, so the awaiting service resumes at
        once rather than at the next timer tick.
        """
        future = Future()

        occupancy_map = self.simulation.occupancy_map  # `map` is read-only: loaded once

        def work():
            try:
                future.set_result(build(values, occupancy_map))
            except Exception as error:  # noqa: B902 - every outcome must reach the service
                future.set_exception(error)
            self._wake.trigger()

        threading.Thread(target=work, name='ball_world-reset', daemon=True).start()
        return future

    def _on_pause(self, request, response):
        was = self.set_paused(request.data)
        state = 'paused' if self.paused else 'running'
        response.success = True
        response.message = (f'already {state}' if was == self.paused else state) + \
            f' at step {self.simulation.step_index}'
        return response

    def _on_step(self, request, response):
        if not self.paused:
            response.success = False
            response.message = 'not paused: call ~/pause with data: true first'
            return response
        if self.finished:
            response.success = False
            response.message = 'the run has finished (max_steps or the end of ROS time)'
            return response
        self._drain_impulses()
        self.agent_topics.drain()
        record = self.step_once()
        response.success = True
        response.message = f'step {record.step} at t = {record.stamp_ns / 1e9:.9g} s'
        return response

    # Parameters -------------------------------------------------------------------------

    def _on_set_parameters(self, parameters):
        """Refuse values outside the table's ranges, with the reason; apply the rest.

        Each value is checked on its own here. How world parameters fit together (six
        balls.* lists of one length, balls inside the arena...) is checked when ~/reset
        builds the world, so they can be changed one at a time from the command line.
        """
        changes = {}
        for item in parameters:
            parameter = table.BY_NAME.get(item.name)
            if parameter is None:
                continue
            try:
                changes[item.name] = parameter.check(item.value)
            except table.ParameterError as error:
                return SetParametersResult(successful=False, reason=str(error))
        candidate = {**current_values(self), **changes}
        if 'rate_hz' in changes or 'dt' in changes:
            try:
                step_duration_ns(candidate)
            except ScenarioError as error:
                return SetParametersResult(successful=False, reason=str(error))
        clash = 'frame_id' in changes and frame_clash(
            changes['frame_id'], str(candidate['frame_prefix']), set(self.simulation.agents.names))
        if clash:
            return SetParametersResult(successful=False, reason=f"parameter 'frame_id': {clash}")
        if 'rate_hz' in changes:
            self._schedule(changes['rate_hz'])
            self._window = (time.monotonic(), self.steps_done)
        if 'frame_id' in changes:
            self.simulation.frame_id = changes['frame_id']
            self._rebuild_markers()
            self._publish_map()
        if 'markers.rate_hz' in changes:
            self._set_markers_rate(changes['markers.rate_hz'])
        return SetParametersResult(successful=True)

    # Reporting and recording ------------------------------------------------------------

    def _report(self):
        start, steps = self._window
        now = time.monotonic()
        rate = (self.steps_done - steps) / (now - start)
        simulation = self.simulation
        rtf = rate * simulation.dt_ns * 1e-9
        rejected = sum(simulation.rejected.values())
        detail = ', '.join(f'{k} {v}' for k, v in sorted(simulation.rejected.items()))
        self.get_logger().info(
            f'step {simulation.step_index}: {rate:.1f} steps/s, real-time factor {rtf:.3f}; '
            f'impulses applied {simulation.applied}'
            + (f" (and {simulation.drive_applied} by the agents' drives)"
               if len(simulation.agents) or simulation.drive_applied else '')
            + f', rejected {rejected}'
            + (f' ({detail})' if detail else '')
            + f', discarded by reset {simulation.discarded}'
            + f'; balls subscribers {self.balls_pub.get_subscription_count()}'
            + (' [paused]' if self.paused else ''))
        if self._slowest_publish >= SLOW_PUBLISH:
            # rmw_fastrtps publishes synchronously: a send that blocks holds stepping up
            self.get_logger().warning(
                f'publishing a step took up to {self._slowest_publish:.2f} s in the last '
                f'{REPORT_PERIOD:g} s: the middleware could not send it at once (a '
                'subscriber not taking the data, or a full socket buffer)')
        self._slowest_publish = 0.0
        self._window = (now, self.steps_done)

    def _on_sink_failure(self, failure):
        sink = getattr(failure.sink, 'sink', failure.sink)  # the one a BackgroundSink wraps
        self.get_logger().error(
            f'recording to {type(sink).__name__} stopped: {failure.error}; the simulation '
            'goes on without it')

    def destroy_node(self):
        """Leave the graph now, the action server with the rest (see
        SimulationInterfaces.destroy); a second call does nothing more."""
        interfaces = getattr(self, 'interfaces', None)
        if interfaces is not None:
            interfaces.destroy()
        super().destroy_node()

    def close(self):
        """Finish the recordings (called on every way out); say in all how far behind its
        schedule the node fell, if it did (the warnings while it ran are throttled).

        Returns that last word when it cannot be said here: after Ctrl-C the context is
        gone, and a line logged through the node's logger, whose /rosout publisher cannot
        publish any more, makes rcl print an error of its own; the caller says it."""
        waited = sum(getattr(sink, 'waited', 0.0) for sink in self._sinks)
        self.simulation.close()
        self.agent_topics.destroy()
        if self.controller is not None:
            self.controller.close()
        dropped = getattr(self, '_dropped_steps', 0)
        if not dropped:
            return None
        # The rate may have changed since (rate_hz is set at run time; 0: no schedule).
        schedule = (f'the {1.0 / self._step_period:g} Hz schedule' if self._step_period
                    else 'its schedule')
        summary = (f'in all, {dropped} steps of wall time were dropped behind {schedule} (the '
                   'world kept every step it took, and the recordings hold them all)'
                   + (f'; the recordings held stepping back for {waited:.1f} s: their writer '
                      'could not keep up' if waited >= 0.1 else ''))
        if not self.context.ok():
            return summary
        self.get_logger().warning(summary)
        return None


def usage():
    """--help: what the node does and every parameter with its default and range."""
    lines = [USAGE]
    for parameter in table.PARAMETERS:
        default = parameter.default if parameter.default != '' else '""'
        lines.append(f'  {parameter.name} ({parameter.kind}, default {default}'
                     + (f'; {parameter.range_text()}' if parameter.range_text() else '')
                     + f'): {parameter.description}')
    return '\n'.join(lines)


def ignored_arguments(own):
    """The warning for arguments before --ros-args, which rclpy never reads.

    `ball_world -p rate_hz:=30` would otherwise run at the default rate without a word.
    """
    hint = ' '.join(own) if any(':=' in arg for arg in own) else '-p NAME:=VALUE'
    return (f"ball_world: warning: ignoring {' '.join(own)!r}: ROS arguments go after "
            f'--ros-args, e.g. ball_world --ros-args {hint}')


def run(args=None):
    """Start the node and spin until shutdown or max_steps; return the exit code.

    Recordings are closed with SIGINT and SIGTERM blocked, so a second Ctrl-C cannot cut a
    file short while its summary is being written.
    """
    argv = sys.argv if args is None else args
    own = argv[1:argv.index('--ros-args')] if '--ros-args' in argv else argv[1:]
    if '-h' in own or '--help' in own:
        print(usage())
        return 0
    if own:
        print(ignored_arguments(own), file=sys.stderr)
    tune_allocator()
    refused = init_quietly(args)  # rcl's own [ERROR] lines held back: one line of ours
    if refused is not None:
        print(f'ball_world: cannot start: {refused}', file=sys.stderr)
        return 2
    node = None
    code = 0
    try:
        with stopped_by_signal():
            node = BallWorld()
            while rclpy.ok() and not node.finished:
                rclpy.spin_once(node, timeout_sec=0.1)
            if rclpy.ok():  # QUITTING or max_steps: answer the calls and goals still running
                node.interfaces.finish(lambda: rclpy.spin_once(node, timeout_sec=0.05))
            code = node.exit_code
    except StartupError as error:
        print(f'ball_world: {error}', file=sys.stderr)
        code = 2
    finally:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        if node is not None:
            unsaid = node.close()
            node.destroy_node()
            if unsaid:  # a logger of another name, which has no /rosout publisher to fail
                rclpy.logging.get_logger(f'{node.get_logger().name}.exit').warning(unsaid)
        rclpy.try_shutdown()
    return code


def main(args=None):
    code = run(args)
    # Everything is closed by now. Leave without the interpreter's teardown: a recording
    # stream abandoned after a failure (a full disk) may abort the process if a destructor
    # touches it, which would turn a clean exit into SIGABRT.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == '__main__':
    main()
