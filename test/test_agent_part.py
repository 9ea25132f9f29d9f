"""The agents as one part (ball_world.agents.part): the Simulation's calls around a step.

What the part adds to core.agents is bookkeeping the Simulation used to hold: the agents'
rows in the World's arrays (kept between steps, found again when balls move), commands
taken many at once (a controller's way in), and the frame of a step. Each must give what
the one-by-one path gives.
"""
import numpy as np
import pytest

from ball_world.core.agents import CommandRejected
from ball_world.core.parameters import MAX_AGENTS, MAX_AGENTS_EACH
from ball_world.simulation import Simulation

BASE = {'rate_hz': 50.0, 'random.count': 10, 'random.seed': 4, 'physics.backend': 'numpy',
        'agents': ['ball_2', 'ball_5', 'ball_8'], 'agent.scan.samples': 0}
COMMANDS = np.array([[1.0, 0.5, 0.25], [-0.5, 0.0, 2.0], [0.0, -1.0, -1.5]])


def run(give, steps=20):
    """Records of a run whose commands, given at steps 1 and 10, `give` hands over."""
    simulation = Simulation(BASE)
    records = []
    for k in range(1, steps + 1):
        if k in (1, 10):
            give(simulation, COMMANDS * (1.0 if k == 1 else -0.5))
        records.append(simulation.step()[0])
    return records


def one_by_one(simulation, commands):
    for name, (vx, vy, wz) in zip(simulation.agents.names, commands.tolist()):
        simulation.command(name, vx, vy, wz)


def many(simulation, commands):
    since_ns = (simulation.step_index + 1) * simulation.dt_ns
    simulation.agents.command_many(simulation.agents.names, commands, since_ns)


def test_commands_taken_many_at_once_are_the_commands_taken_one_by_one():
    single, batched = run(one_by_one), run(many)
    for a, b in zip(single, batched):
        assert a.positions.tobytes() == b.positions.tobytes()
        assert [c.cdr for c in a.commands] == [c.cdr for c in b.commands]
        assert [i.cdr for i in a.impulses] == [i.cdr for i in b.impulses]
        assert a.agents.odom_cdr == b.agents.odom_cdr and a.agents.tf_cdr == b.agents.tf_cdr
    assert len(single[0].commands) == 3 and len(single[9].commands) == 3


@pytest.mark.parametrize('names, commands, words', [
    (['ball_2', 'ball_5'], COMMANDS, r'of shape \(2, 3\), got \(3, 3\)'),
    (['ball_2', 'ball_5', 'ball_0'], COMMANDS, "no agent named 'ball_0'"),
    (['ball_2', 'ball_5', 'ball_8'], np.where(COMMANDS == 2.0, np.nan, COMMANDS),
     'not finite'),
])
def test_a_bad_row_refuses_the_whole_batch(names, commands, words):
    simulation = Simulation(BASE)
    with pytest.raises(CommandRejected, match=words):
        simulation.agents.command_many(names, commands, simulation.dt_ns)
    assert simulation.agents.take_commands() == ()
    assert [simulation.agents.state.last_command(name) for name in BASE['agents']] == \
        [None] * 3


def test_rows_are_found_again_when_balls_move_in_the_arrays():
    simulation = Simulation(BASE)
    simulation.step()  # the rows are looked up and kept
    simulation.delete('ball_0')  # every agent moves one row down
    simulation.delete('ball_5')  # an agent goes
    record, _ = simulation.step()
    index_of = simulation.index_of
    assert record.agents.names == ('ball_2', 'ball_8')
    assert record.agents.indices.tolist() == [index_of['ball_2'], index_of['ball_8']] == [1, 6]
    assert not record.agents.indices.flags.writeable  # shared by records: nobody writes it


def test_only_the_kinds_someone_takes_are_encoded_and_a_swarm_encodes_none():
    parameters = {**BASE, 'agent.scan.samples': 8, 'agent.scan.rate_hz': 50.0}
    simulation = Simulation(parameters)
    whole, _ = simulation.step()
    simulation.agents.encode = frozenset({'odom'})  # as the node says when only odom is taken
    narrow, _ = simulation.step()
    assert len(whole.agents.odom_cdr) == len(narrow.agents.odom_cdr) == 3
    assert whole.agents.tf_cdr and whole.agents.ground_truth_cdr
    assert all(scan.cdr for scan in whole.agents.scans)
    assert narrow.agents.tf_cdr == b'' and narrow.agents.ground_truth_cdr == ()
    assert [scan.cdr for scan in narrow.agents.scans] == [b''] * 3
    assert [len(scan.ranges) for scan in narrow.agents.scans] == [8] * 3  # still scanned
    swarm = Simulation({**parameters, 'agent.topics': 'none'})
    record, _ = swarm.step()
    frame = record.agents
    assert not frame.topics and frame.odom_cdr == () and frame.tf_cdr == b''
    assert frame.tf_static_cdr is None and [scan.cdr for scan in frame.scans] == [b''] * 3
    assert frame.yaws.shape == (3,) and frame.twists.shape == (3, 3)  # the state is all there


@pytest.mark.parametrize('topics, most', [('each', MAX_AGENTS_EACH), ('none', MAX_AGENTS)])
def test_a_world_takes_agents_up_to_the_limit_of_its_topics(topics, most):
    assert Simulation({**BASE, 'agent.topics': topics}).agents.limit == most
