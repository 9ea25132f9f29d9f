"""ball_world_repair on a Rerun .rrd that a SIGKILL cut short: a real node recording .rrd is
killed with its .rrd writer (a process of its own, recording.rerun_process), as a power cut
does; the repaired copy must verify, and hold every step Rerun's reader
finds in the killed file, from step 0 on without a gap. The node killed alone leaves its
writer to finish the file."""
import os
from pathlib import Path
import shutil
import signal
import time

from ball_world_testing.harness import (Children, DEADLINE, rrd_ball_steps, run_rerun,
                                        run_tool)
import pytest

from ball_world.recording.rerun_process import GATHER_SECONDS

#: Enough bytes that several 1 s flushes (several batches of steps) are in the file.
KILL_AFTER_BYTES = 60_000
#: And enough time that the writer has sent the balls' gathered columns (one chunk per entity
#: every GATHER_SECONDS of its wall time) at least twice: a torn last message then cannot be
#: the only chunk holding them, however fast other entities filled the bytes above.
KILL_AFTER_SECONDS = 2.5 * GATHER_SECONDS


@pytest.fixture(scope='module')
def killed(tmp_path_factory):
    """An .rrd whose node and writer were SIGKILLed together while it recorded."""
    return killed_run(tmp_path_factory.mktemp('killed') / 'run.rrd', with_writer=True)


def child_pids(pid):
    """The processes that `pid` started (its .rrd writer), from /proc."""
    found = []
    for task in Path(f'/proc/{pid}/task').iterdir():
        found += [int(child) for child in (task / 'children').read_text().split()]
    return found


def killed_run(path, with_writer):
    """Record .rrd with a node; SIGKILL it (and first its writer, if with_writer) once the
    file holds several flushes; the path."""
    with Children() as children:
        node = children.start_node('record.rerun:=' + str(path), 'rate_hz:=200.0',
                                   'markers.rate_hz:=0.0')
        deadline = time.monotonic() + DEADLINE
        appeared = None  # when the writer created the file
        while True:
            assert node.poll() is None, node.communicate()
            assert time.monotonic() < deadline, 'the node wrote too little to its .rrd'
            if path.exists():
                appeared = appeared or time.monotonic()
                if (path.stat().st_size >= KILL_AFTER_BYTES
                        and time.monotonic() - appeared >= KILL_AFTER_SECONDS):
                    break
            time.sleep(0.1)
        writers = child_pids(node.pid)
        assert len(writers) == 1, writers
        for pid in (writers if with_writer else []) + [node.pid]:
            os.kill(pid, signal.SIGKILL)
        node.communicate(timeout=DEADLINE)  # its stderr ends when its writer has ended too
    return path


def repaired_steps(source, target):
    """Repair `source` into `target`; the steps of the balls in the (verified) copy."""
    code, out, err = run_tool('ball_world_repair', str(source), '-o', str(target))
    assert code == 0, err
    assert out.startswith(f'{source}: {source.stat().st_size} bytes, rerun rrd verify: ')
    assert out.endswith(f'the copy verifies ({target.stat().st_size} bytes)\nwrote {target}\n')
    assert run_rerun('rrd', 'verify', target).returncode == 0
    [steps] = rrd_ball_steps(target)
    assert steps == list(range(len(steps))) and len(steps) > 1  # from step 0, no gap
    assert f'  recording 0: kept steps 0-{steps[-1]} of the balls\n' in out
    return steps


def test_a_sigkilled_rrd_is_made_complete_with_every_step_it_held(killed, tmp_path):
    broken = run_rerun('rrd', 'verify', killed)
    assert broken.returncode != 0 and 'Missing RRD footer' in broken.stderr  # what repair is for
    steps = repaired_steps(killed, tmp_path / 'run.repaired.rrd')
    try:
        [held] = rrd_ball_steps(killed)
    except RuntimeError as error:
        # Killed inside a message: the reader refuses the torn tail (the next test cuts one
        # on purpose); what it would read is then what the repair kept.
        assert 'exceeds file size' in str(error)
    else:
        assert steps == held
        # Rerun's own comparison: the same data in both (the copy only adds the footer).
        compared = run_rerun('rrd', 'compare', killed, tmp_path / 'run.repaired.rrd')
        assert compared.returncode == 0, compared.stderr


def test_a_torn_last_message_is_dropped_and_the_rest_kept(killed, tmp_path):
    whole = repaired_steps(killed, tmp_path / 'whole.rrd')
    torn = tmp_path / 'torn.rrd'
    shutil.copy(killed, torn)
    with open(torn, 'r+b') as stream:
        stream.truncate(killed.stat().st_size - 100)  # inside the last message
    steps = repaired_steps(torn, tmp_path / 'torn.repaired.rrd')
    assert steps == whole[:len(steps)]


def test_what_is_not_a_ball_world_rrd_is_one_line_and_writes_nothing(tmp_path):
    junk = tmp_path / 'junk.rrd'
    junk.write_bytes(bytes(range(256)) * 20)
    code, out, err = run_tool('ball_world_repair', str(junk))
    assert (code, out) == (2, '')
    assert err == (f"ball_world_repair: {junk}: no recording of 'ball_world' in it: not a "
                   'ball_world .rrd\n')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['junk.rrd']


def test_the_node_killed_alone_leaves_its_writer_to_finish_the_file(tmp_path):
    """The writer reads the end of its input and closes the file, footer included: nothing
    to repair, every step the node sent in it from step 0 on."""
    path = killed_run(tmp_path / 'run.rrd', with_writer=False)
    verified = run_rerun('rrd', 'verify', path)
    assert verified.returncode == 0, verified.stderr
    [steps] = rrd_ball_steps(path)
    assert steps == list(range(len(steps))) and len(steps) > 1
