"""A run without ROS: the World, its integer-nanosecond clock, queued impulses and sinks.

The node is a thin ROS shell around a Simulation; re-simulation and tests drive the same
class directly. Keeping the clock, the impulse order and the record layout here is what
makes a live run and its re-simulation bit-identical.
"""
from collections import deque
from dataclasses import dataclass
import math

from ball_world import __version__
from ball_world.core.impulses import ImpulseRejected, velocity_after
from ball_world.core.limits import MAX_SIM_TIME_NS
from ball_world.core.parameters import checked
from ball_world.core.scenario import build_world, step_duration_ns
from ball_world.msgs.cdr import (encode_float64_vector, encode_pose_array, encode_state,
                                 encode_vector3_stamped)
from ball_world.step_record import AppliedImpulse, RunInfo, STATS_FIELDS, StepRecord, WorldSnapshot

DEFAULT_TOPICS = {'balls': '/balls', 'state': '/state', 'stats': '/stats',
                  'impulse': '/impulse'}


@dataclass(frozen=True)
class BuiltWorld:
    """A world built from parameters, not yet in use: building may run on another thread."""

    parameters: dict
    world: object
    dt_ns: int


def build(parameters):
    """Check the parameters and build their world (raises ScenarioError); touches nothing."""
    parameters = checked(parameters)
    return BuiltWorld(parameters=parameters, world=build_world(parameters),
                      dt_ns=step_duration_ns(parameters))


@dataclass(frozen=True)
class SinkFailure:
    """A sink that raised and was dropped, so the simulation could go on without it."""

    sink: object
    error: Exception


class Simulation:
    """Steps a World at a fixed dt and hands every step to its sinks, in order.

    Step k ends at simulation time k * dt_ns. Step 0 is the initial state. Impulses queued
    between two steps are applied, in arrival order, just before the next one, and are
    recorded with that step's stamp.
    """

    def __init__(self, parameters, sinks=(), topics=None, on_sink_failure=None):
        self.sinks = list(sinks)
        self.topics = dict(topics or DEFAULT_TOPICS)
        self.on_sink_failure = on_sink_failure
        self.segment = -1
        self.log_offset_ns = 0
        self.last_log_ns = None
        self.rejected = {}
        self.applied = 0
        self.discarded = 0
        self._queue = deque()
        self.reset(parameters)

    # Life cycle ------------------------------------------------------------------------

    def reset(self, parameters, built=None):
        """Rebuild the world from parameters, back to step 0 (raises ScenarioError).

        `built` is the result of build(parameters) when it was made beforehand (the node
        builds large worlds off its executor thread). Impulses queued for the old world are
        discarded and counted in `discarded`; the number is returned in `last_discarded`.
        Recordings go on: the new segment's log times continue after the last one, so a
        file never goes back in time.
        """
        if built is None:
            built = build(parameters)
        parameters, world, dt_ns = built.parameters, built.world, built.dt_ns
        self.parameters = parameters
        self.world = world
        self.dt_ns = dt_ns
        self.frame_id = str(parameters['frame_id'])
        self.names = [f'ball_{i}' for i in range(len(world))]
        self.index_of = {name: i for i, name in enumerate(self.names)}
        self.step_index = 0
        self.last_discarded = len(self._queue)
        self.discarded += self.last_discarded
        self._queue.clear()
        self.segment += 1
        if self.last_log_ns is not None:
            self.log_offset_ns = self.last_log_ns + dt_ns
        info = RunInfo(parameters=dict(parameters), topics=dict(self.topics),
                       segment=self.segment, log_offset_ns=self.log_offset_ns,
                       package_version=__version__)
        snapshot = WorldSnapshot(
            radii=world.radii.copy(), masses=world.masses.copy(),
            walls=world.walls.segments.copy(), positions=world.positions.copy(),
            velocities=world.velocities.copy(), dt_ns=dt_ns, frame_id=self.frame_id)
        self._each_sink(lambda sink: sink.start_segment(snapshot, info))
        return self.record(stats=None, impulses=())

    @property
    def stamp_ns(self):
        """Simulation time of the current step, integer nanoseconds."""
        return self.step_index * self.dt_ns

    @property
    def out_of_time(self):
        """Whether the next step would end past the last time a ROS stamp can carry."""
        return (self.step_index + 1) * self.dt_ns > MAX_SIM_TIME_NS

    def close(self):
        """Finish every sink's file."""
        self._each_sink(lambda sink: sink.close())
        self.sinks = []

    def flush(self):
        """Make what the sinks hold durable."""
        self._each_sink(lambda sink: sink.flush())

    # Impulses ---------------------------------------------------------------------------

    def queue_impulse(self, ball, jx, jy, frame_id):
        """Queue a checked impulse (see impulses.check_impulse) for the next step."""
        self._queue.append((ball, jx, jy, frame_id))

    @property
    def queued(self):
        return len(self._queue)

    def count_rejection(self, reason):
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def _apply_queued(self, stamp_ns):
        """Apply queued impulses in order; returns (applied, rejected) lists."""
        world = self.world
        applied = []
        rejected = []
        if not self._queue:
            return applied, rejected
        limit = world.speed_limit(self.dt_ns * 1e-9)
        energy = world.kinetic_energy()
        lightest = float(world.masses.min())
        while self._queue:
            ball, jx, jy, frame_id = self._queue.popleft()
            try:
                _, _, energy = velocity_after(world.velocities, world.masses, ball, jx, jy,
                                              limit, energy, lightest)
            except ImpulseRejected as rejection:
                self.count_rejection(rejection.reason)
                rejected.append(rejection)
                continue
            world.apply_impulse(ball, jx, jy)
            self.applied += 1
            applied.append(AppliedImpulse(
                ball=ball, jx=jx, jy=jy, frame_id=frame_id,
                cdr=encode_vector3_stamped(stamp_ns, frame_id, jx, jy, 0.0)))
        return applied, rejected

    # Stepping ---------------------------------------------------------------------------

    def step(self, real_time_factor=None):
        """Apply queued impulses, advance one step, write it to every sink.

        Returns (record, rejected impulses).
        """
        stamp_ns = (self.step_index + 1) * self.dt_ns
        applied, rejected = self._apply_queued(stamp_ns)
        stats = self.world.step(self.dt_ns * 1e-9)
        self.step_index += 1
        record = self.record(stats, tuple(applied), real_time_factor)
        return record, rejected

    def record(self, stats, impulses, real_time_factor=None):
        """Pack the current state as a StepRecord and write it to the sinks."""
        world = self.world
        stamp_ns = self.stamp_ns
        positions = world.positions.copy()
        velocities = world.velocities.copy()
        energy = world.kinetic_energy()
        momentum = world.momentum()
        ball_ball = stats.ball_ball if stats else 0
        ball_wall = stats.ball_wall if stats else 0
        rtf = math.nan if real_time_factor is None else real_time_factor
        record = StepRecord(
            step=self.step_index, stamp_ns=stamp_ns,
            log_time_ns=self.log_offset_ns + stamp_ns,
            positions=positions, velocities=velocities,
            ball_ball=ball_ball, ball_wall=ball_wall, kinetic_energy=energy, momentum=momentum,
            balls_cdr=encode_pose_array(positions, stamp_ns, self.frame_id),
            state_cdr=encode_state(positions, velocities),
            stats_cdr=encode_float64_vector(
                (energy, momentum[0], momentum[1], ball_ball, ball_wall, rtf), STATS_FIELDS),
            impulses=impulses, real_time_factor=real_time_factor)
        self.last_log_ns = record.log_time_ns
        self.last_record = record
        self._each_sink(lambda sink: sink.write_step(record))
        return record

    def _each_sink(self, action):
        """Run action on every sink; a sink that raises is dropped and reported once."""
        for sink in list(self.sinks):
            try:
                action(sink)
            except Exception as error:  # noqa: B902 - any sink failure must not stop stepping
                self.sinks.remove(sink)
                if self.on_sink_failure is not None:
                    self.on_sink_failure(SinkFailure(sink, error))
                else:
                    raise
