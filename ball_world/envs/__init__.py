"""Learning environments on ball_world's worlds: Gymnasium and PettingZoo (docs/learning.md).

Importing this package registers `ball_world/Navigate-v0` with Gymnasium:

    import gymnasium, ball_world.envs
    env = gymnasium.make('ball_world/Navigate-v0', world='sandbox', beams=90)
    vec = gymnasium.make_vec('ball_world/Navigate-v0', num_envs=64,
                             vectorization_mode='vector_entry_point')

`parallel_env(agents=N, **options)` is a PettingZoo ParallelEnv of N robots in one world.

The environments are a thin layer: they build observations and rewards from the World's
arrays, with the node's drive (core.agents) and lidar (core.lidar); no ROS, no files at step
time.
"""
import gymnasium

from ball_world.envs.task import MAX_EPISODE_STEPS

NAVIGATE = 'ball_world/Navigate-v0'

if NAVIGATE not in gymnasium.registry:
    gymnasium.register(id=NAVIGATE, entry_point='ball_world.envs.navigate:NavigateEnv',
                       vector_entry_point='ball_world.envs.vector:NavigateVectorEnv',
                       max_episode_steps=MAX_EPISODE_STEPS)


def parallel_env(agents=2, **options):
    """A PettingZoo ParallelEnv: `agents` robots in one world, each with its own goal, lidar
    and reward (ball_world.envs.parallel; the options are Navigate-v0's)."""
    from ball_world.envs.parallel import NavigateParallelEnv
    return NavigateParallelEnv(agents=agents, **options)
