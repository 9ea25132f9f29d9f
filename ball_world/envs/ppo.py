"""stable-baselines3's PPO on Navigate-v0: train within a wall-time budget, save, evaluate.

`train` steps the worlds through envs.sb3's adapter (K worlds in one process, the compiled
scans and physics; SB3's DummyVecEnv over K single environments was slower, docs/learning.md)
and saves an SB3 model that also holds its PolicyScale and the environment's observation
space and options (envs.policy reads them back). stable_baselines3 and torch are imported
inside the functions: ball_world imports without them.
"""
import time

from ball_world.envs.policy import import_sb3, KEY

#: PPO's settings for Navigate-v0 (docs/learning.md, measured on the sandbox).
HYPERPARAMETERS = {
    'n_steps': 256, 'batch_size': 512, 'n_epochs': 5, 'learning_rate': 3e-4, 'gamma': 0.99,
    'gae_lambda': 0.95, 'clip_range': 0.2, 'ent_coef': 0.0, 'vf_coef': 0.5,
}
NET = [128, 128]
#: How often train logs its progress, s.
LOG_SECONDS = 20.0


def quiet_logger(model):
    """Give an SB3 model a logger that writes nothing: without one of its own, every
    learn() at verbose 0 and no tensorboard makes an empty folder in the temporary
    directory (SB3 2.x's `configure`: tmp/SB3-<date and time>), one per training run."""
    from stable_baselines3.common.logger import Logger
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def train(path, minutes=15.0, timesteps=800_000, num_envs=16, seed=0, threads=1,
          hyperparameters=None, log=print, **options):
    """Train PPO for `timesteps` env steps or `minutes` of wall time, whichever ends first;
    save the model at `path` (a .zip); return (model, env steps done, seconds)."""
    ppo = import_sb3()
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecMonitor

    from ball_world.envs.sb3 import sb3_vec_env

    torch.set_num_threads(threads)
    envs = VecMonitor(sb3_vec_env(num_envs, **options))
    envs.seed(seed)
    settings = dict(HYPERPARAMETERS, **(hyperparameters or {}))
    model = ppo('MlpPolicy', envs, seed=seed, device='cpu', verbose=0,
                policy_kwargs={'net_arch': list(NET)}, **settings)
    quiet_logger(model)
    began = time.monotonic()
    deadline = began + 60.0 * minutes

    class Budget(BaseCallback):
        """Stops at the deadline; logs the recent episodes' success rate every LOG_SECONDS."""

        def __init__(self):
            super().__init__()
            self.ends = []
            self.logged = began

        def _on_step(self):
            for info, done in zip(self.locals['infos'], self.locals['dones']):
                if done:
                    self.ends.append(info['success'])
            return time.monotonic() < deadline

        def _on_rollout_end(self):
            recent = self.ends[-200:]
            if recent and time.monotonic() - self.logged >= LOG_SECONDS:
                self.logged = time.monotonic()
                log(f'learn: {self.num_timesteps:,} steps, {time.monotonic() - began:.0f} s, '
                    f'success {sum(recent) / len(recent):.0%} of the last {len(recent)} '
                    'episodes')

    model.learn(total_timesteps=int(timesteps), callback=Budget())
    seconds = time.monotonic() - began
    scale = envs.venv.scale
    setattr(model, KEY, {'scale': scale._asdict(),
                         'observation_space': envs.venv.task.observation_space,
                         'options': dict(options, max_episode_steps=envs.venv.max_episode_steps)})
    model.save(path)
    envs.close()
    return model, model.num_timesteps, seconds
