"""Navigate-v0 vectorized: K worlds stepped in one process, one call for all.

`gymnasium.make_vec('ball_world/Navigate-v0', num_envs=K,
vectorization_mode='vector_entry_point')` makes it. Each world is a World of its own (the
worlds are never merged into one: a seed-mode World plans its substeps from its fastest
ball, so K worlds in one World would step differently from K worlds alone), stepped by one
Task with K rows, so each world's episodes are bit for bit those of Navigate-v0 with the
same seeds and actions (test/test_envs_vector.py checks it against Gymnasium's
SyncVectorEnv). What is batched: the drive (one core.agents.Agents over the K robots), the K
scans (one compiled call, envs.batch_scan), the observations and the rewards; each world's
physics is its own compiled World.step.

Gymnasium 1.x's autoreset, next-step mode (the default): the step after a world's episode
ended resets that world (its action is ignored) and returns its first observation with
reward 0 and neither terminated nor truncated. reset(seed=s) seeds world k with s + k, as
SyncVectorEnv does; later resets of a world continue its own generator. Truncation at
max_episode_steps (500 unless given), as TimeLimit truncates Navigate-v0.
"""
import gymnasium
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space
import numpy as np

from ball_world.envs.task import (BEAMS, check_num_envs, check_steps, CONTROL_HZ,
                                  MAX_EPISODE_STEPS, Task)


class NavigateVectorEnv(gymnasium.vector.VectorEnv):
    """K Navigate-v0 worlds in one process (see the module's docstring)."""

    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs=1, world=None, beams=BEAMS, control_hz=CONTROL_HZ,
                 terminate_on_collision=False, max_episode_steps=MAX_EPISODE_STEPS,
                 render_mode=None):
        if render_mode is not None:
            raise ValueError(f'render_mode {render_mode!r}: Navigate-v0 does not render')
        self.num_envs = check_num_envs(num_envs)
        self.task = Task(world, self.num_envs, 1, beams, control_hz, terminate_on_collision)
        self.max_episode_steps = check_steps(max_episode_steps)
        self.single_observation_space = self.task.observation_space
        self.single_action_space = self.task.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self._rngs = [None] * self.num_envs
        self._ended = np.zeros(self.num_envs, dtype=bool)
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._observations = {key: np.zeros((self.num_envs, *space.shape), space.dtype)
                              for key, space in self.single_observation_space.items()}

    def _store(self, rows, observed):
        for key, values in observed.items():
            self._observations[key][rows] = values

    def _observed(self):
        return {key: values.copy() for key, values in self._observations.items()}

    def reset(self, *, seed=None, options=None):
        """Reset every world (seed: None, an int s (world k gets s + k) or a list)."""
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + world for world in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f'{len(seeds)} seeds for {self.num_envs} worlds')
        for world, world_seed in enumerate(seeds):
            if world_seed is not None or self._rngs[world] is None:
                self._rngs[world] = seeding.np_random(world_seed)[0]
            self._store([world], self.task.reset(world, self._rngs[world]))
        self._ended[:] = False
        self._steps[:] = 0
        return self._observed(), {}

    def step(self, actions):
        count = self.num_envs
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (count, 2):
            raise ValueError(f'actions must have shape ({count}, 2), got {actions.shape}')
        ended = self._ended
        stepping = np.flatnonzero(~ended)
        rewards = np.zeros(count)
        terminated = np.zeros(count, dtype=bool)
        truncated = np.zeros(count, dtype=bool)
        success = np.zeros(count, dtype=bool)
        impulse = np.zeros(count)
        if len(stepping):
            observed, outcome, impulses = self.task.step(stepping.tolist(), stepping,
                                                         actions[stepping])
            self._store(stepping, observed)
            rewards[stepping] = outcome.reward
            terminated[stepping] = outcome.terminated
            success[stepping] = outcome.success
            impulse[stepping] = impulses
            self._steps[stepping] += 1
            truncated[stepping] = self._steps[stepping] >= self.max_episode_steps
        for world in np.flatnonzero(ended).tolist():
            self._store([world], self.task.reset(world, self._rngs[world]))
            self._steps[world] = 0
        self._ended = terminated | truncated
        mask = ~ended
        infos = ({'success': success, '_success': mask, 'impulse': impulse,
                  '_impulse': mask.copy()} if len(stepping) else {})
        return self._observed(), rewards, terminated, truncated, infos
