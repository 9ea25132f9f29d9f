"""ball_world_teleop: push the balls or drive the robots of a running ball_world by keyboard.

Like turtle_teleop_key, it reads single key presses from the terminal it runs in. It learns
which balls exist from the world's `balls` topic, sends `impulse` messages addressed to a
ball by name, calls the world's ~/pause, ~/step and ~/reset services and shows their answer
on one status line. All names are relative, so `--ros-args -r __ns:=/sim2` drives the world
started in /sim2.

One thread does everything (keys, ROS callbacks, drawing), so a signal always lands where the
terminal can be restored: the terminal is put back exactly as it was on every way out.
"""
import argparse
import math
import sys

from geometry_msgs.msg import PoseArray, Vector3Stamped
from rcl_interfaces.msg import ParameterDescriptor
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from ball_world.msgs.cdr import decode_pose_array
from ball_world.ros.rcl_init import creating_node
from ball_world.tools import usage_exit
from ball_world.tools.keyboard import KeyDecoder, Quit, RawKeys, Screen
from ball_world.tools.teleop_drive import Drive

PROG = 'ball_world_teleop'
#: Impulse per key press at start, N s, and the range +/- may move it in (x2 and /2 steps).
DEFAULT_IMPULSE = 0.1
IMPULSE_RANGE = (1e-4, 100.0)
#: The world node whose services are called, relative to this node's namespace.
WORLD_NODE = 'ball_world'
#: Longest wait for a key: the world line is redrawn at least this often, s.
REDRAW_PERIOD = 0.1
#: ROS callbacks taken per look: the latest balls and the service answers that came.
CALLBACKS_PER_LOOK = 4

KEYS = """\
Push a ball, or drive a robot (an agent), of ball_world with the arrow keys.
---------------------------
arrow keys    a ball: push it along +y, -y, -x, +x
              a robot: up/down drive it forward/back, left/right turn it (cmd_vel)
0-9           select the 1st to 10th ball;  Tab / Shift-Tab: next / previous ball
+ / -         double / halve the impulse
space         pause / resume;  s or .: one step while paused
r             reset the world;  q or Ctrl-C: quit"""

ARROWS = {'up': (0.0, 1.0), 'down': (0.0, -1.0), 'left': (-1.0, 0.0), 'right': (1.0, 0.0)}


class UsageError(Exception):
    """A bad argument or parameter; the message is the one line to print."""


class Selection:
    """The ball the arrow keys push: a name, kept while the world's list of names changes."""

    def __init__(self, name=''):
        self.name = name
        self.names = []
        self._positions = {}

    def update(self, names):
        if names != self.names:
            self.names = names
            self._positions = {name: i for i, name in enumerate(names)}
        if not self.name and names:
            self.name = names[0]

    def position(self):
        """Where the selected ball is in the world's pose order; None if it is not there."""
        return self._positions.get(self.name)

    def pick(self, position):
        if position < len(self.names):
            self.name = self.names[position]
            return True
        return False

    def cycle(self, step):
        if not self.names:
            return
        current = self.position()
        if current is None:
            self.name = self.names[0 if step > 0 else -1]
        else:
            self.name = self.names[(current + step) % len(self.names)]


def names_for(count):
    """Entity names of the balls in pose order, until the world's entity_names arrives.

    A world that has spawned or deleted nothing names its balls ball_<i> in pose order; the
    latched `entity_names` topic gives the names of any world, and replaces these.
    """
    return [f'ball_{i}' for i in range(count)]


def _number(node, name, default, description, low, high):
    value = node.declare_parameter(name, default, ParameterDescriptor(
        description=description, dynamic_typing=True)).value
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not low <= value <= high:
        raise UsageError(f"parameter '{name}': expected a number from {low:g} to {high:g}, "
                         f'got {value!r}')
    return float(value)


class Teleop(Node):
    """The ROS side: knows the balls, sends impulses, calls services, keeps the status line."""

    def __init__(self, **kwargs):
        super().__init__('ball_world_teleop', **kwargs)
        ball = self.declare_parameter('ball', '', ParameterDescriptor(
            description='ball selected at start, e.g. ball_3 (default: the first one)',
            dynamic_typing=True)).value
        if not isinstance(ball, str):
            raise UsageError(f"parameter 'ball': expected a ball name such as ball_3, got "
                             f'{ball!r}')
        self.impulse = _number(self, 'impulse', DEFAULT_IMPULSE,
                               'impulse per key press, N s (+/- double and halve it)',
                               *IMPULSE_RANGE)
        self.selection = Selection(ball)
        self.drive = Drive(self)
        self.positions = None
        self.stamp_ns = None
        self.paused = False
        self.pushes = 0
        self.status = 'ready'
        self.done = False
        self.impulses = self.create_publisher(
            Vector3Stamped, 'impulse',
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(
            PoseArray, 'balls', self._on_balls,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE), raw=True)
        self.balls_topic = self.resolve_topic_name('balls')
        self.names = None  # from entity_names, once heard
        self.create_subscription(
            String, 'entity_names', self._on_names,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.pause_client = self.create_client(SetBool, f'{WORLD_NODE}/pause')
        self.step_client = self.create_client(Trigger, f'{WORLD_NODE}/step')
        self.reset_client = self.create_client(Trigger, f'{WORLD_NODE}/reset')

    def _on_balls(self, data):
        try:
            stamp_ns, _, positions = decode_pose_array(data)
        except ValueError as error:
            self.status = f'ignored a bad message on {self.balls_topic}: {error}'
            return
        self.stamp_ns, self.positions = stamp_ns, positions
        if self.names is None and len(positions) != len(self.selection.names):
            self.selection.update(names_for(len(positions)))

    def _on_names(self, msg):
        """The world's balls by name, in pose order (sent when they change)."""
        self.names = msg.data.split('\n') if msg.data else []
        self.selection.update(self.names)

    # Keys -------------------------------------------------------------------------------

    def on_key(self, key):
        if key in ARROWS:
            self.push(*ARROWS[key], key)
        elif len(key) == 1 and key.isdigit():
            if not self.selection.pick(int(key)):
                self.status = (f'no ball number {int(key) + 1}: the world has '
                               f'{len(self.selection.names)}')
        elif key in ('\t', 'backtab'):
            self.selection.cycle(1 if key == '\t' else -1)
        elif key in ('+', '='):
            self.impulse = min(self.impulse * 2.0, IMPULSE_RANGE[1])
            self.drive.scale(2.0)
        elif key in ('-', '_'):
            self.impulse = max(self.impulse / 2.0, IMPULSE_RANGE[0])
            self.drive.scale(0.5)
        elif key == ' ':
            self.toggle_pause(not self.paused)
        elif key in ('s', '.'):
            self.call('step', self.step_client, Trigger.Request())
        elif key == 'r':
            self.call('reset', self.reset_client, Trigger.Request())
        elif key in ('q', 'Q', '\x03', '\x04'):  # q, Ctrl-C, Ctrl-D
            self.done = True

    def push(self, x, y, key=None):
        name = self.selection.name
        if self.selection.position() is None:
            self.status = (f'no ball {name!r} in the world; Tab selects one' if name else
                           f'no balls yet: waiting for {self.balls_topic}')
            return
        if key is not None and self.drive.is_agent(name):
            self.status = self.drive.send(name, key)
            return
        if self.impulses.get_subscription_count() == 0:
            self.status = f'not sent: nobody subscribes to {self.impulses.topic_name}'
            return
        msg = Vector3Stamped()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = name
        msg.vector.x, msg.vector.y = x * self.impulse, y * self.impulse
        self.impulses.publish(msg)
        self.pushes += 1
        self.status = (f'push {self.pushes}: {name} by ({msg.vector.x:+.4g}, '
                       f'{msg.vector.y:+.4g}) N s')

    # Services ---------------------------------------------------------------------------

    def call(self, action, client, request, on_success=None):
        """Call a service without waiting; its answer becomes the status line."""
        if not client.service_is_ready():
            self.status = (f'{action}: no service {client.srv_name}; is ball_world running '
                           'in this namespace?')
            return
        self.status = f'{action}: waiting for {client.srv_name}'

        def answered(future):
            response = future.result()
            verdict = '' if response.success else 'refused: '
            self.status = f'{action}: {verdict}{response.message}'
            if on_success is not None and response.success:
                on_success(response)

        client.call_async(request).add_done_callback(answered)

    def toggle_pause(self, pause, retry=True):
        """Pause or resume: space means "the other state than the world's".

        What this tool believes can be stale (the world may start paused, or another client
        may pause it). The world answers 'already paused' to a pause that changes nothing;
        then the key meant the opposite, which is sent at once.
        """
        def answered(response):
            self.paused = pause
            if retry and response.message.startswith('already'):
                self.toggle_pause(not pause, retry=False)

        self.call('pause' if pause else 'resume', self.pause_client,
                  SetBool.Request(data=pause), answered)

    # Screen -----------------------------------------------------------------------------

    def world_line(self):
        if self.positions is None:
            return (f'world    waiting for {self.balls_topic} (no world yet, or a paused one: '
                    'space resumes, s steps)')
        state = 'paused' if self.paused else 'running'
        return (f'world    {self.balls_topic}: {len(self.positions)} balls, '
                f't = {self.stamp_ns / 1e9:.3f} s, {state}')

    def ball_line(self):
        name = self.selection.name or '(none yet)'
        position = self.selection.position()
        if position is None:
            return f'ball     {name}: not in the world'
        if self.positions is None or position >= len(self.positions):
            # entity_names (latched) can arrive before the balls they name
            return f'ball     {name}: waiting for {self.balls_topic}'
        x, y = self.positions[position]
        agent = ', a robot: arrows drive it' if self.drive.ready(name) else ''
        return (f'ball     {name} ({position + 1} of {len(self.selection.names)}) '
                f'at ({x:.2f}, {y:.2f}){agent}')

    def lines(self):
        name = self.selection.name
        self.drive.watch(name)
        if name and self.drive.is_agent(name):
            keys = (f'keys     drive {name}: up/down forward/back, left/right turn '
                    f'({self.drive.speed:.3g} m/s, {self.drive.turn:.3g} rad/s per key)')
        else:
            keys = (f'keys     push {name or "the selected ball"}: arrows along +y, -y, -x, +x '
                    f'({self.impulse:.4g} N s per key)')
        return [self.world_line(), self.ball_line(), keys, f'status   {self.status}']


def _parser():
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Push the balls of a running ball_world, or drive its robots, from the '
                    'keyboard (in a terminal).',
        epilog=f"""keys:
{KEYS.split(chr(10), 2)[2]}

ROS parameters (after --ros-args):
  -p ball:=ball_3     ball selected at start (default: the first one)
  -p impulse:=0.5     impulse per key press in N s (default {DEFAULT_IMPULSE:g})
  -r __ns:=/sim2      drive the world started in namespace /sim2

example:
  ros2 run ball_world {PROG} --ros-args -p ball:=ball_3""")
    parser.error = lambda message: usage_exit(parser, message)
    return parser


def run(argv):
    """Set up, drive until q / Ctrl-C / a signal, restore; return the exit code."""
    try:
        own_args = remove_ros_args([PROG, *argv])[1:]
    except Exception as error:  # noqa: B902 - rcl reports bad arguments as generic errors
        print(f'{PROG}: bad ROS arguments: {error}', file=sys.stderr)
        return 2
    _parser().parse_args(own_args)
    node = None
    try:
        rclpy.init(args=[PROG, *argv], signal_handler_options=SignalHandlerOptions.NO)
        with creating_node(PROG):
            node = Teleop()
        if sys.stdin is None or not sys.stdin.isatty():
            raise UsageError('standard input is not a terminal: run it in a terminal, it '
                             'reads single key presses')
        drive(node, sys.stdin.fileno(), sys.stdout.fileno())
    except UsageError as error:
        print(f'{PROG}: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass  # Ctrl-C before the keyboard was taken over
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def drive(node, keyboard, display):
    """The loop: wait for a key (REDRAW_PERIOD at most), handle it, take the ROS work, draw.

    One thread does everything, so signals land where the terminal is restored. The ROS
    work is taken without waiting: the world's balls are read with depth 1, so only the
    latest waits between two looks, and service answers are few.
    """
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    screen = Screen(display, KEYS)
    decoder = KeyDecoder()
    with RawKeys(keyboard) as keys:
        try:
            keys.let_signals_in()
            screen.start()
            while not node.done:
                for key in decoder.feed(keys.read(REDRAW_PERIOD)):
                    node.on_key(key)
                for _ in range(CALLBACKS_PER_LOOK):
                    executor.spin_once(timeout_sec=0.0)
                screen.draw(node.lines())
        except Quit:
            pass
        finally:
            keys.hold_signals()
            screen.finish()
            executor.shutdown(timeout_sec=0.0)


def main(argv=None):
    sys.exit(run(sys.argv[1:] if argv is None else list(argv)))


if __name__ == '__main__':
    main()
