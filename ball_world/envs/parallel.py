"""Many robots in one world: a PettingZoo ParallelEnv of Navigate-v0's task.

`ball_world.envs.parallel_env(agents=N, **options)` puts N robots (`ball_0` ... `ball_<N-1>`,
the names their balls have in the world) in one world of the options' world file, each with
its own goal, lidar, observation and reward, as Navigate-v0's (docs/learning.md). The robots
are balls of the same physics: they collide with each other, with the balls and with the
map, and each feels its collisions in its reward. A robot whose episode ended (its goal
reached, or a hard collision with terminate_on_collision) leaves `agents` and is commanded
to stop, but stays in the world as a ball others can hit. Every robot still in the episode
is truncated at max_episode_steps. One robot is Navigate-v0 bit for bit
(test/test_envs_parallel.py).

reset(seed=s) seeds the episode's generator; a reset without a seed goes on with it.
"""
import copy

from gymnasium.utils import seeding
import numpy as np
from pettingzoo import ParallelEnv

from ball_world.envs.arenas import robot_name
from ball_world.envs.task import BEAMS, check_steps, CONTROL_HZ, MAX_EPISODE_STEPS, Task


class NavigateParallelEnv(ParallelEnv):
    """N robots, one world, a goal each (see the module's docstring)."""

    metadata = {'name': 'ball_world_navigate_v0', 'render_modes': [], 'is_parallelizable': True}

    def __init__(self, agents=2, world=None, beams=BEAMS, control_hz=CONTROL_HZ,
                 terminate_on_collision=False, max_episode_steps=MAX_EPISODE_STEPS,
                 render_mode=None):
        if render_mode is not None:
            raise ValueError(f'render_mode {render_mode!r}: the environment does not render')
        if not isinstance(agents, (int, np.integer)) or isinstance(agents, bool) or agents < 1:
            raise ValueError(f'agents must be a whole number >= 1, got {agents!r}')
        self.task = Task(world, 1, int(agents), beams, control_hz, terminate_on_collision)
        self.max_episode_steps = check_steps(max_episode_steps)
        self.render_mode = None
        self.possible_agents = [robot_name(robot) for robot in range(int(agents))]
        self.agents = []
        self._row = {name: row for row, name in enumerate(self.possible_agents)}
        self._observation_spaces = {name: copy.deepcopy(self.task.observation_space)
                                    for name in self.possible_agents}
        self._action_spaces = {name: copy.deepcopy(self.task.action_space)
                               for name in self.possible_agents}
        self._rng = None
        self._steps = 0

    def observation_space(self, agent):
        return self._observation_spaces[agent]

    def action_space(self, agent):
        return self._action_spaces[agent]

    def reset(self, seed=None, options=None):
        if seed is not None or self._rng is None:
            self._rng = seeding.np_random(seed)[0]
        observed = self.task.reset(0, self._rng)
        self.agents = list(self.possible_agents)
        self._steps = 0
        return self._split(observed, self.agents), {name: {} for name in self.agents}

    def _split(self, observed, names):
        return {name: {key: values[self._row[name]] for key, values in observed.items()}
                for name in names}

    def step(self, actions):
        live = self.agents
        missing = [name for name in live if name not in actions]
        if missing:
            raise ValueError(f'no action for {missing[0]}: every robot in agents needs one')
        moves = np.zeros((len(self.possible_agents), 2))
        for name in live:
            moves[self._row[name]] = np.asarray(actions[name], dtype=np.float64).reshape(2)
        rows = np.arange(len(self.possible_agents))
        observed, outcome, impulses = self.task.step([0], rows, moves)
        self._steps += 1
        truncate = self._steps >= self.max_episode_steps
        observations = self._split(observed, live)
        rewards, terminated, truncated, infos = {}, {}, {}, {}
        for name in live:
            row = self._row[name]
            rewards[name] = float(outcome.reward[row])
            terminated[name] = bool(outcome.terminated[row])
            truncated[name] = truncate
            infos[name] = {'success': bool(outcome.success[row]),
                           'impulse': float(impulses[row])}
        self.agents = [name for name in live if not (terminated[name] or truncated[name])]
        return observations, rewards, terminated, truncated, infos
