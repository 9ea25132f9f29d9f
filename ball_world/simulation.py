"""A run without ROS: the World, its clock, named balls, impulses, edits and sinks.

The node is a thin ROS shell around a Simulation; re-simulation and tests drive the same
class directly. Keeping the clock, the order of impulses and edits and the record layout
here is what makes a live run and its re-simulation bit-identical.

A world with a map is built from the map's bytes (core.occupancy_map), read from its files
once (map_files) or taken from a recording: every reset of a run uses the same map.
"""
from collections import deque
from dataclasses import dataclass
import json
import math

import numpy as np

from ball_world import __version__
from ball_world.agents.part import AgentPart, check as check_agents
from ball_world.core import lidar, limits
from ball_world.core.agents import CommandRejected
from ball_world.core.edits import (check_placement, check_speeds, EditRefused, Entities,
                                   INVALID_POSE, MAX_SPAWN_BATCH, NAME_INVALID, Neighbours,
                                   TOO_MANY)
from ball_world.core.impulses import ImpulseRejected, lookup_ball, velocity_after
from ball_world.core.limits import MAX_SIM_TIME_NS
from ball_world.core.occupancy_map import MapError
from ball_world.core.parameters import checked
from ball_world.core.scenario import build_scene, ScenarioError, step_duration_ns
from ball_world.core.world import World
from ball_world.msgs.cdr import (encode_float64_vector, encode_pose_array, encode_state,
                                 encode_vector3_stamped)
from ball_world.msgs.map_cdr import encode_occupancy_grid
from ball_world.step_record import (AppliedEdit, AppliedImpulse, DriveBatch, impulses_of,
                                    PendingEvents, RunInfo, STATS_FIELDS, StepRecord,
                                    WorldSnapshot)
from ball_world.user_code.describe import UserCodeError

DEFAULT_TOPICS = {'balls': '/balls', 'state': '/state', 'stats': '/stats',
                  'impulse': '/impulse', 'edits': '/edits'}


@dataclass(frozen=True)
class SpawnRequest:
    """One ball to spawn: the name asked for (or ''), and the ball (core.edits.Ball)."""

    name: str
    allow_renaming: bool
    ball: object
    agent: bool = False  # the new ball is an agent (core.agents)


@dataclass(frozen=True)
class BuiltWorld:
    """A world built from parameters, not yet in use: building may run on another thread."""

    parameters: dict
    world: object
    dt_ns: int
    occupancy_map: object = None  # core.occupancy_map.OccupancyMap, when `map` names one
    cells: object = None  # its core.solid_cells.CellQueries


def load_map(parameters):
    """The OccupancyMap `map` names, read from its files (None for no map).

    Raises ScenarioError naming `map` with the one line map_files gives: the node's start
    refuses a missing image or a bad YAML as it refuses any other parameter.
    """
    path = checked(parameters)['map']
    if not path:
        return None
    from ball_world.map_files import load_map_file
    try:
        return load_map_file(path)
    except MapError as error:
        raise ScenarioError('map', str(error)) from None


def build(parameters, occupancy_map=None):
    """Check the parameters and build their world (raises ScenarioError).

    occupancy_map: the map `map` names, already loaded (the node's, or a recording's copy);
    when None and `map` names one, it is read from its files here.
    """
    parameters = checked(parameters)
    if parameters['map'] and occupancy_map is None:
        occupancy_map = load_map(parameters)
    elif not parameters['map']:
        occupancy_map = None
    world, cells = build_scene(parameters, occupancy_map)
    agents = check_agents(parameters, len(world))
    if (agents and occupancy_map is not None and int(parameters['agent.scan.samples'])
            and world.backend == 'numba'):
        # The compiled lidar's free squares of the map, built with the world, not by the
        # first scan (an agent spawned later into a world without agents builds them then).
        lidar.prepare_grid(world.static.scan_grid)
    return BuiltWorld(parameters=parameters, world=world, dt_ns=step_duration_ns(parameters),
                      occupancy_map=occupancy_map, cells=cells)


def _ignore(events):
    """write_pending of a sink that does not record edits (a viewer, a test's collector)."""


@dataclass(frozen=True)
class SinkFailure:
    """A sink that raised and was dropped, so the simulation could go on without it."""

    sink: object
    error: Exception


class Simulation:
    """Steps a World at a fixed dt and hands every step to its sinks, in order.

    Step k ends at simulation time k * dt_ns. Step 0 is the initial state. Impulses queued
    between two steps are applied, in arrival order, just before the next one, and are
    recorded with that step's stamp. Edits (spawn, delete, set_state) are applied when they
    are made, between two steps, after the impulses that arrived before them, and recorded
    with the next step's stamp too.
    """

    def __init__(self, parameters, sinks=(), topics=None, on_sink_failure=None, built=None,
                 occupancy_map=None, controller=None):
        self.sinks = list(sinks)
        # The controller (user_code.controller.ControllerProcess, or any object whose
        # act(Observation) returns checked (N, 3) commands), or None; its agents refuse
        # cmd_vel. A re-simulation has none: it takes the commands from the recording.
        self.controller = controller
        # The map every build of this run uses (a recording's copy in re-simulation), so a
        # reset never reads the map's files again.
        self.occupancy_map = occupancy_map if built is None else built.occupancy_map
        self.topics = dict(topics or DEFAULT_TOPICS)
        self.on_sink_failure = on_sink_failure
        self.segment = -1
        self.log_offset_ns = 0
        self.last_log_ns = None
        self.rejected = {}
        self.applied = 0  # impulses from outside (the impulse topic, services)
        self.drive_applied = 0  # impulses of the agents' drives
        self.discarded = 0
        self._queue = deque()
        self.reset(parameters, built)

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
            built = build(parameters, self.occupancy_map)
        self._hand_over_pending()
        parameters, world, dt_ns = built.parameters, built.world, built.dt_ns
        self.parameters = parameters
        self.world = world
        self.dt_ns = dt_ns
        self.frame_id = str(parameters['frame_id'])
        self.occupancy_map = built.occupancy_map
        self.cells = built.cells
        # /map of the segment: encoded once, at its start (step 0's simulation time).
        self.map_cdr = None if built.occupancy_map is None else encode_occupancy_grid(
            0, self.frame_id, built.occupancy_map)
        self.entities = Entities(len(world))
        self._names = tuple(self.entities.names)
        # The agents as one part (ball_world.agents): their drive, odometry, bumpers, scans
        # and frames, made from the parameters; the Simulation orders its calls.
        self.agents = AgentPart(parameters, check_agents(parameters, len(world)),
                                controlled=self.controller is not None)
        self._drive = None  # the agents' impulses for the next step, once applied
        self._world_changed = False
        self._applied = []  # impulses applied since the last step (and DriveBatches)
        self._batched = 0  # impulses the DriveBatches of _applied hold beyond one each
        self._edits = []  # edits applied since the last step
        self.step_index = 0
        self.last_discarded = len(self._queue)
        self.discarded += self.last_discarded
        self._queue.clear()
        self.segment += 1
        if self.last_log_ns is not None:
            self.log_offset_ns = self.last_log_ns + dt_ns
        info = RunInfo(parameters=dict(parameters), topics=dict(self.topics),
                       segment=self.segment, log_offset_ns=self.log_offset_ns,
                       package_version=__version__, backend=world.backend)
        snapshot = WorldSnapshot(
            radii=world.radii.copy(), masses=world.masses.copy(),
            walls=world.walls.segments.copy(), positions=world.positions.copy(),
            velocities=world.velocities.copy(), dt_ns=dt_ns, frame_id=self.frame_id,
            names=self._names, occupancy_map=self.occupancy_map, map_cdr=self.map_cdr)
        self._each_sink(lambda sink: sink.start_segment(snapshot, info))
        return self.record(stats=None)

    def resume(self, parameters, state, segment, log_offset_ns):
        """Continue a recorded segment where a split file starts (re-simulation only).

        state: recording.resume.ResumeState, the world at the end of step state.step. Walls,
        backend and mode come from the parameters; the balls, their names and the agents
        (headings, last commands) from the state, and in exact mode the predictions step
        state.step handed the next (state.exact), so that the steps from here are bit for
        bit the recorded run's. Raises ValueError for balls or an exact-mode state the
        World refuses. Meant for a Simulation without sinks.
        """
        built = build(parameters, self.occupancy_map)
        base = built.world
        world = World(state.positions.copy(), state.velocities.copy(), state.radii.copy(),
                      state.masses.copy(), walls=base.walls.segments, backend=base.backend,
                      mode=base.mode, solid_cells=base.solid_cells)
        if state.exact is not None:
            world.restore_carried_state(state.exact)
        # The agents are the state's (the parameters name those the segment began with).
        self.reset({**built.parameters, 'agents': []},
                   BuiltWorld({**built.parameters, 'agents': []}, world, built.dt_ns,
                              built.occupancy_map, built.cells))
        self.parameters = built.parameters
        self.entities = Entities.restored(state.names, state.retired, len(base))
        self._names = tuple(self.entities.names)
        self.agents.balls_moved()
        commands = dict(state.commands)
        odometry_poses = dict(zip(state.agents, state.odometry or ()))
        covariances = dict(zip(state.agents, state.odometry_covariances or ()))
        for name, yaw in zip(state.agents, state.yaws):
            self.agents.restore(name, yaw, commands.get(name), odometry_poses.get(name),
                                covariances.get(name))
        self.step_index = state.step
        self.segment = segment
        self.log_offset_ns = log_offset_ns

    @property
    def names(self):
        """The balls' entity names, in the order of the World's arrays and of `balls`."""
        return self._names

    @property
    def pending_edits(self):
        """Edits applied since the last step (recorded with the next one), in order."""
        return tuple(self._edits)

    @property
    def index_of(self):
        """Entity name -> index in the World's arrays."""
        return self.entities.index_of

    @property
    def stamp_ns(self):
        """Simulation time of the current step, integer nanoseconds."""
        return self.step_index * self.dt_ns

    @property
    def out_of_time(self):
        """Whether the next step would end past the last time a ROS stamp can carry."""
        return (self.step_index + 1) * self.dt_ns > MAX_SIM_TIME_NS

    def close(self):
        """Finish every sink's file, with the edits made since the last step."""
        self._hand_over_pending()
        self._each_sink(lambda sink: sink.close())
        self.sinks = []

    def pending_events(self):
        """The impulses and edits applied since the last step, as PendingEvents."""
        step = self.step_index + 1
        stamp_ns = step * self.dt_ns
        return PendingEvents(step=step, stamp_ns=stamp_ns,
                             log_time_ns=self.log_offset_ns + stamp_ns,
                             impulses=impulses_of(self._applied), edits=tuple(self._edits))

    def _hand_over_pending(self):
        """At the end of a segment (close, reset): record what changed after its last step.

        Edits, and the impulses they applied, are recorded with the next step; when no
        step comes they go to the sinks as PendingEvents (write_pending), at the log time
        that step would have had, which the next segment's log times then follow.
        """
        if self.segment < 0 or not (self._applied or self._edits):
            return
        events = self.pending_events()
        self._applied = []
        self._batched = 0
        self._edits = []
        self.last_log_ns = events.log_time_ns
        self._each_sink(lambda sink: getattr(sink, 'write_pending', _ignore)(events))

    def flush(self):
        """Make what the sinks hold durable."""
        self._each_sink(lambda sink: sink.flush())

    # Impulses ---------------------------------------------------------------------------

    def queue_impulse(self, frame_id, jx, jy):
        """Queue a checked impulse (see impulses.check_impulse) for the next step.

        The ball is found by name when the impulse is applied: an edit in between may have
        moved it in the arrays, or deleted it (then the impulse is rejected as unknown_ball).
        """
        self._queue.append((frame_id, jx, jy))

    @property
    def queued(self):
        return len(self._queue)

    def count_rejection(self, reason):
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def apply_queued(self):
        """Apply the queued impulses in order now; returns the rejected ones.

        Called before each step and before each edit, so impulses and edits take effect in
        the order they arrived. Applied impulses are recorded with the next step.
        """
        return self._apply(self._queue)

    def _apply(self, queue, drive=False):
        """Apply the impulses of `queue` (a deque, emptied) in order; returns rejections.

        drive: they are the agents' drive's (counted in drive_applied, marked so).
        """
        world = self.world
        rejected = []
        if not queue:
            return rejected
        stamp_ns = (self.step_index + 1) * self.dt_ns
        limit = world.speed_limit(self.dt_ns * 1e-9)
        energy = world.kinetic_energy()
        lightest = float(world.masses.min()) if len(world) else 1.0
        while queue:
            frame_id, jx, jy = queue.popleft()
            try:
                ball = lookup_ball(frame_id, self.index_of)
                _, _, energy = velocity_after(world.velocities, world.masses, ball, jx, jy,
                                              limit, energy, lightest)
            except ImpulseRejected as rejection:
                self.count_rejection(rejection.reason)
                rejected.append(rejection)
                continue
            world.apply_impulse(ball, jx, jy)
            if drive:
                self.drive_applied += 1
            else:
                self.applied += 1
            self._applied.append(AppliedImpulse(
                ball=ball, jx=jx, jy=jy, frame_id=frame_id,
                cdr=encode_vector3_stamped(stamp_ns, frame_id, jx, jy, 0.0), drive=drive))
        return rejected

    # Agents -----------------------------------------------------------------------------

    def command(self, name, vx, vy, wz, cdr=b''):
        """Give agent `name` a body-frame velocity command, in force from the next step.

        Raises CommandRejected (counted in `rejected` as cmd_vel_<reason>) for an unknown
        agent or a bad command. Taken commands are recorded with the next step, as `cdr`
        (the message as received), or encoded here when given in code.
        """
        try:
            if self.controller is not None and self.agents.controlled(name):
                raise CommandRejected('controlled', f'{name[:64]} is driven by the controller '
                                                    '(parameter controller.agents)')
            self.agents.command(name, vx, vy, wz, (self.step_index + 1) * self.dt_ns, cdr)
        except CommandRejected as rejection:
            self.count_rejection('cmd_vel_' + rejection.reason)
            raise

    def control(self):
        """Ask the controller for its agents' commands when it is due (after step k,
        before step k + 1: agents/control.py); they are in force from the next step and
        recorded with it, as cmd_vel is. step() does it first.

        Raises UserCodeError (one line) for a controller that fails or returns commands
        cmd_vel would refuse; the step is then not taken.
        """
        if self.controller is None:
            return
        observation = self.agents.observe(self.world, self.index_of, self.step_index,
                                          self.dt_ns)
        if observation is None:
            return
        commands = self.controller.act(observation)
        try:
            self.agents.command_many(observation.names, commands,
                                     (self.step_index + 1) * self.dt_ns)
        except CommandRejected as rejection:
            raise UserCodeError(f'controller {self.parameters["controller"]} returned a '
                                f'command at t = {observation.time:.9g} s that cmd_vel '
                                f'would refuse: {rejection}') from None

    def apply_drive(self):
        """Apply the agents' impulses for the next step now, once: (applied, rejected).

        They are computed from the velocities at this moment and applied before the
        impulses still queued. step() does it itself; re-simulation calls it first to learn
        how many of a step's recorded impulses are the drive's (they follow those applied
        by the step's edits and precede the rest).
        """
        if self._drive is not None:  # already applied for this step
            return 0, []
        end_ns = (self.step_index + 1) * self.dt_ns
        self._drive = balls, jx, jy, names = self.agents.drive(self.world, self.index_of,
                                                               self.dt_ns, end_ns)
        before = self._applied_count()
        if len(names) >= 2 and self._apply_at_once(balls, jx, jy, names):
            rejected = []
        else:
            rejected = self._apply(deque(zip(names, jx.tolist(), jy.tolist())), drive=True)
        return self._applied_count() - before, rejected

    def _applied_count(self):
        """How many impulses were applied since the last step (a DriveBatch counts each)."""
        return len(self._applied) + self._batched

    def _apply_at_once(self, balls, jx, jy, names):
        """Apply the drive's impulses (distinct balls) together, if each would pass alone.

        The checks are velocity_after's, in the same order and arithmetic (the energy
        accumulated impulse by impulse), so the outcome is that of applying them one by one;
        when any would be refused this returns False and leaves everything to _apply.
        """
        world = self.world
        masses = world.masses[balls]
        old = world.velocities[balls]
        with np.errstate(over='ignore', invalid='ignore'):
            vx = old[:, 0] + jx / masses
            vy = old[:, 1] + jy / masses
            changes = 0.5 * masses * ((vx * vx + vy * vy)
                                      - (old[:, 0] * old[:, 0] + old[:, 1] * old[:, 1]))
            energies = np.add.accumulate(np.concatenate(([world.kinetic_energy()], changes)))
            reachable = np.sqrt(2.0 * np.maximum(energies[1:], 0.0)
                                / (float(world.masses.min())))
        limit = world.speed_limit(self.dt_ns * 1e-9)
        if not (np.isfinite(vx).all() and np.isfinite(vy).all()
                and np.isfinite(reachable).all() and (reachable <= limit).all()):
            return False
        world.apply_impulses(balls, jx, jy)
        stamp_ns = (self.step_index + 1) * self.dt_ns
        self.drive_applied += len(names)
        # One batch, no object per drive (step_record.AppliedImpulses); drives are neither
        # recorded (recording.agent_topics) nor published: a swarm's have no bytes, the
        # others' are made when someone reads them.
        self._applied.append(DriveBatch(balls.tolist(), jx.tolist(), jy.tolist(), names,
                                        stamp_ns if self.agents.each else None))
        self._batched += len(names) - 1
        return True

    # Edits ------------------------------------------------------------------------------

    @property
    def arena(self):
        """The arena box [xmin, ymin, xmax, ymax] balls must stay inside, or []."""
        return self.parameters['arena']

    def spawn(self, requests):
        """Add balls between steps; one result per request: its name, or the EditRefused.

        Requests are judged in order, each against the world and the balls spawned before
        it; those that pass are added together. Returns (results, rejected impulses).
        """
        requests = list(requests)
        if len(requests) > MAX_SPAWN_BATCH:
            raise EditRefused(TOO_MANY, f'{len(requests):,} balls in one request; at most '
                                        f'{MAX_SPAWN_BATCH:,} per call')
        rejected = self.apply_queued()
        world = self.world
        results = []
        accepted = []
        taken = set()
        energy = world.kinetic_energy()
        lightest = float(world.masses.min()) if len(world) else math.inf
        smallest = world.min_radius if len(world) else math.inf
        largest = float(world.radii.max()) if len(world) else 0.0
        near = Neighbours(world.positions, world.radii)
        placed = np.empty((len(requests), 3))
        agents_added = 0
        for request in requests:
            ball = request.ball
            try:
                if len(world) + len(accepted) >= limits.MAX_BALLS:
                    raise EditRefused(TOO_MANY, f'the world holds {limits.MAX_BALLS:,} balls, '
                                                'the most it can')
                most = self.agents.limit
                if request.agent and len(self.agents) + agents_added >= most:
                    raise EditRefused(TOO_MANY, f'the world has {most:,} agents, the most it '
                                                'can (parameter agents, agent.topics)')
                name = self.entities.new_name(request.name, request.allow_renaming, taken)
                clash = request.agent and self.agents.frame_clash(self.frame_id, name)
                if clash:
                    raise EditRefused(NAME_INVALID, f'an agent named {name}: {clash}')
                what = f"ball '{name}' at"
                check_placement(world, self.entities, self.arena, ball.x, ball.y,
                                ball.radius, what, near=near, cells=self.cells)
                self._check_against_new(ball, accepted, placed, what)
                low = min(smallest, ball.radius)
                high = max(largest, ball.radius)
                if high > limits.MAX_RADIUS_RATIO * low:
                    raise EditRefused(INVALID_POSE, f'radius {ball.radius:g} m: the radii would '
                                                    f'differ by more than '
                                                    f'{limits.MAX_RADIUS_RATIO:g} times')
                added = energy + 0.5 * ball.mass * (ball.vx * ball.vx + ball.vy * ball.vy)
                check_speeds(added, min(lightest, ball.mass), low, self.dt_ns, what[:-3])
            except EditRefused as refusal:
                results.append(refusal)
                continue
            energy, lightest, smallest, largest = added, min(lightest, ball.mass), low, high
            agents_added += bool(request.agent)
            taken.add(name)
            placed[len(accepted)] = ball.x, ball.y, ball.radius
            accepted.append((name, ball))
            results.append(name)
        if accepted:
            balls = [ball for _, ball in accepted]
            world.add_balls([(b.x, b.y) for b in balls], [(b.vx, b.vy) for b in balls],
                            [b.radius for b in balls], [b.mass for b in balls])
            self.entities.append([name for name, _ in accepted])
            agents = {name for name, request in zip(results, requests)
                      if request.agent and isinstance(name, str)}
            for name, ball in accepted:
                if name in agents:
                    self.agents.add(name)
                self._record_edit('spawn', name, ball.x, ball.y, ball.vx, ball.vy,
                                  ball.radius, ball.mass, agent=name in agents)
            self._changed()
        return results, rejected

    @staticmethod
    def _check_against_new(ball, accepted, placed, what):
        """Refuse a ball overlapping one accepted earlier in the request (placed: their x, y
        and radius, one row each, filled as they are accepted)."""
        if not accepted:
            return
        others = placed[:len(accepted)]
        dx = others[:, 0] - ball.x
        dy = others[:, 1] - ball.y
        reach = others[:, 2] + ball.radius
        hits = np.flatnonzero(dx * dx + dy * dy < reach * reach)
        if len(hits):
            raise EditRefused(INVALID_POSE, f'{what} ({ball.x:g}, {ball.y:g}) overlaps '
                                            f"ball '{accepted[hits[0]][0]}' of this request")

    def delete(self, name):
        """Remove the ball named `name` between steps; returns the rejected impulses."""
        index = self.entities.index(name)
        rejected = self.apply_queued()  # impulses never move a ball in the arrays
        self.world.remove_balls([index])
        self.entities.remove(index)
        self.agents.remove(name)
        self._record_edit('delete', name)
        self._changed()
        return rejected

    def set_state(self, name, x, y, vx, vy, yaw=None):
        """Put the ball named `name` at (x, y) with velocity (vx, vy); returns rejections.

        yaw (rad) sets an agent's heading; a plain ball has none (only yaw 0 is taken). The
        impulses queued before it are applied first, so its energy check meets the
        velocities the edit will really replace and keep (a refused edit leaves them
        applied, as the next step would have).
        """
        index = self.entities.index(name)
        if yaw is not None and name not in self.agents and yaw != 0.0:
            raise EditRefused(INVALID_POSE, f"'{name}' is a ball, not an agent: it has no "
                                            'heading to set (only the identity orientation)')
        if yaw is not None and not math.isfinite(yaw):
            raise EditRefused(INVALID_POSE, f'yaw {yaw} is not finite')
        rejected = self.apply_queued()
        world = self.world
        what = f"'{name}' at"
        radius = float(world.radii[index])
        for value in (vx, vy):
            if not math.isfinite(value):
                raise EditRefused(INVALID_POSE, f'velocity ({vx}, {vy}) is not finite')
        check_placement(world, self.entities, self.arena, x, y, radius, what, skip=index,
                        cells=self.cells)
        mass = float(world.masses[index])
        old = world.velocities[index]
        energy = world.kinetic_energy() + 0.5 * mass * (
            vx * vx + vy * vy - float(old[0] * old[0] + old[1] * old[1]))
        check_speeds(energy, float(world.masses.min()), world.min_radius, self.dt_ns,
                     f"'{name}'")
        world.set_ball_state(index, (x, y), (vx, vy))
        if name in self.agents and yaw is not None:
            self.agents.set_yaw(name, yaw)
            yaw = self.agents.yaw(name)
        else:
            yaw = None
        self._record_edit('set_state', name, x, y, vx, vy, yaw=yaw)
        return rejected

    def _record_edit(self, kind, name, x=0.0, y=0.0, vx=0.0, vy=0.0, radius=0.0, mass=0.0,
                     agent=False, yaw=None):
        fields = dict(kind=kind, name=name, x=float(x), y=float(y), vx=float(vx),
                      vy=float(vy), radius=float(radius), mass=float(mass),
                      impulses_before=self._applied_count())
        text_fields = dict(fields)
        if agent:  # only edits of agents carry these keys: other edits read as before
            text_fields['agent'] = True
        if yaw is not None:
            text_fields['yaw'] = float(yaw)
        self._edits.append(AppliedEdit(**fields, agent=agent, yaw=yaw,
                                       text=json.dumps(text_fields)))

    def _changed(self):
        self._names = tuple(self.entities.names)
        self._world_changed = True
        self.agents.balls_moved()

    # Stepping ---------------------------------------------------------------------------

    def step(self, real_time_factor=None):
        """Apply queued impulses, advance one step, write it to every sink.

        Returns (record, rejected impulses).
        """
        self.control()
        _, rejected = self.apply_drive()
        rejected += self.apply_queued()
        self._drive = None
        world = self.world
        self.agents.before_step(world, self.index_of)
        stats = world.step(self.dt_ns * 1e-9)
        self.step_index += 1
        self.agents.after_step(world, self.dt_ns, self.step_index)
        record = self.record(stats, real_time_factor)
        return record, rejected

    def record(self, stats, real_time_factor=None):
        """Pack the state, and what was applied since the last step, for every sink."""
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
            balls_cdr=encode_pose_array(positions, stamp_ns, self.frame_id,
                                        self.agents.headings(self.index_of)),
            state_cdr=encode_state(positions, velocities),
            stats_cdr=encode_float64_vector(
                (energy, momentum[0], momentum[1], ball_ball, ball_wall, rtf), STATS_FIELDS),
            impulses=impulses_of(self._applied), real_time_factor=real_time_factor,
            edits=tuple(self._edits), names=self._names, radii=world.radii,
            masses=world.masses, world_changed=self._world_changed,
            agents=self.agents.frame(world, self.index_of, positions, velocities,
                                     self.step_index, self.dt_ns, self.frame_id),
            commands=self.agents.take_commands(), exact=self._carried_state())
        self._applied = []
        self._batched = 0
        self._edits = []
        self._world_changed = False
        self.last_log_ns = record.log_time_ns
        self.last_record = record
        self._each_sink(lambda sink: sink.write_step(record))
        return record

    def _carried_state(self):
        """Exact mode's state for the next step (core.exact_carry), when a sink wants it: a
        split recording starts each file with it. Taken every step (a file may start after
        any, decided on the writer's thread later), only then: measured 0.04 ms a step at
        1,000 balls, 0.3-0.4 ms at 10,000 (docs/reliability.md)."""
        if self.world.mode != 'exact' or not any(
                getattr(sink, 'wants_carried_state', False) for sink in self.sinks):
            return None
        return self.world.carried_state()

    def _each_sink(self, action):
        """Run action on every sink; a sink that raises is dropped and reported once.

        A Ctrl-C that lands inside one sink's call (most of a step's fan-out: queueing the
        record for a writer thread) is raised only after the sinks after it had the action
        too, so the MCAP and the .rrd end on the same step.
        """
        interrupted = None
        for sink in list(self.sinks):
            try:
                action(sink)
            except KeyboardInterrupt as stop:
                interrupted = stop
            except Exception as error:  # noqa: B902 - any sink failure must not stop stepping
                self.sinks.remove(sink)
                if self.on_sink_failure is not None:
                    self.on_sink_failure(SinkFailure(sink, error))
                else:
                    raise
        if interrupted is not None:
            raise interrupted
