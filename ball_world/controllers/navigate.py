"""A trained Navigate-v0 policy driving robots in the node: learning's way onto ROS.

`make learn` trains stable-baselines3's PPO on `ball_world/Navigate-v0` and saves it to
runs/navigate_ppo.zip; this controller loads it and drives every robot it is given towards
its goals in turn, as the environment's robot was driven: its observation is built from the
robot's scan, true pose and twist by the function the environment's own observation is
tested against (envs.deploy), the commands are the policy's deterministic actions.

    .venv/bin/ball_world --ros-args --params-file worlds/sandbox.yaml \\
      -p controller:=ball_world.controllers.navigate:Navigate \\
      -p agent.scan.samples:=90 -p agent.scan.angle_max:=3.07177948351002

Which policy and which goals: the class attributes POLICY (a file; relative to the working
directory) and GOALS ((x, y) points in frame_id, visited in turn, robot i starting at goal
i), which a subclass of your own sets, or the environment variables BALL_WORLD_POLICY and
BALL_WORLD_GOALS ("x,y x,y ..."). The node's lidar must be the environment's (the beams the
policy was trained with, over a whole turn from straight behind): a scan of another fan
stops the run with one line naming the parameters to set. Needs stable-baselines3 (make
learn installs it).
"""
import os

import numpy as np

from ball_world.envs.deploy import from_controller, reached
from ball_world.envs.policy import load_policy
from ball_world.envs.rewards import GOAL_TOLERANCE

#: The policy make learn saves, and goals in the free space of the TurtleBot3 sandbox.
POLICY = 'runs/navigate_ppo.zip'
GOALS = ((1.5, 1.5), (-1.5, 1.5), (-1.5, -1.5), (1.5, -1.5))


def _goals_from(text):
    """'x,y x,y' as ((x, y), ...) (ValueError in one line)."""
    try:
        goals = tuple(tuple(float(v) for v in point.split(',')) for point in text.split())
    except ValueError:
        goals = ()
    if not goals or any(len(goal) != 2 or not all(np.isfinite(goal)) for goal in goals):
        raise ValueError(f'BALL_WORLD_GOALS {text[:80]!r}: expected points "x,y x,y ..."')
    return goals


class Navigate:
    """A saved Navigate-v0 policy towards goals in turn (module docstring)."""

    POLICY = POLICY
    GOALS = GOALS

    def __init__(self):
        self.policy = load_policy(os.environ.get('BALL_WORLD_POLICY', self.POLICY))
        goals = os.environ.get('BALL_WORLD_GOALS')
        self.goals = _goals_from(goals) if goals is not None else tuple(self.GOALS)
        self.next = {}  # robot name -> index of its goal in self.goals

    def goal_of(self, row, name, position):
        """The goal robot `name` heads for now: the next one once it reached this one."""
        index = self.next.setdefault(name, row % len(self.goals))
        if reached(position, self.goals[index], GOAL_TOLERANCE):
            index = self.next[name] = (index + 1) % len(self.goals)
        return self.goals[index]

    def act(self, obs):
        goals = [self.goal_of(row, name, obs.truth[row, :2])
                 for row, name in enumerate(obs.names)]
        observations = from_controller(obs, goals, self.policy.observation_space)
        commands = np.zeros((len(obs.names), 3))
        if len(obs.names):
            commands[:, [0, 2]] = self.policy.commands(observations)
        return commands
