"""The split limits the node declares are ones it records at; a full disk is said as one
(issue 26, finding 7, the recording part).

record.max_bytes 1 made a file per step and the node fell a third behind its rate, dropping
steps of wall time it never totalled: the declared range now starts at what works
(core.parameters.MIN_SPLIT_BYTES, MIN_SPLIT_SECONDS; 0 still turns splitting off), and at
those edges the node records every step, its .rrd parts beginning at the same steps as the
MCAP files. A recorder stopped by a write error (a full disk, a file size limit) says so in
metadata.yaml, where ball_world_info reads it, instead of looking like a killed recorder.
"""
import errno
import os

from ball_world_testing.harness import finish, rrd_ball_steps, run_rerun, run_tool
import pytest
import yaml

from ball_world.core.parameters import BY_NAME, MIN_SPLIT_BYTES, MIN_SPLIT_SECONDS
from ball_world.recording.bag import RESERVE_FILE
from ball_world.recording.files import Folder
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.recording_set import open_recording
from ball_world.recording.split_writer import SplitMcapSink
from ball_world.simulation import Simulation
from ball_world.tools import info

EXIT_TIMEOUT = 180.0
#: About 60 kB of MCAP a step: 1 MiB splits every 17 steps or so.
LARGE = ('random.count:=2000', 'arena:=[0.0, 0.0, 60.0, 60.0]', 'random.seed:=4')


def metadata(directory):
    return yaml.safe_load((directory / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']


@pytest.mark.parametrize('name, below, least', [
    ('record.max_bytes', 1, MIN_SPLIT_BYTES), ('record.max_bytes', MIN_SPLIT_BYTES - 1, None),
    ('record.max_seconds', 1e-9, MIN_SPLIT_SECONDS), ('record.max_seconds', 0.999, None)])
def test_a_split_below_what_the_recorder_runs_at_is_refused(name, below, least):
    parameter = BY_NAME[name]
    assert parameter.check(0) == 0  # off
    with pytest.raises(ValueError) as refused:
        parameter.check(below)
    assert str(refused.value).startswith(f"parameter '{name}': must be 0 (off), or between ")
    if least is not None:
        assert parameter.check(least) == least


def test_the_node_refuses_a_split_of_one_byte_in_one_line(tmp_path, processes):
    run = processes.start_node(f'record.mcap:={tmp_path / "run"}', 'record.max_bytes:=1')
    code, out, err = finish(run, EXIT_TIMEOUT)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and lines == [
        "ball_world: parameter 'record.max_bytes': must be 0 (off), or between 1,048,576 and "
        '9,223,372,036,854,775,807, got 1'], err
    assert not (tmp_path / 'run').exists()


def node_steps(directory):
    """The steps of a bag directory: each file's first and all, in order."""
    recording = open_recording(directory)
    firsts = [next(s.step for s in f.steps() if s.complete) for f in recording.files]
    return firsts, [s.step for s in recording.steps() if s.complete]


def part_steps(folder, stem):
    """(number, steps) of each .rrd part `<stem>_<n>.rrd`, each verified by Rerun."""
    parts = sorted((int(p.stem.rpartition('_')[2]), p) for p in folder.glob(f'{stem}_*.rrd'))
    found = []
    for number, path in parts:
        verified = run_rerun('rrd', 'verify', path)
        assert verified.returncode == 0, (path, verified.stderr)
        [steps] = rrd_ball_steps(path)
        found.append((number, steps))
    return found


@pytest.mark.parametrize('split, world, steps', [
    (f'record.max_bytes:={MIN_SPLIT_BYTES}', LARGE, 70),
    (f'record.max_seconds:={MIN_SPLIT_SECONDS:g}', ('random.count:=20',), 200)])
def test_at_the_least_split_every_step_is_recorded_and_the_rrd_splits_with_it(
        tmp_path, processes, split, world, steps):
    """The node at 60 Hz, at the least split, to max_steps: every step in the bag, every
    part verifies and opens at the step its MCAP file opens at, max_files kept of each."""
    run = processes.start_node(split, *world, 'markers.rate_hz:=0.0', f'max_steps:={steps}',
                               f'record.mcap:={tmp_path / "run"}',
                               f'record.rerun:={tmp_path / "run.rrd"}', 'record.max_files:=3')
    code, out, err = finish(run, EXIT_TIMEOUT)
    assert code == 0 and 'Traceback' not in err, err
    firsts, recorded = node_steps(tmp_path / 'run')
    names = metadata(tmp_path / 'run')['relative_file_paths']
    assert len(names) == 3 and int(names[-1][4:-5]) >= 3  # the oldest removed
    assert recorded == list(range(recorded[0], steps + 1))  # every step, in order
    parts = part_steps(tmp_path, 'run')
    assert [number for number, _ in parts] == [int(name[4:-5]) for name in names]
    assert [part[0] for _, part in parts] == firsts  # the same steps begin each file
    assert [step for _, part in parts for step in part] == recorded
    code, out, err = run_tool('ball_world_resim', str(tmp_path / 'run'))
    assert code == 0, out + err


def test_a_file_size_limit_is_said_as_such_not_as_a_killed_recorder(tmp_path, processes):
    """RLIMIT_FSIZE: the first file cannot grow past 150 kB (its first chunk of 128 KiB
    is complete); the node goes on and says so, and so do info (from metadata.yaml) and
    repair."""
    bag = tmp_path / 'run'
    run = processes.start_node('max_steps:=400', 'rate_hz:=0.0', 'dt:=0.01',
                               'markers.rate_hz:=0.0', f'record.mcap:={bag}',
                               f'record.max_bytes:={MIN_SPLIT_BYTES}', limit_file_size=150_000)
    code, out, err = finish(run, EXIT_TIMEOUT)
    assert code == 0, err
    assert 'recording to SplitMcapSink stopped: ' in err and 'File too large' in err, err
    assert metadata(bag)['custom_data'] == {
        'ball_world.stopped': 'run_0.mcap could not be written: File too large'}
    code, out, err = run_tool('ball_world_info', str(bag))
    assert code == 2 and err.strip() == (
        f'ball_world_info: {bag}: its recorder stopped before it finished a file: run_0.mcap '
        'could not be written: File too large (the file reached the largest size allowed it: '
        "the process's file size limit, RLIMIT_FSIZE, or the file system's); "
        f'ball_world_repair {bag} keeps their complete records'), err
    code, out, err = run_tool('ball_world_repair', str(bag))
    assert code == 0, out + err
    assert 'metadata.yaml says the recorder stopped: run_0.mcap could not be written' in out
    assert Recording(bag / 'run_0.mcap').has_summary
    code, out, _ = run_tool('ball_world_info', str(bag))
    assert code == 0 and 'run_0.mcap: ' in out


def test_a_full_disk_is_written_into_the_space_set_aside_and_info_says_so(
        tmp_path, monkeypatch, capsys):
    """The disk fills while file 1 is written: no new file can be made, but metadata.yaml
    still says what happened, written into the blocks set aside for it."""
    directory = tmp_path / 'full'
    sink = SplitMcapSink(directory, max_seconds=1.0)
    failures = []
    simulation = Simulation({'rate_hz': 20.0, 'random.count': 8}, sinks=[sink],
                            on_sink_failure=failures.append)
    for _ in range(25):
        simulation.step()  # full_0 finished at step 20
    assert (directory / RESERVE_FILE).stat().st_size >= 64 << 10
    full = os.open('/dev/full', os.O_WRONLY)
    os.dup2(full, sink._sink._file.fileno())  # the disk fills up under the open file
    os.close(full)

    def no_space(self, name, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), name)
    monkeypatch.setattr(Folder, '_write_new', no_space)  # nor for a new file
    for _ in range(20):
        simulation.step()
    simulation.close()
    assert len(failures) == 1 and failures[0].error.errno == errno.ENOSPC
    assert metadata(directory)['relative_file_paths'] == ['full_0.mcap']
    assert metadata(directory)['custom_data'] == {
        'ball_world.stopped': 'full_1.mcap could not be written: No space left on device'}
    assert sorted(p.name for p in directory.iterdir()) == [
        'full_0.mcap', 'full_1.mcap', 'metadata.yaml']  # the reserve became metadata.yaml
    assert info.main([str(directory)]) == 0
    assert ('  STOPPED: the recorder stopped on an error: full_1.mcap could not be written: No '
            'space left on device (the disk filled up)') in capsys.readouterr().out
