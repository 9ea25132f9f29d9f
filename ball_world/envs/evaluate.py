"""A policy's success rate over seeded Navigate-v0 episodes.

Episode i is Navigate-v0 reset with seed `seed + i` (the vector env's world i, the same
bits), played until it ends (the goal reached, or max_episode_steps) with the policy's
actions; every episode is counted once, its first, whatever its world plays after it. The
policy maps a batch of policy inputs (envs.sb3: (n, beams + 4) float32) to (n, 2) actions in
[-1, 1], as an SB3 model's deterministic predict does.
"""
from typing import NamedTuple

import numpy as np

from ball_world.envs.sb3 import NavigateSB3Env


class Evaluation(NamedTuple):
    """What evaluate found, episode by episode (seed order)."""

    success: np.ndarray  # (episodes,) bool: the goal was reached
    steps: np.ndarray  # (episodes,) environment steps the episode lasted
    returns: np.ndarray  # (episodes,) the sum of its rewards

    @property
    def rate(self):
        return float(np.mean(self.success))


def evaluate(policy, episodes=100, seed=0, **options):
    """Play `episodes` seeded episodes (seeds seed .. seed + episodes - 1) with `policy`
    (a function of the input batch); options are Navigate-v0's."""
    if not isinstance(episodes, (int, np.integer)) or isinstance(episodes, bool) \
            or episodes < 1:
        raise ValueError(f'episodes must be a whole number >= 1, got {episodes!r}')
    envs = NavigateSB3Env(int(episodes), **options)
    envs.seed(seed)
    inputs = envs.reset()
    running = np.ones(episodes, dtype=bool)
    success = np.zeros(episodes, dtype=bool)
    steps = np.zeros(episodes, dtype=np.int64)
    returns = np.zeros(episodes)
    while running.any():
        inputs, rewards, dones, infos = envs.step(policy(inputs))
        steps[running] += 1
        returns[running] += rewards[running]
        for world in np.flatnonzero(dones & running).tolist():
            success[world] = infos[world]['success']
            running[world] = False
    envs.close()
    return Evaluation(success, steps, returns)
