"""Hostile requests to the simulation_interfaces services, against the node as a process.

Each request comes from a real rclpy client in another DDS participant; the node's steps are
counted from outside (its `stats` topic), so "the world kept stepping" means steps were
published while the request was being answered. Nothing here is timed: a loaded machine may
make everything slow, never wrong.
"""
import signal

from ball_world_testing.harness import check_running, executable, finish, node_command, start
from geometry_msgs.msg import PoseStamped
import pytest
from rclpy.action import ActionClient
from rclpy.qos import QoSProfile
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import (Result, SimulationState, SpawnEntity as SpawnEntityMsg,
                                       SpawnResult)
from simulation_interfaces.srv import (GetEntities, GetEntitiesStates, GetSimulationState,
                                       GetSpawnables, ResetSimulation, SetSimulationState,
                                       SpawnEntities, SpawnEntity, StepSimulation)
from std_msgs.msg import Float64MultiArray

from ball_world.core.edits import MAX_RESOURCE_LENGTH
from ball_world.ros.calls import Calls

OK = Result.RESULT_OK
NODE = '/ball_world'
#: Resource strings that once ended the node (OverflowError, RecursionError, the digit limit
#: while writing the refusal, a base-60 integer), and their kin at other sizes.
CRASHERS = [
    'radius: ' + '9' * 400, 'radius: ' + '9' * 4000, 'mass: -' + '9' * 1000,
    '[' * 400 + ']' * 400, '{' * 2000, '[' * 330 + '1' + ']' * 330, '- ' * 2000 + 'x',
    'radius: [0x' + 'f' * 4000 + ']', 'radius: 0x' + 'f' * 4080,
    'velocity: [0o' + '7' * 4000 + ', 0]',
    'radius: ' + ':'.join(['59'] * 1300), 'mass: 1:' + '59:' * 1000 + '1',
    'velocity: [' + ', '.join(['1'] * 1300) + ']', 'radius: 2001-13-45',
    '{' + ', '.join(f'k{i}: [1]' for i in range(300)) + '}',
]


@pytest.fixture
def node(probe, processes):
    """A playing node at 50 Hz and a way to count its steps from outside."""
    process = processes.start(node_command('rate_hz:=50.0', 'markers.rate_hz:=0.0'))
    stats = probe.listen(Float64MultiArray, 'stats')
    probe.spin_until(lambda: len(stats) >= 3, 'the node to step', process=process)
    process.stats = stats
    return process


def call_async(probe, srv_type, name, request):
    client = probe.node.create_client(srv_type, f'{NODE}/{name}')
    probe.spin_until(client.service_is_ready, f'the service {name}')
    return client.call_async(request)


def while_stepping(probe, node, future, what):
    """The answer of `future`, asserting that the node published steps while it was pending
    (at least two, so one step already in flight does not count) and is still running."""
    before = len(node.stats)
    answer = probe.result(future, what)
    stepped = len(node.stats) - before
    check_running(node)
    return answer, stepped


def pose_at(x, y):
    pose = PoseStamped()
    pose.pose.position.x, pose.pose.position.y = x, y
    pose.pose.orientation.w = 1.0
    return pose


def test_resource_strings_that_once_crashed_the_node_are_refused_as_parse_errors(probe, node):
    for text in CRASHERS:
        assert len(text) <= MAX_RESOURCE_LENGTH, len(text)
        answer = probe.call(SpawnEntity, f'{NODE}/spawn_entity', SpawnEntity.Request(
            name='hostile', uri='ball', resource_string=text, initial_pose=pose_at(5.0, 5.0)))
        assert answer.result.result == SpawnResult.RESOURCE_PARSE_ERROR, (text[:40], answer)
        assert len(answer.result.error_message) < 300, answer.result.error_message
    items = [SpawnEntityMsg(name=f'h{i}', initial_pose=pose_at(5.0, 5.0))
             for i in range(len(CRASHERS))]
    for item, text in zip(items, CRASHERS):
        item.entity_resource.resource_string = text
    batch = probe.call(SpawnEntities, f'{NODE}/spawn_entities',
                       SpawnEntities.Request(spawn_requests=items))
    assert [r.result.result for r in batch.results] == \
        [SpawnResult.RESOURCE_PARSE_ERROR] * len(CRASHERS)
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 5, 'more steps', process=node)


@pytest.mark.parametrize('pattern', ['.*' * 40 + 'x', '.*.*.*.*x', '(_+)+$', '(a|aa)*$b',
                                     '(x+x+)+y', '(?>(_+)+$)', '((a*)*)*' * 20 + 'c'])
def test_name_filters_never_stop_the_world(probe, node, pattern):
    """Two 256-character names are spawned first: the longest a backtracking matcher chews
    on (a name like them matched by .*.*.*.*x took 26 s)."""
    for name, x in (('a' + '_' * 254 + 'b', 0.06), ('q' * 256, 9.94)):
        spawned = probe.call(SpawnEntity, f'{NODE}/spawn_entity', SpawnEntity.Request(
            name=name, uri='ball', resource_string='{radius: 0.05, mass: 1.0}',
            initial_pose=pose_at(x, 0.06)))
        assert spawned.result.result == OK, spawned.result.error_message
    for srv_type, service in ((GetEntities, 'get_entities'),
                              (GetEntitiesStates, 'get_entities_states')):
        request = srv_type.Request()
        request.filters.filter = pattern
        answer, _ = while_stepping(probe, node, call_async(probe, srv_type, service, request),
                                   f'{service} with {pattern[:20]}')
        assert answer.result.result in (OK, Result.RESULT_OPERATION_FAILED), answer.result
        if answer.result.result != OK:
            assert 'atomic groups' in answer.result.error_message
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 5, 'more steps', process=node)


def test_a_full_spawn_entities_of_the_largest_items_is_answered_while_the_world_steps(probe,
                                                                                      node):
    padding = '# ' + 'p' * (MAX_RESOURCE_LENGTH - 30)
    items = []
    for i in range(1000):
        x, y = 0.1 + 0.3 * (i % 32), 0.1 + 0.3 * (i // 32)
        item = SpawnEntityMsg(name=f'big_{i}', initial_pose=pose_at(x, y))
        item.entity_resource.resource_string = f'radius: 0.05\nmass: 1.0\n{padding}'
        items.append(item)
    assert len(items[0].entity_resource.resource_string) <= MAX_RESOURCE_LENGTH
    answer, _ = while_stepping(
        probe, node, call_async(probe, SpawnEntities, 'spawn_entities',
                                SpawnEntities.Request(spawn_requests=items)), 'SpawnEntities')
    assert len(answer.results) == 1000
    assert sum(r.result.result == OK for r in answer.results) > 900
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 5, 'more steps', process=node)


def set_state(probe, state):
    return call_async(probe, SetSimulationState, 'set_simulation_state',
                      SetSimulationState.Request(state=SimulationState(state=state)))


@pytest.mark.parametrize('stop', ['playing', 'reset', 'stopped'])
def test_an_endless_step_simulation_is_stopped_by_the_standards_own_calls(probe, node, stop):
    assert probe.result(set_state(probe, SimulationState.STATE_PAUSED)).result.result == OK
    stepping = call_async(probe, StepSimulation, 'step_simulation',
                          StepSimulation.Request(steps=2**63 - 1))
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 20, 'StepSimulation to step',
                     process=node)
    if stop == 'playing':
        stopper = set_state(probe, SimulationState.STATE_PLAYING)
    elif stop == 'stopped':
        stopper = set_state(probe, SimulationState.STATE_STOPPED)
    else:
        stopper = call_async(probe, ResetSimulation, 'reset_simulation',
                             ResetSimulation.Request())
    assert probe.result(stopper, 'the stopping call').result.result == OK
    stopped = probe.result(stepping, 'StepSimulation to stop')
    assert stopped.result.result == Result.RESULT_OPERATION_FAILED
    assert 'stopped after' in stopped.result.error_message
    assert 'resumed or reset' in stopped.result.error_message


def test_fifty_concurrent_calls_and_goals_are_all_answered(probe, node):
    """One client sends 50 requests at once, then 50 goals (rclpy's services keep 10 requests
    by default and dropped the rest, unanswered; the client keeps as many as it sends)."""
    client = probe.node.create_client(GetSimulationState, f'{NODE}/get_simulation_state',
                                      qos_profile=QoSProfile(depth=1000))
    probe.spin_until(client.service_is_ready, 'the service get_simulation_state')
    futures = [client.call_async(GetSimulationState.Request()) for _ in range(50)]
    for future in futures:
        assert probe.result(future).state.state == SimulationState.STATE_PLAYING
    assert probe.result(set_state(probe, SimulationState.STATE_PAUSED)).result.result == OK
    deep = QoSProfile(depth=1000)
    client = ActionClient(probe.node, SimulateSteps, f'{NODE}/simulate_steps',
                          goal_service_qos_profile=deep, result_service_qos_profile=deep,
                          cancel_service_qos_profile=deep)
    probe.spin_until(client.server_is_ready, 'the action server')
    goals = [client.send_goal_async(SimulateSteps.Goal(steps=10**7)) for _ in range(50)]
    handles = [probe.result(goal, 'a goal response') for goal in goals]
    assert all(handle.accepted for handle in handles)
    results = [handle.get_result_async() for handle in handles]
    # Each newer goal takes over from the one before; the one left is cancelled. Every goal
    # gets a result with its reason.
    probe.spin_until(lambda: sum(r.done() for r in results) >= 49, '49 superseded goals')
    [last] = [handle for handle, r in zip(handles, results) if not r.done()]
    probe.result(last.cancel_goal_async())
    answers = [probe.result(r).result.result for r in results]
    superseded = [a for a in answers if 'took over' in a.error_message]
    cancelled = [a for a in answers if a.error_message.startswith('cancelled after')]
    assert (len(superseded), len(cancelled)) == (49, 1), [a.error_message for a in answers]
    client.destroy()


@pytest.mark.parametrize('how', ['goal', 'service'])
def test_quitting_answers_the_goal_or_step_call_running(probe, node, how):
    """The answer comes before the node leaves (it used to leave the client waiting)."""
    assert probe.result(set_state(probe, SimulationState.STATE_PAUSED)).result.result == OK
    client = ActionClient(probe.node, SimulateSteps, f'{NODE}/simulate_steps')
    if how == 'goal':
        probe.spin_until(client.server_is_ready, 'the action server')
        goal = probe.result(client.send_goal_async(SimulateSteps.Goal(steps=2**63)))
        running = goal.get_result_async()
    else:
        running = call_async(probe, StepSimulation, 'step_simulation',
                             StepSimulation.Request(steps=2**63 - 1))
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 20, 'the steps to run', process=node)
    assert probe.result(set_state(probe, SimulationState.STATE_QUITTING)).result.result == OK
    ended = probe.result(running, 'the answer after QUITTING')
    result = ended.result.result if how == 'goal' else ended.result
    assert result.result == Result.RESULT_OPERATION_FAILED
    assert 'the run ended after' in result.error_message
    code, _, err = finish(node)
    assert code == 0 and 'Traceback' not in err, err
    client.destroy()


@pytest.mark.parametrize('signal_number', [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize('how', ['goal', 'service'])
def test_a_signal_during_a_goal_or_step_call_stops_the_node_quietly(probe, node, how,
                                                                    signal_number):
    """A signal shuts the context down while a call steps the world; the call's next step or
    the goal's next feedback cannot be published. It used to print rclpy's traceback of the
    goal's abort (itself a publication) and an ERROR line for the step call."""
    assert probe.result(set_state(probe, SimulationState.STATE_PAUSED)).result.result == OK
    client = ActionClient(probe.node, SimulateSteps, f'{NODE}/simulate_steps')
    if how == 'goal':
        probe.spin_until(client.server_is_ready, 'the action server')
        assert probe.result(client.send_goal_async(SimulateSteps.Goal(steps=2**63))).accepted
    else:
        call_async(probe, StepSimulation, 'step_simulation',
                   StepSimulation.Request(steps=2**63 - 1))
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 20, 'the steps to run', process=node)
    node.send_signal(signal_number)
    code, out, err = finish(node)
    assert code == 0, err
    assert 'Traceback' not in err and '[ERROR]' not in err + out, err
    assert 'Failed to publish' not in err, err
    client.destroy()


def test_simulate_says_how_far_it_got_when_the_world_stops_under_it(probe, node):
    """ball_world_cli simulate, the world stopped by SIGINT mid-goal (a goal it cannot answer
    any more): the CLI gives up after --timeout without a step, saying after how many (it
    used to say the count of when it began waiting: 1)."""
    assert probe.result(set_state(probe, SimulationState.STATE_PAUSED)).result.result == OK
    client = start([executable('ball_world_cli'), '--timeout', '3', 'simulate', str(10**9)])
    before = len(node.stats)
    probe.spin_until(lambda: len(node.stats) > before + 250, 'the goal to step', process=node)
    node.send_signal(signal.SIGINT)
    assert finish(node)[0] == 0
    code, out, err = finish(client)
    assert code == 1 and 'Traceback' not in err, (out, err)
    [line] = err.splitlines()
    assert line.startswith('ball_world_cli: simulate: no step done for 3 s (after '), line
    done = int(line.split('(after ')[1].split(' of ')[0])
    assert done >= 200 and line.endswith(f'of {10**9}): did the world stop?'), line


def test_spawnables_echo_a_bounded_remark_and_control_characters_are_no_names(probe, node):
    answer = probe.call(GetSpawnables, f'{NODE}/get_spawnables', GetSpawnables.Request(
        sources=[f'/very/long/source/{i}/' + 'x' * 60 for i in range(10_000)]))
    assert answer.result.result == OK
    assert '10,000 sources ignored' in answer.result.error_message
    assert len(answer.result.error_message) < 400
    for name in ('ab\x01c', 'tab\there', 'bell\x07', 'del\x7f'):
        for renaming in (False, True):
            spawned = probe.call(SpawnEntity, f'{NODE}/spawn_entity', SpawnEntity.Request(
                name=name, allow_renaming=renaming, uri='ball',
                initial_pose=pose_at(5.0, 5.0)))
            assert spawned.result.result == SpawnResult.NAME_INVALID, (name, spawned)
            assert 'control characters' in spawned.result.error_message


class _Logger:
    def __init__(self):
        self.lines = []

    def error(self, line):
        self.lines.append(line)


class _Context:
    def __init__(self, up):
        self.up = up

    def ok(self):
        return self.up


class _Node:
    """What ros.calls needs of a node: a logger, `finished`, its context and wake()."""

    def __init__(self, context_up=True):
        self.logger = _Logger()
        self.finished = False
        self.context = _Context(context_up)

    def get_logger(self):
        return self.logger

    def wake(self):
        pass


class _Unprintable(Exception):
    def __str__(self):
        raise ValueError('Exceeds the limit (4300 digits) for integer string conversion')


@pytest.mark.parametrize('error', [OverflowError('int too large to convert to float'),
                                   RecursionError('maximum recursion depth exceeded'),
                                   ValueError('x' * 100_000), _Unprintable(), KeyError(7)])
def test_any_exception_of_a_callback_is_one_bounded_answer_and_one_log_line(error):
    """The class behind every crash of issue 19: whatever a callback raises, plain or
    coroutine, the request gets RESULT_OPERATION_FAILED and the log one line."""
    def plain(request, response):
        response.entity_name = 'half filled'
        raise error

    async def coroutine(request, response):
        raise error

    for callback in (plain, coroutine):
        node = _Node()
        calls = Calls(node)
        answer = calls.guarded('spawn_entity', callback)(SpawnEntity.Request(),
                                                         SpawnEntity.Response())
        if callback is coroutine:
            with pytest.raises(StopIteration) as done:
                answer.send(None)
            answer = done.value.value
            assert calls.in_flight == 0
        assert answer.result.result == Result.RESULT_OPERATION_FAILED
        assert answer.entity_name == ''
        assert type(error).__name__ in answer.result.error_message
        assert len(answer.result.error_message) < 300
        assert node.logger.lines == [answer.result.error_message]
        calls.sender.close()


def test_a_callback_failing_because_the_node_is_going_is_answered_without_a_log_line():
    """After a signal the context is down: the answer cannot be sent and a log line cannot
    be published (rcl would print an error of its own for it)."""
    def publishes(request, response):
        raise RuntimeError("Failed to publish: publisher's context is invalid")

    node = _Node(context_up=False)
    calls = Calls(node)
    answer = calls.guarded('step_simulation', publishes)(StepSimulation.Request(),
                                                         StepSimulation.Response())
    assert answer.result.result == Result.RESULT_OPERATION_FAILED
    assert node.logger.lines == []
    calls.sender.close()
