"""The world an environment runs in: a ball_world parameters file (or dict), read once.

Why a module of its own: an environment is built from the same parameters the node starts
from (`worlds/sandbox.yaml`, any `--params-file`), so a world that runs under ROS runs in a
learner too, and what an episode did can be re-simulated as a ball_world run. Reading the
file, finding the map and building the world happen here, once per environment; nothing
here runs at step time.

What the environment takes from the world, and what it changes:

- Walls, the arena, the map and its `map.unknown_solid`, `dt` (or `rate_hz`) and the
  physics (`physics.mode`, `physics.backend`) as they are.
- The balls of `balls.*` that are not agents stay where the file puts them, at the start of
  every episode; the `random.count` random balls keep their radii and masses (those of the
  file's own world) and are placed anew each episode (EpisodeLayout).
- The robots: the first of the file's `agents` gives their radius and mass (a TurtleBot3
  Burger's 0.105 m and 1 kg when the file has none); the file's agents are not balls of the
  episode. They drive as `agent.drive: diff` whatever the file says, with its
  `agent.max_speed`, `agent.max_accel`, `agent.max_yaw_rate` and `agent.cmd_timeout`.
- Their lidar: the node's agent.scan.* (range_max, range_min, noise_stddev), with `beams`
  beams over a whole turn.
"""
from dataclasses import dataclass
import math
import os
from pathlib import Path
import sys

from ball_world import params_file
from ball_world.core.agents import agent_names, DIFF, Limits
from ball_world.core.parameters import checked, ParameterError
from ball_world.core.scenario import build_scene, step_duration_ns
from ball_world.simulation import load_map

#: The world of `world=None`: the TurtleBot3 sandbox.
DEFAULT_WORLD = 'sandbox'
#: The robot of a world without agents: a TurtleBot3 Burger's footprint radius and mass.
ROBOT_RADIUS = 0.105
ROBOT_MASS = 1.0


class WorldError(ValueError):
    """A world the environments cannot use; the message is one line naming why."""


def world_path(name):
    """The parameters file `name` means: a path, or the name of a world shipped with
    ball_world (`sandbox`, `depot`: worlds/NAME.yaml, _world_folders)."""
    path = Path(name)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        return path
    for folder in _world_folders():
        candidate = folder / f'{name}.yaml'
        if candidate.is_file():
            return candidate
    raise WorldError(f'world {str(name)[:200]!r}: no such file, and no world of that name '
                     'is shipped with ball_world (sandbox, depot)')


def _world_folders():
    """Where shipped worlds are: the repository's worlds/, the package's share/ball_world/
    worlds of a pip install (under sys.prefix) and of a colcon install (ament's index, when
    ROS is there)."""
    yield Path(__file__).resolve().parents[2] / 'worlds'
    yield Path(sys.prefix) / 'share' / 'ball_world' / 'worlds'
    try:
        from ament_index_python.packages import get_package_share_directory
        yield Path(get_package_share_directory('ball_world')) / 'worlds'
    except (ImportError, KeyError, ValueError, OSError):
        return


def read_parameters(path):
    """The node's parameters in a ROS 2 parameters file, as dotted names (WorldError)."""
    try:
        return params_file.read_parameters(path, 'world')
    except params_file.ParamsFileError as error:
        raise WorldError(str(error)) from None


def resolve_map(parameters, path):
    """`map` as a path that exists: as written (relative to the working directory, as the
    node reads it), else relative to the world file's folder or to its parent (where the
    repository and share/ball_world keep maps/ beside worlds/)."""
    name = parameters.get('map')
    if not name or path is None or os.path.isabs(name) or os.path.exists(name):
        return parameters
    folder = Path(path).resolve().parent
    for base in (folder, folder.parent):
        if (base / name).exists():
            return {**parameters, 'map': str(base / name)}
    return parameters


@dataclass(frozen=True)
class EnvWorld:
    """A world as the environments use it (see the module's docstring)."""

    parameters: dict  # checked, with agents [] and the file's agents' balls removed
    occupancy_map: object  # core.occupancy_map.OccupancyMap, or None
    scene: object  # core.scenario.Scene of `parameters`: the walls, the map, the balls
    dt_ns: int
    explicit: int  # how many of scene.world's balls are fixed (balls.*): the rest are random
    robot_radius: float
    robot_mass: float
    limits: Limits

    @property
    def random_speed(self):
        return float(self.parameters['random.speed'])


def load(world=None):
    """The EnvWorld of `world`: None (the sandbox), a world's name, a parameters file's path,
    or a dict of parameters (dotted names). Raises WorldError with one line."""
    path = None
    if world is None:
        world = DEFAULT_WORLD
    if isinstance(world, dict):
        parameters = dict(world)
    elif isinstance(world, (str, os.PathLike)):
        path = world_path(world)
        parameters = read_parameters(path)
    else:
        raise WorldError(f'world must be a parameters file, a world name or a dict, not '
                         f'{type(world).__name__}')
    parameters = resolve_map(parameters, path)
    where = f'world {str(path)[:200]}' if path is not None else 'world'
    try:
        return _built(parameters)
    except ParameterError as error:
        raise WorldError(f'{where}: {error}') from None


def _built(parameters):
    """The EnvWorld of a dict of parameters (ParameterError from the checks)."""
    parameters = checked(parameters)
    count = len(parameters['balls.x'])
    agents = agent_names(parameters, count)
    agent_rows = [int(name.rpartition('_')[2]) for name in agents]
    if agent_rows:
        radius = float(parameters['balls.radius'][agent_rows[0]])
        mass = float(parameters['balls.mass'][agent_rows[0]])
    else:
        radius, mass = ROBOT_RADIUS, ROBOT_MASS
    keep = [row for row in range(count) if row not in set(agent_rows)]
    fields = ('balls.x', 'balls.y', 'balls.vx', 'balls.vy', 'balls.radius', 'balls.mass')
    parameters = checked({**parameters, 'agents': [], 'agent.drive': DIFF,
                          **{name: [parameters[name][row] for row in keep]
                             for name in fields}})
    occupancy_map = load_map(parameters)
    scene = build_scene(parameters, occupancy_map)
    if scene.cells is None and not parameters['arena']:
        raise ParameterError('arena', 'the environments need a bounded world: an arena or a '
                                      'map to place robots and goals in')
    if not math.isfinite(radius) or radius <= 0.0:
        raise ParameterError('balls.radius', f'the robot radius {radius:g} m is not > 0')
    return EnvWorld(parameters=parameters, occupancy_map=occupancy_map, scene=scene,
                    dt_ns=step_duration_ns(parameters), explicit=len(keep),
                    robot_radius=radius, robot_mass=mass,
                    limits=Limits.from_parameters(parameters))


def fixed_balls(env_world):
    """(positions, velocities, radii, masses) of the file's balls that are not agents."""
    world = env_world.scene.world
    rows = slice(0, env_world.explicit)
    return (world.positions[rows].copy(), world.velocities[rows].copy(),
            world.radii[rows].copy(), world.masses[rows].copy())


def random_sizes(env_world):
    """(radii, masses) of the random balls, as the file's own world drew them."""
    world = env_world.scene.world
    rows = slice(env_world.explicit, len(world))
    return world.radii[rows].copy(), world.masses[rows].copy()
