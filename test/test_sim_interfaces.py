"""The standard simulation_interfaces services and action, driven through a real rclpy client.

Every call goes over DDS to a node in this process (harness.InProcessWorld), as a client of
Gazebo would call it; the test then checks the answer, the world behind it, and what the
node publishes. Refusals must leave the world unchanged.
"""
from ball_world_testing.harness import InProcessWorld
from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from rclpy.action import ActionClient
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import (Bounds, EntityCategory, Result, SimulationState,
                                       SimulatorFeatures, SpawnEntity as SpawnEntityMsg,
                                       SpawnResult)
from simulation_interfaces.srv import (DeleteEntity, GetEntities, GetEntitiesStates,
                                       GetEntityBounds, GetEntityInfo, GetEntityState,
                                       GetSimulationState, GetSimulatorFeatures, GetSpawnables,
                                       ResetSimulation, SetEntityState, SetSimulationState,
                                       SpawnEntities, SpawnEntity, StepSimulation)
from std_msgs.msg import String

from ball_world.core.edits import first_overlap, Neighbours
from ball_world.core.world import Walls
from ball_world.ros.sim_interfaces import name_filter, UNSUPPORTED

THREE_BALLS = {'random.count': 0, 'rate_hz': 100.0, 'markers.rate_hz': 0.0,
               'balls.x': [2.0, 8.0, 5.0], 'balls.y': [2.0, 2.0, 8.0],
               'balls.vx': [0.5, -0.5, 0.0], 'balls.vy': [0.0, 0.0, -0.25],
               'balls.radius': [0.5, 0.5, 0.4], 'balls.mass': [1.0, 1.0, 2.0]}
OK = Result.RESULT_OK


@pytest.fixture
def world():
    made = InProcessWorld(**THREE_BALLS)
    yield made
    made.close()


def pose_at(x, y, z=0.0, frame=''):
    pose = PoseStamped()
    pose.header.frame_id = frame
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = x, y, z
    pose.pose.orientation.w = 1.0
    return pose


def spawn(world, name='', x=5.0, y=5.0, resource='radius: 0.3', **fields):
    request = SpawnEntity.Request(name=name, uri=fields.pop('uri', 'ball'),
                                  resource_string=resource,
                                  initial_pose=fields.pop('pose', pose_at(x, y)), **fields)
    return world.call(SpawnEntity, 'spawn_entity', request)


def set_state(world, name, state):
    return world.call(SetSimulationState, 'set_simulation_state', SetSimulationState.Request(
        state=SimulationState(state=state)))


def pause(world):
    assert set_state(world, None, SimulationState.STATE_PAUSED).result.result == OK


def names_of(world):
    return world.call(GetEntities, 'get_entities', GetEntities.Request()).entities


def test_features_list_exactly_what_is_served_and_spawnables_name_the_ball(world):
    features = world.call(GetSimulatorFeatures, 'get_simulator_features',
                          GetSimulatorFeatures.Request()).features
    F = SimulatorFeatures
    assert sorted(features.features) == sorted([
        F.SPAWNING, F.DELETING, F.ENTITY_CATEGORIES, F.SPAWNING_RESOURCE_STRING,
        F.ENTITY_STATE_GETTING, F.ENTITY_STATE_SETTING, F.ENTITY_INFO_GETTING, F.SPAWNABLES,
        F.SIMULATION_RESET, F.SIMULATION_STATE_GETTING, F.SIMULATION_STATE_SETTING,
        F.SIMULATION_STATE_PAUSE, F.STEP_SIMULATION_SINGLE, F.STEP_SIMULATION_MULTIPLE,
        F.STEP_SIMULATION_ACTION, F.SPAWNING_ENTITIES, F.ENTITY_BOUNDS])
    assert list(features.spawn_formats) == ['ball']
    spawnables = world.call(GetSpawnables, 'get_spawnables', GetSpawnables.Request())
    assert spawnables.result.result == OK
    [ball] = spawnables.spawnables
    assert ball.uri == 'ball' and 'radius' in ball.description
    assert ball.spawn_bounds.type == Bounds.TYPE_BOX
    assert [(p.x, p.y) for p in ball.spawn_bounds.points] == [(0.0, 0.0), (10.0, 10.0)]
    # Every service the node offers answers: nothing is listed that is not there.
    node_services = dict(world.node.get_service_names_and_types_by_node(
        'ball_world', '/'))
    for name in ('spawn_entity', 'spawn_entities', 'delete_entity', 'get_entities',
                 'get_entities_states', 'get_entity_state', 'set_entity_state',
                 'get_entity_info', 'get_spawnables', 'reset_simulation', 'step_simulation',
                 'get_simulation_state', 'set_simulation_state', 'get_simulator_features',
                 'get_entity_bounds'):
        assert f'/ball_world/{name}' in node_services, name


def test_entity_bounds_are_the_balls_sphere(world):
    bounds = world.call(GetEntityBounds, 'get_entity_bounds',
                        GetEntityBounds.Request(entity='ball_2'))
    assert bounds.result.result == OK
    assert bounds.bounds.type == Bounds.TYPE_SPHERE
    assert [(p.x, p.y, p.z) for p in bounds.bounds.points] == [(0.0, 0.0, 0.0), (0.4, 0.0, 0.0)]
    missing = world.call(GetEntityBounds, 'get_entity_bounds',
                         GetEntityBounds.Request(entity='ball_9'))
    assert missing.result.result == Result.RESULT_NOT_FOUND
    assert 'ball_9' in missing.result.error_message


@pytest.mark.parametrize('srv_type, name, why', UNSUPPORTED)
def test_services_of_what_a_ball_world_lacks_answer_unsupported_at_once(world, srv_type, name,
                                                                        why):
    """A client written for Gazebo that asks for worlds or named poses gets an answer, and
    the feature is not listed."""
    answer = world.call(srv_type, name, srv_type.Request())
    assert answer.result.result == Result.RESULT_FEATURE_UNSUPPORTED
    assert answer.result.error_message == why


def test_spawn_places_a_named_ball_that_steps_and_is_published(world):
    names = world.probe.listen(String, 'entity_names',
                               qos=world.node.entities_pub.qos_profile)
    edits = world.probe.listen(String, 'edits')
    pause(world)
    response = spawn(world, 'probe_ball', 5.0, 4.0,
                     '{radius: 0.25, mass: 3.0, velocity: [1.0, -0.5]}')
    assert response.result.result == OK, response.result.error_message
    assert response.entity_name == 'probe_ball'
    assert names_of(world) == ['ball_0', 'ball_1', 'ball_2', 'probe_ball']
    world.spin_until(lambda: names and names[-1].data.split('\n')[-1] == 'probe_ball')
    world.spin_until(lambda: edits)
    assert '"kind": "spawn"' in edits[-1].data and '"probe_ball"' in edits[-1].data
    info = world.call(GetEntityInfo, 'get_entity_info', GetEntityInfo.Request(
        entity='probe_ball'))
    assert info.info.category.category == EntityCategory.CATEGORY_DYNAMIC_OBJECT
    assert info.info.description == 'ball, radius 0.25 m, mass 3 kg'
    world.balls.clear()
    assert world.call(StepSimulation, 'step_simulation', StepSimulation.Request(
        steps=1)).result.result == OK
    world.spin_until(lambda: world.balls)
    poses = world.balls[-1].poses
    assert len(poses) == 4
    dt = world.simulation.dt_ns * 1e-9
    assert (poses[3].position.x, poses[3].position.y) == (5.0 + 1.0 * dt, 4.0 - 0.5 * dt)
    # Impulses address a spawned ball by its name.
    world.impulse('probe_ball', 3.0, 0.0)
    world.spin_until(lambda: world.simulation.queued == 1)
    world.call(StepSimulation, 'step_simulation', StepSimulation.Request(steps=1))
    assert world.simulation.world.velocities[3].tolist() == [1.0 + 3.0 / 3.0, -0.5]


@pytest.mark.parametrize('fields, code, words', [
    (dict(x=2.2, y=2.0), SpawnResult.INVALID_POSE, "overlaps ball 'ball_0'"),
    (dict(x=0.1, y=5.0), SpawnResult.INVALID_POSE, 'not inside the arena'),
    (dict(x=float('nan')), SpawnResult.INVALID_POSE, 'not finite'),
    (dict(x=1e300), SpawnResult.INVALID_POSE, 'beyond'),
    (dict(pose=pose_at(5.0, 5.0, z=1.0)), SpawnResult.INVALID_POSE, 'z = 0 plane'),
    (dict(pose=pose_at(5.0, 5.0, frame='map')), SpawnResult.INVALID_POSE, "frame 'map'"),
    (dict(name='ball_1'), SpawnResult.NAME_NOT_UNIQUE, 'is taken'),
    (dict(name='1ball'), SpawnResult.NAME_INVALID, 'not a letter'),
    (dict(name='b' * 300), SpawnResult.NAME_INVALID, 'at most 256'),
    (dict(name=''), SpawnResult.NAME_INVALID, 'name is empty'),
    (dict(uri='robot.urdf'), SpawnResult.UNSUPPORTED_FORMAT, "'robot.urdf'"),
    (dict(uri='', resource=''), SpawnResult.NO_RESOURCE, 'both empty'),
    (dict(resource='radius: ['), SpawnResult.RESOURCE_PARSE_ERROR, 'not YAML'),
    (dict(resource='radius: -1'), SpawnResult.RESOURCE_PARSE_ERROR, 'radius -1 m'),
    (dict(resource='colour: red'), SpawnResult.RESOURCE_PARSE_ERROR, "unknown key 'colour'"),
    (dict(resource='a: &a [1]\nb: [*a, *a]'), SpawnResult.RESOURCE_PARSE_ERROR, 'aliases'),
    (dict(resource='radius: ' + '9' * 10_000_000), SpawnResult.RESOURCE_PARSE_ERROR,
     'at most 4096'),
    (dict(resource='velocity: [1.0e6, 0.0]'), SpawnResult.INVALID_POSE, 'faster than'),
    (dict(entity_namespace='sim2'), SpawnResult.NAMESPACE_INVALID, 'namespace'),
])
def test_a_bad_spawn_is_refused_with_the_standard_code_and_changes_nothing(world, fields,
                                                                           code, words):
    pause(world)
    before = world.simulation.world.positions.copy()
    response = spawn(world, **{'name': 'new', **fields})
    assert response.result.result == code, response.result.error_message
    assert words in response.result.error_message
    assert names_of(world) == ['ball_0', 'ball_1', 'ball_2']
    assert world.simulation.world.positions.tolist() == before.tolist()
    assert world.simulation.pending_edits == ()


def test_renaming_generates_names_that_are_never_reused(world):
    pause(world)
    renamed = spawn(world, 'ball_1', 5.0, 5.0, allow_renaming=True)
    assert renamed.result.result == OK and renamed.entity_name == 'ball_3'
    generated = spawn(world, '', 5.0, 6.5, allow_renaming=True)
    assert generated.entity_name == 'ball_4'
    deleted = world.call(DeleteEntity, 'delete_entity', DeleteEntity.Request(entity='ball_3'))
    assert deleted.result.result == OK
    again = spawn(world, 'ball_3', 5.0, 5.0)
    assert again.result.result == SpawnResult.NAME_NOT_UNIQUE
    assert 'not reused' in again.result.error_message
    assert spawn(world, '', 5.0, 5.0, allow_renaming=True).entity_name == 'ball_5'


def test_spawn_entities_judges_each_request_in_order(world):
    pause(world)
    requests = [SpawnEntityMsg(name=name, initial_pose=pose_at(x, y))
                for name, x, y in (('a', 4.0, 5.0), ('b', 4.1, 5.0), ('c', 6.0, 5.0),
                                   ('ball_0', 7.0, 7.0))]
    for request in requests:
        request.entity_resource.uri = 'ball'
        request.entity_resource.resource_string = 'radius: 0.3'
    response = world.call(SpawnEntities, 'spawn_entities', SpawnEntities.Request(
        spawn_requests=requests))
    assert response.result.result == SpawnEntities.Response.ENTITIES_SPAWN_FAILED
    codes = [(r.result.result, r.entity_name) for r in response.results]
    assert codes == [(OK, 'a'), (SpawnResult.INVALID_POSE, ''), (OK, 'c'),
                     (SpawnResult.NAME_NOT_UNIQUE, '')]
    assert "overlaps ball 'a'" in response.results[1].result.error_message
    assert names_of(world) == ['ball_0', 'ball_1', 'ball_2', 'a', 'c']
    flood = world.call(SpawnEntities, 'spawn_entities', SpawnEntities.Request(
        spawn_requests=[requests[0]] * 1001))
    assert flood.result.result == Result.RESULT_OPERATION_FAILED
    assert 'at most 1,000 per call' in flood.result.error_message
    assert len(names_of(world)) == 5


def test_states_are_read_and_set_in_the_world_frame_at_the_current_time(world):
    pause(world)
    # The world ran before the pause, for as many steps as the machine's load allowed.
    paused_at = world.simulation.step_index
    world.call(StepSimulation, 'step_simulation', StepSimulation.Request(steps=3))
    got = world.call(GetEntityState, 'get_entity_state', GetEntityState.Request(
        entity='ball_1'))
    assert got.result.result == OK
    stamp = got.state.header.stamp.sec * 10**9 + got.state.header.stamp.nanosec
    assert stamp == world.simulation.stamp_ns == (paused_at + 3) * world.simulation.dt_ns
    assert got.state.header.frame_id == 'world'
    assert got.state.pose.position.x == world.simulation.world.positions[1, 0]
    assert got.state.twist.linear.x == -0.5
    request = SetEntityState.Request(entity='ball_1')
    request.state.pose.position.x, request.state.pose.position.y = 6.0, 6.0
    request.state.pose.orientation.w = 1.0
    request.state.twist.linear.x, request.state.twist.linear.y = 0.0, 2.0
    assert world.call(SetEntityState, 'set_entity_state', request).result.result == OK
    assert world.simulation.world.positions[1].tolist() == [6.0, 6.0]
    assert world.simulation.world.velocities[1].tolist() == [0.0, 2.0]
    everything = world.call(GetEntitiesStates, 'get_entities_states',
                            GetEntitiesStates.Request())
    assert list(everything.entities) == ['ball_0', 'ball_1', 'ball_2']
    assert [[s.pose.position.x, s.pose.position.y] for s in everything.states] == \
        world.simulation.world.positions.tolist()
    for change, code in ((dict(x=2.0, y=2.0), SetEntityState.Response.INVALID_POSE),
                         (dict(spin=1.0), SetEntityState.Response.INVALID_POSE),
                         (dict(vx=float('inf')), SetEntityState.Response.INVALID_POSE),
                         (dict(entity='nobody'), Result.RESULT_NOT_FOUND)):
        bad = SetEntityState.Request(entity=change.get('entity', 'ball_1'))
        bad.state.pose.position.x = change.get('x', 7.0)
        bad.state.pose.position.y = change.get('y', 7.0)
        bad.state.pose.orientation.w = 1.0
        bad.state.twist.linear.x = change.get('vx', 0.0)
        bad.state.twist.angular.z = change.get('spin', 0.0)
        answer = world.call(SetEntityState, 'set_entity_state', bad)
        assert answer.result.result == code, (change, answer.result.error_message)
        assert world.simulation.world.positions[1].tolist() == [6.0, 6.0]


def test_filters_by_name_category_and_bounds(world):
    def query(**filters):
        request = GetEntities.Request()
        for key, value in filters.items():
            setattr(request.filters, key, value)
        return world.call(GetEntities, 'get_entities', request)

    assert list(query(filter='ball_[02]$').entities) == ['ball_0', 'ball_2']
    robots = [EntityCategory(category=EntityCategory.CATEGORY_ROBOT)]
    assert list(query(categories=robots).entities) == []
    objects = [EntityCategory(category=EntityCategory.CATEGORY_DYNAMIC_OBJECT)]
    assert len(query(categories=robots + objects).entities) == 3
    sphere = Bounds(type=Bounds.TYPE_SPHERE)
    sphere.points = [pose_at(2.0, 3.0).pose.position, pose_at(0.6, 0.0).pose.position]
    assert list(query(bounds=sphere).entities) == ['ball_0']
    assert list(query(filter='(a+)+b').entities) == []
    assert list(query(filter='(_[0-9]+)+$').entities) == ['ball_0', 'ball_1', 'ball_2']
    refused = query(filter='(ball)_\\1')
    assert refused.result.result == Result.RESULT_OPERATION_FAILED
    assert 'back references are not accepted' in refused.result.error_message
    tagged = GetEntities.Request()
    tagged.filters.tags.tags = ['robot']
    assert world.call(GetEntities, 'get_entities', tagged).result.result == \
        Result.RESULT_FEATURE_UNSUPPORTED


def test_name_filters_that_backtrack_for_ages_are_matched_in_linear_time():
    """Filters that take a backtracking matcher exponential time match what they mean (a
    closed form of each is the reference) and stay cheap on long names: the work, not the
    time, is what is asserted."""
    closed_forms = {
        '(a+)+$': lambda name: name.endswith('a'),
        '(a*)*b': lambda name: 'b' in name,
        '(a|a)*c': lambda name: 'c' in name,
        '(x+x+)+y': lambda name: 'xxy' in name,
        '((ab)*)+': lambda name: True,
        '.*' * 40 + 'x': lambda name: 'x' in name,
        '(_+)+$': lambda name: name.endswith('_'),
        '(_|__)*$b': lambda name: False,
        '(.*)*.*.*x': lambda name: 'x' in name,
    }
    names = ('aaab', 'ab' * 9, 'xxy', 'xyxy', '', 'ball_1', '___', 'zzzc', '_' * 255 + 'a',
             'a' * 256, '_' * 256, 'x' + 'a' * 255)
    for pattern, expected in closed_forms.items():
        compiled = name_filter(pattern)
        for name in names:
            assert compiled.search(name) == expected(name), (pattern, name)
        # One pass over the NFA per new transition: far below what backtracking would try.
        assert compiled.work < 200_000, (pattern, compiled.work)
    assert name_filter('^ball_[0-9]+$').search('ball_12')
    for pattern, words in (('(?>(_+)+$)', 'atomic groups'), ('a++', 'possessive'),
                           ('(?=b)', 'look-arounds'), ('(a)\\1', 'back references'),
                           ('a{99999}', 'states'), ('x' * 257, 'at most 256')):
        with pytest.raises(ValueError, match=words):
            name_filter(pattern)


def test_simulation_state_transitions(world):
    def state():
        return world.call(GetSimulationState, 'get_simulation_state',
                          GetSimulationState.Request()).state.state

    world.spin_until(lambda: world.simulation.step_index > 2)
    assert state() == SimulationState.STATE_PLAYING
    assert set_state(world, None, SimulationState.STATE_PLAYING).result.result == \
        SetSimulationState.Response.ALREADY_IN_TARGET_STATE
    pause(world)
    assert state() == SimulationState.STATE_PAUSED
    assert spawn(world, 'extra', 5.0, 5.0).result.result == OK
    stopped = set_state(world, None, SimulationState.STATE_STOPPED)
    assert stopped.result.result == OK, stopped.result.error_message
    assert state() == SimulationState.STATE_STOPPED
    assert world.simulation.step_index == 0 and names_of(world) == ['ball_0', 'ball_1',
                                                                    'ball_2']
    assert set_state(world, None, SimulationState.STATE_PAUSED).result.result == \
        SetSimulationState.Response.INCORRECT_TRANSITION
    assert set_state(world, None, SimulationState.STATE_PLAYING).result.result == OK
    world.spin_until(lambda: world.simulation.step_index > 2)
    assert set_state(world, None, SimulationState.STATE_QUITTING).result.result == OK
    assert world.node.finished


def test_step_simulation_needs_a_paused_world_and_answers_when_done(world):
    playing = world.call(StepSimulation, 'step_simulation', StepSimulation.Request(steps=2))
    assert playing.result.result == Result.RESULT_INCORRECT_STATE
    pause(world)
    start = world.simulation.step_index
    assert world.call(StepSimulation, 'step_simulation', StepSimulation.Request(
        steps=250)).result.result == OK
    assert world.simulation.step_index == start + 250


def test_simulate_steps_gives_feedback_per_step_and_can_be_cancelled(world):
    pause(world)
    client = ActionClient(world.probe.node, SimulateSteps, '/ball_world/simulate_steps')
    world.spin_until(client.server_is_ready, 'the action server')
    feedback = []
    start = world.simulation.step_index
    goal = world.probe.result(client.send_goal_async(
        SimulateSteps.Goal(steps=20), feedback_callback=lambda f: feedback.append(
            (f.feedback.completed_steps, f.feedback.remaining_steps))))
    assert goal.accepted
    result = world.probe.result(goal.get_result_async()).result
    assert result.result.result == OK
    assert world.simulation.step_index == start + 20
    # One feedback per step is sent. A client keeps the last 10 and stops listening once it
    # has the result, which may overtake the last few: it never gets them out of order.
    assert len(feedback) >= 3
    assert all(done + left == 20 for done, left in feedback)
    assert [done for done, _ in feedback] == sorted(set(done for done, _ in feedback))
    long_goal = world.probe.result(client.send_goal_async(SimulateSteps.Goal(
        steps=10**12)))
    world.spin_until(lambda: world.simulation.step_index > start + 40)
    world.probe.result(long_goal.cancel_goal_async())
    cancelled = world.probe.result(long_goal.get_result_async())
    assert 'cancelled after' in cancelled.result.result.error_message
    assert world.simulation.step_index < start + 10**6
    client.destroy()


def test_delete_and_reset_simulation(world):
    pause(world)
    assert world.call(DeleteEntity, 'delete_entity', DeleteEntity.Request(
        entity='ball_1')).result.result == OK
    assert names_of(world) == ['ball_0', 'ball_2']
    assert world.call(GetEntityState, 'get_entity_state', GetEntityState.Request(
        entity='ball_1')).result.result == Result.RESULT_NOT_FOUND
    assert world.call(DeleteEntity, 'delete_entity', DeleteEntity.Request(
        entity='ball_1')).result.result == Result.RESULT_NOT_FOUND
    world.impulse('ball_1', 1.0, 0.0)
    world.spin_until(lambda: world.simulation.rejected.get('unknown_ball') == 1)
    unsupported = world.call(ResetSimulation, 'reset_simulation', ResetSimulation.Request(
        scope=ResetSimulation.Request.SCOPE_TIME))
    assert unsupported.result.result == Result.RESULT_FEATURE_UNSUPPORTED
    assert world.call(ResetSimulation, 'reset_simulation',
                      ResetSimulation.Request()).result.result == OK
    assert names_of(world) == ['ball_0', 'ball_1', 'ball_2']
    assert world.simulation.step_index == 0
    assert np.array_equal(world.simulation.world.positions,
                          [[2.0, 2.0], [8.0, 2.0], [5.0, 8.0]])


def test_set_state_is_checked_against_the_impulses_queued_before_it(world):
    """A queued impulse and a SetEntityState that each pass alone, but not together: the
    state is refused (the impulse, which came first, is applied), and no ball can ever
    reach more than the speed the world can step."""
    pause(world)
    simulation = world.simulation
    limit = simulation.world.speed_limit(simulation.dt_ns * 1e-9)
    vx0 = float(simulation.world.velocities[0, 0])
    world.impulse('ball_0', 0.75 * limit - vx0, 0.0)  # ball_0 (1 kg) to 0.75 x the limit
    world.spin_until(lambda: simulation.queued == 1)
    request = SetEntityState.Request(entity='ball_1')
    request.state.pose.position.x, request.state.pose.position.y = 8.0, 6.0
    request.state.pose.orientation.w = 1.0
    request.state.twist.linear.x = 0.75 * limit  # ball_1 (1 kg) too: together 1.06 x
    answer = world.call(SetEntityState, 'set_entity_state', request)
    assert answer.result.result == SetEntityState.Response.INVALID_POSE
    assert 'faster than' in answer.result.error_message
    velocities = simulation.world.velocities
    assert velocities[0, 0] == pytest.approx(0.75 * limit)
    energy = 0.5 * float(np.sum(simulation.world.masses * np.sum(velocities ** 2, axis=1)))
    assert np.sqrt(2.0 * energy / simulation.world.masses.min()) <= limit
    # Alone (the impulse applied) a smaller state passes.
    request.state.twist.linear.x = 0.1 * limit
    assert world.call(SetEntityState, 'set_entity_state', request).result.result == OK


def test_a_large_get_entities_states_is_built_while_the_world_keeps_stepping():
    """20,000 states take a while to build (they took 70 us each, all before any step);
    now the world steps between slices of the answer, which is the world as it was when
    the request came."""
    made = InProcessWorld(**{'random.count': 20_000, 'arena': [0.0, 0.0, 300.0, 300.0],
                             'random.speed': 0.5, 'rate_hz': 100.0, 'markers.rate_hz': 0.0})
    try:
        calls = made.node.interfaces.calls
        steps_during = []
        step_once = made.node.step_once

        def watched_step():
            steps_during.append(calls.in_flight > 0)
            return step_once()

        made.node.step_once = watched_step
        client = made.probe.node.create_client(GetEntitiesStates,
                                               '/ball_world/get_entities_states')
        made.spin_until(client.service_is_ready)
        answer = made.probe.result(client.call_async(GetEntitiesStates.Request()))
        assert answer.result.result == OK
        assert len(answer.states) == len(answer.entities) == 20_000
        assert any(steps_during), 'no step while the answer was built'
        stamps = {(s.header.stamp.sec, s.header.stamp.nanosec) for s in answer.states}
        assert len(stamps) == 1
        assert answer.entities[:2] == ['ball_0', 'ball_1']
    finally:
        made.close()


def test_spawn_checks_only_nearby_balls_and_finds_the_same_first_overlap():
    """Neighbours (balls sorted by x) must never hide an overlap: against a plain loop over
    every ball, for random worlds, probes, touching pairs and a ball to skip."""
    rng = np.random.default_rng(7)
    walls = Walls(np.zeros((0, 4)))
    for _ in range(30):
        n = int(rng.integers(1, 400))
        positions = rng.uniform(0.0, 20.0, (n, 2))
        positions[: n // 4, 0] = positions[0, 0]  # ties in x
        radii = rng.uniform(0.05, 0.5, n)
        near = Neighbours(positions, radii)
        for _ in range(50):
            x, y = rng.uniform(-1.0, 21.0, 2)
            radius = float(rng.uniform(0.01, 1.0))
            if rng.random() < 0.3:  # exactly touching ball k: not an overlap
                k = int(rng.integers(n))
                x = positions[k, 0] + radii[k] + radius
                y = positions[k, 1]
            skip = int(rng.integers(n)) if rng.random() < 0.3 else None
            expected = next((('ball', i) for i in range(n) if i != skip and (
                (positions[i, 0] - x) ** 2 + (positions[i, 1] - y) ** 2
                < (radii[i] + radius) ** 2)), None)
            assert first_overlap(x, y, radius, positions, radii, walls, skip, near) == \
                expected == first_overlap(x, y, radius, positions, radii, walls, skip)
