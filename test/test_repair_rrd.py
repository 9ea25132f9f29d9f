"""ball_world_repair on a Rerun .rrd that a SIGKILL cut short: a real node process recording
.rrd is killed; the repaired copy must verify, and hold every step Rerun's reader finds in the
killed file, from step 0 on without a gap."""
import shutil
import signal
import time

from ball_world_testing.harness import (Children, DEADLINE, rrd_ball_steps, run_rerun,
                                        run_tool)
import pytest

#: Enough bytes that several 1 s flushes (several batches of steps) are in the file.
KILL_AFTER_BYTES = 60_000


@pytest.fixture(scope='module')
def killed(tmp_path_factory):
    """An .rrd whose node was SIGKILLed while it recorded."""
    path = tmp_path_factory.mktemp('killed') / 'run.rrd'
    with Children() as children:
        node = children.start_node('record.rerun:=' + str(path), 'rate_hz:=200.0',
                                   'markers.rate_hz:=0.0')
        deadline = time.monotonic() + DEADLINE
        while not path.exists() or path.stat().st_size < KILL_AFTER_BYTES:
            assert node.poll() is None, node.communicate()
            assert time.monotonic() < deadline, 'the node wrote too little to its .rrd'
            time.sleep(0.1)
        node.send_signal(signal.SIGKILL)
        node.wait(timeout=DEADLINE)
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
