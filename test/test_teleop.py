"""ball_world_teleop as a user drives it: keys typed into a real terminal (tmux) against a
running node, with an rclpy probe watching what arrives; and its terminal handling alone.
"""
import os
from pathlib import Path
import pty
import select
import shutil
import signal
import subprocess
import termios
import time

from ball_world_testing.harness import (executable, finish, node_command, Probe, RECEIVE_QOS,
                                        start)
from geometry_msgs.msg import PoseArray, Vector3Stamped
import numpy as np
import pytest
import rclpy
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool

from ball_world.tools import teleop
from ball_world.tools.keyboard import KeyDecoder, RawKeys

NAMESPACE = '/sim2'
#: Three balls of 4 kg at rest, 3 m apart: an impulse J gives exactly v = J / 4 (a power of
#: two), and at the speeds the keys give nothing touches anything for over a minute.
MASS = 4.0
WORLD = ['-p', 'random.count:=0', '-p', 'balls.x:=[2.0, 5.0, 8.0]',
         '-p', 'balls.y:=[5.0, 5.0, 5.0]', '-p', 'balls.vx:=[0.0, 0.0, 0.0]',
         '-p', 'balls.vy:=[0.0, 0.0, 0.0]', '-p', 'balls.radius:=[0.3, 0.3, 0.3]',
         '-p', f'balls.mass:=[{MASS}, {MASS}, {MASS}]']
RATE_HZ = 50
DT_NS = 10**9 // RATE_HZ
DEADLINE = 30.0


# --- Pieces without a terminal --------------------------------------------------------------

def test_key_decoder_reads_arrows_in_both_cursor_modes_and_shift_tab():
    decoder = KeyDecoder()
    assert decoder.feed(b'\x1b[A\x1b[B\x1bOC\x1bOD\x1b[Z\t 3+q') == [
        'up', 'down', 'right', 'left', 'backtab', '\t', ' ', '3', '+', 'q']


def test_key_decoder_waits_for_a_sequence_split_across_reads():
    decoder = KeyDecoder()
    assert decoder.feed(b'1\x1b') == ['1']
    assert decoder.feed(b'[') == []
    assert decoder.feed(b'Cs') == ['right', 's']


def test_key_decoder_never_takes_the_digits_of_other_sequences_for_keys():
    # Ctrl-Right, F5, Delete: parameters such as '1;5' must not select ball 1 or 5.
    assert KeyDecoder().feed(b'\x1b[1;5C\x1b[15~\x1b[3~\x1bx2') == ['x', '2']


def test_selection_keeps_a_name_cycles_and_picks_by_position():
    selection = teleop.Selection('ball_7')
    selection.update(teleop.names_for(3))
    assert selection.name == 'ball_7' and selection.position() is None
    selection.cycle(1)
    assert selection.name == 'ball_0'
    selection.cycle(-1)
    assert selection.name == 'ball_2'
    selection.cycle(1)
    assert selection.name == 'ball_0'
    assert selection.pick(1) and selection.name == 'ball_1'
    assert not selection.pick(3) and selection.name == 'ball_1'
    selection.update(teleop.names_for(1))  # a reset to a smaller world
    assert selection.name == 'ball_1' and selection.position() is None
    empty = teleop.Selection()
    empty.update(teleop.names_for(2))
    assert empty.name == 'ball_0'


def run_teleop(*args, stdin=subprocess.DEVNULL):
    return finish(start([executable('ball_world_teleop'), *args], stdin=stdin))


def test_help_prints_usage_keys_and_parameters():
    code, out, err = run_teleop('--help')
    assert code == 0, err
    assert out.startswith('usage: ball_world_teleop')
    for text in ('arrow keys', 'Tab / Shift-Tab', 'space', 'ball:=ball_3', 'impulse:=',
                 '__ns:=/sim2'):
        assert text in out


@pytest.mark.parametrize('args, problem', [
    ((), 'standard input is not a terminal'),
    (('--ros-args', '-p', 'impulse:=-1.0'), "parameter 'impulse'"),
    (('--ros-args', '-p', 'impulse:=fast'), "parameter 'impulse'"),
    (('--ros-args', '-p', 'ball:=3'), "parameter 'ball'"),
    (('--ros-args', '-p'), 'bad ROS arguments'),
    (('--speed', '3'), 'unrecognized arguments'),
])
def test_bad_start_is_one_line_and_exit_2(args, problem):
    code, out, err = run_teleop(*args)
    assert code == 2
    assert problem in err and len(err.strip().splitlines()) == 1, err
    assert 'Traceback' not in err


def test_terminal_is_restored_when_a_key_handler_raises():
    master, slave = pty.openpty()
    before = termios.tcgetattr(slave)
    context = rclpy.Context()
    rclpy.init(context=context)
    handlers = {s: signal.getsignal(s) for s in RawKeys.QUIT_SIGNALS}
    node = teleop.Teleop(context=context)

    def broken(key):
        raise RuntimeError(f'key {key!r}')

    node.on_key = broken
    os.write(master, b'x')
    try:
        with pytest.raises(RuntimeError, match="key 'x'"):
            teleop.drive(node, slave, slave)
        assert termios.tcgetattr(slave) == before
        shown = b''
        while select.select([master], [], [], 0.0)[0]:
            shown += os.read(master, 65536)
        assert shown.endswith(b'\x1b[?25h\r\n')  # the cursor is shown again, last
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, RawKeys.QUIT_SIGNALS)
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        os.close(master)
        os.close(slave)


# --- In a real terminal ---------------------------------------------------------------------

class Tmux:
    """A private tmux server running one script in a detached 100 x 24 terminal."""

    def __init__(self, directory):
        if shutil.which('tmux') is None:
            pytest.skip('tmux is not installed (apt-get install tmux)')
        self.directory = directory
        self.socket = str(directory / 'tmux.socket')  # a server of its own for each test

    def tmux(self, *args):
        return subprocess.run(['tmux', '-S', self.socket, *args], check=True,
                              capture_output=True, text=True).stdout

    def start(self, *teleop_args):
        """Run the teleop in the terminal, with the terminal's settings saved before/after."""
        script = self.directory / 'run.sh'
        script.write_text(
            'cd "$(dirname "$0")"\n'
            'stty -g > before\n'
            'sh -c \'echo $$ > pid; exec "$@"\' sh "$@"\n'
            'echo $? > rc\n'
            'stty -g > after\n'
            'stty -a > after_all\n'
            'exec sleep 600\n')
        environment = [f'-e{name}={os.environ[name]}' for name in
                       ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')]
        self.tmux('new-session', '-d', '-s', 'teleop', '-x', '100', '-y', '24', *environment,
                  'sh', str(script), executable('ball_world_teleop'), *teleop_args)

    def keys(self, *keys):
        self.tmux('send-keys', '-t', 'teleop', *keys)

    def screen(self):
        return self.tmux('capture-pane', '-p', '-t', 'teleop')

    def wait_for(self, text, timeout=DEADLINE):
        deadline = time.monotonic() + timeout
        while text not in (screen := self.screen()):
            assert time.monotonic() < deadline, f'{text!r} never appeared:\n{screen}'
            time.sleep(0.05)
        return screen

    def file(self, name, timeout=DEADLINE):
        path = self.directory / name
        deadline = time.monotonic() + timeout
        while not path.exists() or not path.read_text():
            assert time.monotonic() < deadline, f'{name} never written:\n{self.screen()}'
            time.sleep(0.05)
        return path.read_text()

    def close(self):
        subprocess.run(['tmux', '-S', self.socket, 'kill-server'], capture_output=True)


@pytest.fixture
def terminal(tmp_path):
    tmux = Tmux(tmp_path)
    yield tmux
    tmux.close()


def assert_restored(terminal):
    assert terminal.file('rc').strip() == '0', terminal.screen()
    assert terminal.file('after') == terminal.file('before'), 'terminal settings differ'
    flags = terminal.file('after_all').split()
    assert 'icanon' in flags and 'echo' in flags and 'isig' in flags
    assert 'Traceback' not in terminal.screen()


@pytest.mark.parametrize('way_out', ['C-c', 'SIGTERM', 'SIGHUP'])
def test_terminal_is_restored_on_every_way_out(terminal, way_out):
    terminal.start('--ros-args', '-r', f'__ns:={NAMESPACE}_alone')
    terminal.wait_for('q or Ctrl-C: quit')
    if way_out.startswith('SIG'):
        os.kill(int(terminal.file('pid')), getattr(signal, way_out))
    else:
        terminal.keys(way_out)
    assert_restored(terminal)


def test_a_closed_terminal_ends_the_teleop(terminal):
    terminal.start('--ros-args', '-r', f'__ns:={NAMESPACE}_alone')
    terminal.wait_for('q or Ctrl-C: quit')
    pid = int(terminal.file('pid'))
    terminal.tmux('kill-session', '-t', 'teleop')  # the window closes: SIGHUP, then EIO
    deadline = time.monotonic() + DEADLINE
    while Path(f'/proc/{pid}').exists() and b'Z' not in _state(pid):
        assert time.monotonic() < deadline, 'the teleop outlived its terminal'
        time.sleep(0.05)


def _state(pid):
    try:
        return Path(f'/proc/{pid}/stat').read_bytes().split(b') ')[1][:1]
    except (FileNotFoundError, IndexError):
        return b'Z'


class WorldProbe(Probe):
    """Watches the world's topics in its namespace: impulses, step stamps, velocities."""

    def __init__(self, namespace):
        super().__init__('teleop_probe', namespace=namespace, timeout=DEADLINE)
        self.impulses, self.stamps, self.velocities = [], [], None
        self.impulse_sub = self.node.create_subscription(
            Vector3Stamped, 'impulse', self._on_impulse, RECEIVE_QOS)
        self.node.create_subscription(PoseArray, 'balls', self._on_balls, RECEIVE_QOS)
        self.node.create_subscription(Float64MultiArray, 'state', self._on_state, RECEIVE_QOS)

    def _on_impulse(self, msg):
        self.impulses.append((msg.header.frame_id, msg.vector.x, msg.vector.y, msg.vector.z))

    def _on_balls(self, msg):
        self.stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)

    def _on_state(self, msg):
        self.velocities = np.asarray(msg.data).reshape(-1, 4)[:, 2:]

    def pause(self, paused):
        """Pause or resume; the step the world was at, read from its answer ('... at step N')."""
        answer = self.call(SetBool, 'ball_world/pause', SetBool.Request(data=paused))
        assert answer.success, answer.message
        return int(answer.message.rsplit(' ', 1)[1])


@pytest.fixture
def world():
    watcher = WorldProbe(NAMESPACE)
    yield watcher
    watcher.close()


@pytest.fixture
def start_world(processes):

    def start_node():
        processes.start(node_command(ros_args=[
            '-r', f'__ns:={NAMESPACE}', '-p', f'rate_hz:={RATE_HZ}.0', '-p',
            'markers.rate_hz:=0.0', *WORLD]))

    yield start_node
    for node in processes.started:
        node.send_signal(signal.SIGINT)
    ends = [finish(node) for node in processes.started]
    for code, _, err in ends:
        assert code == 0, err


def test_keys_drive_the_world_in_a_terminal(terminal, world, start_world):
    # The teleop starts before the world, as it may for a user. By the time the world is
    # up, the teleop and the probe have long discovered each other, so the probe hears
    # every impulse (a volatile publisher sends only to the readers it already knows).
    terminal.start('--ros-args', '-r', f'__ns:={NAMESPACE}', '-p', 'ball:=ball_1')
    terminal.wait_for(f'world    waiting for {NAMESPACE}/balls (no world yet, or a paused one')
    terminal.wait_for('ball     ball_1: not in the world')
    world.spin_until(lambda: world.impulse_sub.get_publisher_count() > 0,
                     'the probe to discover the teleop')
    terminal.keys('Right')
    terminal.wait_for("status   no ball 'ball_1' in the world; Tab selects one")
    start_world()
    terminal.wait_for(f'world    {NAMESPACE}/balls: 3 balls')
    expected = []
    velocities = np.zeros((3, 2))

    def push(keys, ball, x, y):
        terminal.keys(*keys)
        expected.append((f'ball_{ball}', x, y, 0.0))
        velocities[ball] += (x / MASS, y / MASS)
        world.spin_until(lambda: len(world.impulses) >= len(expected), f'impulse {keys}')
        assert world.impulses == expected
        world.spin_until(lambda: np.array_equal(world.velocities, velocities),
                         f'the node to apply {expected[-1]}')

    screen = terminal.wait_for('ball     ball_1 (2 of 3) at (5.00, 5.00)')
    assert 'keys     push ball_1: arrows along +y, -y, -x, +x (0.1 N s per key)' in screen
    push(['Right'], 1, 0.1, 0.0)
    terminal.wait_for('status   push 1: ball_1 by (+0.1, +0) N s')
    push(['+', 'Up'], 1, 0.0, 0.2)
    terminal.wait_for('keys     push ball_1: arrows along +y, -y, -x, +x (0.2 N s per key)')
    push(['0', 'Down'], 0, 0.0, -0.2)
    terminal.keys('Tab', 'Tab')
    terminal.wait_for('ball     ball_2 (3 of 3)')
    terminal.keys('Tab')
    terminal.wait_for('ball     ball_0 (1 of 3)')
    push(['BTab', 'Left'], 2, -0.2, 0.0)
    terminal.keys('-', '-', '9')
    terminal.wait_for('status   no ball number 10: the world has 3')
    push(['Right'], 2, 0.05, 0.0)
    terminal.wait_for('keys     push ball_2: arrows along +y, -y, -x, +x (0.05 N s per key)')

    # Another client pauses the world: space then means resume, although the teleop last
    # saw it running (its pause changes nothing, so it resumes at once).
    # The step it stopped at comes from the answer: a loaded machine may deliver the last
    # steps' messages late, so what arrived so far is no measure.
    stopped_at = world.pause(True) * DT_NS
    world.spin_until(lambda: world.stamps[-1] == stopped_at, 'the last step before the pause')
    terminal.keys('Space')
    terminal.wait_for(f'status   resume: running at step {stopped_at // DT_NS}')
    world.spin_until(lambda: world.stamps[-1] > stopped_at, 'stepping after the resume')
    terminal.keys('Space')
    screen = terminal.wait_for('status   pause: paused at step')
    paused_at = int(screen.split('status   pause: paused at step ')[1].split()[0]) * DT_NS
    world.spin_until(lambda: world.stamps[-1] == paused_at, 'the last step before the pause')
    world.spin_for(0.5)  # 25 steps would have come at 50 Hz
    assert world.stamps[-1] == paused_at
    terminal.wait_for(f't = {paused_at / 1e9:.3f} s, paused')
    terminal.keys('s')
    world.spin_until(lambda: world.stamps[-1] == paused_at + DT_NS, 'one step')
    terminal.keys('.')
    world.spin_until(lambda: world.stamps[-1] == paused_at + 2 * DT_NS, 'another step')
    terminal.wait_for(f'status   step: step {(paused_at + 2 * DT_NS) // DT_NS} at')
    terminal.keys('Space')
    terminal.wait_for('status   resume: running at step')
    world.spin_until(lambda: world.stamps[-1] > paused_at + 2 * DT_NS, 'stepping again')

    terminal.keys('r')
    screen = terminal.wait_for('status   reset: reset to step 0: 3 balls')
    world.spin_until(lambda: world.stamps[-1] < paused_at, 'a step after the reset')
    world.spin_until(lambda: not world.velocities.any(), 'the balls at rest again')
    assert screen.startswith(teleop.KEYS + '\n')  # the help screen, as printed
    terminal.keys('q')
    assert_restored(terminal)
    assert world.impulses == expected  # nothing more was sent
