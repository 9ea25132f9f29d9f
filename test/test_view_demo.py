"""make view / make demo: everything they start stops with them, and their ports are free
again; the wander example keeps its robot off the walls.

The launchers run as a user runs them (ball_world_view, ball_world_demo), on free ports; a
Ctrl-C is SIGINT to the launcher, as a terminal sends it. A launcher killed outright
(SIGKILL: nothing of it runs any more) must not leave the Rerun server holding its ports.
"""
import os
from pathlib import Path
import signal
import socket
import subprocess
import time

from ball_world_testing.harness import DEADLINE, executable, start
import numpy as np
import pytest

from ball_world.simulation import Simulation
from ball_world.tools.processes import port_free, port_open
from ball_world.tools.wander import Options, Wander


def free_ports(count):
    sockets = [socket.socket() for _ in range(count)]
    try:
        for probe in sockets:
            probe.bind(('127.0.0.1', 0))
        return [probe.getsockname()[1] for probe in sockets]
    finally:
        for probe in sockets:
            probe.close()


def children_of(pid):
    """Every process whose parent chain reaches pid (from /proc)."""
    parents = {}
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                with open(f'/proc/{entry}/stat') as stat:
                    parents[int(entry)] = int(stat.read().rsplit(')', 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def wait_until(predicate, what, timeout=DEADLINE):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f'{what} within {timeout:g} s'
        time.sleep(0.2)


def alive(pid):
    try:
        with open(f'/proc/{pid}/stat') as stat:
            return stat.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def launch(tool, tmp_path, *extra):
    web, grpc = free_ports(2)
    process = start([executable(tool), '--web-port', str(web), '--grpc-port', str(grpc),
                     '--log-dir', str(tmp_path / 'logs'), *extra], cwd=tmp_path)
    wait_until(lambda: port_open(grpc) or process.poll() is not None, 'the server')
    assert process.poll() is None, process.communicate()
    return process, web, grpc


@pytest.mark.parametrize('tool, started', [('ball_world_view', 2), ('ball_world_demo', 5)])
def test_ctrl_c_stops_everything_it_started_and_frees_the_ports(tmp_path, tool, started):
    process, web, grpc = launch(tool, tmp_path)
    try:
        wait_until(lambda: len(children_of(process.pid)) >= started, f'{started} programs')
        wait_until(lambda: 'step' in (tmp_path / 'logs' / 'world.log').read_text()
                   if tool == 'ball_world_demo' else True, "the world's first progress line",
                   timeout=4 * DEADLINE)
        descendants = children_of(process.pid)
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=4 * DEADLINE)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, err
    assert out.lstrip().startswith(('Open http://127.0.0.1', 'ball_world demo')), out
    assert f'http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}' in out
    assert not [pid for pid in descendants if alive(pid)]
    assert port_free(web) and port_free(grpc)
    if tool == 'ball_world_demo':
        # Its last line says that everything stopped, not only that it is stopping.
        assert out.rstrip().splitlines()[-1].strip().startswith(
            'ball_world_demo: stopped; every program it started has ended'), out
        # The world counted its robots' drive apart from pushes, and closed cleanly.
        log = (tmp_path / 'logs' / 'world.log').read_text()
        assert 'impulses applied 0 (and ' in log and "by the agents' drives)" in log


def test_make_views_logs_go_in_a_folder_of_their_own():
    """`make view` left runs/rerun_server.log loose at the top of runs/."""
    from ball_world.tools import view
    assert view.parser().parse_args([]).log_dir == Path('runs/view')


@pytest.mark.parametrize('tool, started', [('ball_world_view', 2), ('ball_world_demo', 5)])
def test_a_killed_launcher_leaves_no_server_on_its_ports(tmp_path, tool, started):
    # Every child is told to stop (SIGTERM) when its launcher dies, and none waits on a peer
    # that died with it (the world on its view: test_shutdown_deadlines.py; the figures,
    # well under 2 s, are in docs/reliability.md)
    process, web, grpc = launch(tool, tmp_path)
    wait_until(lambda: len(children_of(process.pid)) >= started, f'{started} programs')
    descendants = children_of(process.pid)
    process.kill()
    process.communicate()
    wait_until(lambda: not [pid for pid in descendants if alive(pid)],
               'every child to end with its launcher')
    wait_until(lambda: port_free(web) and port_free(grpc), 'the ports to be free')


def test_a_taken_port_is_refused_in_one_line(tmp_path):
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run([executable('ball_world_view'), '--grpc-port', str(port)],
                                cwd=tmp_path, capture_output=True, text=True, timeout=DEADLINE)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [
        f'ball_world_view: port {port} on 127.0.0.1 is taken (another viewer?); free it or '
        'choose others with --web-port / --grpc-port']


def test_a_missing_world_file_is_refused_in_one_line(tmp_path):
    result = subprocess.run([executable('ball_world_view'), '--world', 'nope.yaml'],
                            cwd=tmp_path, capture_output=True, text=True, timeout=DEADLINE)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "ball_world_view: --world 'nope.yaml': no such file (see --help)"]


def test_a_policy_the_demo_cannot_use_is_refused_in_one_line(tmp_path):
    result = subprocess.run([executable('ball_world_demo'), '--policy', 'none.zip'],
                            cwd=tmp_path, capture_output=True, text=True, timeout=DEADLINE)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "ball_world_demo: --policy: no policy file 'none.zip' (ball_world_learn train saves "
        'one) (see --help)']


# The wander example, headless -----------------------------------------------------------------

ROOM = {'balls.x': [5.0], 'balls.y': [5.0], 'balls.vx': [0.0], 'balls.vy': [0.0],
        'balls.radius': [0.3], 'balls.mass': [0.3], 'random.count': 0, 'agents': ['ball_0'],
        # two walls inside the 10 m box: corners to get out of
        'walls': [3.0, 3.0, 3.0, 7.0, 6.0, 2.0, 8.0, 4.0]}


def segment_distance(point, walls):
    """Distance from point to each wall segment (x1, y1, x2, y2)."""
    a, b = walls[:, 0:2], walls[:, 2:4]
    t = np.clip(np.einsum('ij,ij->i', point - a, b - a) / np.einsum('ij,ij->i', b - a, b - a),
                0.0, 1.0)
    return np.hypot(*(point - (a + t[:, None] * (b - a))).T)


def test_wander_roams_for_two_minutes_without_touching_a_wall():
    simulation = Simulation(ROOM)
    walls = simulation.world.walls.segments
    controller = Wander(Options(), seed=1)
    radius = 0.3
    clearance, visited, wall_hits = np.inf, set(), 0
    for _ in range(60 * 120):
        record = simulation.last_record
        if record.agents.scans:
            scan = record.agents.scans[0]
            forward, yaw_rate = controller.command(
                scan.ranges, scan.fan.angle_min, scan.fan.angle_increment, scan.fan.range_max,
                record.stamp_ns * 1e-9)
            simulation.command('ball_0', forward, 0.0, yaw_rate)
        record, _ = simulation.step()
        wall_hits += record.ball_wall
        position = record.positions[0]
        clearance = min(clearance, segment_distance(position, walls).min() - radius)
        visited.add((int(position[0]), int(position[1])))
    assert wall_hits == 0
    assert clearance > 0.05  # never closer than 5 cm to a wall
    assert len(visited) >= 12  # it roams: a dozen of the box's 1 m squares at least


def test_wander_turns_away_from_what_is_ahead_and_goes_on_when_clear():
    controller = Wander(Options(speed=0.6, turn_rate=1.5), seed=0)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    clear = np.full(360, np.inf)
    forward, _ = controller.command(clear, -np.pi, 2 * np.pi / 360, 12.0, 0.0)
    assert forward == 0.6
    blocked = clear.copy()
    blocked[np.abs(angles) < 0.2] = 0.5  # something 0.5 m ahead
    blocked[angles > 0.5] = 1.0  # and the left side is closer than the right
    assert controller.command(blocked, -np.pi, 2 * np.pi / 360, 12.0, 0.1) == (0.0, -1.5)
    # Still blocked, the left side now further: it keeps turning right, no dithering.
    blocked[angles > 0.5] = np.inf
    blocked[angles < -0.5] = 1.0
    assert controller.command(blocked, -np.pi, 2 * np.pi / 360, 12.0, 0.2) == (0.0, -1.5)
    assert controller.command(clear, -np.pi, 2 * np.pi / 360, 12.0, 0.3)[0] == 0.6
