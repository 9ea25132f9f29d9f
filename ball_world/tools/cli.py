"""ball_world_cli: drive a running ball_world from the shell, without a ROS 2 installation.

Why: the `.venv` set-up has rclpy but no `ros2` command (ros2cli has no wheels), so
`ros2 topic pub`, `ros2 topic echo`, `ros2 topic hz`, `ros2 bag record` and
`ros2 service call` are out of reach there. This tool does what those lines of the README do,
one subcommand each, like `gz service` / `gz topic` do for Gazebo:

    ball_world_cli push ball_3 0.5 0          # an impulse on `impulse`, J in N s
    ball_world_cli spawn red 5 5 --radius 0.3 --vx 1
    ball_world_cli state [NAME]               # poses, velocities and masses, now
    ball_world_cli status                     # playing or paused, step, time, balls, agents
    ball_world_cli pause | step 60 | resume | reset
    ball_world_cli set-param rate_hz 30       # what ros2 param set does
    ball_world_cli drive ball_0 0.5 1.0 --for 3    # ros2 topic pub -r 10 ball_0/cmd_vel ...
    ball_world_cli echo balls --once          # ros2 topic echo --once balls
    ball_world_cli hz state                   # ros2 topic hz state
    ball_world_cli record -o run balls state  # ros2 bag record -s mcap -o run balls state

It speaks only through the world's public names: its topics, the latched `entity_names`, the
standard simulation_interfaces services and the parameter services of the world node, so it
works against any world, in any namespace (`--ns /sim2`, or `--ros-args -r __ns:=/sim2`).
The options --ns, --node and --timeout go before or after the subcommand. Every wait has a
deadline (--timeout, finite and at most an hour): with no world answering it says so in one
line and exits 1; a refused request prints the world's reason and exits 1; bad arguments are
one line and exit 2 (tools.cli_client checks each before anything is sent).
"""
import argparse
import math
import os
import re
import sys
import time

from ball_world.tools import print_report, usage_exit
from ball_world.tools.cli_client import (Client, count, DEFAULT_TIMEOUT, duration, Failure, finite,
                                         fits, integer, interrupt_on_signals, MAX_TIMEOUT,
                                         name, one_line, PROG, rate, shown, timeout, topic,
                                         UsageError, WORLD_NODE)

#: Most balls whose masses `state` asks for (one GetEntityInfo each); past it, `info NAME`.
MASSES_UP_TO = 500
#: Most names a refusal or a listing quotes.
LISTED = 5

EXAMPLES = f"""examples:
  {PROG} push ball_3 0.5 0                 impulse of (0.5, 0) N s on ball_3
  {PROG} spawn red 5 5 --radius 0.3 --mass 2 --vx 1
  {PROG} set-state red 2 2 0 1             move red to (2, 2) with velocity (0, 1) m/s
  {PROG} state                             every ball: x, y, vx, vy, mass at the current time
  {PROG} status                            playing or paused, step, time, balls, agents
  {PROG} pause; {PROG} step 60; {PROG} resume
  {PROG} set-param rate_hz 30              what ros2 param set /ball_world rate_hz 30 does
  {PROG} drive ball_0 0.5 1.0 --for 3      cmd_vel at 10 Hz for 3 s, then a stop
  {PROG} echo state --once                 what ros2 topic echo --once state prints
  {PROG} hz balls                          what ros2 topic hz balls prints
  {PROG} record -o run balls state         what ros2 bag record -s mcap -o run ... writes
  {PROG} reset --ns /sim2                  the world started with -r __ns:=/sim2"""


class _Parser(argparse.ArgumentParser):
    """argparse, with every usage error (its subcommands' too) as one line and exit 2."""

    def error(self, message):
        usage_exit(self, one_line(message))


def _global_options(parser, defaults):
    """--ns, --node, --timeout: on the main parser with their defaults, and on every
    subcommand without (SUPPRESS), so they may come before or after the subcommand."""
    keep = (lambda value: value) if defaults else (lambda value: argparse.SUPPRESS)
    parser.add_argument('--ns', default=keep(None),
                        help='namespace of the world (default: /, or what --ros-args -r '
                             '__ns:=NS gives)')
    parser.add_argument('--node', default=keep(WORLD_NODE), type=name,
                        help=f'name of the world node (default {WORLD_NODE})')
    parser.add_argument('--timeout', type=timeout, default=keep(DEFAULT_TIMEOUT),
                        help=f'seconds to wait for the world and for each answer (default '
                             f'{DEFAULT_TIMEOUT:g}, at most {MAX_TIMEOUT:g})')


def _parser():
    parser = _Parser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Drive a running ball_world through its topics and simulation_interfaces '
                    'services (what ros2 topic pub / echo / hz, ros2 bag record and ros2 '
                    'service call do).',
        epilog=EXAMPLES)
    _global_options(parser, True)
    common = _Parser(add_help=False)
    _global_options(common, False)
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND',
                                     parser_class=_Parser)

    def command(command_name, **options):
        return commands.add_parser(command_name, parents=[common], **options)

    push = command('push', help='push a ball: an impulse (JX, JY) in N s')
    push.add_argument('ball', type=name)
    push.add_argument('jx', type=finite)
    push.add_argument('jy', type=finite)

    spawn = command('spawn', help='add a ball at (X, Y)')
    spawn.add_argument('name', type=name, help="the new ball's name ('' lets the world choose)")
    spawn.add_argument('x', type=finite)
    spawn.add_argument('y', type=finite)
    spawn.add_argument('--radius', type=finite, help='m (default 0.2)')
    spawn.add_argument('--mass', type=finite, help='kg (default 1 kg/m^2 x area)')
    spawn.add_argument('--vx', type=finite, default=0.0, help='m/s')
    spawn.add_argument('--vy', type=finite, default=0.0, help='m/s')
    spawn.add_argument('--rename', action='store_true',
                       help='take a free ball_<k> name if NAME is taken')

    delete = command('delete', help='remove a ball')
    delete.add_argument('name', type=name)

    set_state = command('set-state', help='put a ball at (X, Y), optionally with velocity '
                        '(VX, VY) (default: its current velocity)')
    set_state.add_argument('name', type=name)
    set_state.add_argument('x', type=finite)
    set_state.add_argument('y', type=finite)
    set_state.add_argument('velocity', type=finite, nargs='*', metavar='VX VY')

    state = command('state', help='x, y, vx, vy, radius and mass of every ball, or of one')
    state.add_argument('name', nargs='?', type=name)
    info = command('info', help="a ball's radius and mass")
    info.add_argument('name', type=name)

    set_param = command('set-param', help='set a parameter of the world (what ros2 param set '
                        'does); VALUE in YAML: 30, true, [0, 0, 8, 8]')
    set_param.add_argument('name', type=name)
    set_param.add_argument('value')
    get_param = command('get-param', help='a parameter of the world')
    get_param.add_argument('name', type=name)

    command('status', help='playing or paused, step, simulation time, real-time factor, '
                           'balls, agents')
    command('pause', help='pause stepping')
    command('resume', aliases=['play'], help='resume stepping')
    command('stop', help='pause and rebuild the world at step 0')
    command('quit', help='end the world node (recordings closed)')
    command('reset', help='rebuild the world from its parameters, step 0')
    step = command('step', help='advance a paused world N steps (default 1)')
    step.add_argument('steps', type=integer, nargs='?', default=1)
    simulate = command('simulate', help='advance a paused world N steps through the '
                       'SimulateSteps action, showing progress (Ctrl-C cancels the goal)')
    simulate.add_argument('steps', type=integer)

    drive = command('drive', help='send an agent cmd_vel (ros2 topic pub -r), ending with a '
                    'zero command (Ctrl-C or --for)')
    drive.add_argument('agent', type=name, metavar='NAME')
    drive.add_argument('vx', type=finite, metavar='VX', help='forward, m/s (body frame)')
    drive.add_argument('wz', type=finite, metavar='WZ', help='yaw rate, rad/s')
    drive.add_argument('--vy', type=finite, default=0.0, help='leftward, m/s (omni drive)')
    drive.add_argument('--rate', type=rate, default=10.0, help='commands per second (10)')
    drive.add_argument('--for', dest='seconds', type=duration, metavar='S',
                       help='stop S seconds after the command started, joining the graph '
                            'included (default: at Ctrl-C)')
    drive.add_argument('-w', '--wait-matching-subscriptions', dest='matching', type=count,
                       metavar='N', help='send the first command only once N subscriptions '
                       'match, within --timeout (ros2 topic pub -w; default: the agent, then '
                       'up to 2 s for the others on the graph)')

    echo = command('echo', help='print the messages of a topic (ros2 topic echo)')
    echo.add_argument('topic', type=topic)
    echo.add_argument('--once', action='store_true',
                      help='print one message and exit (waits --timeout at most)')
    echo.add_argument('--for', dest='seconds', type=duration, metavar='S',
                      help='stop after S seconds (default: at Ctrl-C)')
    echo.add_argument('--full-length', action='store_true',
                      help='print whole arrays and strings (default: the first 128 items)')

    hz = command('hz', help='the rate of a topic, each second (ros2 topic hz)')
    hz.add_argument('topic', type=topic)
    hz.add_argument('--window', type=integer, default=10000,
                    help='messages the statistics cover (10000)')
    hz.add_argument('--for', dest='seconds', type=duration, metavar='S',
                    help='stop after S seconds (default: at Ctrl-C)')

    record = command('record', help='record topics to a rosbag2 MCAP bag directory (ros2 bag '
                     'record -s mcap)')
    record.add_argument('-o', '--output', required=True, metavar='DIR',
                        help='the bag directory to make (DIR/metadata.yaml, DIR/DIR_0.mcap)')
    record.add_argument('topics', nargs='+', type=topic, metavar='TOPIC')
    record.add_argument('--overwrite', action='store_true',
                        help="replace an existing DIR's bag files (refused otherwise)")
    record.add_argument('--for', dest='seconds', type=duration, metavar='S',
                        help='stop after S seconds (default: at Ctrl-C)')
    return parser


# What the world answers ---------------------------------------------------------------------

def _checked(response, what, accepted=()):
    """The response, if its Result is OK (or one of `accepted`); else Failure with why."""
    from simulation_interfaces.msg import Result
    result = response.result
    if result.result != Result.RESULT_OK and result.result not in accepted:
        raise Failure(f'{what}: refused ({_code_name(response, result.result)}): '
                      f'{one_line(result.error_message)}')
    return response


def _ok(response):
    from simulation_interfaces.msg import Result
    return response.result.result == Result.RESULT_OK


def _code_name(response, code):
    """The standard's name of a result code (RESULT_NOT_FOUND, INVALID_POSE...)."""
    from simulation_interfaces.msg import Result
    for owner in (Result, type(response)):
        for attribute in dir(owner):
            if attribute.isupper() and getattr(owner, attribute) == code:
                return attribute
    return str(code)


def _state_names():
    from simulation_interfaces.msg import SimulationState
    return {SimulationState.STATE_STOPPED: 'stopped (paused at step 0)',
            SimulationState.STATE_PLAYING: 'playing',
            SimulationState.STATE_PAUSED: 'paused',
            SimulationState.STATE_QUITTING: 'quitting'}


def _number(value):
    """A readable number: 6 significant digits, no exponent for everyday sizes."""
    value = float(value)
    text = f'{value:.6g}'
    return '0' if text == '-0' else text


def _state_row(name_text, state, mass=None):
    position, velocity = state.pose.position, state.twist.linear
    row = [name_text, _number(position.x), _number(position.y), _number(velocity.x),
           _number(velocity.y)]
    if mass is not None:
        row.append(mass)
    return row


def _table(header, rows):
    """Rows as aligned columns (names left, numbers right), under their header."""
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(len(header))]
    lines = []
    for row in [header, *rows]:
        cells = [str(row[0]).ljust(widths[0])] + [
            str(cell).rjust(width) for cell, width in zip(row[1:], widths[1:])]
        lines.append('  '.join(cells).rstrip())
    return lines


def _stamp_seconds(stamp):
    return (stamp.sec * 10**9 + stamp.nanosec) / 1e9


_MASS = re.compile(r'radius (\S+) m, mass (\S+) kg')


def _radius_mass(info_response):
    """(radius, mass) texts from a GetEntityInfo description ('ball, radius 0.3 m, mass 4
    kg'), or ('?', '?') when the world describes its entities otherwise."""
    match = _MASS.search(info_response.info.description)
    if not match:
        return ('?', '?')
    try:
        return tuple(_number(float(text)) for text in match.groups())
    except ValueError:
        return match.groups()


# The world's commands: each takes (client, args) and returns the lines to print. ------------

def push(client, args):
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from ball_world.core.impulses import check_impulse, ImpulseRejected
    names = client.names()
    try:  # the world's own rule (core.impulses): refused here, not sent to be refused there
        check_impulse(args.ball, args.jx, args.jy, 0.0, {n: i for i, n in enumerate(names)})
    except ImpulseRejected as rejection:
        if rejection.reason != 'unknown_ball':
            raise Failure(f'push: {rejection}') from None
        listed = ', '.join(names[:LISTED]) + (', ...' if len(names) > LISTED else '')
        raise Failure(f'no ball {shown(args.ball)} in the world (it has {len(names)}: '
                      f'{listed})') from None
    publisher = client.node.create_publisher(
        Vector3Stamped, 'impulse', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    client.wait(lambda: publisher.get_subscription_count() > 0,
                client.no_world(publisher.topic_name))
    msg = Vector3Stamped()
    msg.header.stamp = client.node.get_clock().now().to_msg()
    msg.header.frame_id = args.ball
    msg.vector.x, msg.vector.y = args.jx, args.jy
    publisher.publish(msg)
    # Reliable: the world has the message once it acknowledged it; leaving before would
    # lose it with this process.
    if not publisher.wait_for_all_acked(Duration(seconds=client.timeout)):
        raise Failure(f'the world did not acknowledge the impulse within {client.timeout:g} s')
    # The topic has no answer: the world applies the impulse before its next step, or then
    # refuses it if it would make the world too fast to step (its log says which). Say so.
    return [f'pushed {args.ball} by ({args.jx:g}, {args.jy:g}) N s on {publisher.topic_name}: '
            'delivered; applied before the next step unless the world refuses it then as '
            'too fast (its log says so)']


def spawn(client, args):
    import json

    from simulation_interfaces.srv import SpawnEntity
    resource = {'velocity': [args.vx, args.vy]}
    if args.radius is not None:
        resource['radius'] = args.radius
    if args.mass is not None:
        resource['mass'] = args.mass
    request = SpawnEntity.Request(name=args.name, allow_renaming=args.rename, uri='ball',
                                  resource_string=json.dumps(resource))
    request.initial_pose.pose.position.x, request.initial_pose.pose.position.y = args.x, args.y
    request.initial_pose.pose.orientation.w = 1.0
    response = _checked(client.call(SpawnEntity, 'spawn_entity', request), 'spawn')
    return [f'spawned {response.entity_name} at ({args.x:g}, {args.y:g})']


def delete(client, args):
    from simulation_interfaces.srv import DeleteEntity
    _checked(client.call(DeleteEntity, 'delete_entity', DeleteEntity.Request(entity=args.name)),
             'delete')
    return [f'deleted {args.name}']


def set_state(client, args):
    from simulation_interfaces.msg import EntityState
    from simulation_interfaces.srv import GetEntityState, SetEntityState
    if len(args.velocity) not in (0, 2):
        raise UsageError('set-state takes NAME X Y, or NAME X Y VX VY')
    entity_state = EntityState()
    if args.velocity:
        entity_state.twist.linear.x, entity_state.twist.linear.y = args.velocity
    else:
        current = _checked(client.call(GetEntityState, 'get_entity_state',
                                       GetEntityState.Request(entity=args.name)), 'set-state')
        entity_state.twist.linear = current.state.twist.linear
    entity_state.pose.position.x, entity_state.pose.position.y = args.x, args.y
    entity_state.pose.orientation.w = 1.0
    _checked(client.call(SetEntityState, 'set_entity_state',
                         SetEntityState.Request(entity=args.name, state=entity_state)),
             'set-state')
    velocity = entity_state.twist.linear
    return [f'set {args.name}: x {_number(args.x)}  y {_number(args.y)}  vx '
            f'{_number(velocity.x)}  vy {_number(velocity.y)}']


def state(client, args):
    from simulation_interfaces.srv import (GetEntitiesStates, GetEntityInfo,
                                           GetEntityState)
    header = ['name', 'x m', 'y m', 'vx m/s', 'vy m/s', 'radius m', 'mass kg']
    if args.name is not None:
        found, described = client.call_many([
            (GetEntityState, 'get_entity_state', GetEntityState.Request(entity=args.name)),
            (GetEntityInfo, 'get_entity_info', GetEntityInfo.Request(entity=args.name))])
        _checked(found, 'state')
        _checked(described, 'state')
        row = _state_row(args.name, found.state) + list(_radius_mass(described))
        return [f't = {_stamp_seconds(found.state.header.stamp):.9g} s, frame '
                f'{found.state.header.frame_id}', *_table(header, [row])]
    response = _checked(client.call(GetEntitiesStates, 'get_entities_states',
                                    GetEntitiesStates.Request()), 'state')
    if not response.states:
        return ['no balls']
    rows = [_state_row(n, s) for n, s in zip(response.entities, response.states)]
    notes = []
    if len(rows) <= MASSES_UP_TO:
        infos = client.call_many([(GetEntityInfo, 'get_entity_info',
                                   GetEntityInfo.Request(entity=n)) for n in response.entities])
        for row, described in zip(rows, infos):
            # a ball deleted between the two answers has no info: '?'
            row.extend(_radius_mass(described) if _ok(described) else ('?', '?'))
    else:
        header = header[:5]
        notes = [f'({len(rows):,} balls: radius and mass of one by `{PROG} info NAME`)']
    first = response.states[0].header
    return [f't = {_stamp_seconds(first.stamp):.9g} s, frame {first.frame_id}, '
            f'{len(rows)} balls', *_table(header, rows), *notes]


def _parameter_client(client):
    """The world node's parameter services, once they are offered."""
    from rclpy.parameter_client import AsyncParameterClient
    parameters = AsyncParameterClient(client.node, client.world)
    service = client.service_name('set_parameters')
    client.wait(parameters.services_are_ready, client.no_world(service))
    return parameters


def set_param(client, args):
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rclpy.parameter import get_parameter_value, Parameter, parameter_value_to_python
    try:
        value = get_parameter_value(args.value)
    except (Exception, RecursionError) as error:  # noqa: B902 - YAML's errors are many
        raise UsageError(f'set-param: VALUE {shown(args.value)} is not YAML rclpy can '
                         f'read: {one_line(error)[:120]}') from None
    parameters = _parameter_client(client)
    future = parameters.set_parameters([Parameter.from_parameter_msg(
        ParameterMsg(name=args.name, value=value))])
    client.wait(future.done, f'the world did not answer set-param within {client.timeout:g} s')
    [result] = future.result().results
    if not result.successful:
        raise Failure(f'set-param {args.name}: refused: {one_line(result.reason)}')
    return [f'set {args.name} to {parameter_value_to_python(value)!r}'[:2000]]


def get_param(client, args):
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import parameter_value_to_python
    parameters = _parameter_client(client)
    future = parameters.get_parameters([args.name])
    client.wait(future.done, f'the world did not answer get-param within {client.timeout:g} s')
    values = future.result().values
    if not values or values[0].type == ParameterType.PARAMETER_NOT_SET:
        raise Failure(f'get-param: the world has no parameter {shown(args.name)}')
    return [repr(parameter_value_to_python(values[0]))]


def info(client, args):
    from simulation_interfaces.srv import GetEntityInfo
    response = _checked(client.call(GetEntityInfo, 'get_entity_info',
                                    GetEntityInfo.Request(entity=args.name)), 'info')
    return [f'{args.name}: {one_line(response.info.description)}']


def _step_ns(values):
    """The step length the parameters give, in ns (as core.scenario.step_duration_ns), or
    None when they give none (dt 0 and rate_hz 0)."""
    dt, rate_hz = values
    if not dt:
        if not rate_hz:
            return None
        dt = 1.0 / rate_hz
    return max(1, round(dt * 1e9))


def _stats_heard(client, seconds):
    """The last real_time_factor the world published on `stats` within `seconds`, or None."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray
    heard = []
    subscription = client.node.create_subscription(
        Float64MultiArray, 'stats', heard.append,
        QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    try:
        try:
            client.wait(lambda: len(heard) >= 2, '', seconds)
        except Failure:
            pass
    finally:
        client.node.destroy_subscription(subscription)
    if not heard:
        return None
    message = heard[-1]
    labels = [dim.label for dim in message.layout.dim]
    index = labels.index('real_time_factor') if 'real_time_factor' in labels else -1
    return message.data[index] if len(message.data) else None


def status(client, args):
    """What a user asks first: is it running, where is it, how fast, what is in it."""
    from rcl_interfaces.msg import ParameterType
    from simulation_interfaces.msg import EntityCategory, SimulationState
    from simulation_interfaces.srv import GetEntities, GetEntityState, GetSimulationState
    robots = GetEntities.Request()
    robots.filters.categories = [EntityCategory(category=EntityCategory.CATEGORY_ROBOT)]
    simulation, entities, agents = client.call_many([
        (GetSimulationState, 'get_simulation_state', GetSimulationState.Request()),
        (GetEntities, 'get_entities', GetEntities.Request()),
        (GetEntities, 'get_entities', robots)])
    _checked(simulation, 'status')
    _checked(entities, 'status')
    code = simulation.state.state
    lines = [f'state: {_state_names().get(code, f"state {code}")}']
    parameters = _parameter_client(client)
    future = parameters.get_parameters(['dt', 'rate_hz'])
    client.wait(future.done, f'the world did not answer its parameters within '
                             f'{client.timeout:g} s')
    values = [v.double_value if v.type == ParameterType.PARAMETER_DOUBLE else None
              for v in future.result().values]
    stamp_ns = None
    if entities.entities:
        first = client.call(GetEntityState, 'get_entity_state',
                            GetEntityState.Request(entity=entities.entities[0]))
        if _ok(first):
            stamp = first.state.header.stamp
            stamp_ns = stamp.sec * 10**9 + stamp.nanosec
    step_ns = _step_ns(values) if None not in values else None
    if stamp_ns is None:
        lines.append('step: unknown (no ball to read the time from)')
    elif step_ns is not None and stamp_ns % step_ns == 0:
        lines.append(f'step: {stamp_ns // step_ns}')
    else:
        lines.append('step: unknown (dt or rate_hz changed since the last reset)')
    if stamp_ns is not None:
        lines.append(f'simulation time: {stamp_ns / 1e9:.9g} s')
    if code == SimulationState.STATE_PLAYING:
        factor = _stats_heard(client, client.timeout)
        lines.append('real-time factor: ' + (
            'unknown (no stats heard)' if factor is None or not math.isfinite(factor)
            else f'{factor:.3f}'))
    else:
        lines.append('real-time factor: 0 (not playing)')
    lines.append(f'balls: {len(entities.entities)}')
    names = list(agents.entities) if _ok(agents) else []
    listed = ', '.join(names[:LISTED]) + (', ...' if len(names) > LISTED else '')
    lines.append(f'agents: {len(names)}' + (f' ({listed})' if names else ''))
    return lines


def _set_state(client, target, done, gone=None):
    from simulation_interfaces.srv import SetSimulationState
    request = SetSimulationState.Request()
    request.state.state = target
    already = (SetSimulationState.Response.ALREADY_IN_TARGET_STATE,)
    response = client.call(SetSimulationState, 'set_simulation_state', request, gone=gone)
    if response is None:
        return None
    response = _checked(response, done, already)
    if response.result.result in already:
        return [f'already {_state_names()[target]}']
    return [done]


def pause(client, args):
    from simulation_interfaces.msg import SimulationState
    return _set_state(client, SimulationState.STATE_PAUSED, 'paused')


def resume(client, args):
    from simulation_interfaces.msg import SimulationState
    return _set_state(client, SimulationState.STATE_PLAYING, 'playing')


def stop(client, args):
    from simulation_interfaces.msg import SimulationState
    return _set_state(client, SimulationState.STATE_STOPPED, 'stopped at step 0')


def quit_world(client, args):
    """Ask the world to end. A world that ends may leave the graph before its answer
    reaches us (it was busy with another client's goal, say): gone from the graph is the
    answer then, and said so."""
    from simulation_interfaces.msg import SimulationState
    seen = []

    def gone():
        # The world must have been seen first: a slow discovery is not a world that left.
        present = client.world_present()
        seen.append(present)
        return any(seen) and not present

    lines = _set_state(client, SimulationState.STATE_QUITTING, 'the world is quitting', gone)
    if lines is None:
        return ['the world quit (it left the graph before its answer reached us)']
    return lines


def reset(client, args):
    from simulation_interfaces.srv import ResetSimulation
    _checked(client.call(ResetSimulation, 'reset_simulation', ResetSimulation.Request()),
             'reset')
    return ['reset to step 0']


def _check_steps(message_type, field, steps):
    """steps fit the message's field (uint64) and are at least 1: checked before connecting."""
    fits(message_type, field, steps, 'steps')
    if steps < 1:
        raise UsageError(f'steps must be at least 1, got {steps}')


class _Steps:
    """Counts the world's `stats` messages: the steps it takes, for a wait that lasts as long
    as the world keeps stepping (a long `step` on a slow world), and not forever."""

    def __init__(self, client):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64MultiArray
        self.count = 0
        self.node = client.node
        self.subscription = client.node.create_subscription(
            Float64MultiArray, 'stats', self._heard,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))

    def _heard(self, message):
        self.count += 1

    def close(self):
        self.node.destroy_subscription(self.subscription)


def step(client, args):
    from simulation_interfaces.srv import StepSimulation
    steps = _Steps(client)
    try:
        _checked(client.call(StepSimulation, 'step_simulation',
                             StepSimulation.Request(steps=args.steps),
                             progress=lambda: steps.count), 'step')
    except KeyboardInterrupt:
        raise Failure(f'interrupted after {steps.count} steps heard; the world goes on with '
                      f'the call ({args.steps} steps) unless it is resumed, stopped or '
                      'reset') from None
    finally:
        steps.close()
    return [f'stepped {args.steps}']


def simulate(client, args):
    from rclpy.action import ActionClient
    from simulation_interfaces.action import SimulateSteps
    action = ActionClient(client.node, SimulateSteps, f'{client.world}/simulate_steps')
    handle = None
    progress = [0]
    try:
        client.wait(action.server_is_ready,
                    client.no_world(client.service_name('simulate_steps')))

        def feedback(message):
            progress[0] = message.feedback.completed_steps

        sent = action.send_goal_async(SimulateSteps.Goal(steps=args.steps),
                                      feedback_callback=feedback)
        client.wait(sent.done, 'the SimulateSteps goal was not answered')
        handle = sent.result()
        if not handle.accepted:
            raise Failure('simulate: the goal was rejected')
        finished = handle.get_result_async()
        shown_steps = [0]

        def done():
            if progress[0] // 100 > shown_steps[0] // 100:
                shown_steps[0] = progress[0]
                print_report(f'{progress[0]} of {args.steps} steps')
            return finished.done()

        client.wait(done, lambda: f'simulate: no step done for {client.timeout:g} s (after '
                                  f'{progress[0]} of {args.steps}): did the world stop?',
                    progress=lambda: progress[0])
        _checked(finished.result().result, 'simulate')
    except KeyboardInterrupt:
        # Cancel the goal, so the world does not go on stepping for nobody.
        if handle is not None and handle.accepted:
            cancelled = handle.cancel_goal_async()
            try:
                client.wait(cancelled.done, '', min(client.timeout, 5.0))
            except (Failure, KeyboardInterrupt):
                raise Failure(f'interrupted after {progress[0]} steps; the cancel was not '
                              'answered: the world may go on stepping') from None
            raise Failure(f'interrupted: the goal was cancelled after {progress[0]} of '
                          f'{args.steps} steps') from None
        raise
    finally:
        action.destroy()
    return [f'simulated {args.steps} steps']


def _commands():
    from ball_world.tools import cli_record, cli_topics
    return {'push': push, 'spawn': spawn, 'delete': delete, 'set-state': set_state,
            'state': state, 'info': info, 'status': status, 'pause': pause,
            'resume': resume, 'play': resume, 'stop': stop, 'quit': quit_world,
            'reset': reset, 'step': step, 'simulate': simulate, 'set-param': set_param,
            'get-param': get_param, 'drive': cli_topics.drive, 'echo': cli_topics.echo,
            'hz': cli_topics.hz, 'record': cli_record.record}


def _check(args):
    """The checks argparse cannot make: names rcl validates, values that depend on others."""
    from rclpy.validate_namespace import validate_namespace
    from rclpy.validate_node_name import validate_node_name

    from ball_world.tools.cli_client import check_ros_name
    if args.ns is not None:
        if not args.ns.isprintable() or len(args.ns) > 1024:
            raise UsageError(f'--ns {shown(args.ns)}: not a namespace')
        if not args.ns.startswith('/'):
            args.ns = '/' + args.ns
        check_ros_name(validate_namespace, args.ns, '--ns')
    check_ros_name(validate_node_name, args.node, '--node')
    if args.command == 'step':
        from simulation_interfaces.srv import StepSimulation
        _check_steps(StepSimulation.Request, 'steps', args.steps)
    if args.command == 'simulate':
        from simulation_interfaces.action import SimulateSteps
        _check_steps(SimulateSteps.Goal, 'steps', args.steps)
    if args.command == 'hz' and not 2 <= args.window <= 10**6:
        raise UsageError(f'--window must be between 2 and 1000000 messages, got '
                         f'{shown(args.window)}')


def process_started(now):
    """time.monotonic() of this process's start (from /proc: Python's start-up and imports
    took 0.3-0.7 s under load before run() began), or `now` where /proc does not say."""
    try:
        with open('/proc/self/stat') as stat:
            ticks = int(stat.read().rsplit(')', 1)[1].split()[19])
        with open('/proc/uptime') as uptime:
            up = float(uptime.read().split()[0])
        age = up - ticks / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return now
    return now - age if 0.0 <= age < 60.0 else now


def run(argv):
    """Parse, connect, do one command; return the exit code (0 done, 1 failed, 2 usage)."""
    started = time.monotonic()
    begun = process_started(started)
    own = argv
    if '--ros-args' in argv:
        from rclpy.utilities import remove_ros_args
        try:
            own = remove_ros_args([PROG, *argv])[1:]
        except Exception as error:  # noqa: B902 - rcl reports bad arguments as generic errors
            print(f'{PROG}: bad ROS arguments: {one_line(error)[:200]} (see --help)',
                  file=sys.stderr)
            return 2
    args = _parser().parse_args(own)
    args.started = begun  # drive's --for counts from the process's start (cli_topics.drive)
    client = None
    try:
        _check(args)
        interrupt_on_signals()
        client = Client(args, argv)
        if args.command in ('drive', 'echo', 'hz', 'record'):
            return _commands()[args.command](client, args)
        lines = _commands()[args.command](client, args)
        for line in lines:
            print_report(line)
        return 0
    except Failure as failure:
        print(f'{PROG}: {one_line(failure)}', file=sys.stderr)
        return 1
    except UsageError as error:
        print(f'{PROG}: {one_line(error)} (see --help)', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted', file=sys.stderr)
        return 130
    finally:
        if client is not None:
            try:
                client.close()
            except KeyboardInterrupt:
                pass
        if __debug__ and _timing():
            print(f'{PROG}: {time.monotonic() - started:.3f} s after start-up', file=sys.stderr)


def _timing():
    return os.environ.get('BALL_WORLD_CLI_TIMING') == '1'


def main(argv=None):
    """The console script. Run as one (argv None), it leaves with os._exit once its output
    is flushed and its node closed: the interpreter's teardown after rclpy (module
    finalizers, the middleware's threads) measured 0.4-0.6 s of a 1.3-1.9 s call on two
    loaded cores (docs/cli.md), for nothing left to do."""
    if argv is not None:
        sys.exit(run(list(argv)))
    code = run(sys.argv[1:])
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        pass
    sys.stderr.flush()
    os._exit(code)


if __name__ == '__main__':
    main()
