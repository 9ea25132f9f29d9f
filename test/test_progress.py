"""Progress bars: redrawn in place on a terminal, one final line anywhere else.

The terminal case runs the real console tool with stderr on a pseudo-terminal (pty), since
what matters is that the tool asks the stream it writes to; the other case pipes stderr.
"""
import os
import pty
import select
import subprocess
import time

from ball_world_testing.harness import executable, finish, start
import pytest

from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation
from ball_world.tools.progress import Progress

#: Generous: a tool that has not finished in this long is hanging.
DEADLINE = 120.0


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """Enough steps that a conversion takes several redraw intervals."""
    path = tmp_path_factory.mktemp('progress') / 'run.mcap'
    simulation = Simulation({'rate_hz': 100.0, 'random.count': 200, 'random.seed': 1,
                             'random.radius': [0.05, 0.1]}, sinks=[McapSink(path)])
    for _ in range(1500):
        simulation.step()
    simulation.close()
    return path


def on_a_terminal(processes, command):
    """(exit code, what the tool wrote to its stderr), with stderr a pseudo-terminal."""
    controller, terminal = pty.openpty()
    process = processes.start(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=terminal)
    os.close(terminal)
    written = b''
    deadline = time.monotonic() + DEADLINE
    while time.monotonic() < deadline:
        ready, _, _ = select.select([controller], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(controller, 65536)
            except OSError:  # EIO: the tool closed the terminal
                break
            if not chunk:
                break
            written += chunk
        elif process.poll() is not None:
            break
    os.close(controller)
    code = process.wait(timeout=DEADLINE)
    return code, written.decode()


@pytest.mark.parametrize('tool, arguments', [
    ('ball_world_to_rrd', ['-o', '{dir}/out.rrd']),
    ('ball_world_resim', []),
])
def test_on_a_terminal_the_bar_redraws_in_place(recording, tmp_path, processes, tool,
                                                arguments):
    command = [executable(tool), str(recording)] + [a.format(dir=tmp_path) for a in arguments]
    code, written = on_a_terminal(processes, command)
    assert code == 0, written
    written = written.replace('\r\n', '\n')  # the terminal's own line ends (onlcr)
    bar = [line for line in written.split('\n') if '1,501 steps' in line or '/1,501' in line]
    assert len(bar) == 1, written  # one terminal line, redrawn
    draws = bar[0].split('\r')[1:]
    assert len(draws) >= 2 and all(d.startswith(tool + ': [') for d in draws), written
    assert '100% 1,501/1,501 steps in ' in draws[-1]


@pytest.mark.parametrize('tool, arguments', [
    ('ball_world_to_rrd', ['-o', '{dir}/out.rrd']),
    ('ball_world_resim', []),
    ('ball_world_repair', ['-o', '{dir}/out.mcap']),
])
def test_elsewhere_the_bar_is_one_final_line(recording, tmp_path, tool, arguments):
    command = [executable(tool), str(recording)] + [a.format(dir=tmp_path) for a in arguments]
    code, _, err = finish(start(command), DEADLINE)
    assert code == 0, err
    progress = [line for line in err.splitlines() if line.startswith(tool + ': [')]
    assert len(progress) == 1 and '\r' not in err, err
    assert '100% ' in progress[0]


class Terminal:
    """A stream that says it is a terminal and keeps what is written."""

    def __init__(self, tty):
        self.tty = tty
        self.text = ''

    def isatty(self):
        return self.tty

    def write(self, text):
        self.text += text

    def flush(self):
        pass


def test_progress_redraws_at_most_once_per_interval_and_ends_its_line():
    stream = Terminal(tty=True)
    progress = Progress(1000, 'steps', 'tool', stream, interval=3600.0)
    for _ in range(1000):
        progress.advance()
    progress.finish()
    draws = stream.text.split('\r')[1:]
    assert len(draws) == 2 and stream.text.endswith('\n')  # the first draw, and the last
    assert draws[-1].startswith('tool: [' + '#' * 30 + '] 100% 1,000/1,000 steps in ')
    quiet = Terminal(tty=False)
    progress = Progress(0, 'bytes', 'tool', quiet)
    progress.advance(5)
    progress.abandon()
    assert quiet.text == ''  # an error follows: nothing of the bar before it
