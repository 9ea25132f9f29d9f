"""The navigation task over Arenas: resets, steps, observations and outcomes of robot rows.

The Gymnasium env, the vector env and the PettingZoo env are thin shells over one Task: each
only says which worlds step, which rows it wants back and how it hands them out, so the
same seeds and actions give the same bits in all three.
"""
import numpy as np

from ball_world.envs.arenas import Arenas
from ball_world.envs.observations import (action_space, forward_speeds, goal_terms,
                                          observation_space, observe)
from ball_world.envs.rewards import outcome as step_outcome
from ball_world.envs.world_file import load

#: Defaults of the options (docs/learning.md).
BEAMS = 90
CONTROL_HZ = 10.0
MAX_EPISODE_STEPS = 500


class Task:
    """`count` worlds of `world`, `robots` robots each, with their spaces and bookkeeping."""

    def __init__(self, world=None, count=1, robots=1, beams=BEAMS, control_hz=CONTROL_HZ,
                 terminate_on_collision=False):
        self.env_world = load(world)
        self.arenas = Arenas(self.env_world, count, robots, beams, control_hz)
        self.terminate_on_collision = bool(terminate_on_collision)
        self.control_hz = float(control_hz)
        limits = self.env_world.limits
        xmin, ymin, xmax, ymax = self.arenas.layout.bounds()
        self.reach = float(np.hypot(xmax - xmin, ymax - ymin))
        self.speed = float(self.arenas.speed_limit)
        self.observation_space = observation_space(self.arenas.fan, limits, self.reach,
                                                   self.speed)
        self.action_space = action_space(limits)
        self.distances = np.zeros(count * robots)

    @property
    def robots(self):
        return self.arenas.robots

    def rows_of(self, world):
        first = world * self.robots
        return np.arange(first, first + self.robots)

    def reset(self, world, rng):
        """A new episode in world `world`; the observations of its robots' rows."""
        arenas = self.arenas
        arenas.reset_world(world, rng)
        rows = self.rows_of(world)
        positions = arenas.worlds[world].positions[:self.robots]
        yaws = arenas.agents.yaws()
        distance, bearing = goal_terms(positions, yaws[rows], arenas.goals[rows])
        self.distances[rows] = distance
        return observe(arenas.scans(rows), arenas.fan.range_max, distance, bearing,
                       forward_speeds(yaws[rows], np.zeros((len(rows), 2))),
                       np.zeros(len(rows)), self.reach, self.speed)

    def step(self, worlds, rows, actions):
        """Command robot rows `rows` with `actions` ((n, 2): forward, yaw rate; clipped to
        the limits), step the worlds `worlds` one environment step, and return the
        observations and rewards.Outcome of `rows` and their collision impulses."""
        actions = np.asarray(actions, dtype=np.float64).reshape(len(rows), 2)
        bad = np.flatnonzero(~np.isfinite(actions).all(axis=1))
        if len(bad):
            raise ValueError(f'actions must be finite, got {actions[bad[0]].tolist()}')
        arenas = self.arenas
        arenas.command(rows, actions)
        impulses = arenas.advance(worlds)[rows]
        positions, yaws, velocities = arenas.robot_state()
        distance, bearing = goal_terms(positions[rows], yaws[rows], arenas.goals[rows])
        limits = self.env_world.limits
        outcome = step_outcome(self.distances[rows], distance, impulses,
                               self.env_world.robot_mass, limits.max_speed,
                               self.terminate_on_collision)
        self.distances[rows] = distance
        observed = observe(arenas.scans(rows), arenas.fan.range_max, distance, bearing,
                           forward_speeds(yaws[rows], velocities[rows]),
                           arenas.yaw_rates()[rows], self.reach, self.speed)
        return observed, outcome, impulses


def check_steps(max_episode_steps):
    """max_episode_steps as an int >= 1 (ValueError otherwise)."""
    steps = max_episode_steps
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f'max_episode_steps must be a whole number >= 1, got '
                         f'{max_episode_steps!r}')
    return int(max_episode_steps)


def check_num_envs(num_envs):
    """num_envs (the worlds of a vector env) as an int >= 1 (ValueError otherwise)."""
    if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool) \
            or num_envs < 1:
        raise ValueError(f'num_envs must be a whole number >= 1, got {num_envs!r}')
    return int(num_envs)
