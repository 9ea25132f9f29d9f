"""Controllers beside the physics: what they see (closed forms), when they are asked, what
becomes of what they return, how they fail, and that a run re-simulates without them.

In-process tests give the Simulation a plain object as its controller (the node and
ball_world_sim give it user_code.controller.ControllerProcess, tested below through real
worker processes and through the tools themselves).
"""
import math

import numpy as np
import pytest

from ball_world.agents.control import Observation
from ball_world.controllers.flocking import Flocking
from ball_world.controllers.wander import Wander
from ball_world.core.agents import CommandRejected
from ball_world.core.parameters import ParameterError
from ball_world.simulation import build, Simulation
from ball_world.tools import resim, sim
from ball_world.user_code import checks
from ball_world.user_code.controller import ControllerProcess
from ball_world.user_code.describe import UserCodeError

SPEC = 'test_controllers.py:Local'


class Local:
    """A controller in this process: keeps what it saw, returns `reply(obs)`, checked as a
    ControllerProcess checks it."""

    def __init__(self, reply=None):
        self.seen = []
        self.reply = reply or (lambda obs: np.zeros((len(obs.names), 3)))

    def act(self, obs):
        self.seen.append(obs)
        return checks.commands(self.reply(obs), len(obs.names), SPEC, f't = {obs.time}')


def world(**overrides):
    """Two agents facing +x in an empty 10 m box, scanners of 4 beams, no noise."""
    parameters = {
        'arena': [0.0, 0.0, 10.0, 10.0], 'random.count': 0, 'dt': 0.1,
        'balls.x': [2.0, 5.0, 8.0], 'balls.y': [5.0, 5.0, 2.0],
        'balls.vx': [0.0, 0.0, 0.0], 'balls.vy': [0.0, 0.0, 0.0],
        'balls.radius': [0.2, 0.2, 0.2], 'balls.mass': [1.0, 1.0, 1.0],
        'agents': ['ball_0', 'ball_2'], 'agent.drive': 'diff', 'agent.topics': 'none',
        'agent.scan.samples': 4, 'agent.scan.angle_min': 0.0,
        'agent.scan.angle_max': 1.5 * math.pi, 'agent.scan.noise_stddev': 0.0,
        'agent.scan.rate_hz': 10.0, 'controller': SPEC, 'controller.rate_hz': 4.0}
    parameters.update(overrides)
    return parameters


def test_it_is_asked_at_its_rate_of_simulated_time_and_sees_the_truth_in_closed_form():
    controller = Local()
    simulation = Simulation(world(), controller=controller)
    for _ in range(10):
        simulation.step()
    # dt 100 ms, period 250 ms: after steps 0, 3 (300 ms), 5 (500 ms) and 8 (800 ms).
    assert [round(obs.time, 9) for obs in controller.seen] == [0.0, 0.3, 0.5, 0.8]
    first = controller.seen[0]
    assert first.names == ('ball_0', 'ball_2')
    np.testing.assert_array_equal(first.truth, [[2.0, 5.0, 0.0], [8.0, 2.0, 0.0]])
    np.testing.assert_array_equal(first.odom, first.truth)  # no odometry noise
    np.testing.assert_array_equal(first.twist, np.zeros((2, 3)))
    # Beams at 0, pi/2, pi, 3 pi/2 from (2, 5) and (8, 2) in the 10 m box: ball_1 (at x 5,
    # radius 0.2) is 2.8 m ahead of ball_0; the walls are the rest.
    np.testing.assert_array_equal(  # float32, as a LaserScan carries them
        first.scan, np.float32([[2.8, 5.0, 2.0, 5.0], [2.0, 8.0, 8.0, 2.0]]))
    assert first.scan.dtype == np.float32 and first.scan_time.tolist() == [0.0, 0.0]
    assert first.fan == pytest.approx((0.0, 0.5 * math.pi, 0.25, 12.0), rel=1e-15)
    np.testing.assert_array_equal(first.bumper, np.zeros((2, 2)))
    with pytest.raises(ValueError):
        first.truth[0, 0] = 1.0  # read-only: what it sees is what the world holds


def test_commands_take_the_road_of_cmd_vel_and_their_agents_refuse_cmd_vel():
    # v 1 m/s, turning 0.5 rad/s from the first call: a diff drive follows the heading.
    controller = Local(lambda obs: np.tile([1.0, 0.7, 0.5], (len(obs.names), 1)))
    simulation = Simulation(world(**{'controller.agents': ['ball_2']}), controller=controller)
    record, _ = simulation.step()
    assert [(c.name, c.vx, c.vy, c.wz) for c in record.commands] == [
        ('ball_2', 1.0, 0.7, 0.5)]
    np.testing.assert_array_equal(record.agents.command_rows, [[2.0, 1.0, 0.7, 0.5]])
    assert record.agents.yaws.tolist() == pytest.approx([0.0, 0.05], abs=1e-15)  # 0.5 rad/s
    assert all(obs.names == ('ball_2',) for obs in controller.seen)
    with pytest.raises(CommandRejected, match='driven by the controller'):
        simulation.command('ball_2', 1.0, 0.0, 0.0)
    simulation.command('ball_0', 0.5, 0.0, 0.0)  # not one of controller.agents
    assert simulation.rejected == {'cmd_vel_controlled': 1}


def test_the_bumper_sums_the_collision_impulses_since_the_last_call_in_base_link():
    # ball_1 (1 kg) comes at ball_0 (1 kg, at rest, heading +y) along -x at 2 m/s: the
    # head-on elastic collision gives ball_0 the impulse (-2, 0) N s in the world, which is
    # (0, +2) in its base_link (forward +y, left -x).
    controller = Local()
    parameters = world(**{'balls.vx': [0.0, -2.0, 0.0], 'agent.max_accel': 0.0,
                          'controller.rate_hz': 1.0})
    simulation = Simulation(parameters, controller=controller)
    simulation.set_state('ball_0', 2.0, 5.0, 0.0, 0.0, yaw=math.pi / 2)
    for _ in range(21):  # they meet at 1.3 s; ball_0 reaches the wall after 2.1 s
        simulation.step()
    assert [round(obs.time, 9) for obs in controller.seen] == [0.0, 1.0, 2.0]
    np.testing.assert_array_equal(controller.seen[1].bumper, np.zeros((2, 2)))
    np.testing.assert_allclose(controller.seen[2].bumper, [[0.0, 2.0], [0.0, 0.0]],
                               rtol=0, atol=1e-12)


def test_controller_agents_name_agents_and_a_bad_command_stops_the_run_in_one_line():
    with pytest.raises(ParameterError, match="controller.agents.*'ball_1' is not one of"):
        build(world(**{'controller.agents': ['ball_1']}))
    with pytest.raises(ParameterError, match='controller'):
        build(world(controller='not a spec'))
    huge = Simulation(world(), controller=Local(lambda obs: np.full((2, 3), 1e300)))
    with pytest.raises(UserCodeError, match='that cmd_vel would refuse'):
        huge.step()
    assert huge.step_index == 0  # the step was not taken


def polarization(yaws):
    """|mean heading|: 1 when every robot heads the same way, near 0 when they scatter."""
    return math.hypot(np.cos(yaws).mean(), np.sin(yaws).mean())


def test_flocking_aligns_a_scattered_swarm_and_wander_keeps_every_robot_moving():
    count = 40
    rng = np.random.default_rng(3)
    positions = [(x, y) for x in np.arange(20.0, 31.0, 1.5) for y in np.arange(20.0, 28.0, 1.5)]
    parameters = {'arena': [0.0, 0.0, 50.0, 50.0], 'random.count': 0, 'dt': 0.1,
                  'balls.x': [p[0] for p in positions[:count]],
                  'balls.y': [p[1] for p in positions[:count]],
                  'balls.vx': [0.0] * count, 'balls.vy': [0.0] * count,
                  'balls.radius': [0.15] * count, 'balls.mass': [1.0] * count,
                  'agents': [f'ball_{i}' for i in range(count)], 'agent.drive': 'diff',
                  'agent.topics': 'none', 'agent.scan.samples': 16,
                  'agent.scan.range_max': 2.0, 'controller': SPEC}
    flock = Simulation(parameters, controller=Flocking())
    for name, yaw in zip(flock.agents.names, rng.uniform(-math.pi, math.pi, count)):
        flock.set_state(name, *flock.world.positions[flock.index_of[name]], 0.0, 0.0, yaw=yaw)
    before = polarization(flock.agents.yaws())
    for _ in range(200):
        flock.step()
    assert before < 0.5 and polarization(flock.agents.yaws()) > 0.95
    wander = Simulation(parameters, controller=Wander())
    start = wander.world.positions.copy()
    for _ in range(100):
        wander.step()
    moved = np.hypot(*(wander.world.positions - start).T)
    assert moved.min() > 0.5  # nobody stuck in 10 s


class Shape:
    def act(self, obs):
        return np.zeros((len(obs.names), 2))


class Raises:
    def act(self, obs):
        return {}['missing']


class Writes:
    def act(self, obs):
        obs.truth[0, 0] = 5.0


class Exits:
    def act(self, obs):
        import os
        os._exit(3)


class Hangs:
    def act(self, obs):
        while True:
            pass


class Fine:
    def act(self, obs):
        return [[0.5, 0.0, 0.1]] * len(obs.names)


@pytest.mark.parametrize('name, words', [
    ('Shape', 'returned an array of shape (2, 2) at t = 0 s, not (2, 3)'),
    ('Raises', "Raises.act raised KeyError: 'missing' (at test_controllers.py:"),
    ('Writes', 'Writes.act raised ValueError: assignment destination is read-only'),
    ('Exits', 'exited with status 3: os._exit(3) (at test_controllers.py:'),
    ('Hangs', 'ran past the controller deadline of 1.5 s (at test_controllers.py:'),
    ('Missing', 'test_controllers.py has no class Missing'),
])
def test_every_way_a_controller_fails_is_one_line_naming_it(name, words):
    spec = f'{__file__}:{name}'
    observation = Observation(0.0, ('a', 'b'), *(np.zeros((2, 3)),) * 3, np.zeros((2, 0)),
                              np.zeros(2), np.zeros((2, 2)), (0.0, 0.0, 0.0, 0.0))
    # Only Hangs needs a short deadline; for the others it would also time the worker's
    # import of this module, seconds on a loaded machine.
    deadline_s = 1.5 if name == 'Hangs' else 60.0
    with pytest.raises(UserCodeError) as caught:
        with ControllerProcess(spec, deadline_s=deadline_s) as controller:
            controller.act(observation)
    text = str(caught.value)
    assert words in text and '\n' not in text and (name == 'Missing' or spec in text)


def test_a_controller_in_its_worker_gets_what_the_simulation_sees():
    with ControllerProcess(f'{__file__}:Fine') as controller:
        simulation = Simulation(world(), controller=controller)
        record, _ = simulation.step()
    np.testing.assert_array_equal(record.agents.command_rows,
                                  [[0.0, 0.5, 0.0, 0.1], [2.0, 0.5, 0.0, 0.1]])


@pytest.mark.parametrize('topics', ['none', 'each'])
def test_a_run_of_ball_world_sim_resimulates_without_the_controller(tmp_path, capsys, topics):
    params = tmp_path / 'swarm.yaml'
    params.write_text(
        '/**:\n  ros__parameters:\n    dt: 0.1\n    arena: [0.0, 0.0, 12.0, 12.0]\n'
        '    random.count: 30\n    random.radius: [0.1, 0.2]\n'
        '    agents: [ball_0, ball_1, ball_2, ball_3, ball_4, ball_5]\n'
        f'    agent.drive: diff\n    agent.topics: {topics}\n    agent.scan.samples: 16\n'
        '    agent.scan.range_max: 2.0\n    agent.odom.noise: [0.01, 0.01, 0.01, 0.01]\n'
        '    controller: ball_world.controllers.wander:Wander\n'
        '    controller.agents: [ball_1, ball_2, ball_4, ball_5]\n')
    recording = tmp_path / 'run.mcap'
    assert sim.main(['--params-file', str(params), '--steps', '120',
                     '--record', str(recording)]) == 0
    out = capsys.readouterr().out
    assert 'controller ball_world.controllers.wander:Wander at 10 Hz' in out
    assert '120 steps in' in out and 'real-time factor' in out
    assert resim.main([str(recording)]) == 0
    assert 'bit-identically' in capsys.readouterr().out


def test_ball_world_sim_refuses_bad_input_in_one_line(tmp_path, capsys):
    params = tmp_path / 'w.yaml'
    params.write_text('/**:\n  ros__parameters:\n    random.count: 2\n    agents: [ball_0]\n')
    assert sim.main(['--params-file', str(params), '--controller', 'nowhere:X']) == 2
    assert sim.main(['--params-file', str(tmp_path / 'none.yaml')]) == 2
    assert sim.main(['--params-file', str(params), '--controller', f'{__file__}:Raises',
                     '--steps', '3']) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all(line.startswith('ball_world_sim: ') for line in err)
    assert 'importing nowhere failed: ModuleNotFoundError' in err[0]
    assert 'cannot read it' in err[1] and 'step 1: ' in err[2]
