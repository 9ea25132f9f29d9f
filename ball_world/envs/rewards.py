"""Rewards and ends of an environment step, for any number of robots at once.

Per robot and environment step (docs/learning.md has the table):

- progress: PROGRESS times how much nearer the goal the robot came (m; negative when it
  went away);
- success: SUCCESS once, when it comes within GOAL_TOLERANCE of the goal's point, which
  ends its episode (terminated);
- collision: -COLLISION times the collision impulse it took (the node's bumper: m |dv| from
  collisions, summed over the physics steps), over m * max_speed: a head-on stop from full
  speed costs about 1, a bounce about 2;
- time: -TIME every step, so dawdling costs.

A hard collision (impulse >= HARD_COLLISION * m * max_speed: the velocity changed by at least
the robot's top speed) also ends the episode when the environment's terminate_on_collision
is on.
"""
from typing import NamedTuple

import numpy as np

PROGRESS = 10.0  # per metre nearer the goal
SUCCESS = 10.0
COLLISION = 1.0  # per m * max_speed of impulse
TIME = 0.01
#: A robot whose centre is this near its goal has reached it, m.
GOAL_TOLERANCE = 0.2
#: A collision impulse of this many m * max_speed is hard.
HARD_COLLISION = 1.0


class Outcome(NamedTuple):
    """What a step gave each robot: reward, terminated, success, hard collision."""

    reward: np.ndarray  # float64
    terminated: np.ndarray  # bool
    success: np.ndarray  # bool
    hard: np.ndarray  # bool


def outcome(before, after, impulses, mass, max_speed, terminate_on_collision):
    """The Outcome of a step: goal distances before and after it, collision impulses (N s)."""
    success = after <= GOAL_TOLERANCE
    scale = mass * max_speed
    knocks = impulses / scale
    hard = knocks >= HARD_COLLISION
    reward = PROGRESS * (before - after) - COLLISION * knocks - TIME + np.where(
        success, SUCCESS, 0.0)
    terminated = success | hard if terminate_on_collision else success
    return Outcome(reward, terminated, success, hard)
