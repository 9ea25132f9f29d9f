"""Navigate-v0 vectorized (ball_world.envs.vector): K worlds in one process whose episodes
are Gymnasium's SyncVectorEnv of the single env's, bit for bit, through next-step autoresets;
its spaces and refusals."""
import gymnasium
from gymnasium.vector import AutoresetMode
import numpy as np
import pytest

import ball_world.envs  # noqa: F401 - registers Navigate-v0
from ball_world.envs.vector import NavigateVectorEnv

NAVIGATE = 'ball_world/Navigate-v0'
BOX = {'arena': [-2.0, -1.5, 2.0, 1.5], 'random.count': 6, 'random.radius': [0.08, 0.15],
       'random.speed': 0.8, 'agent.max_speed': 0.4, 'agent.scan.range_max': 3.0}


def test_the_vector_env_equals_sync_vector_env_of_the_single_env_bit_for_bit():
    count = 3
    options = dict(world=BOX, beams=24, max_episode_steps=12, terminate_on_collision=True)
    ours = gymnasium.make_vec(NAVIGATE, num_envs=count,
                              vectorization_mode='vector_entry_point', **options)
    sync = gymnasium.make_vec(NAVIGATE, num_envs=count, vectorization_mode='sync', **options)
    assert isinstance(ours, NavigateVectorEnv)
    assert ours.metadata['autoreset_mode'] == AutoresetMode.NEXT_STEP
    assert ours.observation_space == sync.observation_space
    assert ours.action_space == sync.action_space
    first, _ = ours.reset(seed=21)
    second, _ = sync.reset(seed=21)
    assert all(first[key].tobytes() == second[key].tobytes() for key in first)
    ours.action_space.seed(4)
    ends = 0
    for _ in range(40):
        move = ours.action_space.sample()
        mine, theirs = ours.step(move), sync.step(move)
        assert all(mine[0][key].tobytes() == theirs[0][key].tobytes() for key in mine[0])
        for field in (1, 2, 3):
            assert mine[field].dtype == theirs[field].dtype
            assert mine[field].tobytes() == theirs[field].tobytes()
        assert mine[4].keys() == theirs[4].keys()
        for key in mine[4]:
            assert mine[4][key].tobytes() == theirs[4][key].tobytes()
        ends += int((mine[2] | mine[3]).sum())
    assert ends >= count * 2  # episodes ended and the worlds were reset, several times


def test_seeds_per_world_and_refusals():
    env = NavigateVectorEnv(num_envs=2, world=BOX, beams=12)
    by_int, _ = env.reset(seed=7)
    by_list, _ = env.reset(seed=[7, 8])
    assert by_int['goal'].tobytes() == by_list['goal'].tobytes()
    swapped, _ = env.reset(seed=[8, 7])
    assert swapped['goal'][0].tobytes() == by_int['goal'][1].tobytes()
    with pytest.raises(ValueError, match=r'actions must have shape \(2, 2\)'):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match='3 seeds for 2 worlds'):
        env.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match='num_envs must be a whole number'):
        NavigateVectorEnv(num_envs=0, world=BOX)


def test_the_batched_scan_is_the_scanners_bit_for_bit():
    """The K scans of one compiled call (envs.batch_scan) equal core.lidar.Scanner.scan's,
    robot by robot (the path taken without numba), noise included."""
    env = NavigateVectorEnv(num_envs=4, world={**BOX, 'agent.scan.noise_stddev': 0.02},
                            beams=33)
    env.reset(seed=3)
    env.step(np.tile(np.array([[0.3, 1.0]], np.float32), (4, 1)))
    arenas = env.task.arenas
    assert arenas._batch is not None
    rows = np.array([2, 0, 3])
    batched = arenas.scans(rows)
    arenas._batch = None
    assert batched.tobytes() == arenas.scans(rows).tobytes()
