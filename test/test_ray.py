"""Beyond one machine: ball_world_score --ray and envs.rollouts on a Ray cluster give the
reports and rollouts of this machine bit for bit; every way a tracker ends on a Ray worker
is one line with no task left running; an unreachable cluster is one line, not a hang.

One Ray cluster for the module (`ray start --head --block` on this machine, 2 CPUs; a
minute to start on a loaded machine), stopped at the end with every process it started
(they carry a mark in their environment: the test checks that none is left)."""
import json
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from ball_world.tools import score
from ball_world.user_code.ray_pool import RayPool
from ball_world.user_code.workers import JobFailed

ROOT = Path(__file__).resolve().parents[1]
STARTED = 'Ray runtime started'

KINDS = """
import ctypes, os, time


def hangs_started():  # the other kinds fail once a Hangs runs beside them
    end = time.monotonic() + 120
    while not os.path.exists(__file__ + '.pid') and time.monotonic() < end:
        time.sleep(0.05)


class Raises:
    def __init__(self):
        hangs_started()
        {}['missing']


class Quits:
    def __init__(self):
        hangs_started()
        os._exit(3)


class Crashes:
    def __init__(self):
        hangs_started()
        ctypes.string_at(0)


class Hangs:
    def __init__(self):
        with open(__file__ + '.pid', 'w') as out:
            out.write(str(os.getpid()))
        while True:
            time.sleep(0.05)
"""

POLICY = """
import numpy as np


def act(observations):
    lidar = next(iter(observations.values()))
    return np.tanh(np.stack([lidar[:, 0], -lidar[:, -1]], axis=1))
"""


def free_port():
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


def marked_processes(mark):
    found = []
    for entry in os.listdir('/proc'):
        try:
            with open(f'/proc/{entry}/environ', 'rb') as environ:
                if f'{mark}=1'.encode() in environ.read().split(b'\0'):
                    found.append(int(entry))
        except (OSError, ValueError):
            pass
    return found


def alive(pid):
    try:
        with open(f'/proc/{pid}/stat') as stat:
            return stat.read().split(')')[-1].split()[0] != 'Z'
    except OSError:
        return False


def wait_until(condition, seconds):
    end = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.2)
    return True


def environment(**extra):
    return {**os.environ, 'PYTHONPATH': os.pathsep.join(
        filter(None, [str(ROOT), os.environ.get('PYTHONPATH')])), **extra}


def start_cluster(mark, log_path):
    """(process, address) of `ray start --head --block` on this machine, or (None, why)."""
    port = free_port()
    with open(log_path, 'w') as log:
        process = subprocess.Popen(
            [str(Path(sys.executable).parent / 'ray'), 'start', '--head', '--block',
             '--port', str(port), '--node-ip-address', '127.0.0.1', '--num-cpus', '2',
             '--include-dashboard=false', '--disable-usage-stats',
             '--object-store-memory', str(100 * 2 ** 20)],
            stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
            env=environment(**{mark: '1'}))
    wait_until(lambda: process.poll() is not None or STARTED in log_path.read_text(), 300.0)
    if process.poll() is None and STARTED in log_path.read_text():
        return process, f'127.0.0.1:{port}'
    stop_cluster(process)
    return None, log_path.read_text()[-1500:]


def stop_cluster(process):
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)  # ray start --block stops what it started
    try:
        process.wait(90)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()


@pytest.fixture(scope='module')
def cluster(tmp_path_factory):
    """The address of a 2-CPU Ray cluster on this machine, stopped (and checked gone) after
    the module. Three tries: on a heavily loaded machine Ray's raylet can give up waiting
    for its agents (about 16 s) and the node does not start."""
    mark = f'BALL_WORLD_RAY_TEST_{uuid.uuid4().hex}'
    directory = tmp_path_factory.mktemp('ray')
    process = None
    try:
        for attempt in range(3):
            process, address = start_cluster(mark, directory / f'ray_start_{attempt}.log')
            if process is not None:
                break
        assert process is not None, f'no Ray cluster started in 3 tries: {address}'
        yield address
    finally:
        import ray
        if ray.is_initialized():
            ray.shutdown()
        if process is not None:
            stop_cluster(process)
        left = not wait_until(lambda: not marked_processes(mark), 60.0)
        for pid in marked_processes(mark):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        assert not left, 'Ray processes were left running after ray start stopped'


def run_score(*argv):
    return subprocess.run([sys.executable, '-m', 'ball_world.tools.score', *map(str, argv)],
                          capture_output=True, text=True, timeout=600, env=environment())


def test_the_scorer_on_a_cluster_reports_what_it_reports_here(cluster, capsys):
    argv = ['--seeds', '0:3', '--duration', '1', '--jobs', '2', '--json']
    there = run_score(*argv, '--ray', cluster)
    assert there.returncode == 0 and there.stderr == '', there.stderr  # Ray kept quiet
    assert score.main(argv) == 0
    here = json.loads(capsys.readouterr().out)
    there = json.loads(there.stdout)
    assert here['scenes'] == there['scenes'] == 3 and there['jobs'] == 2
    del here['seconds'], there['seconds']
    assert json.dumps(there) == json.dumps(here)


def test_an_unreachable_cluster_is_one_line():
    done = run_score('--seeds', '0:1', '--duration', '1', '--ray', f'127.0.0.1:{free_port()}')
    assert done.returncode == 1 and done.stdout == '', done
    assert done.stderr.count('\n') == 1 and 'no Ray cluster answers there' in done.stderr, \
        done.stderr
    # auto: the cluster RAY_ADDRESS or the last `ray start` names, which may be gone
    gone = f'127.0.0.1:{free_port()}'
    done = subprocess.run([sys.executable, '-m', 'ball_world.tools.score', '--seeds', '0:1',
                           '--ray', 'auto'], capture_output=True, text=True, timeout=600,
                          env=environment(RAY_ADDRESS=gone))
    assert done.returncode == 1 and done.stderr == (
        f'ball_world_score: --ray auto (the cluster at {gone}): no Ray cluster answers there '
        '(Connection refused)\n'), done.stderr


@pytest.mark.parametrize('argv, expected', [
    (['--scenes', 'scenes', '--ray', 'auto'], '--ray runs simulated scenes (--seeds, --worlds)'),
    (['run.mcap', '--ray', 'auto'], '--ray runs simulated scenes: give it with --seeds'),
    (['--seeds', '2', '--ray', ' '], '--ray is empty'),
])
def test_ray_arguments_that_cannot_run_exit_2(argv, expected, capsys):
    with pytest.raises(SystemExit) as ended:
        score.main(argv)
    assert ended.value.code == 2 and expected in capsys.readouterr().err


@pytest.mark.parametrize('name, expected', [
    ('Raises', "making one raised KeyError: 'missing' (at kinds.py:"),
    ('Quits', 'exited with status 3: os._exit(3) (at kinds.py:'),
    ('Crashes', 'killed by SIGSEGV (at kinds.py:'),
    ('Hangs', 'ran past the test deadline of 3 s (at kinds.py:'),
])
def test_every_way_a_tracker_ends_on_a_worker_is_one_line_and_no_task_runs_on(
        cluster, tmp_path, name, expected):
    from ball_world.tools.score_bench import check_tracker
    kinds = tmp_path / 'kinds.py'
    kinds.write_text(KINDS)
    pid_file = Path(f'{kinds}.pid')
    # Another kind fails while a Hangs runs beside it (with no deadline of its own): the
    # Hangs task must be cancelled.
    deadline = 3.0 if name == 'Hangs' else 600.0
    specs = [f'{kinds}:{name}'] + ([] if name == 'Hangs' else [f'{kinds}:Hangs'])
    with pytest.raises(JobFailed) as caught:
        with RayPool(cluster, 2, None, deadline, f'the test deadline of {deadline:g} s') as pool:
            list(pool.map_unordered(check_tracker, specs, ['--tracker'] * len(specs)))
    line = str(caught.value)
    assert '\n' not in line and expected in line, line
    assert wait_until(lambda: pid_file.exists() and pid_file.read_text(), 120.0)
    assert wait_until(lambda: not alive(int(pid_file.read_text())), 60.0), \
        'a Ray task was left running'


def test_a_sigterm_ends_the_scorer_and_its_ray_tasks(cluster, tmp_path):
    kinds = tmp_path / 'kinds.py'
    kinds.write_text(KINDS)
    pid_file = Path(f'{kinds}.pid')
    process = subprocess.Popen(
        [sys.executable, '-m', 'ball_world.tools.score', '--seeds', '0:2', '--duration', '1',
         '--tracker', f'{kinds}:Hangs', '--timeout', '600', '--ray', cluster],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment())
    try:
        assert wait_until(lambda: pid_file.exists() and pid_file.read_text(), 300.0)
        process.send_signal(signal.SIGTERM)  # ray.init's own handler would exit at once
        out, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 143 and err == 'ball_world_score: terminated\n', err
    assert out == ''
    assert wait_until(lambda: not alive(int(pid_file.read_text())), 60.0), \
        'a Ray task was left running'


def test_rollouts_on_a_cluster_equal_those_here(cluster, tmp_path):
    from ball_world.envs.rollouts import rollouts
    policy = tmp_path / 'policy.py'
    policy.write_text(POLICY)
    for spec in (None, f'{policy}:act'):
        here = rollouts([4, 9], num_envs=2, steps=6, policy=spec)
        there = rollouts([4, 9], num_envs=2, steps=6, policy=spec, ray=cluster)
        assert len(there) == 2
        for mine, theirs in zip(here, there):
            assert mine.keys() == theirs.keys()
            for key in ('rewards', 'terminated', 'truncated'):
                assert mine[key].tobytes() == theirs[key].tobytes(), key
            for key, values in mine['observation'].items():
                assert np.array_equal(values, theirs['observation'][key]), key
    assert not np.array_equal(here[0]['rewards'], here[1]['rewards'])  # seeds matter


if __name__ == '__main__':
    sys.exit(pytest.main([__file__]))
