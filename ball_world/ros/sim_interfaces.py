"""The standard ROS 2 simulation interfaces (simulation_interfaces 1.5.1) of a ball world.

Why: Gazebo, Isaac Sim and O3DE implement this standard, so one test pipeline written
against it drives any of them; here it drives ball_world, for speed and exactness, unchanged.

What the standard means in a ball world:
- Entities are balls, of category DYNAMIC_OBJECT, named as core.edits says (`ball_<i>` for
  the balls a world starts with; names are never reused). GetSpawnables lists one spawnable,
  uri `ball`; SpawnEntity takes its radius, mass and velocity from resource_string (YAML or
  JSON, core.edits.RESOURCE_FORMAT) and its position from initial_pose.
- Poses are in the node's frame_id (header.frame_id empty or equal to it), in the z = 0
  plane, unrotated; twists are linear velocities in that plane. Anything else is refused
  with the standard's code and a message naming the problem; the world is then unchanged.
- Every edit is applied between two steps, after the impulses that arrived before it, and
  recorded (core.edits, simulation.Simulation), so a recording re-simulates exactly.
- The simulation is PLAYING, PAUSED, or STOPPED (= paused at step 0: after a start with
  start_paused, or a stop, which rebuilds the world from the parameters). QUITTING ends the
  node as max_steps does, recordings closed.
- ResetSimulation rebuilds the world from the parameters (scopes DEFAULT and ALL; time,
  state or spawned entities alone cannot be reset without breaking re-simulation).
- StepSimulation and the SimulateSteps action step a paused world; they go on step by step
  between other callbacks, and stop early if the world is resumed, stopped or reset.
- GetEntityBounds answers a ball's sphere: centre at its origin, x of the second point its
  radius.
Features not listed in FEATURES are answered with RESULT_FEATURE_UNSUPPORTED: filters by tags,
and the services of named poses, worlds and SetEntityInfo, which are served so that a client
written for a bigger simulator gets that answer at once instead of waiting for a service.
"""
import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Accel, Point, Pose, Quaternion, Twist, Vector3
import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import (Bounds, EntityCategory, EntityState, Result,
                                       SimulationState, SimulatorFeatures, Spawnable,
                                       SpawnResult)
from simulation_interfaces.srv import (DeleteEntity, GetAvailableWorlds, GetCurrentWorld,
                                       GetEntities, GetEntitiesStates, GetEntityBounds,
                                       GetEntityInfo, GetEntityState, GetNamedPoseBounds,
                                       GetNamedPoses, GetSimulationState, GetSimulatorFeatures,
                                       GetSpawnables, LoadWorld, ResetSimulation,
                                       SetEntityInfo, SetEntityState, SetSimulationState,
                                       SpawnEntities, SpawnEntity, StepSimulation, UnloadWorld)
from std_msgs.msg import Header

from ball_world.core import edits
from ball_world.core.name_filter import FilterRefused, NameFilter
from ball_world.core.parameters import number_text
from ball_world.ros.calls import _NextTurn, Calls, describe, SERVICE_QOS, Stranded
from ball_world.simulation import SpawnRequest

_F = SimulatorFeatures
#: Exactly what works, as GetSimulatorFeatures lists it.
FEATURES = (_F.SPAWNING, _F.DELETING, _F.ENTITY_CATEGORIES, _F.SPAWNING_RESOURCE_STRING,
            _F.ENTITY_STATE_GETTING, _F.ENTITY_STATE_SETTING, _F.ENTITY_INFO_GETTING,
            _F.SPAWNABLES, _F.SIMULATION_RESET, _F.SIMULATION_STATE_GETTING,
            _F.SIMULATION_STATE_SETTING, _F.SIMULATION_STATE_PAUSE, _F.STEP_SIMULATION_SINGLE,
            _F.STEP_SIMULATION_MULTIPLE, _F.STEP_SIMULATION_ACTION, _F.SPAWNING_ENTITIES,
            _F.ENTITY_BOUNDS)
#: Services of the standard for what a ball world does not have: (type, name, why), each
#: answered with RESULT_FEATURE_UNSUPPORTED and the reason.
UNSUPPORTED = (
    (GetNamedPoses, 'get_named_poses', 'a ball world has no named poses'),
    (GetNamedPoseBounds, 'get_named_pose_bounds', 'a ball world has no named poses'),
    (GetAvailableWorlds, 'get_available_worlds',
     'worlds are made from parameters (see ~/reset and reset_simulation), not loaded'),
    (GetCurrentWorld, 'get_current_world',
     'worlds are made from parameters (see ~/reset and reset_simulation), not loaded'),
    (LoadWorld, 'load_world',
     'worlds are made from parameters (see ~/reset and reset_simulation), not loaded'),
    (UnloadWorld, 'unload_world',
     'worlds are made from parameters (see ~/reset and reset_simulation), not loaded'),
    (SetEntityInfo, 'set_entity_info',
     'a ball is always a DYNAMIC_OBJECT described by its radius and mass'),
)
CATEGORY = EntityCategory.CATEGORY_DYNAMIC_OBJECT
#: |q| of a heading quaternion may differ from 1 by this much (float rounding of clients).
UNIT_QUATERNION_TOLERANCE = 1e-6
#: The node-private name of the standard's action (its services are listed in __init__).
ACTION = 'simulate_steps'
#: Steps a StepSimulation call or SimulateSteps goal takes before letting other callbacks in.
STEPS_PER_TURN = 8
#: Names matched, or states built, between two looks at the clock of a long answer.
CHUNK = 256
#: Answers with more entities than this are sent from a worker thread (see ros.calls).
LARGE_ANSWER = 2_000
#: Most items of a request a refusal or remark names (GetSpawnables' sources...).
ECHOED = 3

_SPAWN_CODES = {
    edits.NAME_NOT_UNIQUE: SpawnResult.NAME_NOT_UNIQUE,
    edits.NAME_INVALID: SpawnResult.NAME_INVALID,
    edits.NO_RESOURCE: SpawnResult.NO_RESOURCE,
    edits.UNSUPPORTED_FORMAT: SpawnResult.UNSUPPORTED_FORMAT,
    edits.NAMESPACE_INVALID: SpawnResult.NAMESPACE_INVALID,
    edits.RESOURCE_PARSE_ERROR: SpawnResult.RESOURCE_PARSE_ERROR,
    edits.INVALID_POSE: SpawnResult.INVALID_POSE,
    edits.TOO_MANY: Result.RESULT_OPERATION_FAILED,
    edits.NOT_FOUND: Result.RESULT_NOT_FOUND,
}


def category(agent):
    """An entity's EntityCategory: a robot for an agent, a dynamic object for a ball."""
    return EntityCategory.CATEGORY_ROBOT if agent else CATEGORY


def planar_yaw(z, w):
    """The yaw of the quaternion (0, 0, z, w), rad in [-pi, pi]."""
    return math.remainder(2.0 * math.atan2(z, w), 2.0 * math.pi)


def _result(code=Result.RESULT_OK, message=''):
    return Result(result=code, error_message=message)


def _unsupported(why):
    """A service callback that answers RESULT_FEATURE_UNSUPPORTED, saying why."""
    def answer(request, response):
        response.result = _result(Result.RESULT_FEATURE_UNSUPPORTED, why)
        return response
    return answer


# Requests to plain values ------------------------------------------------------------------

def _check_frame(frame_id, world_frame):
    if frame_id not in ('', world_frame):
        raise edits.EditRefused(edits.INVALID_POSE, f"frame '{frame_id[:64]}' is unknown; "
                                                    f"poses are in '{world_frame}'")


def planar_position(pose, frame_id, world_frame):
    """(x, y) of a Pose, which must lie in the z = 0 plane, unrotated, in the world frame."""
    _check_frame(frame_id, world_frame)
    p = pose.position
    q = pose.orientation
    if not all(math.isfinite(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w)):
        raise edits.EditRefused(edits.INVALID_POSE, 'the pose is not finite')
    if p.z != 0.0:
        raise edits.EditRefused(edits.INVALID_POSE, f'position z is {p.z:g}; balls live in '
                                                    'the z = 0 plane')
    if (q.x, q.y, q.z) != (0.0, 0.0, 0.0) or abs(q.w) != 1.0:
        raise edits.EditRefused(edits.INVALID_POSE, 'the orientation is a rotation; balls '
                                                    'are not rotated (use w = 1)')
    return p.x, p.y


def planar_pose(pose, frame_id, world_frame):
    """(x, y, yaw) of a Pose in the z = 0 plane, rotated about z only (an agent's heading)."""
    q = pose.orientation
    if all(math.isfinite(v) for v in (q.x, q.y, q.z, q.w)) and (q.x, q.y) == (0.0, 0.0) \
            and abs(math.hypot(q.z, q.w) - 1.0) <= UNIT_QUATERNION_TOLERANCE:
        turned = type(pose)()
        turned.position = pose.position
        turned.orientation.w = 1.0
        x, y = planar_position(turned, frame_id, world_frame)
        return x, y, planar_yaw(q.z, q.w)
    if all(math.isfinite(v) for v in (q.x, q.y, q.z, q.w)) and (q.x, q.y) == (0.0, 0.0):
        raise edits.EditRefused(edits.INVALID_POSE, 'the orientation is not a unit quaternion')
    x, y = planar_position(pose, frame_id, world_frame)
    return x, y, 0.0


def planar_velocity(twist):
    """(vx, vy) of a Twist, which must be linear and in the z = 0 plane."""
    linear, angular = twist.linear, twist.angular
    if not all(math.isfinite(v) for v in (linear.x, linear.y, linear.z, angular.x,
                                          angular.y, angular.z)):
        raise edits.EditRefused(edits.INVALID_POSE, 'the twist is not finite')
    if linear.z != 0.0 or (angular.x, angular.y, angular.z) != (0.0, 0.0, 0.0):
        raise edits.EditRefused(edits.INVALID_POSE, 'balls move in the z = 0 plane and do '
                                                    'not spin: linear.z and angular must be 0')
    return linear.x, linear.y


def spawn_request(name, allow_renaming, uri, resource_string, namespace, initial_pose,
                  world_frame):
    """A SpawnRequest from the fields SpawnEntity and SpawnEntities share."""
    if not uri and not resource_string:
        raise edits.EditRefused(edits.NO_RESOURCE, 'uri and resource_string are both empty; '
                                                   f"use uri '{edits.BALL_URI}'")
    if uri and uri != edits.BALL_URI:
        raise edits.EditRefused(edits.UNSUPPORTED_FORMAT, f"uri '{uri[:64]}' is not "
                                                          f"'{edits.BALL_URI}', the one "
                                                          'spawnable')
    if namespace:
        raise edits.EditRefused(edits.NAMESPACE_INVALID, 'balls have no ROS interfaces to '
                                                         'put in a namespace; leave it empty')
    radius, mass, (vx, vy), agent = edits.parse_spawn(resource_string)
    x, y = planar_position(initial_pose.pose, initial_pose.header.frame_id, world_frame)
    ball = edits.Ball(x=x, y=y, vx=vx, vy=vy, radius=radius, mass=mass)
    return SpawnRequest(name=name, allow_renaming=allow_renaming, ball=ball, agent=agent)


def name_filter(pattern):
    """A compiled name filter (POSIX extended syntax, searched anywhere in the name).

    Matched by an automaton (core.name_filter) in time linear in the names, with a work
    budget: names are public input, and no filter may stall the world.
    """
    return NameFilter(pattern)


def echoed(items):
    """At most ECHOED of a request's strings, each cut to 64 characters, and how many."""
    shown = ', '.join(edits.brief(item) for item in items[:ECHOED])
    more = len(items) - ECHOED
    return f'[{shown}' + (f', and {more:,} more]' if more > 0 else ']')


def _bare(message_type):
    """A message made without its constructor, its field checks off (values are trusted)."""
    message = message_type.__new__(message_type)
    message._check_fields = False
    return message


def entity_states(positions, velocities, stamp_ns, frame_id):
    """EntityStates of balls, built about 5 times faster than through their constructors.

    Why: a generated message's __init__ builds every nested default even when it is given
    (kwargs.get(name, Default())): about 70 us per EntityState, 7 s for 100,000 balls. Here
    each message is made with __new__ and its slots (rosidl_generator_py names a field f's
    slot _f) are filled directly with floats from numpy, without the setters' type checks;
    the parts every state shares (the header, the unrotated orientation, the zero spin and
    acceleration) are one object each.
    """
    sec, nanosec = divmod(int(stamp_ns), 10**9)
    header = Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)
    unrotated = Quaternion()
    still = Vector3()
    acceleration = Accel()
    states = []
    for (x, y), (vx, vy) in zip(positions.tolist(), velocities.tolist()):
        position = _bare(Point)
        position._x, position._y, position._z = x, y, 0.0
        pose = _bare(Pose)
        pose._position, pose._orientation = position, unrotated
        linear = _bare(Vector3)
        linear._x, linear._y, linear._z = vx, vy, 0.0
        twist = _bare(Twist)
        twist._linear, twist._angular = linear, still
        state = _bare(EntityState)
        state._header, state._pose, state._twist, state._acceleration = \
            header, pose, twist, acceleration
        states.append(state)
    return states


def _overlaps_bounds(bounds, positions, radii):
    """Mask of balls (spheres at z = 0) overlapping a sphere or box Bounds."""
    points = bounds.points
    if bounds.type == Bounds.TYPE_SPHERE and len(points) >= 2:
        c, reach = points[0], points[1].x + radii
        dx = positions[:, 0] - c.x
        dy = positions[:, 1] - c.y
        return dx * dx + dy * dy + c.z * c.z < reach * reach
    if bounds.type == Bounds.TYPE_BOX and len(points) >= 2:
        low = [min(getattr(points[0], a), getattr(points[1], a)) for a in 'xyz']
        high = [max(getattr(points[0], a), getattr(points[1], a)) for a in 'xyz']
        dx = positions[:, 0] - positions[:, 0].clip(low[0], high[0])
        dy = positions[:, 1] - positions[:, 1].clip(low[1], high[1])
        dz = 0.0 - min(max(0.0, low[2]), high[2])
        return dx * dx + dy * dy + dz * dz < radii * radii
    raise ValueError('bounds filters of type sphere (points: centre, (radius, 0, 0)) and box '
                     '(points: two corners) are supported')


class SimulationInterfaces:
    """The standard's services and action on a BallWorld node (see the module docstring).

    Every callback runs guarded (ros.calls): any exception is answered, never raised into
    the executor. All are in one reentrant group: a long StepSimulation, a large answer or a
    reset waiting for its world must not hold back SetSimulationState, ResetSimulation or
    a cancel, which stop it.
    """

    def __init__(self, node):
        self.node = node
        self.calls = Calls(node)
        self._stepper = None
        group = ReentrantCallbackGroup()
        services = (
            (GetSimulatorFeatures, 'get_simulator_features', self.get_simulator_features),
            (SpawnEntity, 'spawn_entity', self.spawn_entity),
            (SpawnEntities, 'spawn_entities', self.spawn_entities),
            (DeleteEntity, 'delete_entity', self.delete_entity),
            (GetEntities, 'get_entities', self.get_entities),
            (GetEntitiesStates, 'get_entities_states', self.get_entities_states),
            (GetEntityState, 'get_entity_state', self.get_entity_state),
            (SetEntityState, 'set_entity_state', self.set_entity_state),
            (GetEntityInfo, 'get_entity_info', self.get_entity_info),
            (GetEntityBounds, 'get_entity_bounds', self.get_entity_bounds),
            (GetSpawnables, 'get_spawnables', self.get_spawnables),
            (GetSimulationState, 'get_simulation_state', self.get_simulation_state),
            (ResetSimulation, 'reset_simulation', self.reset_simulation),
            (StepSimulation, 'step_simulation', self.step_simulation),
            (SetSimulationState, 'set_simulation_state', self.set_simulation_state),
        )
        large = {'get_entities', 'get_entities_states'}
        for srv_type, name, callback in services:
            service = node.create_service(srv_type, f'~/{name}',
                                          self.calls.guarded(name, callback),
                                          qos_profile=SERVICE_QOS, callback_group=group)
            if name in large:
                self.calls.sender.wrap(service,
                                       lambda answer: len(answer.entities) > LARGE_ANSWER)
        for srv_type, name, why in UNSUPPORTED:
            node.create_service(srv_type, f'~/{name}', _unsupported(why),
                                qos_profile=SERVICE_QOS, callback_group=group)
        #: The services' names, for the node's start-up line.
        self.names = [name for _, name, _ in services]
        self._action = ActionServer(
            node, SimulateSteps, f'~/{ACTION}', execute_callback=self.simulate_steps,
            goal_callback=lambda goal: GoalResponse.ACCEPT,
            cancel_callback=lambda goal: CancelResponse.ACCEPT,
            callback_group=group, goal_service_qos_profile=SERVICE_QOS,
            result_service_qos_profile=SERVICE_QOS, cancel_service_qos_profile=SERVICE_QOS)

    def destroy(self):
        """Destroy the action server (a second call does nothing).

        rclpy's Node.destroy_node leaves waitables alone, and the server's handle keeps the
        node's, and through it the context's DDS participant, alive until a garbage
        collection finds the cycle between the server and the node: then on whatever thread
        runs it, in the middle of whatever runs then (measured: every world made and closed
        in a test process kept its participant and its 9 threads until gc.collect())."""
        if self._action is not None:
            self._action.destroy()
            self._action = None

    def finish(self, spin_once):
        """Answer the calls in flight (each sees the run end at its next turn) before the
        node leaves; see ros.calls.Calls.finish."""
        self.calls.finish(spin_once)

    @property
    def simulation(self):
        return self.node.simulation

    # Features and spawnables ------------------------------------------------------------

    def get_simulator_features(self, request, response):
        response.features.features = list(FEATURES)
        response.features.spawn_formats = [edits.BALL_URI]
        response.features.custom_info = (
            f"ball_world: entities are balls. Spawn uri '{edits.BALL_URI}'; resource_string: "
            f'{edits.RESOURCE_FORMAT}. Poses in the z = 0 plane of the frame_id parameter, '
            'unrotated. ResetSimulation scopes DEFAULT and ALL.')
        return response

    def get_spawnables(self, request, response):
        spawnable = Spawnable(uri=edits.BALL_URI, description=f'a ball: {edits.RESOURCE_FORMAT}')
        arena = self.simulation.arena
        if arena:
            spawnable.spawn_bounds.type = Bounds.TYPE_BOX
            spawnable.spawn_bounds.points = [Point(x=arena[0], y=arena[1]),
                                             Point(x=arena[2], y=arena[3])]
        response.spawnables = [spawnable]
        sources = list(request.sources)
        response.result = _result(message=f'{len(sources):,} sources ignored (balls need '
                                  f'none): {echoed(sources)}' if sources else '')
        return response

    # Spawning and deleting --------------------------------------------------------------

    def spawn_entity(self, request, response):
        try:
            spawn = spawn_request(request.name, request.allow_renaming, request.uri,
                                  request.resource_string, request.entity_namespace,
                                  request.initial_pose, self.simulation.frame_id)
            results = self.node.edit(lambda: self.simulation.spawn([spawn]))
            outcome = results[0]
        except edits.EditRefused as refusal:
            outcome = refusal
        if isinstance(outcome, edits.EditRefused):
            response.result = _result(_SPAWN_CODES[outcome.kind], str(outcome))
        else:
            response.entity_name = outcome
            response.result = _result()
        return response

    async def spawn_entities(self, request, response):
        """Each item is read in slices between steps (about 0.1 ms each, bounded by
        core.edits); all that pass are then spawned at once, between two steps."""
        items = request.spawn_requests
        if len(items) > edits.MAX_SPAWN_BATCH:
            response.result = _result(Result.RESULT_OPERATION_FAILED,
                                      f'{len(items):,} balls in one request; at most '
                                      f'{edits.MAX_SPAWN_BATCH:,} per call')
            return response
        slices = self.calls.slices()
        spawns = []
        outcomes = []
        for item in items:
            try:
                spawns.append(spawn_request(
                    item.name, item.allow_renaming, item.entity_resource.uri,
                    item.entity_resource.resource_string, item.entity_namespace,
                    item.initial_pose, self.simulation.frame_id))
                outcomes.append(None)
            except edits.EditRefused as refusal:
                outcomes.append(refusal)
            await slices.give_way()
        try:
            spawned = iter(self.node.edit(lambda: self.simulation.spawn(spawns)))
        except edits.EditRefused as refusal:
            response.result = _result(Result.RESULT_OPERATION_FAILED, str(refusal))
            return response
        results = []
        for outcome in outcomes:
            outcome = next(spawned) if outcome is None else outcome
            if isinstance(outcome, edits.EditRefused):
                results.append(SpawnResult(result=_result(_SPAWN_CODES[outcome.kind],
                                                          str(outcome))))
            else:
                results.append(SpawnResult(result=_result(), entity_name=outcome))
        response.results = results
        failed = sum(r.result.result != Result.RESULT_OK for r in results)
        response.result = _result() if not failed else _result(
            SpawnEntities.Response.ENTITIES_SPAWN_FAILED,
            f'{failed} of {len(results)} balls were not spawned; see results')
        return response

    def delete_entity(self, request, response):
        try:
            self.node.edit(lambda: (None, self.simulation.delete(request.entity)))
            response.result = _result()
        except edits.EditRefused as refusal:
            response.result = _result(_SPAWN_CODES[refusal.kind], str(refusal))
        return response

    # Entities and their states ----------------------------------------------------------

    async def _matching(self, filters):
        """(indices, names, positions, velocities, stamp_ns) of the balls matching
        EntityFilters, all as they were when the request came; or a Result saying why not.

        Names are matched in slices between steps (core.name_filter bounds the work).
        """
        simulation = self.simulation
        world = simulation.world
        names = simulation.names
        positions = world.positions.copy()
        velocities = world.velocities.copy()
        snapshot = (names, positions, velocities, simulation.stamp_ns)
        if filters.tags.tags:
            return _result(Result.RESULT_FEATURE_UNSUPPORTED, 'balls have no tags')
        keep = np.ones(len(names), dtype=bool)
        if filters.categories:
            wanted = {c.category for c in filters.categories}
            agents = simulation.agents
            keep &= np.fromiter((category(name in agents) in wanted for name in names),
                                dtype=bool, count=len(names))
        if filters.bounds.type != Bounds.TYPE_EMPTY:
            try:
                keep &= _overlaps_bounds(filters.bounds, positions, world.radii)
            except ValueError as error:
                return _result(Result.RESULT_FEATURE_UNSUPPORTED, str(error))
        if filters.filter:
            slices = self.calls.slices()
            try:
                pattern = name_filter(filters.filter)
                for start in range(0, len(names), CHUNK):
                    for i in range(start, min(start + CHUNK, len(names))):
                        if keep[i] and not pattern.search(names[i]):
                            keep[i] = False
                    await slices.give_way()
            except FilterRefused as error:
                return _result(Result.RESULT_OPERATION_FAILED, str(error))
        return (np.flatnonzero(keep),) + snapshot

    async def _answer_matching(self, filters, response):
        """Fill response.entities (and result) with the matching names.

        Returns what _matching does, or None when the filters cannot be applied (the result
        then says why).
        """
        matching = await self._matching(filters)
        if isinstance(matching, Result):
            response.result = matching
            return None
        indices, names = matching[0], matching[1]
        response.entities = [names[i] for i in indices.tolist()]
        response.result = _result()
        return matching

    async def get_entities(self, request, response):
        await self._answer_matching(request.filters, response)
        return response

    def _state(self, index):
        simulation = self.simulation
        world = simulation.world
        return entity_states(world.positions[index:index + 1],
                             world.velocities[index:index + 1], simulation.stamp_ns,
                             simulation.frame_id)[0]

    async def get_entities_states(self, request, response):
        """States are built in slices between steps from the world as it was when the
        request came; a large answer is sent from a worker thread (ros.calls)."""
        matching = await self._answer_matching(request.filters, response)
        if matching is None:
            return response
        indices, _, positions, velocities, stamp_ns = matching
        frame_id = self.simulation.frame_id
        slices = self.calls.slices()
        states = []
        for start in range(0, len(indices), CHUNK):
            chosen = indices[start:start + CHUNK]
            states += entity_states(positions[chosen], velocities[chosen], stamp_ns, frame_id)
            await slices.give_way()
        response.states = states
        return response

    def get_entity_state(self, request, response):
        try:
            response.state = self._state(self.simulation.entities.index(request.entity))
            response.result = _result()
        except edits.EditRefused as refusal:
            response.result = _result(Result.RESULT_NOT_FOUND, str(refusal))
        return response

    def set_entity_state(self, request, response):
        state = request.state
        try:
            x, y, yaw = planar_pose(state.pose, state.header.frame_id,
                                    self.simulation.frame_id)
            vx, vy = planar_velocity(state.twist)
            self.node.edit(lambda: (None, self.simulation.set_state(request.entity, x, y,
                                                                    vx, vy, yaw=yaw)))
            response.result = _result()
        except edits.EditRefused as refusal:
            code = SetEntityState.Response.INVALID_POSE if refusal.kind == edits.INVALID_POSE \
                else _SPAWN_CODES[refusal.kind]
            response.result = _result(code, str(refusal))
        return response

    def get_entity_info(self, request, response):
        simulation = self.simulation
        try:
            index = simulation.entities.index(request.entity)
        except edits.EditRefused as refusal:
            response.result = _result(Result.RESULT_NOT_FOUND, str(refusal))
            return response
        world = simulation.world
        agent = request.entity in simulation.agents
        response.info.category.category = category(agent)
        radius = number_text(world.radii[index])
        kind = 'agent' if agent else 'ball'
        response.info.description = (f'{kind}, radius {radius} m, mass '
                                     f'{number_text(world.masses[index])} kg')
        response.result = _result()
        return response

    def get_entity_bounds(self, request, response):
        try:
            index = self.simulation.entities.index(request.entity)
        except edits.EditRefused as refusal:
            response.result = _result(Result.RESULT_NOT_FOUND, str(refusal))
            return response
        response.bounds.type = Bounds.TYPE_SPHERE
        response.bounds.points = [Vector3(), Vector3(x=float(self.simulation.world.radii[index]))]
        response.result = _result()
        return response

    # The simulation's state, reset and steps --------------------------------------------

    def state(self):
        node = self.node
        if node.finished:
            return SimulationState.STATE_QUITTING
        if not node.paused:
            return SimulationState.STATE_PLAYING
        if self.simulation.step_index == 0:
            return SimulationState.STATE_STOPPED
        return SimulationState.STATE_PAUSED

    def get_simulation_state(self, request, response):
        response.state.state = self.state()
        response.result = _result()
        return response

    async def set_simulation_state(self, request, response):
        target = request.state.state
        current = self.state()
        codes = SetSimulationState.Response
        if target == current:
            response.result = _result(codes.ALREADY_IN_TARGET_STATE,
                                      f'already in state {target}')
        elif target == SimulationState.STATE_PLAYING:
            self.node.set_paused(False)
            response.result = _result()
        elif target == SimulationState.STATE_PAUSED:
            if current == SimulationState.STATE_STOPPED:
                response.result = _result(codes.INCORRECT_TRANSITION, 'a stopped simulation '
                                          'is already paused at step 0; play it or step it')
            else:
                self.node.set_paused(True)
                response.result = _result()
        elif target == SimulationState.STATE_STOPPED:
            self.node.set_paused(True)
            ok, message = await self.node.reset_world()
            response.result = _result() if ok else _result(codes.STATE_TRANSITION_ERROR,
                                                           message)
        elif target == SimulationState.STATE_QUITTING:
            self.node.quit('SetSimulationState QUITTING')
            response.result = _result()
        else:
            response.result = _result(codes.INCORRECT_TRANSITION,
                                      f'state {target} cannot be set: worlds are not loaded '
                                      'or unloaded here')
        return response

    async def reset_simulation(self, request, response):
        scope = request.scope
        full = (ResetSimulation.Request.SCOPE_TIME | ResetSimulation.Request.SCOPE_STATE
                | ResetSimulation.Request.SCOPE_SPAWNED)
        if scope not in (ResetSimulation.Request.SCOPE_DEFAULT,
                         ResetSimulation.Request.SCOPE_ALL, full):
            response.result = _result(
                Result.RESULT_FEATURE_UNSUPPORTED, f'scope {scope}: only the whole world is '
                'reset (DEFAULT or ALL), rebuilt from the parameters, so that a recording '
                'can be re-simulated')
            return response
        ok, message = await self.node.reset_world()
        response.result = _result() if ok else _result(Result.RESULT_OPERATION_FAILED, message)
        return response

    async def _step(self, steps, feedback=None, cancelled=None):
        """Step a paused world `steps` times; returns (steps done, Result).

        A newer StepSimulation or SimulateSteps supersedes this one (which stops with
        RESULT_OPERATION_FAILED saying so): a goal whose client vanished, or whose cancel was
        lost, never blocks the world's stepping for anyone else.
        """
        node = self.node
        if not node.paused:
            return 0, _result(Result.RESULT_INCORRECT_STATE, 'the simulation is playing; '
                              'pause it first (SetSimulationState PAUSED)')
        me = object()
        self._stepper = me
        segment = self.simulation.segment
        done = 0
        try:
            while done < steps:
                for _ in range(min(STEPS_PER_TURN, steps - done)):
                    if node.finished or not node.context.ok():  # quitting, or a signal
                        return done, _result(Result.RESULT_OPERATION_FAILED,
                                             f'the run ended after {done} of {steps} steps')
                    node.step_once()
                    done += 1
                    if feedback is not None:
                        feedback(done, steps - done)
                if done == steps:
                    break
                node.wake()
                await _NextTurn()
                if cancelled is not None and cancelled():
                    return done, None
                if self._stepper is not me:
                    return done, _result(Result.RESULT_OPERATION_FAILED,
                                         f'stopped after {done} of {steps} steps: a newer '
                                         'StepSimulation or SimulateSteps took over')
                if not node.paused or self.simulation.segment != segment:
                    return done, _result(Result.RESULT_OPERATION_FAILED,
                                         f'stopped after {done} of {steps} steps: the '
                                         'simulation was resumed or reset')
            return done, _result()
        finally:
            if self._stepper is me:
                self._stepper = None

    async def step_simulation(self, request, response):
        _, response.result = await self._step(request.steps)
        return response

    async def simulate_steps(self, goal_handle):
        """The action's execution; any exception aborts the goal with its reason."""
        self.calls.in_flight += 1
        try:
            return await self._simulate_steps(goal_handle)
        except Exception as error:  # noqa: B902 - no goal may end the node
            if not self.node.context.ok():  # it failed because nothing can be sent now
                await Stranded()
            line = f'{ACTION}: the goal failed with {describe(error)}'
            self.node.get_logger().error(line)
            if goal_handle.is_active:
                goal_handle.abort()
            return SimulateSteps.Result(result=_result(Result.RESULT_OPERATION_FAILED, line))
        finally:
            self.calls.in_flight -= 1

    async def _simulate_steps(self, goal_handle):
        steps = goal_handle.request.steps

        def feedback(completed, remaining):
            goal_handle.publish_feedback(SimulateSteps.Feedback(
                completed_steps=completed, remaining_steps=remaining))

        done, result = await self._step(steps, feedback,
                                        lambda: goal_handle.is_cancel_requested)
        if not self.node.context.ok():
            await Stranded()
        answer = SimulateSteps.Result()
        if result is None:
            goal_handle.canceled()
            answer.result = _result(Result.RESULT_OK, f'cancelled after {done} steps')
        elif result.result == Result.RESULT_OK:
            goal_handle.succeed()
            answer.result = result
        else:
            goal_handle.abort()
            answer.result = result
        return answer
