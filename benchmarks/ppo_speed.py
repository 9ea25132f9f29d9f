"""How fast PPO (stable-baselines3) trains on Navigate-v0 through each way of stepping its
worlds: ball_world's SB3 adapter (envs.sb3: K worlds in one process) against SB3's
DummyVecEnv of K single environments, and torch on one thread against two, side by side.

Each variant trains a fresh PPO (make learn's settings, envs.ppo) for --steps env steps of the
same K worlds of the sandbox, seeded alike; the DummyVecEnv's environments are wrapped to see
and act as the adapter's (envs.sb3.PolicyScale), so the network does the same work and only
the stepping differs. Rounds alternate the variants (a busy core slows all alike); the table
gives env steps per second of wall time and of the process's CPU time, the median of the
rounds. Needs stable-baselines3 and torch (make learn installs them). Never a timed
assertion: this prints a table for docs/learning.md.

`python -m benchmarks.ppo_speed` (options: --envs, --steps, --rounds).
"""
import argparse
import statistics
import time

import gymnasium

import ball_world.envs  # noqa: F401 - registers Navigate-v0
from ball_world.envs.sb3 import NavigateSB3Env

NAVIGATE = 'ball_world/Navigate-v0'


class Scaled(gymnasium.Wrapper):
    """One Navigate-v0 that sees and acts as the adapter's worlds do."""

    def __init__(self, env):
        super().__init__(env)
        self.scale = NavigateSB3Env(1).scale
        self.observation_space, self.action_space = self.scale.spaces()

    def reset(self, **kwargs):
        observed, info = self.env.reset(**kwargs)
        return self.scale.inputs({k: v[None] for k, v in observed.items()})[0], info

    def step(self, action):
        observed, *rest = self.env.step(self.scale.commands(action)[0])
        return (self.scale.inputs({k: v[None] for k, v in observed.items()})[0], *rest)


def variants(envs):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from ball_world.envs.sb3 import sb3_vec_env
    return {
        'adapter, 1 thread': (lambda: sb3_vec_env(envs), 1),
        'adapter, 2 threads': (lambda: sb3_vec_env(envs), 2),
        'DummyVecEnv, 1 thread': (
            lambda: DummyVecEnv([lambda: Scaled(gymnasium.make(NAVIGATE))] * envs), 1),
    }


def train(make, threads, steps):
    import torch
    from stable_baselines3 import PPO

    from ball_world.envs.ppo import HYPERPARAMETERS, NET, quiet_logger
    torch.set_num_threads(threads)
    venv = make()
    venv.seed(0)
    model = PPO('MlpPolicy', venv, seed=0, device='cpu', policy_kwargs={'net_arch': NET},
                **HYPERPARAMETERS)
    quiet_logger(model)
    wall, cpu = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=steps)
    return model.num_timesteps / (time.perf_counter() - wall), \
        model.num_timesteps / (time.process_time() - cpu)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.ppo_speed',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--envs', type=int, default=16, help='worlds (default 16)')
    parser.add_argument('--steps', type=int, default=32768,
                        help='env steps per training (default 32768)')
    parser.add_argument('--rounds', type=int, default=3, help='rounds (default 3)')
    args = parser.parse_args(argv)
    found = {name: [] for name in variants(args.envs)}
    for _ in range(args.rounds):
        for name, (make, threads) in variants(args.envs).items():
            found[name].append(train(make, threads, args.steps))
    print(f'| PPO on Navigate-v0, {args.envs} worlds, {args.steps} env steps | '
          'env steps/s (wall) | (CPU) |')
    print('|---|---|---|')
    for name, rates in found.items():
        wall = statistics.median(rate[0] for rate in rates)
        cpu = statistics.median(rate[1] for rate in rates)
        print(f'| {name} | {wall:,.0f} | {cpu:,.0f} |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
