"""Recordings are never destroyed by accident, and never hang on a file that is not one.

The rules live in recording.files; each is checked there with its siblings (a file, a
symlink to one, a dangling symlink, a hard link, a relative path; a FIFO, a directory, a
device), then where users meet them: the node's record.* parameters (a subprocess, as users
start it) and the tools' outputs (--force).
"""
import os
from pathlib import Path
import subprocess
import sys
import time

from ball_world_testing.harness import DEADLINE, finish, kill, start_node
import pytest

from ball_world.recording.files import (claim_output, ClaimedSink, FileRefused,
                                        PartialOutput, remove_stale_partials)
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation
from ball_world.tools import repair, to_rrd

#: Generous: two noisy cores; a test fails only on a hang.
EXIT_TIMEOUT = 120.0
PARAMS = {'rate_hz': 20.0, 'random.count': 5, 'random.seed': 1}
OLD = b'an earlier recording that must survive'


def recorded(path, steps=5):
    simulation = Simulation(PARAMS, sinks=[McapSink(path)])
    for _ in range(steps):
        simulation.step()
    simulation.close()
    return path


# The rules -------------------------------------------------------------------------------

def test_existing_files_are_refused_unless_overwrite_and_symlinks_always(tmp_path):
    old = tmp_path / 'old.mcap'
    old.write_bytes(OLD)
    with pytest.raises(FileRefused) as raised:
        claim_output(old, hint='set record.overwrite:=true')
    assert str(raised.value) == \
        f'{old}: already exists; set record.overwrite:=true to replace it'
    to_old = tmp_path / 'link.mcap'
    to_old.symlink_to(old)
    dangling = tmp_path / 'dangling.mcap'
    dangling.symlink_to(tmp_path / 'nowhere.mcap')
    for path in (to_old, dangling):
        for overwrite in (False, True):  # told to overwrite, still never through a link
            with pytest.raises(FileRefused) as raised:
                claim_output(path, overwrite=overwrite, hint='set record.overwrite:=true')
            assert str(raised.value).startswith(f'{path}: is a symbolic link (to ')
            assert 'ball_world never writes through one' in str(raised.value)
    assert old.read_bytes() == OLD and not (tmp_path / 'nowhere.mcap').exists()
    assert to_old.is_symlink() and dangling.is_symlink()
    claim = claim_output(old, overwrite=True)  # told to: the file itself, truncated
    claim.release()
    assert old.read_bytes() == b''


def test_a_file_with_other_names_is_never_truncated(tmp_path):
    old = tmp_path / 'old.mcap'
    old.write_bytes(OLD)
    os.link(old, tmp_path / 'backup.mcap')
    with pytest.raises(FileRefused) as raised:
        claim_output(old, overwrite=True)
    assert str(raised.value) == (f'{old}: has 2 names (hard links); overwriting it would '
                                 'change the others too')
    assert (tmp_path / 'backup.mcap').read_bytes() == OLD


def test_non_regular_files_are_refused_at_once_even_with_overwrite(tmp_path):
    fifo = tmp_path / 'fifo.mcap'
    os.mkfifo(fifo)
    kinds = {fifo: 'a FIFO', tmp_path: 'a directory', Path('/dev/null'): 'a character device'}
    # with a reader on the FIFO, opening it for writing would succeed; without one, block
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    for reader_open in (True, False):
        for overwrite in (False, True):
            for path, kind in kinds.items():
                with pytest.raises(FileRefused) as raised:
                    claim_output(path, overwrite=overwrite)
                assert str(raised.value) == f'{path}: is {kind}, not a regular file'
        if reader_open:
            os.close(reader)
    assert Path('/dev/null').is_char_device() and fifo.is_fifo()


def test_one_file_cannot_be_claimed_twice_by_any_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    first = claim_output(tmp_path / 'run.mcap')
    (tmp_path / 'alias.mcap').symlink_to(tmp_path / 'run.mcap')
    os.link(tmp_path / 'run.mcap', tmp_path / 'hard.mcap')
    for name in ('run.mcap', './sub/../run.mcap', 'alias.mcap', 'hard.mcap'):
        if name.startswith('./sub'):
            (tmp_path / 'sub').mkdir(exist_ok=True)
        with pytest.raises(FileRefused, match='is the same file as record.mcap'):
            claim_output(name, overwrite=True, others=[('record.mcap', first)])
    first.release()


def test_a_file_being_recorded_is_locked_and_never_truncated_by_a_second_claim(tmp_path):
    path = recorded(tmp_path / 'run.mcap')
    size = path.stat().st_size
    claim = claim_output(path, overwrite=True)
    claim.writer().write(OLD)
    claim.writer().flush()
    # another process, told to overwrite, is refused and leaves the content alone
    other = subprocess.run(
        [sys.executable, '-c', 'import sys; from ball_world.recording.files import '
         'claim_output; claim_output(sys.argv[1], overwrite=True)', str(path)],
        capture_output=True, text=True, timeout=DEADLINE)
    assert other.returncode == 1
    assert 'is being recorded by another process (it is locked)' in other.stderr
    assert path.read_bytes() == OLD
    claim.release()
    claim_output(path, overwrite=True).release()  # free again once released
    assert size > len(OLD)


def test_a_recording_closed_before_any_segment_leaves_no_file(tmp_path):
    McapSink(tmp_path / 'never.mcap').close()
    assert not (tmp_path / 'never.mcap').exists()
    claim = claim_output(tmp_path / 'never.rrd')
    sink = ClaimedSink(McapSink(tmp_path / 'other.mcap'), claim)
    sink.close()
    assert not (tmp_path / 'never.rrd').exists() and not (tmp_path / 'other.mcap').exists()
    assert Recording(recorded(tmp_path / 'kept.mcap')).has_summary


# The node ----------------------------------------------------------------------------------

def refusal(*parameters):
    """The one stderr line of a node that must refuse to start (exit code 2)."""
    code, out, err = finish(start_node('max_steps:=3', 'rate_hz:=0.0', 'dt:=0.01',
                                       *parameters), EXIT_TIMEOUT)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert 'Traceback' not in out + err
    return lines[0]


def test_node_refuses_existing_recordings_unless_record_overwrite(tmp_path):
    mcap, rrd = tmp_path / 'run.mcap', tmp_path / 'run.rrd'
    mcap.write_bytes(OLD)
    rrd.symlink_to(mcap)
    assert refusal(f'record.mcap:={mcap}') == (
        f"ball_world: parameter 'record.mcap': cannot record to {mcap}: already exists; set "
        'record.overwrite:=true to replace it')
    assert refusal(f'record.rerun:={rrd}') == (
        f"ball_world: parameter 'record.rerun': cannot record to {rrd}: is a symbolic link "
        f'(to {mcap}); ball_world never writes through one: name the file itself or remove '
        'the link')
    # told to overwrite, the link is still refused and what it points to left as it was
    assert refusal(f'record.rerun:={rrd}', 'record.overwrite:=true').startswith(
        f"ball_world: parameter 'record.rerun': cannot record to {rrd}: is a symbolic link")
    assert mcap.read_bytes() == OLD
    code, _, err = finish(start_node('max_steps:=3', 'rate_hz:=0.0', 'dt:=0.01',
                                     f'record.mcap:={mcap}', 'record.overwrite:=true'),
                          EXIT_TIMEOUT)
    assert code == 0, err
    assert [s.step for s in Recording(mcap).steps()] == [0, 1, 2, 3]


def test_node_refuses_one_file_for_both_recordings(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = refusal('record.mcap:=run.mcap', f'record.rerun:={tmp_path}/run.mcap',
                   'record.overwrite:=true')
    assert line == (f"ball_world: parameter 'record.rerun': cannot record to "
                    f'{tmp_path}/run.mcap: is the same file as record.mcap')
    assert not (tmp_path / 'run.mcap').exists()  # nothing recorded, nothing left


def test_node_refuses_a_fifo_and_a_file_another_node_records(tmp_path, processes):
    fifo = tmp_path / 'fifo.mcap'
    os.mkfifo(fifo)
    assert refusal(f'record.mcap:={fifo}', 'record.overwrite:=true').endswith(
        f'{fifo}: is a FIFO, not a regular file')
    path = tmp_path / 'shared.mcap'
    first = processes.start_node('rate_hz:=20.0', f'record.mcap:={path}')
    deadline = time.monotonic() + EXIT_TIMEOUT
    while not (path.exists() and path.stat().st_size > 0):
        assert first.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    assert refusal(f'record.mcap:={path}', 'record.overwrite:=true').endswith(
        f'{path}: is being recorded by another process (it is locked)')
    first.terminate()
    code, _, err = finish(first, EXIT_TIMEOUT)
    assert code == 0, err
    steps = [s.step for s in Recording(path).steps()]
    assert steps == list(range(len(steps))) and Recording(path).has_summary


def test_a_start_that_fails_on_its_parameters_leaves_no_recording(tmp_path):
    mcap, rrd = tmp_path / 'run.mcap', tmp_path / 'run.rrd'
    line = refusal(f'record.mcap:={mcap}', f'record.rerun:={rrd}', 'random.radius:=[0.5]')
    assert "parameter 'random.radius'" in line
    assert list(tmp_path.iterdir()) == []  # so the corrected command is not refused


# The tools ---------------------------------------------------------------------------------

def test_to_rrd_never_replaces_an_existing_rrd_without_force(tmp_path, capsys):
    mcap = recorded(tmp_path / 'run.mcap')
    rrd = tmp_path / 'run.rrd'
    rrd.write_bytes(OLD)
    assert to_rrd.main([str(mcap)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f'ball_world_to_rrd: error: {rrd}: already exists; pass --force to '
                   'replace it')
    assert rrd.read_bytes() == OLD
    assert to_rrd.main([str(mcap), '--force']) == 0
    assert rrd.read_bytes().startswith(b'RRF2')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['run.mcap', 'run.rrd']


def test_repair_refuses_an_existing_output_and_cleans_up_after_a_killed_run(
        tmp_path, capsys, processes):
    source = recorded(tmp_path / 'run.mcap')
    target = tmp_path / 'run.repaired.mcap'
    target.write_bytes(OLD)
    assert repair.main([str(source)]) == 2
    assert capsys.readouterr().err.strip() == (
        f'ball_world_repair: {target}: already exists; pass --force to replace it')
    assert target.read_bytes() == OLD
    # partials of killed repairs: a dead pid's is removed, a live process's (locked) is kept
    dead = subprocess.run([sys.executable, '-c', 'import os; print(os.getpid())'],
                          capture_output=True, text=True, check=True).stdout.strip()
    (tmp_path / f'run.repaired.mcap.partial-{dead}').write_bytes(b'left by a SIGKILL')
    holder = processes.start(
        [sys.executable, '-c', 'import sys, time; from ball_world.recording.files import '
         'claim_output; c = claim_output(sys.argv[1]); print(flush=True); time.sleep(60)',
         f'{target}.partial-{os.getpid() + 100000}'], stderr=None)
    holder.stdout.readline()
    assert repair.main([str(source), '--force']) == 0
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ['run.mcap', 'run.repaired.mcap',
                    f'run.repaired.mcap.partial-{os.getpid() + 100000}']
    kill(holder)
    assert Recording(target).has_summary
    assert remove_stale_partials(str(target)) == \
        [f'{target}.partial-{os.getpid() + 100000}']


def test_partial_output_is_moved_into_place_only_when_complete(tmp_path):
    target = tmp_path / 'out.mcap'
    output = PartialOutput(target, hint='pass --force')
    output.claim.writer().write(b'complete')
    target.write_bytes(OLD)  # appeared meanwhile: not replaced without overwrite
    with pytest.raises(FileRefused, match='already exists; pass --force'):
        output.commit()
    assert target.read_bytes() == OLD and sorted(tmp_path.iterdir()) == [target]
    output = PartialOutput(target, overwrite=True)
    output.discard()
    assert target.read_bytes() == OLD and sorted(tmp_path.iterdir()) == [target]
