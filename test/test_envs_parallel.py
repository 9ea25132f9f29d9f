"""The PettingZoo env (ball_world.envs.parallel_env): PettingZoo's own API and seed tests,
robots that collide with each other through the physics, and one robot that is Navigate-v0
bit for bit."""
import warnings

import numpy as np
from pettingzoo.test import parallel_api_test, parallel_seed_test
import pytest

from ball_world.envs import parallel_env
from ball_world.envs.navigate import NavigateEnv

BOX = {'arena': [-2.0, -1.5, 2.0, 1.5], 'random.count': 3, 'random.radius': [0.08, 0.15],
       'random.speed': 0.6, 'agent.max_speed': 0.4, 'agent.scan.range_max': 3.0}
OPTIONS = dict(world=BOX, beams=16, max_episode_steps=15)


def test_pettingzoo_api_test_passes():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        parallel_api_test(parallel_env(agents=3, **OPTIONS), num_cycles=40)
    assert not [str(warning.message) for warning in caught]


def test_pettingzoo_seed_test_passes():
    parallel_seed_test(lambda: parallel_env(agents=3, **OPTIONS), num_cycles=20)


def test_one_robot_is_navigate_bit_for_bit():
    multi = parallel_env(agents=1, **OPTIONS)
    single = NavigateEnv(**OPTIONS)
    seen, _ = multi.reset(seed=9)
    alone, _ = single.reset(seed=9)
    space = single.action_space
    space.seed(1)
    for _ in range(15):
        move = space.sample()
        seen, paid, ended, cut, _ = multi.step({'ball_0': move})
        alone, reward, terminated, truncated, _ = single.step(move)
        assert all(seen['ball_0'][key].tobytes() == alone[key].tobytes() for key in alone)
        assert (paid['ball_0'], ended['ball_0']) == (reward, terminated)
        if terminated:
            break


def test_robots_collide_with_each_other():
    """Two robots driven at each other take the physics' collision: each a bumper impulse,
    equal and opposite momentum changes (the pair's momentum conserved in the contact)."""
    env = parallel_env(agents=2, world={**BOX, 'random.count': 0}, beams=8)
    env.reset(seed=3)
    world = env.task.arenas.worlds[0]
    agents = env.task.arenas.agents
    world.set_ball_state(0, (-0.5, 0.0), (0.0, 0.0))
    world.set_ball_state(1, (0.5, 0.0), (0.0, 0.0))
    agents.set_yaw('0/0', 0.0)
    agents.set_yaw('0/1', np.pi)
    impulses = []
    for _ in range(12):
        _, _, _, _, infos = env.step({'ball_0': np.array([0.4, 0.0], np.float32),
                                      'ball_1': np.array([0.4, 0.0], np.float32)})
        impulses.append((infos['ball_0']['impulse'], infos['ball_1']['impulse']))
        if impulses[-1][0] > 0.0:
            break
    first, second = impulses[-1]
    assert first > 0.0 and first == pytest.approx(second, rel=1e-9)


def test_a_missing_action_is_refused():
    env = parallel_env(agents=2, **OPTIONS)
    env.reset(seed=0)
    with pytest.raises(ValueError, match='no action for ball_1'):
        env.step({'ball_0': np.zeros(2, np.float32)})
