"""ball_world_cli as a user runs it: the installed command against a real node process, each
command a process of its own, checked by what the world then answers and does."""
from ball_world_testing.harness import Children, run_tool
import pytest
from simulation_interfaces.msg import Result
from simulation_interfaces.srv import GetEntityState

NAMESPACE = '/sim2'
#: Three balls of 4 kg at rest, 3 m apart: an impulse J gives exactly v = J / 4 (a power of
#: two), and nothing touches anything during the few steps taken here.
WORLD = ['random.count:=0', 'balls.x:=[2.0, 5.0, 8.0]', 'balls.y:=[5.0, 5.0, 5.0]',
         'balls.vx:=[0.0, 0.0, 0.0]', 'balls.vy:=[0.0, 0.0, 0.0]',
         'balls.radius:=[0.3, 0.3, 0.3]', 'balls.mass:=[4.0, 4.0, 4.0]', 'rate_hz:=50.0',
         'start_paused:=true']


#: How long the tool may wait for the world (its default is 10 s): discovery on two loaded
#: cores can take longer; only a hang takes this long.
TIMEOUT = ('--timeout', '60')


def cli(*args):
    """(exit code, stdout, stderr) of ball_world_cli driving the world in NAMESPACE."""
    return run_tool('ball_world_cli', '--ns', NAMESPACE, *TIMEOUT, *args)


def ok(*args):
    code, out, err = cli(*args)
    assert code == 0, err
    return out.splitlines()


def refused(*args):
    """The one stderr line of a command the world refused (exit 1)."""
    code, out, err = cli(*args)
    assert code == 1 and out == '', (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    return lines[0]


def ball_state(name):
    """(time in s, x, y, vx, vy) of a ball, as the world answers GetEntityState."""
    stamp, header, line = ok('state', name)
    time = float(stamp.split()[2])
    words = line.split()
    assert header.split()[1::2] == ['x', 'y', 'vx', 'vy', 'radius', 'mass'], header
    assert words[0] == name and len(words) == 7, line
    return (time, *map(float, words[1:5]))


def world_state(probe, name):
    """(time in s, x, y, vx, vy) of a ball as the world answers a probe's GetEntityState: what
    a command did, checked without a process of its own (the state command is checked too)."""
    answer = probe.call(GetEntityState, f'{NAMESPACE}/ball_world/get_entity_state',
                        GetEntityState.Request(entity=name))
    assert answer.result.result == Result.RESULT_OK, answer.result.error_message
    stamp, state = answer.state.header.stamp, answer.state
    return (stamp.sec + stamp.nanosec * 1e-9, state.pose.position.x, state.pose.position.y,
            state.twist.linear.x, state.twist.linear.y)


@pytest.fixture(scope='module')
def shared_world():
    """One world process for the file: each test leaves it as it found it (paused at step 0,
    three balls, the parameters of WORLD), which the next one's first command shows."""
    with Children() as children:
        yield children.start_node(*WORLD, ros_args=['-r', f'__ns:={NAMESPACE}'])


@pytest.fixture
def world(shared_world):
    yield shared_world
    assert shared_world.poll() is None, shared_world.communicate()


def test_push_step_and_the_simulation_state(world, probe):
    assert ok('status')[:2] == ['state: stopped (paused at step 0)', 'step: 0']
    t0, *_ = ball_state('ball_1')
    # The impulse topic has no answer: the line says what is known (delivered) and what not.
    assert ok('push', 'ball_1', '0.5', '-0.25') == [
        f'pushed ball_1 by (0.5, -0.25) N s on {NAMESPACE}/impulse: delivered; applied before '
        'the next step unless the world refuses it then as too fast (its log says so)']
    assert ok('step') == ['stepped 1']
    t1, _, _, vx, vy = world_state(probe, 'ball_1')
    # v = J / m exactly, one step of 1/50 s later than before (whatever step it was at).
    assert (vx, vy) == (0.125, -0.0625) and t1 == pytest.approx(t0 + 0.02, abs=1e-9)
    assert ok('pause') == ['already paused']
    assert ok('resume') == ['playing']
    assert 'RESULT_INCORRECT_STATE' in refused('step', '3')
    assert ok('pause') == ['paused']
    assert ok('reset') == ['reset to step 0']
    assert ok('status')[0] == 'state: stopped (paused at step 0)'
    assert world_state(probe, 'ball_1') == (0.0, 5.0, 5.0, 0.0, 0.0)


def test_spawn_set_state_and_delete_through_simulation_interfaces(world, probe):
    assert ok('spawn', 'red', '5', '8', '--radius', '0.25', '--mass', '2', '--vx', '1') == [
        'spawned red at (5, 8)']
    assert ok('info', 'red') == ['red: ball, radius 0.25 m, mass 2 kg']
    assert 'NAME_NOT_UNIQUE' in refused('spawn', 'red', '2', '8')
    assert ok('set-state', 'red', '2', '8') == ['set red: x 2  y 8  vx 1  vy 0']
    assert world_state(probe, 'red')[1:] == (2.0, 8.0, 1.0, 0.0)  # the velocity kept
    ok('set-state', 'red', '2', '8', '0', '-1')
    assert world_state(probe, 'red')[1:] == (2.0, 8.0, 0.0, -1.0)
    assert 'INVALID_POSE' in refused('set-state', 'red', '5', '5')  # on ball_1
    lines = ok('state')
    assert [line.split()[0] for line in lines[2:]] == ['ball_0', 'ball_1', 'ball_2', 'red']
    assert lines[-1].split()[-2:] == ['0.25', '2']  # red's radius and mass
    assert ok('delete', 'red') == ['deleted red']
    assert refused('state', 'red') == (
        "ball_world_cli: state: refused (RESULT_NOT_FOUND): no entity named 'red'")
    assert refused('push', 'red', '1', '0') == (
        "ball_world_cli: no ball 'red' in the world (it has 3: ball_0, ball_1, ball_2)")


def test_the_namespace_can_come_from_ros_arguments(world):
    code, out, err = run_tool('ball_world_cli', *TIMEOUT, 'status', '--ros-args', '-r',
                              f'__ns:={NAMESPACE}')
    assert (code, out.splitlines()[0]) == (0, 'state: stopped (paused at step 0)'), err


def test_no_world_is_one_line_and_exit_1():
    code, out, err = run_tool('ball_world_cli', '--ns', '/nobody', '--timeout', '1', 'state')
    assert (code, out) == (1, '')
    assert err == ('ball_world_cli: no world answers /nobody/ball_world/get_entities_states '
                   'within 1 s: is ball_world running in namespace /nobody (--ns), named '
                   "'ball_world' (--node)?\n")


@pytest.mark.parametrize('args, problem', [
    (('step', '0'), 'steps must be at least 1'),
    (('push', 'ball_0', 'east', '0'), "not a number: 'east'"),
    (('set-state', 'ball_0', '1', '1', '2'), 'set-state takes NAME X Y, or NAME X Y VX VY'),
    (('--timeout', '0', 'status'), "--timeout: must be more than 0 and at most 3600 s, got '0'"),
    (('--ns', 'bad ns!', 'status'), 'namespace'),
    (('fly',), 'invalid choice'),
    (('status', '--ros-args', '-r'), 'bad ROS arguments'),
])
def test_bad_usage_is_one_line_and_exit_2(args, problem):
    code, out, err = run_tool('ball_world_cli', '--timeout', '1', *args)
    assert code == 2 and problem in err, err
    assert len(err.strip().splitlines()) == 1 and 'Traceback' not in err


def test_parameters_are_set_and_read_as_ros2_param_would(world, probe):
    assert ok('get-param', 'rate_hz') == ['50.0']
    assert ok('set-param', 'rate_hz', '30') == ['set rate_hz to 30']  # an integer, as typed
    assert ok('get-param', 'rate_hz') == ['30.0']  # the world keeps doubles double
    assert ok('set-param', 'arena', '[0, 0, 12, 12]') == ['set arena to [0, 0, 12, 12]']
    assert ok('get-param', 'arena') == ['[0.0, 0.0, 12.0, 12.0]']
    line = refused('set-param', 'rate_hz', '-5.0')
    assert line.startswith('ball_world_cli: set-param rate_hz: refused: ') and 'rate_hz' in line
    assert ok('get-param', 'rate_hz') == ['30.0']
    assert refused('get-param', 'rate') == (
        "ball_world_cli: get-param: the world has no parameter 'rate'")
    # The world as the other tests expect it (a reset would build the 12 m arena).
    probe.set_parameters(f'{NAMESPACE}/ball_world', {'rate_hz': 50.0,
                                                     'arena': [0.0, 0.0, 10.0, 10.0]})
