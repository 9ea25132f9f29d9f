"""User code at arm's length (ball_world.user_code): whatever a tracker or controller
returns is accepted as the scoring reads it or refused in one line naming who, when and the
value; however its code ends (an exception, SystemExit, KeyboardInterrupt, os._exit, a
segfault, SIGKILL, a hang) the supervisor says so in one line, and no process is left.

The failure kinds run through real worker processes (user_code.workers.Remote: a spawned
worker, no simulation: cheap); ball_world_score itself through three runs of the installed
tool (a segfault with two workers, SystemExit(0) with one, a real Ctrl-C)."""
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
import uuid

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from ball_world.user_code import checks, workers
from ball_world.user_code.calls import call
from ball_world.user_code.describe import describe_exit, shown, UserCodeError
from ball_world.user_code.loading import load_class
from ball_world.user_code.workers import JobFailed, LocalPool, Remote

WHO, WHEN = 'my.py:T', 'on seed 3 at scan 12 (stamp 1.200 s)'

KINDS = """
import ctypes, os, signal, time


class Good:
    def __init__(self, offset=0.0):
        self.offset = offset

    def act(self, observation):
        print('a print of the user')
        return observation + self.offset


class Raises:
    def act(self, observation):
        return {}['missing']


class Exits:
    def act(self, observation):
        raise SystemExit(0)


class Interrupted:
    def act(self, observation):
        raise KeyboardInterrupt


class Quits:
    def act(self, observation):
        os._exit(3)


class Crashes:
    def act(self, observation):
        ctypes.string_at(0)


class Killed:
    def act(self, observation):
        os.kill(os.getpid(), signal.SIGKILL)


class Hangs:
    def act(self, observation):
        while True:
            time.sleep(0.05)


class Broken:
    def __init__(self):
        raise SystemExit(2)


class EndsHanging:
    def update(self, scan, pose):
        return []

    def __del__(self):
        while True:
            time.sleep(0.05)
"""


def one_line(text):
    return text.count('\n') == 0 and text.strip() == text and text


# What a tracker returns ----------------------------------------------------------------------

@pytest.mark.parametrize('rows, ids', [
    ([(1, 0.0, 0.0), ('ball', 1, 2)], [1, 'ball']),
    (np.array([[3.0, 0.5, 0.25, 9.0], [4.0, 1.0, 1.0, 9.0]]), [3, 4]),  # a float array
    (np.array([[7, 1, 2]], dtype=np.int64), [7]),
    ([(np.int32(5), np.float32(0.5), np.float64(1.0))], [5]),
    ([(10 ** 400, 1e308, -1e308)], [10 ** 400]),  # any int; far, but finite
    ((row for row in [(2, 0.0, 0.0)]), [2]),
    ([], []), (np.empty((0, 3)), []), (np.empty(0), []),
])
def test_rows_a_tracker_may_return_are_accepted(rows, ids):
    got, xy = checks.track_rows(rows, WHO, WHEN)
    assert got == ids and all(isinstance(i, (int, str)) for i in got)
    assert all(math.isfinite(v) for point in xy for v in point)


@pytest.mark.parametrize('rows, expected', [
    (None, 'returned None, not rows (id, x, y, ...)'),
    (5, 'returned 5, not rows'), ('abc', "returned 'abc', not rows"),
    ({1: (0, 0)}, 'not rows'), (np.array([1.0, 2.0, 3.0]), 'array of shape (3,)'),
    ([(1, 2.0)], 'row 0 = (1, 2.0) with 2 fields'), ([5], 'row 0 = 5, not rows'),
    ([(float('nan'), 0, 0)], 'whose id is nan (row 0)'),
    ([(1, 0, 0), (math.inf, 0, 0)], 'whose id is inf (row 1)'),
    ([(3.5, 0, 0)], 'whose id is 3.5'), ([(None, 0, 0)], 'whose id is None'),
    ([(True, 0, 0)], 'whose id is True'), ([((1, 2), 0, 0)], 'whose id is (1, 2)'),
    ([(1, float('nan'), 0)], 'whose x is nan (row 0, id 1)'),
    ([(1, 0, -math.inf)], 'whose y is -inf'), ([(1, '3.5', 0)], "whose x is '3.5'"),
    ([(1, None, 0)], 'whose x is None'), ([(1, 10 ** 400, 0)], 'x is an int of 401 digits'),
    ([(1, 10 ** 5000, 0)], 'x is an int of many digits'),
    ([(1, 1j, 0)], 'whose x is 1j'),
    ([(i, 0, 0) for i in range(checks.MAX_TRACKS + 1)], 'more than 10,000 tracks'),
    ((1 / 0 for _ in [1]), 'raised ZeroDivisionError: division by zero'),
])
def test_what_is_no_rows_is_one_line_naming_who_when_and_the_value(rows, expected):
    with pytest.raises(UserCodeError) as caught:
        checks.track_rows(rows, WHO, WHEN)
    text = one_line(str(caught.value))
    assert expected in text and text.startswith(WHO) and WHEN in text, text


values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=3)
    | st.integers(-2 ** 63, 2 ** 63 - 1).map(np.int64) | st.floats(width=32).map(np.float32)
    | st.just(10 ** 400),
    lambda inner: st.lists(inner, max_size=4) | st.tuples(inner, inner, inner)
    | st.tuples(inner, inner), max_leaves=12)


@settings(max_examples=300, deadline=None)
@given(values)
def test_anything_a_tracker_returns_is_accepted_or_one_line(value):
    try:
        ids, xy = checks.track_rows(value, WHO, WHEN)
    except UserCodeError as error:
        assert one_line(str(error)) and WHO in str(error)
        return
    assert len(ids) == len(xy)
    assert all(isinstance(i, (int, str)) and not isinstance(i, bool) for i in ids)
    assert np.isfinite(np.asarray(xy, dtype=float)).all()


def test_a_controllers_commands_are_checked():
    good = checks.commands([[1, 0, 0.5], [0, 0, 0]], 2, WHO, WHEN)
    assert good.dtype == np.float64 and good.shape == (2, 3)
    for value, expected in (([[1, 0, 0]], 'shape (1, 3)'), ('x', "returned 'x'"),
                            ([[1, 0, math.nan], [0, 0, 0]], 'row 0, column 2 is nan'),
                            ([[1, 0, 0], [0, 10 ** 400, 0]], 'returned [[1, 0, 0]')):
        with pytest.raises(UserCodeError) as caught:
            checks.commands(value, 2, WHO, WHEN)
        assert expected in one_line(str(caught.value)), caught.value


def test_shown_never_fails_and_stays_short():
    class Nasty:
        def __repr__(self):
            raise RuntimeError('no')

    assert shown(Nasty()) == '<a Nasty whose repr fails>'
    assert shown(10 ** 5000) == 'an int of many digits' and len(shown('x' * 500)) == 60
    assert describe_exit(-signal.SIGSEGV) == 'killed by SIGSEGV'
    assert describe_exit(3) == 'exited with status 3'


# Loading and calling, in this process --------------------------------------------------------

def test_loading_a_class_and_every_way_it_fails(tmp_path):
    path = tmp_path / 'kinds.py'
    path.write_text(KINDS + '\nfrom dataclasses import dataclass\n\n\n@dataclass\n'
                    'class Data:\n    x: int = 1\n')
    assert load_class(f'{path}:Data')().x == 1  # a dataclass needs its module registered
    (tmp_path / 'syntax.py').write_text('def broken(:\n')
    (tmp_path / 'exits.py').write_text('import sys\nsys.exit(4)\n')
    for spec, expected in ((f'{path}:Nope', 'has no class Nope'),
                           (f'{tmp_path}/none.py:X', 'none.py is not a file'),
                           ('just_a_name', 'expected MODULE:CLASS'),
                           (f'{path}:1x', 'expected MODULE:CLASS'),
                           (f'{tmp_path}/syntax.py:X', 'failed: SyntaxError'),
                           (f'{tmp_path}/exits.py:X', 'failed: SystemExit: 4 (at exits.py:2)'),
                           ('no_such_module_here:X', "No module named 'no_such_module_here'")):
        with pytest.raises(UserCodeError) as caught:
            load_class(spec, '--tracker')
        assert expected in one_line(str(caught.value)), caught.value


def test_a_call_turns_every_exception_into_one_line_but_lets_a_ctrl_c_through():
    def leave(kind):
        raise kind

    for kind, expected in ((SystemExit(0), 'update raised SystemExit: 0 (at test_user_code'),
                           (GeneratorExit(), 'raised GeneratorExit'),
                           (ValueError('a\nb'), 'raised ValueError: a b')):
        with pytest.raises(UserCodeError) as caught:
            call('update', leave, kind)
        assert expected in one_line(str(caught.value)), caught.value
    with pytest.raises(KeyboardInterrupt):  # outside a worker: the user's Ctrl-C
        call('update', leave, KeyboardInterrupt())


# Through real worker processes --------------------------------------------------------------

def marked_processes(mark):
    """Pids of live processes whose environment holds `mark` (psutil-free), but for this
    process's own multiprocessing resource tracker (one per process, for its life)."""
    found = []
    for name in os.listdir('/proc'):
        if not name.isdigit() or int(name) == os.getpid():
            continue
        try:
            with open(f'/proc/{name}/environ', 'rb') as stream:
                if mark.encode() not in stream.read():
                    continue
            with open(f'/proc/{name}/stat') as stat:
                state, parent = stat.read().rpartition(')')[2].split()[:2]
            with open(f'/proc/{name}/cmdline', 'rb') as stream:
                ours = int(parent) == os.getpid() and b'resource_tracker' in stream.read()
        except OSError:
            continue
        if state != 'Z' and not ours:
            found.append(int(name))
    return found


def gone(mark, seconds=20.0):
    """True once no process holds `mark` (the resource tracker ends when its pipe closes)."""
    end = time.monotonic() + seconds
    while marked_processes(mark):
        if time.monotonic() > end:
            return False
        time.sleep(0.1)
    return True


@pytest.fixture
def marked(monkeypatch):
    mark = f'BALL_WORLD_TEST_{uuid.uuid4().hex}'
    monkeypatch.setenv(mark, '1')  # workers inherit it: how the test finds them
    return mark


@pytest.mark.parametrize('name, expected', [
    ('Raises', "Raises.act raised KeyError: 'missing' (at kinds.py:"),
    ('Exits', 'Exits.act raised SystemExit: 0 (at kinds.py:'),
    ('Interrupted', 'Interrupted.act raised KeyboardInterrupt (at kinds.py:'),
    ('Quits', 'exited with status 3: os._exit(3) (at kinds.py:'),
    ('Crashes', 'killed by SIGSEGV (at kinds.py:'),
    ('Killed', 'killed by SIGKILL'),
    ('Hangs', 'ran past the test deadline of 2 s (at kinds.py:'),
])
def test_every_way_user_code_ends_in_a_worker_is_one_line_and_no_process(
        tmp_path, marked, name, expected):
    path = tmp_path / 'kinds.py'
    path.write_text(KINDS)
    began = time.monotonic()
    with pytest.raises(JobFailed) as caught:
        with Remote(f'{path}:{name}', '--controller', deadline_s=2.0,
                    deadline_text='the test deadline of 2 s') as remote:
            remote.call('act', np.zeros(3))
    assert expected in one_line(str(caught.value)), caught.value
    assert time.monotonic() - began < 60.0
    assert gone(marked)


def test_a_controller_in_a_worker_answers_and_a_bad_one_is_refused(tmp_path, marked, capfd):
    path = tmp_path / 'kinds.py'
    path.write_text(KINDS)
    with Remote(f'{path}:Good', '--controller', args=(2.0,)) as remote:
        assert remote.call('act', np.ones(3)).tolist() == [3.0, 3.0, 3.0]
        assert remote.call('act', np.zeros((2, 3))).shape == (2, 3)  # it kept its state
    out, err = capfd.readouterr()
    assert 'a print of the user' not in out and 'a print of the user' in err  # stdout: reports
    with pytest.raises(JobFailed) as caught:
        Remote(f'{path}:Broken', '--controller')
    assert 'making one raised SystemExit: 2 (at kinds.py:' in one_line(str(caught.value))
    assert gone(marked)


def test_a_module_that_ends_its_worker_on_import_is_one_line(tmp_path, marked):
    path = tmp_path / 'leaves.py'
    path.write_text('import os\nos._exit(5)\n')
    with pytest.raises(JobFailed) as caught:
        Remote(f'{path}:X', '--tracker')
    assert one_line(str(caught.value)) == (f'the worker for --tracker {path}:X exited with '
                                           'status 5: os._exit(5) (at leaves.py:2)')
    assert gone(marked)


def test_a_tracker_whose_end_hangs_is_stopped_by_the_deadline(tmp_path, marked):
    """Its __del__ is user code too: the scorer lets go of a tracker under the deadline."""
    from ball_world.tools.score_bench import check_tracker
    path = tmp_path / 'kinds.py'
    path.write_text(KINDS)
    with pytest.raises(JobFailed) as caught:
        with LocalPool(1, 2.0, 'the test deadline of 2 s') as pool:
            list(pool.map_unordered(check_tracker, [f'{path}:EndsHanging'], ['a check']))
    line = len(KINDS.split('class EndsHanging')[0].splitlines()) + 7  # its sleep
    assert one_line(str(caught.value)) == ('a check: user code ran past the test deadline of '
                                           f'2 s (at kinds.py:{line}); its worker was stopped')
    assert gone(marked)


# Through ball_world_score ----------------------------------------------------------------------

def score_command(tracker, jobs, *extra):
    from ball_world_testing.harness import executable
    return [executable('ball_world_score'), '--seeds', '0:2', '--duration', '0.2', '--jobs',
            str(jobs), '--tracker', tracker, *extra]


@pytest.mark.parametrize('name, jobs, expected', [
    ('Crashes', 2, 'ball_world_score: the worker for seed '),
    ('Exits', 1, 'ball_world_score: '),
])
def test_the_scorer_says_how_a_tracker_ended_and_exits_non_zero(
        tmp_path, marked, name, jobs, expected):
    path = tmp_path / 'kinds.py'
    path.write_text(KINDS.replace('def act(self, observation)', 'def update(self, scan, pose)'))
    done = subprocess.run(score_command(f'{path}:{name}', jobs), capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 1 and done.stdout == '', done
    assert one_line(done.stderr.rstrip('\n')) and expected in done.stderr, done.stderr
    assert ('killed by SIGSEGV (at kinds.py:' if name == 'Crashes' else
            'raised SystemExit: 0 (at kinds.py:') in done.stderr
    assert gone(marked)


@pytest.mark.parametrize('sent, code, line', [
    (signal.SIGINT, 130, 'interrupted'),  # a terminal's Ctrl-C, to the process group
    (signal.SIGTERM, 143, 'terminated'),  # timeout(1), CI cancelling a job: to the tool
])
def test_a_ctrl_c_or_sigterm_stops_the_scorer_and_its_workers(tmp_path, marked, sent, code,
                                                              line):
    path = tmp_path / 'kinds.py'
    path.write_text(KINDS.replace('def act(self, observation)', 'def update(self, scan, pose)'))
    temporary = tmp_path / 'tmp'
    temporary.mkdir()
    process = subprocess.Popen(
        score_command(f'{path}:Hangs', 2, '--timeout', '600'), stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, start_new_session=True,
        env={**os.environ, 'TMPDIR': str(temporary)},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        end = time.monotonic() + 240.0  # until both workers run the tracker's update
        while len(marked_processes(marked)) < 3 and time.monotonic() < end:
            time.sleep(0.2)  # the tool and its two workers
        time.sleep(1.0)
        (os.killpg if sent == signal.SIGINT else os.kill)(process.pid, sent)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == code and err == f'ball_world_score: {line}\n', err
    assert out == '' and gone(marked)
    assert os.listdir(temporary) == []  # the workers' notes removed


if __name__ == '__main__':
    sys.exit(pytest.main([__file__]))


def test_a_pool_removes_the_notes_of_processes_that_are_gone(tmp_path, monkeypatch):
    # A Ray worker's pool lives as long as its process, which Ray kills: its notes folder
    # is removed by the next pool made on the machine, never a living process's.
    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
    child = subprocess.Popen(['true'])
    child.wait()  # ended and reaped: no process has this pid now
    dead = tmp_path / f'{workers.NOTES_PREFIX}{child.pid}_x'
    living = tmp_path / f'{workers.NOTES_PREFIX}{os.getpid()}_y'
    other = tmp_path / f'{workers.NOTES_PREFIX}of_someone'  # no pid: left alone
    for folder in (dead, living, other):
        folder.mkdir()
        (folder / 'worker_0.txt').write_text('notes')
    with LocalPool(1) as pool:
        made = Path(pool._notes)
        assert made.parent == tmp_path
        assert made.name.startswith(f'{workers.NOTES_PREFIX}{os.getpid()}_')
        assert not dead.exists() and living.exists() and other.exists()
    assert not made.exists()
