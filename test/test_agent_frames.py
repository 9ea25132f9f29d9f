"""Agents' frames tf2 takes: no leading '/', no whitespace, no empty segment, no clash.

tf2 refuses a frame id that starts with '/' (a ROS 1 global name); whitespace or 'a//b' give
frames that look alike and are not; a frame_id that is an agent's own odom or base_link
makes /tf_static a transform from a frame to itself. Each is refused in one line naming its
parameter: at start, on ros2 param set, and for a spawned agent.
"""
from ball_world_testing.harness import run_tool
import pytest

from ball_world.core import parameters as table
from ball_world.core.edits import Ball, EditRefused
from ball_world.core.scenario import ScenarioError
from ball_world.simulation import build, Simulation, SpawnRequest


@pytest.mark.parametrize('name, value, words', [
    ('frame_prefix', '/', "starts with '/'"),
    ('frame_prefix', '/robots/', "starts with '/'"),
    ('frame_prefix', 'a//', "empty segment ('//')"),
    ('frame_prefix', 'w 1/', 'whitespace'),
    ('frame_prefix', '\tw/', 'control characters'),
    ('frame_id', '/world', "starts with '/'"),
    ('frame_id', 'map/', "ends with '/'"),
    ('frame_id', 'my map', 'whitespace'),
    ('frame_id', 'a//b', "empty segment ('//')"),
    ('frame_id', ' ', 'must name a frame'),
])
def test_frames_tf2_would_refuse_are_refused(name, value, words):
    with pytest.raises(table.ParameterError) as refused:
        table.check(name, value)
    assert str(refused.value).startswith(f"parameter '{name}': ")
    assert words in str(refused.value)


@pytest.mark.parametrize('name, value', [('frame_prefix', ''), ('frame_prefix', 'w1/'),
                                         ('frame_prefix', 'sim2_'), ('frame_id', 'map'),
                                         ('frame_id', 'sim2/world')])
def test_ordinary_frames_are_taken(name, value):
    assert table.check(name, value) == value


@pytest.mark.parametrize('frame_id, prefix', [('ball_0/odom', ''), ('ball_1/base_link', ''),
                                              ('w/ball_1/odom', 'w/')])
def test_a_frame_id_that_is_an_agents_own_frame_is_refused(frame_id, prefix):
    with pytest.raises(ScenarioError) as refused:
        build({'random.count': 3, 'agents': ['ball_0', 'ball_1'], 'frame_id': frame_id,
               'frame_prefix': prefix})
    assert str(refused.value).startswith("parameter 'frame_id': ")
    assert 'own frame' in str(refused.value) and '\n' not in str(refused.value)


def test_a_frame_id_named_like_a_ball_that_is_no_agent_is_fine():
    build({'random.count': 3, 'agents': ['ball_0'], 'frame_id': 'ball_2/odom'})
    build({'random.count': 3, 'agents': ['ball_0'], 'frame_id': 'ball_0/odom',
           'frame_prefix': 'w/'})


def test_an_agent_spawned_under_the_frame_id_is_refused():
    simulation = Simulation({'random.count': 0, 'frame_id': 'rover/odom'})
    [refused], _ = simulation.spawn([SpawnRequest('rover', False,
                                                  Ball(5.0, 5.0, 0.0, 0.0, 0.3, 1.0),
                                                  agent=True)])
    assert isinstance(refused, EditRefused) and 'own frame' in str(refused)
    [name], _ = simulation.spawn([SpawnRequest('rover', False,
                                               Ball(5.0, 5.0, 0.0, 0.0, 0.3, 1.0))])
    assert name == 'rover'  # a plain ball has no frames


@pytest.mark.parametrize('argument, words', [
    ('frame_prefix:=/', "parameter 'frame_prefix'"),
    ('frame_id:=ball_0/odom', "parameter 'frame_id'")])
def test_the_node_refuses_them_in_one_line(argument, words):
    code, out, err = run_tool('ball_world', '--ros-args', '-p', 'random.count:=2',
                              '-p', 'agents:=[ball_0]', '-p', argument)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and words in lines[0], err
    assert 'Traceback' not in out + err
