"""Damage repair cannot undo is reported, never called success; repair never makes a set worse
(issue 26, finding 4).

A split set (files of 20 steps, chunks of a few steps) is damaged the ways disks and users
damage one: a chunk of a finished file corrupted under a valid summary, a middle file lost
or cut short, a stray copy beside the files. ball_world_repair must find the damage, keep
every readable record, name what is lost and exit 1 (0 only when nothing but a killed
writer's torn end was lost), and leave a stray alone; ball_world_resim must re-simulate what
can be, name the steps it could not check and exit 3; ball_world_to_rrd must convert what
there is.
"""
import shutil

from mcap.reader import make_reader
import pytest
import yaml

from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.split_writer import SplitMcapSink
from ball_world.simulation import Simulation
from ball_world.tools import info, repair, resim, to_rrd

PARAMS = {'rate_hz': 20.0, 'random.count': 24, 'random.seed': 3}


def run(sinks, steps=60):
    simulation = Simulation(PARAMS, sinks=sinks)
    for k in range(1, steps + 1):
        if k % 7 == 0:
            simulation.queue_impulse(f'ball_{k % 5}', 0.05, -0.03)
        simulation.step()
        if k % 3 == 0:
            simulation.flush()  # chunks of about three steps
    simulation.close()


@pytest.fixture(scope='module')
def pristine(tmp_path_factory):
    """run_0 (steps 0-19), run_1 (20-39), run_2 (40-59), run_3 (60), every file finished."""
    directory = tmp_path_factory.mktemp('sets') / 'run'
    run([SplitMcapSink(directory, max_seconds=1.0)])
    return directory


@pytest.fixture
def bag(pristine, tmp_path):
    directory = tmp_path / 'run'
    shutil.copytree(pristine, directory)
    return directory


def listed(directory):
    document = yaml.safe_load((directory / 'metadata.yaml').read_text())
    return document['rosbag2_bagfile_information']['relative_file_paths']


def corrupt_a_chunk(path, which=3):
    """Flip bytes in the middle of the `which`-th chunk's data; its log-time span (s)."""
    with open(path, 'rb') as stream:
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes,
                        key=lambda index: index.chunk_start_offset)
    chunk = chunks[which]
    data = bytearray(path.read_bytes())
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle:middle + 8] = bytes(b ^ 0x5A for b in data[middle:middle + 8])
    path.write_bytes(bytes(data))
    return chunk.message_start_time / 1e9, chunk.message_end_time / 1e9


def steps_of(path):
    return [step.step for step in Recording(path).steps() if step.complete]


def test_a_corrupt_chunk_under_a_valid_summary_is_found_mended_and_called_a_loss(bag, capsys):
    start, end = corrupt_a_chunk(bag / 'run_1.mcap')
    # as it is, the tools that read the chunk stop there and say how to mend it
    assert resim.main([str(bag)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f'ball_world_resim: {bag}: the record at byte ') and err.endswith(
        '(ball_world_repair keeps every other record)') and '\n' not in err, err
    assert repair.main([str(bag)]) == 1
    out = capsys.readouterr()
    assert f'log time {start:.9g} s to {end:.9g} s, lost: the record at byte ' in out.out
    assert 'NOT ALL DATA COULD BE KEPT' in out.out
    assert 'some recorded data could not be kept' in out.err
    kept = steps_of(bag / 'run_1.mcap')
    lost = sorted(set(range(20, 40)) - set(kept))
    assert lost and kept[0] == 20 and kept[-1] == 39  # the chunks after it are kept
    assert listed(bag) == ['run_0.mcap', 'run_1.mcap', 'run_2.mcap', 'run_3.mcap']
    # resim checks what can be: up to the hole, then from the next file's state on
    assert resim.main([str(bag)]) == 3
    out = capsys.readouterr().out
    assert f'segment 0: {lost[0]} steps compared (last step {lost[0] - 1})' in out
    assert (f'NOT CHECKED: segment 0 jumps from step {lost[0] - 1} to step {lost[-1] + 1}: '
            'the steps between are not recorded') in out
    assert f'steps {lost[-1] + 1}-39 NOT CHECKED: no state to go on from' in out
    assert ('segment 0: 21 steps compared (last step 60), 3 impulses: identical (picked up at '
            'step 40 from the state a split file resumes from)') in out
    assert to_rrd.main([str(bag), '-o', str(bag.parent / 'run.rrd')]) == 0
    err = capsys.readouterr().err
    assert f'warning: segment 0: steps {lost[-1] + 1}-39 not converted' in err


def test_a_single_file_keeps_the_chunks_after_a_corrupt_one_and_says_what_is_lost(tmp_path,
                                                                                  capsys):
    path = tmp_path / 'one.mcap'
    run([McapSink(path, chunk_bytes=1 << 30)], steps=30)
    corrupt_a_chunk(path, which=4)
    assert repair.main([str(path)]) == 1
    assert '  DAMAGED: bytes ' in capsys.readouterr().out
    steps = steps_of(tmp_path / 'one.repaired.mcap')
    assert steps[0] == 0 and steps[-1] == 30 and len(steps) < 31


def test_a_lost_middle_file_is_reported_by_repair_and_resim_checks_the_rest(bag, capsys):
    (bag / 'run_1.mcap').unlink()
    assert repair.main([str(bag)]) == 1
    out = capsys.readouterr().out
    assert ('run_1.mcap: listed in metadata.yaml but gone; its steps are lost (a gap in the '
            'set)') in out
    assert listed(bag) == ['run_0.mcap', 'run_2.mcap', 'run_3.mcap']
    assert resim.main([str(bag)]) == 3
    out = capsys.readouterr().out
    assert ('segment 0: steps 20-39 NOT CHECKED: run_0.mcap ends at step 19; run_2.mcap '
            'resumes later') in out
    assert 'segment 0: 21 steps compared (last step 60)' in out


def test_a_middle_file_cut_short_is_a_loss_not_a_killed_writer(bag, capsys):
    path = bag / 'run_1.mcap'
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    assert resim.main([str(bag)]) == 3  # before repair too
    out = capsys.readouterr().out
    kept = steps_of(path)
    assert (f'segment 0: steps {kept[-1] + 1}-39 NOT CHECKED: run_1.mcap ends at step '
            f'{kept[-1]}; run_2.mcap resumes later') in out
    assert repair.main([str(bag)]) == 1
    out = capsys.readouterr().out
    assert ('DAMAGED: run_1.mcap was finished by its recorder (it is listed in metadata.yaml); '
            'its end is gone, lost') in out
    assert Recording(path).has_summary and steps_of(path) == kept


@pytest.mark.parametrize('stray, why', [
    ('run_000.mcap', 'not a name the recorder writes'),
    ('run_7.mcap', 'its log times begin at 0 s, not after the set before it (3 s): not part '
                   'of this run'),
])
def test_a_stray_copy_is_left_alone_and_the_set_stays_one_run(bag, capsys, stray, why):
    shutil.copy(bag / 'run_0.mcap', bag / stray)
    copy = (bag / stray).read_bytes()
    before = listed(bag)
    assert resim.main([str(bag)]) == 0
    capsys.readouterr()
    assert repair.main([str(bag)]) == 0
    out = capsys.readouterr().out
    assert f'{stray}: left alone, {why}' in out
    assert listed(bag) == before and (bag / stray).read_bytes() == copy
    assert resim.main([str(bag)]) == 0  # still one run, after repair too
    assert 'all 61 recorded steps re-simulate bit-identically' in capsys.readouterr().out
    assert info.main([str(bag)]) == 0
    out = capsys.readouterr().out
    assert f'  left out: {stray}: {why}' in out and 'NOT LISTED' not in out
