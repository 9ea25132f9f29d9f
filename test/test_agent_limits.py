"""The agents parameter's range is what the node runs: its edges start, step and stop.

At MAX_AGENTS_EACH (1,000) agents with topics of their own the node makes 4,000 DDS
entities: it says so while it makes them, steps, and stops on SIGINT (leaving the graph
within its budget, the rest with the process). A swarm (agent.topics none) makes none, up to
MAX_AGENTS (10,000). One more than either is refused in one line, and so is a spawned agent
past the limit.
"""
import time

from ball_world_testing.harness import finish, node_command, run_tool
from geometry_msgs.msg import PoseArray
import pytest

from ball_world.core.edits import Ball, EditRefused, TOO_MANY
from ball_world.core.parameters import MAX_AGENTS, MAX_AGENTS_EACH
from ball_world.simulation import Simulation, SpawnRequest


def world(count):
    side = (count * 0.2) ** 0.5 * 3.0
    return ('rate_hz:=50.0', 'markers.rate_hz:=0.0', f'random.count:={count}',
            'random.radius:=[0.1, 0.2]', f'arena:=[0.0, 0.0, {side:.1f}, {side:.1f}]',
            'agents:=[' + ', '.join(f'ball_{i}' for i in range(count)) + ']',
            'agent.scan.samples:=0')


def test_the_most_agents_start_step_and_stop(probe, processes):
    process = processes.start(node_command(*world(MAX_AGENTS_EACH)))
    stamps = probe.listen(PoseArray, 'balls',
                          keep=lambda m: m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
    probe.spin_until(lambda: len(stamps) > 20, 'twenty steps of 1,000 agents', process=process)
    assert len(set(stamps)) == len(stamps)  # steps, each its own time
    process.send_signal(2)
    code, _, err = finish(process)
    assert code == 0, err
    assert f'making the topics of {MAX_AGENTS_EACH:,} agents' in err
    assert 'Traceback' not in err


def test_a_swarm_of_the_most_agents_starts_steps_and_stops(probe, processes):
    began = time.monotonic()
    process = processes.start(node_command(*world(MAX_AGENTS), 'agent.topics:=none',
                                           'rate_hz:=10.0'))
    sizes = probe.listen(PoseArray, 'balls', keep=lambda m: (
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, len(m.poses)))
    probe.spin_until(lambda: len(sizes) > 5, 'five steps of 10,000 agents', process=process)
    started = time.monotonic() - began
    assert len({stamp for stamp, _ in sizes}) == len(sizes)
    assert {size for _, size in sizes} == {MAX_AGENTS}
    topics = [name for name, _ in probe.node.get_topic_names_and_types()]
    assert not [t for t in topics if t.startswith('/ball_') and not t.startswith('/ball_world/')
                or t in ('/tf', '/tf_static')]
    stop = time.monotonic()
    process.send_signal(2)
    code, _, err = finish(process)
    stopped = time.monotonic() - stop
    assert code == 0, err
    assert 'Traceback' not in err and 'making the topics' not in err
    print(f'10,000-agent swarm: first steps {started:.1f} s after launch, exit {stopped:.1f} s '
          'after SIGINT')


@pytest.mark.parametrize('count, topics, most', [(MAX_AGENTS_EACH + 1, 'each', '1,000'),
                                                 (MAX_AGENTS + 1, 'none', '10,000')])
def test_one_more_agent_is_refused_in_one_line(count, topics, most):
    code, out, err = run_tool('ball_world', '--ros-args', *[
        word for value in (*world(count), f'agent.topics:={topics}') for word in ('-p', value)])
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert "parameter 'agents'" in lines[0] and f'at most {most}' in lines[0]
    assert 'Traceback' not in out + err


def test_a_spawned_agent_past_the_limit_is_refused():
    names = [f'ball_{i}' for i in range(MAX_AGENTS_EACH - 1)]
    simulation = Simulation({'random.count': MAX_AGENTS_EACH - 1,
                             'arena': [0.0, 0.0, 60.0, 60.0],
                             'random.radius': [0.1, 0.2], 'agents': names,
                             'agent.scan.samples': 0})
    requests = [SpawnRequest(f'rover{i}', False, Ball(0.5 + i, 59.5, 0.0, 0.0, 0.1, 1.0),
                             agent=True) for i in range(2)]
    (first, second), _ = simulation.spawn(requests)
    assert first == 'rover0' and len(simulation.agents) == MAX_AGENTS_EACH
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
