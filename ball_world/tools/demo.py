"""ball_world_demo: robots among balls, live in the browser, in one command (`make demo`).

Starts, in this order, and stops on Ctrl-C, the server last (tools/processes.py):
the Rerun web viewer server; a world with two agents (robots) among balls; ball_world_wander
driving ball_0 on its own (Stage's wander, reading its lidar); ball_world_tracker following
the balls that ball_1's lidar sees; ball_world_view_tracks drawing those tracks into the
view. ball_1 is yours to drive, from a second terminal: ball_world_teleop's arrow keys, or
ball_world_cli drive.

The world is worlds/sandbox.yaml (a real map) when that file is there, else a walled room
(DEMO_WALLS); --world takes another parameters file. With --policy FILE (a policy `make
learn` trained), ball_0 is driven by it instead (ball_world_navigate, to POLICY_GOALS in
turn, for ever), and the world's lidar is the one the policy was trained on. Logs go to
runs/demo/.
"""
import os
from pathlib import Path
import sys
import uuid

from ball_world.core.parameters import BY_NAME
from ball_world.tools.processes import Children, hold_signals, raise_on_signals, Stop
from ball_world.tools.view import (check_arguments, page_url, parser, proxy_url,
                                   split_ros_args, start_server, watch, world_command)

PROG = 'ball_world_demo'
#: The map world, when the repository has it.
SANDBOX = Path('worlds/sandbox.yaml')
#: The robots: ball_0 wanders, ball_1 is driven by you and tracks the balls.
WANDERER, DRIVEN = 'ball_0', 'ball_1'
#: Without a map: the default 10 m box with a wall up from the floor, one down from the
#: ceiling and a shelf from the left, so the wanderer has corners to get out of.
DEMO_WALLS = [3.5, 0.0, 3.5, 4.0, 6.5, 10.0, 6.5, 6.0, 0.0, 7.0, 2.0, 7.0]
#: The sandbox's robots are TurtleBot3 Burgers (0.105 m, 0.22 m/s) among balls of 0.05-0.1 m:
#: the wanderer's corridor and the tracker's ball sizes follow (the defaults are for the
#: room's 0.25 m robots and 0.1-0.3 m balls).
SANDBOX_WANDER = ['-p', 'half_width:=0.25', '-p', 'avoid_distance:=0.5', '-p', 'speed:=0.22']
SANDBOX_TRACKER = ['-p', 'radius:=[0.05,0.1]', '-p', 'gate:=0.3']
#: Where a trained policy takes ball_0 in turn: the sandbox's free space around its pillars
#: (controllers.navigate's goals).
POLICY_GOALS = [1.5, 1.5, -1.5, 1.5, -1.5, -1.5, 1.5, -1.5]
#: The robots as the first two balls (so they are ball_0 and ball_1), then slow random balls
#: the tracker can follow.
DEMO_BALLS = {'balls.x': [1.5, 8.5], 'balls.y': [1.5, 2.0], 'balls.vx': [0.0, 0.0],
              'balls.vy': [0.0, 0.0], 'balls.radius': [0.25, 0.25], 'balls.mass': [0.4, 0.4],
              'random.count': 12, 'random.speed': 1.0}


def yaml_value(value):
    if isinstance(value, list):
        return '[' + ','.join(repr(float(v)) if isinstance(v, float) else str(v)
                              for v in value) + ']'
    return str(value)


def demo_parameters(world):
    """-p arguments of the demo world: the walls and balls when there is no map, the
    agents, and a differential drive where the world has one (agent.drive)."""
    values = {} if world is not None else {'walls': DEMO_WALLS, **DEMO_BALLS}
    values['agents'] = [WANDERER, DRIVEN]
    if 'agent.drive' in BY_NAME:
        values['agent.drive'] = 'diff'
    arguments = []
    for name, value in values.items():
        arguments += ['-p', f'{name}:={yaml_value(value)}']
    return arguments


def policy_arguments(path):
    """(the world's -p arguments for the policy's lidar, the beams) of a policy file; one
    line (PolicyError, FanMismatch's text) when it cannot be used."""
    from ball_world.envs.arenas import scan_angles
    from ball_world.envs.policy import load_policy
    beams = int(load_policy(path).observation_space['scan'].shape[0])
    angle_min, angle_max = scan_angles(beams)
    return ['-p', f'agent.scan.samples:={beams}', '-p', f'agent.scan.angle_min:={angle_min!r}',
            '-p', f'agent.scan.angle_max:={angle_max!r}'], beams


def tool(name):
    return Path(sys.executable).parent / name


def shown(path):
    """A path as short as it can be written from here (.venv/bin/... in the repository)."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def instructions(args, world):
    driver = (f'{WANDERER} wanders on its own (ball_world_wander reads its lidar and steers '
              'clear).' if args.policy is None else
              f'{WANDERER} is driven by the policy {args.policy} (ball_world_navigate) to four '
              'goals in turn.')
    domain = os.environ.get('ROS_DOMAIN_ID')
    env = f'ROS_DOMAIN_ID={domain} ' if domain else ''
    what = f'the map {world}' if world is not None and world == SANDBOX else (
        f'the world {world}' if world is not None else 'a walled room')
    return f"""
  ball_world demo: two robots among balls in {what}, live in your browser.

  Open  {page_url(args.web_port, args.grpc_port)}
        (the page takes 5-30 s to load)

  {driver}
  {DRIVEN} is yours; ball_world_tracker follows the balls its lidar sees (the green rings).
  Drive {DRIVEN} from a second terminal:
    {env}{shown(tool('ball_world_teleop'))} --ros-args -p ball:={DRIVEN}    (arrow keys)
    {env}{shown(tool('ball_world_cli'))} drive {DRIVEN} 0.2 0.8 --for 5      (0.2 m/s, turning)

  Ctrl-C stops everything. Logs: {args.log_dir}/
"""


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    own, ros_args = split_ros_args(argv)
    command_line = parser(PROG, __doc__.splitlines()[0])
    command_line.set_defaults(log_dir=Path('runs/demo'))
    command_line.add_argument('--policy', metavar='FILE',
                              help='a trained Navigate-v0 policy (make learn) drives ball_0 '
                                   'instead of ball_world_wander')
    args = command_line.parse_args(own)
    check_arguments(command_line, args)
    lidar = []
    if args.policy is not None:
        from ball_world.envs.policy import PolicyError
        try:
            lidar, _ = policy_arguments(args.policy)
        except PolicyError as error:
            command_line.error(f'--policy: {error}')
    world = args.world if args.world is not None else (SANDBOX if SANDBOX.is_file() else None)
    recording = str(uuid.uuid4())
    children = Children(args.log_dir)
    code = 0
    raise_on_signals()
    try:
        print(instructions(args, world), flush=True)
        if start_server(children, args, PROG) is None:
            return 1
        children.start('world', world_command(
            args.grpc_port, world, args.steps, demo_parameters(world) + lidar + ros_args[1:],
            recording))
        sandbox = world == SANDBOX
        if args.policy is None:
            children.start('wander', [tool('ball_world_wander'), '--ros-args',
                                      '-p', f'agent:={WANDERER}',
                                      *(SANDBOX_WANDER if sandbox else [])])
        else:
            children.start('navigate', [tool('ball_world_navigate'), '--ros-args',
                                        '-p', f'agent:={WANDERER}',
                                        '-p', f'policy:={args.policy}', '-p', 'loop:=true',
                                        '-p', f"goal:=[{','.join(map(str, POLICY_GOALS))}]"])
        children.start('tracker', [tool('ball_world_tracker'), '--ros-args',
                                   '-p', f'agent:={DRIVEN}',
                                   *(SANDBOX_TRACKER if sandbox else [])])
        children.start('view_tracks', [tool('ball_world_view_tracks'), '--ros-args',
                                       '-p', f'agent:={DRIVEN}',
                                       '-p', f'view:={proxy_url(args.grpc_port)}',
                                       '-p', f'recording_id:={recording}'])
        print(f"  {PROG}: running (world, {'wander' if args.policy is None else 'navigate'}, "
              'tracker, view_tracks)', flush=True)
        code = watch(children, PROG)
    except Stop:
        code = 0
    finally:
        hold_signals()
        print(f'  {PROG}: stopping', flush=True)
        children.stop()
        print(f'  {PROG}: stopped; every program it started has ended (logs in '
              f'{args.log_dir}/)', flush=True)
    return code


if __name__ == '__main__':
    sys.exit(main())
