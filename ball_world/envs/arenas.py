"""K worlds of one EnvWorld with R robots each, stepped together: the environments' engine.

Navigate-v0 is one world with one robot, the vector env K worlds with one each, the
PettingZoo env one world with R: the same code steps them all, so a world steps bit for bit
alike whichever environment holds it (what the tests check).

An environment step is `substeps` physics steps of the world's dt, each as the node's
Simulation.step takes it (ball_world/simulation.py):

1. the drive (core.agents.Agents, agent.drive diff): each robot's last command turned into
   an impulse J = m dv, applied to its ball as the Simulation applies it (v += J / m);
2. World.step(dt) (seed or exact mode, as the file says);
3. the headings turn by the commanded yaw rate; the collision impulse each robot took in
   the step is m (v after - v before) (the node's bumper).

A command takes effect at the first physics step of the environment step, as a cmd_vel
received just before it: the Agents' clock here counts from there (since = one dt, the end
of physics step j at (j + 1) dt), which gives the drive the same differences of times as
the node's absolute clock, so the same bits, whatever time each world is at. One Agents
holds the robots of all K worlds: its rule works row by row, so a batch computes each row
as it would alone.

After the physics steps, each robot's observation: its lidar (core.lidar, the node's scan,
noise seeded by the episode's noise seed, the robot's name and the physics step), the goal
in its base_link (distance, bearing) and its twist (forward speed, yaw rate), as the node's
odometry reports them. Rewards and ends are in rewards.py.
"""
import math

import numpy as np

from ball_world.core import lidar
from ball_world.core.agents import Agents
from ball_world.core.noise_seed import EntropyRows
from ball_world.core.stepping import reachable_speed, speed_limit, travel_per_substep
from ball_world.core.world import World
from ball_world.core.world_batch import supports, WorldBatch
from ball_world.envs.batch_scan import BatchScanner, scan_worlds
from ball_world.envs.layout import EpisodeLayout
from ball_world.envs.world_file import fixed_balls, random_sizes
from ball_world.scans import fan_from

#: The yaw of beam 0 (body frame): beams go counter-clockwise from straight behind, as the
#: node's default fan (agent.scan.angle_min -pi).
ANGLE_MIN = -math.pi


def substeps_per_step(dt_ns, control_hz):
    """Physics steps per environment step: the control period in whole steps of dt
    (ValueError when 1 / control_hz is not a whole number of them)."""
    if not (isinstance(control_hz, (int, float)) and math.isfinite(control_hz)
            and control_hz > 0):
        raise ValueError(f'control_hz must be a number > 0, got {control_hz!r}')
    ratio = 1e9 / (control_hz * dt_ns)
    count = round(ratio)
    if count < 1 or abs(ratio - count) > 1e-3 * count:
        raise ValueError(f'control_hz {control_hz:g}: the control period must be a whole '
                         f'number of the world steps of {dt_ns * 1e-9:.9g} s (a divisor of '
                         f'{1e9 / dt_ns:.6g} Hz)')
    return count


def scan_fan(env_world, beams):
    """The robots' lidar: the node's fan (scans.fan_from) with `beams` beams over a turn."""
    if not isinstance(beams, (int, np.integer)) or isinstance(beams, bool) or beams < 1:
        raise ValueError(f'beams must be a whole number >= 1, got {beams!r}')
    beams = int(beams)
    angle_min, angle_max = scan_angles(beams)
    parameters = {**env_world.parameters, 'agent.scan.samples': beams,
                  'agent.scan.angle_min': angle_min, 'agent.scan.angle_max': angle_max}
    return fan_from(parameters, env_world.robot_radius)


def scan_angles(beams):
    """(agent.scan.angle_min, agent.scan.angle_max) of `beams` beams over a whole turn."""
    return ANGLE_MIN, ANGLE_MIN + (beams - 1) * (2.0 * math.pi / beams)


def robot_name(robot):
    """The entity name of robot `robot` in an episode's world (its ball's): ball_<robot>."""
    return f'ball_{robot}'


class Arenas:
    """`count` worlds of `env_world`, `robots` robots each (balls 0 to robots - 1)."""

    def __init__(self, env_world, count, robots, beams, control_hz):
        self.env_world = env_world
        self.count = int(count)
        self.robots = int(robots)
        if self.count < 1 or self.robots < 1:
            raise ValueError(f'need at least one world and one robot, got {count} and {robots}')
        self.dt_ns = env_world.dt_ns
        self.dt = self.dt_ns * 1e-9
        self.substeps = substeps_per_step(self.dt_ns, control_hz)
        self.fan = scan_fan(env_world, beams)
        self.limits = env_world.limits
        fixed = fixed_balls(env_world)
        radii, masses = random_sizes(env_world)
        self.layout = EpisodeLayout(env_world.scene, env_world.parameters['arena'], fixed,
                                    radii, env_world.random_speed, env_world.robot_radius)
        base = env_world.scene.world
        self.radii = np.concatenate((np.full(self.robots, env_world.robot_radius), fixed[2],
                                     radii))
        self.masses = np.concatenate((np.full(self.robots, env_world.robot_mass), fixed[3],
                                      masses))
        self.worlds = [World(np.zeros((0, 2)), np.zeros((0, 2)), [], [],
                             walls=base.walls.segments, backend=base.backend, mode=base.mode,
                             solid_cells=base.solid_cells) for _ in range(self.count)]
        #: No ball of these worlds is ever faster: the energy an episode can start with (the
        #: fixed balls', the random ones' at random.speed and the robots' at max_speed) could
        #: not make one so.
        self.speed_limit = speed_limit(travel_per_substep(float(self.radii.min())), self.dt)
        energy = 0.5 * (float(np.dot(fixed[3], (fixed[1] ** 2).sum(axis=1)))
                        + float(masses.sum()) * env_world.random_speed ** 2
                        + self.robots * env_world.robot_mass * self.limits.max_speed ** 2)
        if not reachable_speed(energy, float(self.masses.min())) <= self.speed_limit:
            raise ValueError(f'the balls of an episode could carry a ball past the '
                             f'{self.speed_limit:.3g} m/s the world can step: lower '
                             'random.speed, the speeds of the balls or agent.max_speed')
        rows = self.count * self.robots
        self.names = [f'{world}/{robot}' for world in range(self.count)
                      for robot in range(self.robots)]
        self.agents = Agents(self.names, self.limits)
        self._robot_masses = np.full(rows, env_world.robot_mass)
        self.goals = np.zeros((rows, 2))
        self.commands = np.zeros((rows, 2))  # the last (forward, yaw rate) each robot took
        self.steps = np.zeros(self.count, dtype=np.int64)  # physics steps since reset
        self.scanners = [None] * rows
        self._entropy = EntropyRows(rows)  # each row's noise seed and name key
        self.layouts = [None] * self.count  # what each episode started from (recording)
        grid = self.worlds[0].static.scan_grid  # every world's map cells are these
        self._batch = (BatchScanner(self.fan, base.walls.segments, grid)
                       if scan_worlds is not None else None)
        self._radii_rows = np.ascontiguousarray(np.broadcast_to(self.radii,
                                                                (rows, len(self.radii))))
        #: The worlds' physics in one compiled call (core.world_batch), made at the first
        #: step, when every world has its balls; None without numba or in exact mode.
        self._world_batch = None

    # Episodes ---------------------------------------------------------------------------

    def reset_world(self, world, rng):
        """Start a new episode in world `world`, its layout drawn from `rng`."""
        noise_seed, starts, yaws, goals, positions, velocities = self.layout.draw(
            rng, self.robots)
        state = self.worlds[world]
        state.remove_balls(np.arange(len(state)))
        robots = self.robots
        state.add_balls(np.concatenate((starts, positions)),
                        np.concatenate((np.zeros((robots, 2)), velocities)),
                        self.radii, self.masses)
        first = world * robots
        for robot in range(robots):
            name = self.names[first + robot]
            self.agents.set_yaw(name, yaws[robot])
            self.agents.command(name, 0.0, 0.0, 0.0, 0)
            scanner = self.scanners[first + robot] = lidar.Scanner(
                self.fan, 'auto', noise_seed, robot_name(robot))
            self._entropy.set(first + robot, scanner.seed, scanner.key)
        self.goals[first:first + robots] = goals
        self.commands[first:first + robots] = 0.0
        self.steps[world] = 0
        if self._world_batch is not None:
            self._world_batch.bind(world)
        self.layouts[world] = (noise_seed, starts, self.agents.yaws()[first:first + robots],
                               goals, positions, velocities)

    # Stepping ---------------------------------------------------------------------------

    def command(self, rows, actions):
        """Give each robot row in `rows` its action (forward m/s, yaw rate rad/s), clipped to
        the robot's limits, in force from the next physics step."""
        limits = self.limits
        forward = np.clip(actions[:, 0], -limits.max_speed, limits.max_speed)
        turn = np.clip(actions[:, 1], -limits.max_yaw_rate, limits.max_yaw_rate)
        self.commands[rows, 0] = forward
        self.commands[rows, 1] = turn
        self.agents.command_rows(np.asarray(rows, dtype=np.int64),
                                 np.column_stack((forward, np.zeros(len(forward)), turn)),
                                 self.dt_ns)

    def advance(self, worlds):
        """Step the worlds `worlds` (a list of indices) by one environment step; returns
        the collision impulse (N s, summed over the physics steps) of every robot row.

        The drive's impulses are applied to the gathered velocities as World.apply_impulse
        applies them (v += J / m, one division and one addition a component, each robot's
        alone: the same bits), and written back to each world before its step.
        """
        robots = self.robots
        agents = self.agents
        dt_ns = self.dt_ns
        dt = self.dt
        rows = (np.concatenate([np.arange(world * robots, (world + 1) * robots)
                                for world in worlds]) if worlds else np.zeros(0, np.int64))
        slots = np.full(len(self.names), -1, dtype=np.int64)  # agent row -> its slot
        slots[rows] = np.arange(len(rows))
        masses = self._robot_masses[rows]
        impulses = np.zeros(len(rows))
        batch = self._batch_of_worlds()
        if batch is not None:
            read, write, step = _batch_access(batch, np.asarray(worlds, np.int64), robots, dt)
        else:
            read, write, step = _world_access([self.worlds[world] for world in worlds],
                                              robots, dt)
        # The velocities as the next physics step takes them (then after the drive): nothing
        # changes them between one physics step's end and the next one's drive.
        moving = read()
        for substep in range(self.substeps):
            end_ns = (substep + 1) * dt_ns
            driven = moving
            due, jx, jy = agents.impulse_arrays(driven, masses, slots, dt_ns, end_ns)
            if len(due):
                where = slots[due]
                mass = masses[where]
                driven[where, 0] += jx / mass
                driven[where, 1] += jy / mass
            write(driven)
            step()
            moving = read()
            change = moving - driven
            impulses += masses * np.hypot(change[:, 0], change[:, 1])
            agents.turn(dt_ns, end_ns)
        self.steps[worlds] += self.substeps
        out = np.zeros(self.count * robots)
        out[rows] = impulses
        return out

    def _batch_of_worlds(self):
        """The WorldBatch of every world, made on the first step (when each has its balls),
        or None where the worlds cannot be batched (numpy backend, exact mode)."""
        if self._world_batch is None and supports(self.worlds[0]):
            self._world_batch = WorldBatch(self.worlds)
        return self._world_batch

    # Observations -----------------------------------------------------------------------

    def robot_state(self):
        """(positions (rows, 2), headings (rows,), world velocities (rows, 2))."""
        robots = self.robots
        batch = self._world_batch
        if batch is not None:  # every world's arrays are rows of the batch's
            positions = batch.positions[:, :robots].reshape(-1, 2).copy()
            velocities = batch.velocities[:, :robots].reshape(-1, 2).copy()
        else:
            positions = np.concatenate([state.positions[:robots] for state in self.worlds])
            velocities = np.concatenate([state.velocities[:robots]
                                         for state in self.worlds])
        return positions, self.agents.yaws(), velocities

    def scans(self, rows):
        """The lidar ranges (len(rows), beams) of robot rows `rows`, REP 117 with noise:
        the node's scan (core.lidar.Scanner.scan), all rows in one compiled call where
        numba is installed (envs.batch_scan: the same bits), their noise in another
        (core.noise_kernel: the same draws)."""
        robots = self.robots
        yaws = self.agents.yaws()
        steps = self.steps
        if self._batch is None:
            out = np.empty((len(rows), self.fan.samples))
            for slot, row in enumerate(rows):
                world, robot = divmod(row, robots)
                state = self.worlds[world]
                out[slot] = self.scanners[row].scan(
                    state.positions, state.radii, state.walls, state.positions[robot],
                    float(yaws[row]), robot, int(steps[world]), state.static.scan_grid)
            return out
        rows = np.asarray(rows, dtype=np.int64)
        worlds, excludes = np.divmod(rows, robots)
        if self._world_batch is not None:
            positions = self._world_batch.positions[worlds]
        else:
            states = self.worlds
            positions = np.stack([states[world].positions for world in worlds.tolist()])
        origins = positions[np.arange(len(rows)), excludes]
        out = self._batch.ranges(positions, self._radii_rows[:len(rows)], origins, yaws[rows],
                                 excludes)
        stddev = self.fan.noise_stddev
        if stddev > 0.0:  # each row's default_rng([seed, key, step]) draws, in one call
            self._entropy.add_noise(out, rows, steps[worlds], stddev)
        return out

    def yaw_rates(self):
        """The yaw rate each robot turned at in its last physics step, rad/s."""
        return self.agents.yaw_rates(self.substeps * self.dt_ns)


def _batch_access(batch, indices, robots, dt):
    """(read, write, step) of the worlds `indices` of a WorldBatch: their robots'
    velocities (rows, 2) gathered and scattered over its (K, balls, 2) array in one
    operation each, the worlds stepped by dt in one call."""
    velocities = batch.velocities
    count = len(indices)

    def read():
        return velocities[indices, :robots].reshape(count * robots, 2)

    def write(driven):
        velocities[indices, :robots] = driven.reshape(count, robots, 2)

    def step():
        batch.step(indices, dt)

    return read, write, step


def _world_access(active, robots, dt):
    """(read, write, step) of the Worlds `active` stepped one by one (World.step)."""
    def read():
        return np.concatenate([state.velocities[:robots] for state in active])

    def write(driven):
        first = 0
        for state in active:
            state.velocities[:robots] = driven[first:first + robots]
            first += robots

    def step():
        for state in active:
            state.step(dt)

    return read, write, step
