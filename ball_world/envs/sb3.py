"""Navigate-v0 as stable-baselines3 wants it: K worlds behind SB3's VecEnv API.

SB3 steps its own VecEnv API, not Gymnasium's VectorEnv: `reset()` takes no seed (`seed(s)`
stores s + k for world k's next reset), `step_wait()` returns a list of infos, and a world
whose episode ended is reset in the same step: the observation returned is the new
episode's first one, and the ended episode's last is `infos[k]['terminal_observation']`,
with `infos[k]['TimeLimit.truncated']` when it was cut at max_episode_steps rather than
terminated (PPO then bootstraps its value). Gymnasium 1.x's next-step autoreset (the vector
env's) returns that last observation instead, so the adapter is a second thin shell over
the one Task (envs/task.py) rather than a wrapper of the vector env: world k with seed s + k
then plays exactly the episodes of Navigate-v0 reset with seed s + k and reset again without
one after each end (test/test_envs_learn.py).

What the policy sees and does is scaled to about [-1, 1] (`PolicyScale`): the observation
is one float32 vector, the scan over range_max, the goal's distance over the world's
diagonal and its bearing over pi, the forward speed over max_speed and the yaw rate over
max_yaw_rate; an action in [-1, 1]^2 is (forward, yaw rate) as fractions of the robot's
limits. A saved policy keeps its PolicyScale (envs.policy), so a controller hands it
Navigate-v0's observation dict and gets m/s and rad/s back.

This module imports no SB3: `sb3_vec_env` makes the SB3 subclass when it is called.
"""
import math
from typing import NamedTuple

import gymnasium
from gymnasium.utils import seeding
import numpy as np

from ball_world.envs.task import (BEAMS, check_num_envs, check_steps, CONTROL_HZ,
                                  MAX_EPISODE_STEPS, Task)

FLOAT = np.float32


class PolicyScale(NamedTuple):
    """How Navigate-v0's observations and actions are scaled for a policy network."""

    range_max: float  # m: the scan's bound
    reach: float  # m: the world's diagonal, the goal distance's bound
    max_speed: float  # m/s
    max_yaw_rate: float  # rad/s
    beams: int

    @classmethod
    def of(cls, task):
        limits = task.env_world.limits
        return cls(float(task.arenas.fan.range_max), float(task.reach), float(limits.max_speed),
                   float(limits.max_yaw_rate), int(task.arenas.fan.samples))

    def inputs(self, observed):
        """The policy's input (n, beams + 4) float32 from Navigate-v0 observations (a dict
        of arrays with a leading axis of n)."""
        divisors = np.array([self.range_max] * self.beams
                            + [self.reach, math.pi, self.max_speed, self.max_yaw_rate])
        joined = np.concatenate([observed['scan'], observed['goal'], observed['twist']],
                                axis=1).astype(np.float64)
        return (joined / divisors).astype(FLOAT)

    def commands(self, actions):
        """(n, 2) actions in [-1, 1] (clipped) as (forward m/s, yaw rate rad/s)."""
        actions = np.clip(np.asarray(actions, dtype=np.float64).reshape(-1, 2), -1.0, 1.0)
        return actions * np.array([self.max_speed, self.max_yaw_rate])

    def spaces(self):
        """(observation space, action space) of the policy."""
        size = self.beams + 4
        observation = gymnasium.spaces.Box(-np.inf, np.inf, (size,), FLOAT)
        return observation, gymnasium.spaces.Box(-1.0, 1.0, (2,), FLOAT)


class NavigateSB3Env:
    """K Navigate-v0 worlds with SB3's VecEnv methods (see the module's docstring); options
    are Navigate-v0's."""

    def __init__(self, num_envs=1, world=None, beams=BEAMS, control_hz=CONTROL_HZ,
                 terminate_on_collision=False, max_episode_steps=MAX_EPISODE_STEPS):
        self.num_envs = check_num_envs(num_envs)
        self.task = Task(world, self.num_envs, 1, beams, control_hz, terminate_on_collision)
        self.max_episode_steps = check_steps(max_episode_steps)
        self.scale = PolicyScale.of(self.task)
        self.observation_space, self.action_space = self.scale.spaces()
        self.render_mode = None
        self.metadata = {'render_modes': []}
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._seeds = [None] * self.num_envs
        self._options = [{} for _ in range(self.num_envs)]
        self._rngs = [None] * self.num_envs
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._inputs = np.zeros((self.num_envs, *self.observation_space.shape), FLOAT)
        self._actions = None

    def seed(self, seed=None):
        """World k's next reset uses seed + k (None: fresh entropy); returns the seeds."""
        self._seeds = [None if seed is None else int(seed) + world
                       for world in range(self.num_envs)]
        return self._seeds

    def _reset_world(self, world):
        self._inputs[world] = self.scale.inputs(self.task.reset(world, self._rngs[world]))[0]
        self._steps[world] = 0

    def reset(self):
        for world, seed in enumerate(self._seeds):
            if seed is not None or self._rngs[world] is None:
                self._rngs[world] = seeding.np_random(seed)[0]
            self._reset_world(world)
        self._seeds = [None] * self.num_envs
        return self._inputs.copy()

    def step_async(self, actions):
        self._actions = actions

    def step_wait(self):
        count = self.num_envs
        worlds = np.arange(count)
        observed, outcome, impulses = self.task.step(worlds.tolist(), worlds,
                                                     self.scale.commands(self._actions))
        self._inputs[:] = self.scale.inputs(observed)
        self._steps += 1
        truncated = self._steps >= self.max_episode_steps
        dones = outcome.terminated | truncated
        infos = [{'success': bool(outcome.success[world]), 'impulse': float(impulses[world])}
                 for world in range(count)]
        for world in np.flatnonzero(dones).tolist():
            infos[world]['terminal_observation'] = self._inputs[world].copy()
            infos[world]['TimeLimit.truncated'] = bool(truncated[world]
                                                       and not outcome.terminated[world])
            self._reset_world(world)
        return self._inputs.copy(), outcome.reward.astype(FLOAT), dones, infos

    def step(self, actions):
        self.step_async(actions)
        return self.step_wait()

    def close(self):
        pass

    def _indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name) for _ in self._indices(indices)]

    def set_attr(self, attr_name, value, indices=None):
        setattr(self, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        raise AttributeError(f'the worlds of NavigateSB3Env have no method {method_name!r} '
                             'of their own')

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._indices(indices)]


def sb3_vec_env(num_envs=1, **options):
    """A NavigateSB3Env that is an instance of SB3's VecEnv (imports stable_baselines3)."""
    from stable_baselines3.common.vec_env import VecEnv

    class NavigateVecEnv(NavigateSB3Env, VecEnv):
        """NavigateSB3Env as a subclass of SB3's VecEnv (its own methods first)."""

        def get_images(self):
            return [None] * self.num_envs

    return NavigateVecEnv(num_envs, **options)
