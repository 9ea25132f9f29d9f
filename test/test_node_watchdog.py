"""A process that cannot make its ROS node says why within NODE_SECONDS, and Ctrl-C or
SIGTERM ends it (issue 33, item 7; ros/rcl_init.creating_node, ros/node_watchdog.py).

The hang is real: a zero-length Fast DDS port segment in /dev/shm (what a process killed
while making one leaves) makes the next participant of its domain spin in rcl_node_init,
holding the GIL. The test makes one for a domain of its own (201-232, which the suite's
domains, 1-200, never use), claimed with O_EXCL so two runs at once never share it.
"""
import os
from pathlib import Path
import select
import signal
import subprocess
import sys
import time

from ball_world_testing.harness import DEADLINE
import pytest

from ball_world.ros import node_watchdog
from ball_world.ros.rcl_init import creating_node

#: Domains no other test uses (conftest's are 1 to 200; Linux allows up to 232).
SPARE_DOMAINS = range(201, 233)
SHM = Path('/dev/shm')

STUCK = """
import ctypes, sys, time
from ball_world.ros.rcl_init import creating_node
seconds = float(sys.argv[1])
if sys.argv[2] == 'dds':
    import rclpy
    rclpy.init()
    make = lambda: rclpy.create_node('stuck')
else:  # a C call that holds the GIL and never returns, whatever the signal, as Fast DDS's
    # spin: a second lock of a (default, not recursive) mutex, which glibc never gives up
    libc, mutex = ctypes.PyDLL(None), ctypes.create_string_buffer(64)
    make = lambda: (libc.pthread_mutex_lock(mutex), libc.pthread_mutex_lock(mutex))
print('making', flush=True)
with creating_node('stuck', seconds=seconds):
    make()
print('made', flush=True)
"""


def port_segment(domain):
    """The shared-memory port of participant 0's user traffic in `domain` (Fast DDS's
    7400 + 250 d + 11)."""
    return SHM / f'fastrtps_port{7411 + 250 * domain}'


@pytest.fixture
def half_made_domain():
    """A spare domain whose first participant's port segment is left half-made."""
    for domain in SPARE_DOMAINS:
        try:
            os.close(os.open(port_segment(domain), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            continue
        break
    else:
        pytest.fail('no spare ROS domain: every one of 201-232 has a port segment')
    try:
        yield domain
    finally:
        port = port_segment(domain).name
        for name in (port, f'{port}_el', f'sem.{port}_mutex'):
            (SHM / name).unlink(missing_ok=True)


def start_stuck(how, seconds, domain=None):
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    if domain is not None:
        env['ROS_DOMAIN_ID'] = str(domain)
    return subprocess.Popen([sys.executable, '-c', STUCK, str(seconds), how],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0, env=env)


def read_line(stream, process, what):
    """The next line of `stream` (an unbuffered pipe of `process`), within the harness's
    deadline."""
    deadline = time.monotonic() + DEADLINE
    line = b''
    while not line.endswith(b'\n'):
        assert time.monotonic() < deadline, f'{what} within {DEADLINE:g} s'
        if select.select([stream], [], [], 0.1)[0]:
            got = os.read(stream.fileno(), 1)
            if not got:
                raise AssertionError(f'{what}: the process ended ({process.wait()}) first')
            line += got
    return line.decode().strip()


def stop_and_read(process, sig):
    process.send_signal(sig)
    try:
        process.wait(DEADLINE)
    finally:
        if process.poll() is None:
            process.kill()
    return process.stderr.read().decode().strip().splitlines()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_node_stuck_in_a_c_call_says_why_and_a_signal_ends_it(sig):
    process = start_stuck('gil', 0.5)
    try:
        assert read_line(process.stdout, process, 'the start') == 'making'
        said = read_line(process.stderr, process, 'the line saying why')
        assert said.startswith('stuck: no ROS node after 0.5 s (rcl_node_init has not '
                               'returned): ')
        assert f"remove Fast DDS's files: {node_watchdog.REMEDY}" in said
        assert said.endswith('Ctrl-C ends this')
        lines = stop_and_read(process, sig)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == -signal.SIGKILL  # it could not act on the signal itself
    assert len(lines) == 1 and lines[0].startswith(
        f'stuck: {sig.name} while its ROS node was being made, and rcl_node_init has not '
        'returned for ')


def test_a_half_made_port_segment_is_named_and_ctrl_c_ends_the_process(half_made_domain):
    process = start_stuck('dds', 1.0, domain=half_made_domain)
    try:
        assert read_line(process.stdout, process, 'the start') == 'making'
        said = read_line(process.stderr, process, 'the line saying why')
        assert said.startswith('stuck: no ROS node after 1 s'), said
        assert "Fast DDS's shared-memory transport waiting on a segment that a killed " \
            'process left half-made' in said
        assert str(port_segment(half_made_domain)) in said
        lines = stop_and_read(process, signal.SIGINT)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == -signal.SIGKILL
    assert lines and lines[-1].startswith('stuck: SIGINT while its ROS node was being made')


def test_a_signal_while_the_node_is_made_is_held_until_it_is_made():
    made = False
    with pytest.raises(KeyboardInterrupt):
        with creating_node('held', seconds=60):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)  # Python runs the handler here: it holds the signal
            made = True
    assert made


def test_half_made_segments_are_told_from_made_ones_and_from_new_ones(tmp_path):
    made = (2).to_bytes(4, sys.byteorder) + bytes(60)
    (tmp_path / 'fastrtps_port7411').write_bytes(made)
    (tmp_path / 'fastrtps_port7413').write_bytes(b'')  # cut before its size was set
    (tmp_path / 'fastrtps_port7415').write_bytes((1).to_bytes(4, sys.byteorder) + bytes(60))
    (tmp_path / 'fastrtps_port7415_el').write_bytes(b'')  # a lock, never a segment
    (tmp_path / 'fastrtps_0123456789abcdef').write_bytes(bytes(64))
    (tmp_path / 'other').write_bytes(b'')
    old = time.time() - 60
    for path in tmp_path.iterdir():
        os.utime(path, (old, old))
    (tmp_path / 'fastrtps_port7417').write_bytes(b'')  # being made right now
    found = node_watchdog.half_made(tmp_path, before=time.time() - 1)
    assert found == [str(tmp_path / name) for name in (
        'fastrtps_0123456789abcdef', 'fastrtps_port7413', 'fastrtps_port7415')]
    assert 'no half-made Fast DDS segment' in node_watchdog.diagnosis(tmp_path / 'none')


def test_the_port_of_this_domain_is_named_first_among_many_half_made_files():
    """A machine where processes were killed holds many half-made files; the line names a
    few, and the port segment of the process's own domain must be among them (the fresh-clone
    suite failed: /dev/shm's other files sorted first and hid domain 201's port)."""
    others = [f'/dev/shm/fastrtps_{index:016x}' for index in range(5)]
    ports = ['/dev/shm/fastrtps_port7411', '/dev/shm/fastrtps_port57661',
             '/dev/shm/fastrtps_port57899', '/dev/shm/fastrtps_port57900']
    ordered = node_watchdog.likeliest_first(sorted(others + ports), 201)
    # Domain 201's ports are 57650 to 57899; 57900 is domain 202's.
    assert ordered[:2] == ['/dev/shm/fastrtps_port57661', '/dev/shm/fastrtps_port57899']
    assert ordered[2:4] == ['/dev/shm/fastrtps_port57900', '/dev/shm/fastrtps_port7411']
    assert ordered[4:] == others
