"""ball_world/Navigate-v0: one differential-drive robot reaches a goal among moving balls.

A gymnasium.Env over one world of a Task (envs/task.py); docs/learning.md says what it
observes, how it is rewarded and when an episode ends. Truncation: `gymnasium.make` wraps it
in a TimeLimit of `max_episode_steps` (500 unless given); made directly, the env truncates
at its own `max_episode_steps` when one is given.
"""
import gymnasium
import numpy as np

from ball_world.envs.task import BEAMS, check_steps, CONTROL_HZ, Task

_ROWS = np.array([0])


class NavigateEnv(gymnasium.Env):
    """Navigate-v0's environment (docs/learning.md)."""

    metadata = {'render_modes': []}

    def __init__(self, world=None, beams=BEAMS, control_hz=CONTROL_HZ,
                 terminate_on_collision=False, max_episode_steps=None, render_mode=None):
        if render_mode is not None:
            raise ValueError(f'render_mode {render_mode!r}: Navigate-v0 does not render (record '
                             'an episode and look at it in Rerun or Foxglove)')
        self.task = Task(world, 1, 1, beams, control_hz, terminate_on_collision)
        self.observation_space = self.task.observation_space
        self.action_space = self.task.action_space
        self.max_episode_steps = (None if max_episode_steps is None
                                  else check_steps(max_episode_steps))
        self._steps = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        observed = self.task.reset(0, self.np_random)
        self._steps = 0
        return _first(observed), {}

    def step(self, action):
        observed, outcome, impulses = self.task.step([0], _ROWS, action)
        self._steps += 1
        truncated = self.max_episode_steps is not None and self._steps >= self.max_episode_steps
        info = {'success': bool(outcome.success[0]), 'impulse': float(impulses[0])}
        return (_first(observed), float(outcome.reward[0]), bool(outcome.terminated[0]),
                truncated, info)


def _first(observed):
    """Row 0 of a batch of observations."""
    return {key: value[0] for key, value in observed.items()}
