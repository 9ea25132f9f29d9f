"""ball_world_cli: drive a running ball_world from the shell, without a ROS 2 installation.

Why: the `.venv` set-up has rclpy but no `ros2` command (ros2cli has no wheels), so
`ros2 topic pub` and `ros2 service call` are out of reach there. This tool does what those
lines of the README do, one subcommand each, like `gz service` / `gz topic` do for Gazebo:

    ball_world_cli push ball_3 0.5 0          # an impulse on `impulse`, J in N s
    ball_world_cli spawn red 5 5 --radius 0.3 --vx 1
    ball_world_cli state [NAME]               # poses and velocities, at the current time
    ball_world_cli pause | step 60 | resume | reset
    ball_world_cli set-param rate_hz 30       # what ros2 param set does

It speaks only through the world's public names: the `impulse` topic, the latched
`entity_names`, the standard simulation_interfaces services and the parameter services of
the world node, so it works against any world, in any namespace (`--ns /sim2`, or
`--ros-args -r __ns:=/sim2`). Every wait has a deadline (`--timeout`): with no world
answering it says so in one line and exits 1; a refused request prints the world's reason
and exits 1.
"""
import argparse
import json
import os
import sys
import time

from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType
import rclpy
from rclpy.action import ActionClient
from rclpy.duration import Duration
from rclpy.exceptions import NameValidationException
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import get_parameter_value, Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from rclpy.validate_namespace import validate_namespace
from rclpy.validate_node_name import validate_node_name
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import EntityState, Result, SimulationState
from simulation_interfaces.srv import (DeleteEntity, GetEntitiesStates, GetEntityInfo,
                                       GetEntityState, GetSimulationState, ResetSimulation,
                                       SetEntityState, SetSimulationState, SpawnEntity,
                                       StepSimulation)
from std_msgs.msg import String

from ball_world.tools import print_report, usage_exit

PROG = 'ball_world_cli'
#: The world node whose services are called, relative to the namespace.
WORLD_NODE = 'ball_world'
#: Seconds to wait for the world to be discovered and for each answer, unless --timeout.
DEFAULT_TIMEOUT = 10.0
#: Seconds a step may take on average before `step` / `simulate` give up waiting for it.
STEP_ALLOWANCE = 0.1
STATE_NAMES = {SimulationState.STATE_STOPPED: 'stopped (paused at step 0)',
               SimulationState.STATE_PLAYING: 'playing',
               SimulationState.STATE_PAUSED: 'paused',
               SimulationState.STATE_QUITTING: 'quitting'}
#: Answers of SetSimulationState that leave the world as the user wanted it.
ALREADY = (SetSimulationState.Response.ALREADY_IN_TARGET_STATE,)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
IMPULSE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

EXAMPLES = f"""examples:
  {PROG} push ball_3 0.5 0                 impulse of (0.5, 0) N s on ball_3
  {PROG} spawn red 5 5 --radius 0.3 --mass 2 --vx 1
  {PROG} set-state red 2 2 0 1             move red to (2, 2) with velocity (0, 1) m/s
  {PROG} state                             every ball: x, y, vx, vy at the current time
  {PROG} pause; {PROG} step 60; {PROG} resume
  {PROG} set-param rate_hz 30              what ros2 param set /ball_world rate_hz 30 does
  {PROG} --ns /sim2 reset                  the world started with -r __ns:=/sim2"""


class Failure(Exception):
    """The command could not be done; the message is the one line to print (exit 1)."""


class UsageError(Exception):
    """Arguments that parse but make no request; the message is the line to print (exit 2)."""


class _Parser(argparse.ArgumentParser):
    """argparse, with every usage error (its subcommands' too) as one line and exit 2."""

    def error(self, message):
        usage_exit(self, message)


def _parser():
    parser = _Parser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Drive a running ball_world through its topics and simulation_interfaces '
                    'services (what ros2 topic pub / ros2 service call do).',
        epilog=EXAMPLES)
    parser.add_argument('--ns', default=None,
                        help='namespace of the world (default: /, or what --ros-args -r '
                             '__ns:=NS gives)')
    parser.add_argument('--node', default=WORLD_NODE,
                        help=f'name of the world node (default {WORLD_NODE})')
    parser.add_argument('--timeout', type=float, default=DEFAULT_TIMEOUT,
                        help=f'seconds to wait for the world and for each answer '
                             f'(default {DEFAULT_TIMEOUT:g})')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    push = commands.add_parser('push', help='push a ball: an impulse (JX, JY) in N s')
    push.add_argument('ball')
    push.add_argument('jx', type=float)
    push.add_argument('jy', type=float)

    spawn = commands.add_parser('spawn', help='add a ball at (X, Y)')
    spawn.add_argument('name', help="the new ball's name ('' lets the world choose)")
    spawn.add_argument('x', type=float)
    spawn.add_argument('y', type=float)
    spawn.add_argument('--radius', type=float, help='m (default 0.2)')
    spawn.add_argument('--mass', type=float, help='kg (default 1 kg/m^2 x area)')
    spawn.add_argument('--vx', type=float, default=0.0, help='m/s')
    spawn.add_argument('--vy', type=float, default=0.0, help='m/s')
    spawn.add_argument('--rename', action='store_true',
                       help='take a free ball_<k> name if NAME is taken')

    delete = commands.add_parser('delete', help='remove a ball')
    delete.add_argument('name')

    set_state = commands.add_parser('set-state', help='put a ball at (X, Y), optionally with '
                                    'velocity (VX, VY) (default: its current velocity)')
    set_state.add_argument('name')
    set_state.add_argument('x', type=float)
    set_state.add_argument('y', type=float)
    set_state.add_argument('velocity', type=float, nargs='*', metavar='VX VY')

    state = commands.add_parser('state', help='x, y, vx, vy of every ball, or of one')
    state.add_argument('name', nargs='?')
    info = commands.add_parser('info', help="a ball's radius and mass")
    info.add_argument('name')

    set_param = commands.add_parser('set-param', help='set a parameter of the world (what '
                                    'ros2 param set does); VALUE in YAML: 30, true, [0, 0, 8, 8]')
    set_param.add_argument('name')
    set_param.add_argument('value')
    get_param = commands.add_parser('get-param', help='a parameter of the world')
    get_param.add_argument('name')

    commands.add_parser('status', help='playing, paused, stopped or quitting')
    commands.add_parser('pause', help='pause stepping')
    commands.add_parser('resume', aliases=['play'], help='resume stepping')
    commands.add_parser('stop', help='pause and rebuild the world at step 0')
    commands.add_parser('quit', help='end the world node (recordings closed)')
    commands.add_parser('reset', help='rebuild the world from its parameters, step 0')
    step = commands.add_parser('step', help='advance a paused world N steps (default 1)')
    step.add_argument('steps', type=int, nargs='?', default=1)
    simulate = commands.add_parser('simulate', help='advance a paused world N steps through '
                                   'the SimulateSteps action, showing progress')
    simulate.add_argument('steps', type=int)
    return parser


class Client:
    """One node in its own context; every wait is bounded by `timeout`."""

    def __init__(self, args, argv):
        self.timeout = args.timeout
        self.context = rclpy.Context()
        # rcl reads only the --ros-args parts of the command line.
        rclpy.init(args=[PROG, *argv], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        options = {} if args.ns is None else {'namespace': args.ns}
        # A unique name: two commands run at once are two nodes of the graph.
        self.node = rclpy.create_node(f'{PROG}_{os.getpid()}', context=self.context, **options)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.world = args.node

    def close(self):
        self.executor.shutdown(timeout_sec=0.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def wait(self, predicate, what, timeout=None):
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while not predicate():
            if time.monotonic() > deadline:
                raise Failure(what)
            self.executor.spin_once(timeout_sec=0.05)

    def _no_world(self, name):
        namespace = self.node.get_namespace()
        return (f'no world answers {name} within {self.timeout:g} s: is ball_world running '
                f"in namespace {namespace} (--ns), named '{self.world}' (--node)?")

    def call(self, srv_type, service, request, answer_timeout=None):
        """The response of the world's service `service` (relative to the world node)."""
        client = self.node.create_client(srv_type, f'{self.world}/{service}')
        name = self.node.resolve_service_name(client.srv_name)
        try:
            self.wait(client.service_is_ready, self._no_world(name))
            future = client.call_async(request)
            waited = self.timeout if answer_timeout is None else answer_timeout
            self.wait(future.done, f'{name} did not answer within {waited:g} s',
                      waited)
            return future.result()
        finally:
            self.node.destroy_client(client)

    def names(self):
        """The world's balls in pose order, from its latched `entity_names`."""
        heard = []
        subscription = self.node.create_subscription(
            String, 'entity_names', lambda msg: heard.append(msg.data), LATCHED)
        try:
            topic = subscription.topic_name
            self.wait(lambda: heard, self._no_world(topic))
        finally:
            self.node.destroy_subscription(subscription)
        return heard[-1].split('\n') if heard[-1] else []


def _checked(response, what, accepted=()):
    """The response, if its Result is OK (or one of `accepted`); else Failure with why."""
    result = response.result
    if result.result != Result.RESULT_OK and result.result not in accepted:
        raise Failure(f'{what}: refused ({_code_name(response, result.result)}): '
                      f'{result.error_message}')
    return response


def _code_name(response, code):
    """The standard's name of a result code (RESULT_NOT_FOUND, INVALID_POSE...)."""
    for owner in (Result, type(response)):
        for name in dir(owner):
            if name.isupper() and getattr(owner, name) == code:
                return name
    return str(code)


def _number(value):
    return repr(float(value))


def _state_line(name, state):
    position, velocity = state.pose.position, state.twist.linear
    return (f'{name}  x {_number(position.x)}  y {_number(position.y)}  vx '
            f'{_number(velocity.x)}  vy {_number(velocity.y)}')


def _stamp(state):
    stamp = state.header.stamp
    return f't = {(stamp.sec * 10**9 + stamp.nanosec) / 1e9:g} s, frame {state.header.frame_id}'


# Commands: each takes (client, args) and returns the lines to print. -----------------------

def push(client, args):
    names = client.names()
    if args.ball not in names:
        shown = ', '.join(names[:5]) + (', ...' if len(names) > 5 else '')
        raise Failure(f'no ball {args.ball!r} in the world (it has {len(names)}: {shown})')
    publisher = client.node.create_publisher(Vector3Stamped, 'impulse', IMPULSE_QOS)
    client.wait(lambda: publisher.get_subscription_count() > 0,
                client._no_world(publisher.topic_name))
    msg = Vector3Stamped()
    msg.header.stamp = client.node.get_clock().now().to_msg()
    msg.header.frame_id = args.ball
    msg.vector.x, msg.vector.y = args.jx, args.jy
    publisher.publish(msg)
    # Reliable: the world has the message once it acknowledged it; leaving before would
    # lose it with this process.
    if not publisher.wait_for_all_acked(Duration(seconds=client.timeout)):
        raise Failure(f'the world did not acknowledge the impulse within {client.timeout:g} s')
    return [f'pushed {args.ball} by ({args.jx:g}, {args.jy:g}) N s on {publisher.topic_name}']


def spawn(client, args):
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
    _checked(client.call(DeleteEntity, 'delete_entity', DeleteEntity.Request(entity=args.name)),
             'delete')
    return [f'deleted {args.name}']


def set_state(client, args):
    if len(args.velocity) not in (0, 2):
        raise UsageError('set-state takes NAME X Y, or NAME X Y VX VY')
    state = EntityState()
    if args.velocity:
        state.twist.linear.x, state.twist.linear.y = args.velocity
    else:
        current = _checked(client.call(GetEntityState, 'get_entity_state',
                                       GetEntityState.Request(entity=args.name)), 'set-state')
        state.twist.linear = current.state.twist.linear
    state.pose.position.x, state.pose.position.y = args.x, args.y
    state.pose.orientation.w = 1.0
    _checked(client.call(SetEntityState, 'set_entity_state',
                         SetEntityState.Request(entity=args.name, state=state)), 'set-state')
    return [f'set {args.name}: ' + _state_line(args.name, state).split('  ', 1)[1]]


def state(client, args):
    if args.name is not None:
        response = _checked(client.call(GetEntityState, 'get_entity_state',
                                        GetEntityState.Request(entity=args.name)), 'state')
        return [_stamp(response.state), _state_line(args.name, response.state)]
    response = _checked(client.call(GetEntitiesStates, 'get_entities_states',
                                    GetEntitiesStates.Request()), 'state')
    if not response.states:
        return ['no balls']
    return [_stamp(response.states[0])] + [
        _state_line(name, entity) for name, entity in zip(response.entities, response.states)]


def _parameter_client(client):
    """The world node's parameter services, once they are offered."""
    parameters = AsyncParameterClient(client.node, client.world)
    name = client.node.resolve_service_name(f'{client.world}/set_parameters')
    client.wait(parameters.services_are_ready, client._no_world(name))
    return parameters


def set_param(client, args):
    value = get_parameter_value(args.value)
    parameters = _parameter_client(client)
    future = parameters.set_parameters([Parameter.from_parameter_msg(
        ParameterMsg(name=args.name, value=value))])
    client.wait(future.done, f'the world did not answer set-param within {client.timeout:g} s')
    [result] = future.result().results
    if not result.successful:
        raise Failure(f'set-param {args.name}: refused: {result.reason}')
    return [f'set {args.name} to {parameter_value_to_python(value)!r}']


def get_param(client, args):
    parameters = _parameter_client(client)
    future = parameters.get_parameters([args.name])
    client.wait(future.done, f'the world did not answer get-param within {client.timeout:g} s')
    values = future.result().values
    if not values or values[0].type == ParameterType.PARAMETER_NOT_SET:
        raise Failure(f"get-param: the world has no parameter '{args.name}'")
    return [repr(parameter_value_to_python(values[0]))]


def info(client, args):
    response = _checked(client.call(GetEntityInfo, 'get_entity_info',
                                    GetEntityInfo.Request(entity=args.name)), 'info')
    return [f'{args.name}: {response.info.description}']


def status(client, args):
    response = _checked(client.call(GetSimulationState, 'get_simulation_state',
                                    GetSimulationState.Request()), 'status')
    return [STATE_NAMES.get(response.state.state, f'state {response.state.state}')]


def _set_state(client, target, done):
    request = SetSimulationState.Request()
    request.state.state = target
    response = _checked(client.call(SetSimulationState, 'set_simulation_state', request),
                        done, ALREADY)
    if response.result.result in ALREADY:
        return [f'already {STATE_NAMES[target]}']
    return [done]


def pause(client, args):
    return _set_state(client, SimulationState.STATE_PAUSED, 'paused')


def resume(client, args):
    return _set_state(client, SimulationState.STATE_PLAYING, 'playing')


def stop(client, args):
    return _set_state(client, SimulationState.STATE_STOPPED, 'stopped at step 0')


def quit_world(client, args):
    return _set_state(client, SimulationState.STATE_QUITTING, 'the world is quitting')


def reset(client, args):
    _checked(client.call(ResetSimulation, 'reset_simulation', ResetSimulation.Request()),
             'reset')
    return ['reset to step 0']


def _check_steps(steps):
    if steps < 1:
        raise UsageError(f'steps must be at least 1, got {steps}')


def step(client, args):
    _check_steps(args.steps)
    _checked(client.call(StepSimulation, 'step_simulation',
                         StepSimulation.Request(steps=args.steps),
                         client.timeout + args.steps * STEP_ALLOWANCE), 'step')
    return [f'stepped {args.steps}']


def simulate(client, args):
    _check_steps(args.steps)
    action = ActionClient(client.node, SimulateSteps, f'{client.world}/simulate_steps')
    try:
        name = client.node.resolve_service_name(f'{client.world}/simulate_steps')
        client.wait(action.server_is_ready, client._no_world(name))
        progress = []
        sent = action.send_goal_async(SimulateSteps.Goal(steps=args.steps),
                                      feedback_callback=lambda f: progress.append(
                                          f.feedback.completed_steps))
        client.wait(sent.done, 'the SimulateSteps goal was not answered')
        handle = sent.result()
        if not handle.accepted:
            raise Failure('simulate: the goal was rejected')
        finished = handle.get_result_async()
        shown = 0
        deadline = time.monotonic() + client.timeout + args.steps * STEP_ALLOWANCE
        while not finished.done():
            if time.monotonic() > deadline:
                raise Failure(f'simulate: not finished after {args.steps * STEP_ALLOWANCE:g} s')
            client.executor.spin_once(timeout_sec=0.05)
            if progress and progress[-1] // 100 > shown // 100:
                shown = progress[-1]
                print_report(f'{shown} of {args.steps} steps')
        _checked(finished.result().result, 'simulate')
    finally:
        action.destroy()
    return [f'simulated {args.steps} steps']


COMMANDS = {'push': push, 'spawn': spawn, 'delete': delete, 'set-state': set_state,
            'state': state, 'info': info, 'status': status, 'pause': pause, 'resume': resume,
            'play': resume, 'stop': stop, 'quit': quit_world, 'reset': reset, 'step': step,
            'simulate': simulate, 'set-param': set_param, 'get-param': get_param}


def run(argv):
    """Parse, connect, do one command; return the exit code (0 done, 1 failed, 2 usage)."""
    try:
        own = remove_ros_args([PROG, *argv])[1:]
    except Exception as error:  # noqa: B902 - rcl reports bad arguments as generic errors
        print(f'{PROG}: bad ROS arguments: {error}', file=sys.stderr)
        return 2
    args = _parser().parse_args(own)
    if not args.timeout > 0:
        usage_exit(_parser(), f'--timeout must be a positive number of seconds, got '
                              f'{args.timeout:g}')
    if args.ns is not None and not args.ns.startswith('/'):
        args.ns = '/' + args.ns
    for option, value, validate in (('--ns', args.ns, validate_namespace),
                                    ('--node', args.node, validate_node_name)):
        try:
            if value is not None:
                validate(value)
        except NameValidationException as error:
            reason = str(error).splitlines()[0].rstrip(':')
            usage_exit(_parser(), f'{option} {value!r}: {reason}')
    client = None
    try:
        client = Client(args, argv)
        for line in COMMANDS[args.command](client, args):
            print_report(line)
        return 0
    except Failure as failure:
        print(f'{PROG}: {failure}', file=sys.stderr)
        return 1
    except UsageError as error:
        print(f'{PROG}: {error} (see --help)', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        if client is not None:
            client.close()


def main(argv=None):
    sys.exit(run(sys.argv[1:] if argv is None else list(argv)))


if __name__ == '__main__':
    main()
