"""Navigate-v0's episodes recorded as ball_world MCAPs, to look at and to re-simulate.

    env = RecordEpisodes(gymnasium.make('ball_world/Navigate-v0'), 'runs/episodes')

Each episode (from a reset to the next reset or close) becomes `<folder>/episode_<n>.mcap`, a
ball_world recording like the node's: the world, the robot's odom, scan, bumper and /tf,
its commands; `ball_world_resim` re-simulates it bit for bit, `ball_world_to_rrd` turns it into
a Rerun file, Foxglove opens it (docs/learning.md).

How: an episode is a ball_world run (envs/runs.py), so a Simulation built from the episode's
parameters with an MCAP sink, its robot given the episode's start heading (a set_state edit,
recorded) and each step's command (recorded as cmd_vel), steps with the environment; after
each environment step the wrapper checks that the Simulation's balls are the environment's,
bit for bit (RuntimeError otherwise: a recording that would not show what happened is never
written on quietly). Recording costs what the node's step costs (the messages' bytes, the
file): it is for looking, not for training at speed. The goal is not in the file (a ball_world
recording has no goals); `info` has it nowhere either: it is in the observation.
"""
from pathlib import Path

import gymnasium

from ball_world.envs.runs import episode_parameters, initial_headings
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation


class RecordEpisodes(gymnasium.Wrapper):
    """Records every episode of a Navigate-v0 env (made by gymnasium.make or directly)."""

    def __init__(self, env, folder, overwrite=False):
        super().__init__(env)
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.overwrite = overwrite
        self.episodes = 0
        self.paths = []
        self._simulation = None

    def _finish(self):
        if self._simulation is not None:
            self._simulation.close()
            self._simulation = None

    def reset(self, *, seed=None, options=None):
        self._finish()
        result = self.env.reset(seed=seed, options=options)
        task = self.env.unwrapped.task
        path = self.folder / f'episode_{self.episodes:04d}.mcap'
        simulation = Simulation(episode_parameters(task),
                                sinks=[McapSink(path, overwrite=self.overwrite)])
        for name, x, y, yaw in initial_headings(task):
            simulation.set_state(name, x, y, 0.0, 0.0, yaw=yaw)
        self._simulation = simulation
        self.episodes += 1
        self.paths.append(path)
        return result

    def step(self, action):
        result = self.env.step(action)
        simulation = self._simulation
        if simulation is None:
            return result
        arenas = self.env.unwrapped.task.arenas
        forward, turn = arenas.commands[0].tolist()
        simulation.command('ball_0', forward, 0.0, turn)
        for _ in range(arenas.substeps):
            simulation.step()
        world = arenas.worlds[0]
        if (simulation.world.positions.tobytes() != world.positions.tobytes()
                or simulation.world.velocities.tobytes() != world.velocities.tobytes()):
            self._finish()
            raise RuntimeError(f'the recording {self.paths[-1]} parted from the episode at '
                               f'step {simulation.step_index}: it was closed there')
        return result

    def close(self):
        self._finish()
        super().close()
