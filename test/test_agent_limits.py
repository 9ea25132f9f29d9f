"""The agents parameter's range is what the node runs: its edge starts, steps and stops.

At MAX_AGENTS (1,000) agents the node makes 4,000 DDS entities: it says so while it makes
them, steps, and stops on SIGINT (leaving the graph within its budget, the rest with the
process). One more is refused in one line, and so is a spawned agent past the limit.
"""
from ball_world_testing.harness import finish, node_command, run_tool
from geometry_msgs.msg import PoseArray
import pytest

from ball_world.core.edits import Ball, EditRefused, TOO_MANY
from ball_world.core.parameters import MAX_AGENTS
from ball_world.simulation import Simulation, SpawnRequest


def world(count):
    side = (count * 0.2) ** 0.5 * 3.0
    return ('rate_hz:=50.0', 'markers.rate_hz:=0.0', f'random.count:={count}',
            'random.radius:=[0.1, 0.2]', f'arena:=[0.0, 0.0, {side:.1f}, {side:.1f}]',
            'agents:=[' + ', '.join(f'ball_{i}' for i in range(count)) + ']',
            'agent.scan.samples:=0')


def test_the_most_agents_start_step_and_stop(probe, processes):
    process = processes.start(node_command(*world(MAX_AGENTS)))
    stamps = probe.listen(PoseArray, 'balls',
                          keep=lambda m: m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
    probe.spin_until(lambda: len(stamps) > 20, 'twenty steps of 1,000 agents', process=process)
    assert len(set(stamps)) == len(stamps)  # steps, each its own time
    process.send_signal(2)
    code, _, err = finish(process)
    assert code == 0, err
    assert f'making the topics of {MAX_AGENTS:,} agents' in err
    assert 'Traceback' not in err


def test_one_more_agent_is_refused_in_one_line():
    code, out, err = run_tool('ball_world', '--ros-args', *[
        word for value in world(MAX_AGENTS + 1) for word in ('-p', value)])
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert "parameter 'agents'" in lines[0] and 'at most 1,000' in lines[0]
    assert 'Traceback' not in out + err


def test_a_spawned_agent_past_the_limit_is_refused():
    names = [f'ball_{i}' for i in range(MAX_AGENTS - 1)]
    simulation = Simulation({'random.count': MAX_AGENTS - 1, 'arena': [0.0, 0.0, 60.0, 60.0],
                             'random.radius': [0.1, 0.2], 'agents': names,
                             'agent.scan.samples': 0})
    requests = [SpawnRequest(f'rover{i}', False, Ball(0.5 + i, 59.5, 0.0, 0.0, 0.1, 1.0),
                             agent=True) for i in range(2)]
    (first, second), _ = simulation.spawn(requests)
    assert first == 'rover0' and len(simulation.agents) == MAX_AGENTS
    assert isinstance(second, EditRefused) and second.kind == TOO_MANY
    assert 'most it can' in str(second)
    [plain], _ = simulation.spawn([SpawnRequest('stone', False,
                                                Ball(5.0, 59.5, 0.0, 0.0, 0.1, 1.0))])
    assert plain == 'stone'  # a plain ball is still welcome


@pytest.mark.parametrize('count', [0, 1])
def test_few_agents_are_no_trouble(count):
    simulation = Simulation({'random.count': 3, 'agents': [f'ball_{i}' for i in range(count)]})
    record, _ = simulation.step()
    assert (record.agents is None) == (count == 0)
