"""A saved stable-baselines3 policy of Navigate-v0 as a controller's function.

    policy = load_policy('runs/navigate_ppo.zip')
    observation = navigate_observation(ranges, pose, goal, twist, policy.observation_space)
    v, w = policy(observation)          # m/s and rad/s, within the robot's limits

The file is an SB3 model (envs.ppo trains it) that carries, beside its network, how its
inputs and actions are scaled (envs.sb3.PolicyScale) and Navigate-v0's observation space and
options it was trained with, so the function takes the environment's observation dict
(envs.observations.navigate_observation builds one from a scan, a pose, a goal and a twist)
and returns the command. Its actions are the deterministic ones (the mean of PPO's Gaussian).
stable_baselines3 is imported when a policy is loaded, not before.
"""
from pathlib import Path

import numpy as np

from ball_world.envs.sb3 import PolicyScale

#: The attribute of a saved SB3 model that holds what envs.ppo adds to it.
KEY = 'ball_world'


class PolicyError(ValueError):
    """A policy file that cannot be used, or no stable-baselines3 to read it: one line."""


def import_sb3():
    """stable_baselines3's PPO, or PolicyError naming the command that installs it."""
    try:
        from stable_baselines3 import PPO
    except ImportError as error:
        raise PolicyError(f'stable-baselines3 is not installed ({error}): make learn installs '
                          'it (requirements/learn.txt)') from None
    return PPO


class Policy:
    """act(observation dict) -> (v, w), from an SB3 model and its PolicyScale."""

    def __init__(self, model, scale, observation_space, options):
        self.model = model
        self.scale = scale
        self.observation_space = observation_space
        self.options = dict(options)

    def batch(self, inputs):
        """(n, 2) actions in [-1, 1] for a batch of policy inputs (envs.evaluate's policy)."""
        actions, _ = self.model.predict(inputs, deterministic=True)
        return actions

    def commands(self, observations):
        """(n, 2) commands (forward m/s, yaw rate rad/s) for n robots' observations (a dict
        of arrays with a leading axis of n, as the vector env's or a swarm's)."""
        observed = {key: np.asarray(observations[key], dtype=np.float32)
                    for key in ('scan', 'goal', 'twist')}
        if observed['scan'].ndim != 2 or observed['scan'].shape[1] != self.scale.beams:
            raise ValueError(f'{observed["scan"].shape[-1]} ranges for a policy of '
                             f'{self.scale.beams} beams')
        return self.scale.commands(self.batch(self.scale.inputs(observed)))

    def __call__(self, observation):
        """The command (forward m/s, yaw rate rad/s) for one Navigate-v0 observation."""
        forward, yaw_rate = self.commands({key: np.asarray(observation[key])[None]
                                           for key in ('scan', 'goal', 'twist')})[0]
        return float(forward), float(yaw_rate)


def load_policy(path, device='cpu'):
    """The Policy saved at `path` (PolicyError, one line, for a missing or foreign file)."""
    path = Path(path)
    if not path.is_file():
        raise PolicyError(f'no policy file {str(path)!r} (ball_world_learn train saves one)')
    ppo = import_sb3()
    try:
        model = ppo.load(path, device=device)
    except Exception as error:  # a zip SB3 cannot read: its reason, on one line
        reason = ' '.join(str(error).split()) or type(error).__name__
        raise PolicyError(f'{path} is not a stable-baselines3 PPO file: {reason}') from None
    saved = getattr(model, KEY, None)
    if not isinstance(saved, dict) or 'scale' not in saved:
        raise PolicyError(f'{path} is an SB3 model but not a Navigate-v0 policy of ball_world '
                          '(no scale saved with it)')
    return Policy(model, PolicyScale(**saved['scale']), saved['observation_space'],
                  saved['options'])
