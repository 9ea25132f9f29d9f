"""Seeded rollouts of Navigate-v0's vector env, here or as tasks on a Ray cluster, with the
same results bit for bit (docs/learning.md).

    from ball_world.envs.rollouts import rollouts
    here = rollouts(range(8), num_envs=16, steps=200)              # in this process
    there = rollouts(range(8), num_envs=16, steps=200, ray='auto')  # one Ray task per seed
    here[3]['rewards']                                             # (200, 16) float64

A rollout of seed s makes the vector env (`options` are Navigate-v0's: world, beams, ...),
resets it with seed s (world k gets s + k) and steps it `steps` times with the actions of
`policy`, a function named 'module:function' (or 'file.py:function') given the batch of
observations (a dict of (num_envs, ...) arrays) and returning (num_envs, 2) actions, or,
without one, uniform random actions in the action box from numpy's default_rng(s). Its
result is a dict of arrays: rewards (steps, num_envs), terminated and truncated (steps,
num_envs) booleans, and the last observations. Every number of a rollout is its own, so a
Ray task computes what this process does, given the same ball_world and numpy on its node.

On a cluster the rollouts run as the scorer's scenes do (user_code.ray_pool.RayPool: at
most `jobs` tasks at once, default the cluster's CPUs); a policy that raises, exits or
crashes its worker ends the call with one JobFailed line, and no task is left running.
"""
import numpy as np


def rollout(job):
    """One rollout: job = (seed, num_envs, steps, policy spec or None, options dict)."""
    seed, num_envs, steps, policy, options = job
    import gymnasium
    import ball_world.envs as envs
    env = gymnasium.make_vec(envs.NAVIGATE, num_envs=num_envs,
                             vectorization_mode='vector_entry_point', **options)
    try:
        act = _policy(policy)
        generator = np.random.default_rng(seed)
        space = env.single_action_space
        observation, _ = env.reset(seed=seed)
        rewards = np.zeros((steps, num_envs))
        terminated = np.zeros((steps, num_envs), dtype=bool)
        truncated = np.zeros((steps, num_envs), dtype=bool)
        for step in range(steps):
            if act is None:
                actions = generator.uniform(space.low, space.high, (num_envs, *space.shape))
            else:
                from ball_world.user_code.calls import call
                actions = call(f'policy {policy}', act, observation)
            observation, rewards[step], terminated[step], truncated[step], _ = \
                env.step(actions)
    finally:
        env.close()
    return {'rewards': rewards, 'terminated': terminated, 'truncated': truncated,
            'observation': observation}


def _policy(spec):
    if spec is None:
        return None
    from ball_world.user_code.loading import load_class
    return load_class(spec, 'policy')


def rollouts(seeds, num_envs=8, steps=100, policy=None, ray=None, jobs=None, **options):
    """[rollout of each seed] in the order of `seeds`: in this process, or with ray=ADDRESS
    ('host:port' or 'auto') one Ray task per seed (JobFailed or ClusterError, one line)."""
    work = [(int(seed), int(num_envs), int(steps), policy, dict(options)) for seed in seeds]
    if ray is None:
        return [rollout(job) for job in work]
    from ball_world.user_code.ray_pool import RayPool
    results = [None] * len(work)
    with RayPool(ray, jobs, len(work) or None) as pool:
        for position, result in pool.map_unordered(rollout, work,
                                                   [f'rollout seed {job[0]}' for job in work]):
            results[position] = result
    return results
