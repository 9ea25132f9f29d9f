"""An episode as a ball_world run: the parameters that start the node's world where the
episode started, and the commands that drive it on.

Why: an episode is the node's physics, drive and lidar (envs/arenas.py), so a Simulation
built from these parameters and given the robots' commands (as cmd_vel, one per
environment step, in force from the next physics step) steps through the same states bit
for bit and scans the same ranges (test/test_envs.py checks it). That is what lets an
episode be recorded, re-simulated and looked at with ball_world's own tools.
"""
import numpy as np

from ball_world.envs.arenas import robot_name, scan_angles


def episode_parameters(task, world=0):
    """The parameters of the run episode `world` of `task` started as (its latest reset):
    every ball explicit (robots first, as ball_0 ...), the robots its agents with their
    diff drive, the random balls none, random.seed the episode's noise seed, and the lidar
    the robots' (samples, angles, one scan per environment step). The robots' headings are
    not parameters: give them with `initial_headings` (set_state) before the first step."""
    arenas = task.arenas
    noise_seed, starts, _, _, positions, velocities = arenas.layouts[world]
    robots = arenas.robots
    where = np.concatenate((starts, positions))
    moving = np.concatenate((np.zeros((robots, 2)), velocities))
    fan = arenas.fan
    return {**task.env_world.parameters,
            'balls.x': where[:, 0].tolist(), 'balls.y': where[:, 1].tolist(),
            'balls.vx': moving[:, 0].tolist(), 'balls.vy': moving[:, 1].tolist(),
            'balls.radius': arenas.radii.tolist(), 'balls.mass': arenas.masses.tolist(),
            'agents': [robot_name(robot) for robot in range(robots)],
            'random.count': 0, 'random.seed': int(noise_seed),
            'agent.scan.samples': fan.samples,
            'agent.scan.angle_min': scan_angles(fan.samples)[0],
            'agent.scan.angle_max': scan_angles(fan.samples)[1],
            'agent.scan.rate_hz': task.control_hz}


def initial_headings(task, world=0):
    """[(robot name, x, y, heading)] of episode `world`'s robots at its start."""
    _, starts, yaws, _, _, _ = task.arenas.layouts[world]
    return [(robot_name(robot), float(x), float(y), float(yaw))
            for robot, ((x, y), yaw) in enumerate(zip(starts.tolist(), yaws.tolist()))]
