"""The split .rrd (recording.rrd_parts): parts that each open on their own, and the tools.

A run is recorded through RrdParts as the node records it (a writer process, with its
spare), split by simulated time on its own or following a split MCAP; each part must verify,
hold the walls, the balls' looks, the scale and a blueprint of its own, begin at the step its
MCAP file begins at, and the parts together must hold every step once. ball_world_repair
mends a part left without footer in place, ball_world_info lists the parts, and
ball_world_to_rrd --split writes one part per MCAP file the same way.
"""
import shutil
import time

from ball_world_testing.harness import open_rrd, rrd_ball_steps, run_rerun
import pytest

from ball_world.recording import rerun_process
from ball_world.recording.recording_set import open_recording
from ball_world.recording.rrd_parts import part_names, RrdParts
from ball_world.recording.split_writer import SplitMcapSink, SplitRule
from ball_world.simulation import Simulation
from ball_world.tools import info, repair, to_rrd

PARAMS = {'rate_hz': 20.0, 'random.count': 12, 'random.seed': 2}


def run(sinks, steps=70):
    simulation = Simulation(PARAMS, sinks=sinks)
    for k in range(1, steps + 1):
        if k % 9 == 0:
            simulation.queue_impulse('ball_2', 0.1, 0.05)
        simulation.step()
        if k % 10 == 0:
            simulation.flush()
    simulation.close()


def entities(path):
    """{entity path: component names} of an .rrd's recording, static data included."""
    reader = open_rrd(path)
    (store,) = reader.recordings()
    found = {}
    for chunk in reader.stream(store=store):
        names = {name for name in chunk.to_record_batch().schema.names if ':' in name}
        found.setdefault(chunk.entity_path, set()).update(names)
    return found, len(reader.blueprints())


@pytest.fixture(scope='module')
def followed(tmp_path_factory):
    """A split MCAP (1 s files) with .rrd parts following it, max_files 3 of each."""
    folder = tmp_path_factory.mktemp('parts')
    said = []
    mcap = SplitMcapSink(folder / 'run', max_seconds=1.0, max_files=3, report=said.append)
    mcap.follower = RrdParts(folder / 'run.rrd', None, max_files=3, report=said.append)
    run([mcap])
    return folder, said


def test_parts_follow_the_mcap_files_each_complete_and_on_its_own(followed):
    folder, said = followed
    recording = open_recording(folder / 'run')
    names = [name for _, name in part_names(folder / 'run.rrd')]
    assert names == ['run_1.rrd', 'run_2.rrd', 'run_3.rrd']  # run_0: the oldest, removed
    assert said.count(f'record.max_files 3: removed the oldest .rrd part {folder}/run_0.rrd') \
        == 1
    mcap_steps = [[s.step for s in f.steps() if s.complete] for f in recording.files]
    for name, steps in zip(names, mcap_steps):
        assert run_rerun('rrd', 'verify', folder / name).returncode == 0, name
        assert rrd_ball_steps(folder / name) == [steps], name  # the same steps, every one
        found, blueprints = entities(folder / name)
        assert blueprints == 1, name
        assert {'Points2D:positions', 'Points2D:radii', 'Points2D:colors'} <= found[
            '/arena/balls'], name
        assert 'LineStrips2D:strips' in found['/arena/walls'], name
        assert 'Transform3D:rotation_axis_angle' in found['/arena'], name
        assert '/arena/scale' in found and '/arena/labels' in found, name


def test_parts_alone_split_by_their_own_rule(tmp_path):
    parts = RrdParts(tmp_path / 'alone.rrd', SplitRule(max_seconds=1.0), file_process=False)
    run([parts], steps=45)
    names = [name for _, name in part_names(tmp_path / 'alone.rrd')]
    assert names == ['alone_0.rrd', 'alone_1.rrd', 'alone_2.rrd']
    assert [rrd_ball_steps(tmp_path / name) for name in names] == [
        [list(range(0, 20))], [list(range(20, 40))], [list(range(40, 46))]]


def test_existing_parts_are_refused_unless_overwrite(tmp_path):
    (tmp_path / 'run_0.rrd').write_bytes(b'an earlier run')
    with pytest.raises(OSError) as refused:
        RrdParts(tmp_path / 'run.rrd', SplitRule(max_seconds=1.0), file_process=False)
    assert str(refused.value) == (f'{tmp_path}/run.rrd: has parts already (run_0.rrd, ...); '
                                  'set record.overwrite:=true to replace them')
    assert (tmp_path / 'run_0.rrd').read_bytes() == b'an earlier run'


def test_repair_mends_a_part_without_footer_and_leaves_a_lookalike(followed, tmp_path, capsys):
    folder, _ = followed
    for name in ('run_1.rrd', 'run_2.rrd', 'run_3.rrd'):
        shutil.copy(folder / name, tmp_path / name)
    data = (tmp_path / 'run_3.rrd').read_bytes()
    (tmp_path / 'run_3.rrd').write_bytes(data[:len(data) * 2 // 3])  # killed: no footer
    shutil.copy(tmp_path / 'run_1.rrd', tmp_path / 'run_003.rrd')
    assert info.main([str(tmp_path / 'run.rrd')]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'parts:       3 parts of {tmp_path}/run.rrd (run_<i>.rrd')
    assert '  run_3.rrd: ' in out and ', FAILS: rerun rrd verify' in out
    assert '  left out: run_003.rrd: not a name the recorder gives a part' in out
    assert repair.main([str(tmp_path / 'run.rrd')]) == 0
    out = capsys.readouterr().out
    assert f'{tmp_path}/run_1.rrd: verifies' in out
    assert f'{tmp_path}/run_003.rrd: left alone' in out
    assert out.strip().endswith('3 parts of ' + str(tmp_path / 'run.rrd') + ': 3 verify')
    assert run_rerun('rrd', 'verify', tmp_path / 'run_3.rrd').returncode == 0
    [steps] = rrd_ball_steps(tmp_path / 'run_3.rrd')
    assert steps and steps[0] == 60


def test_to_rrd_split_writes_a_part_per_mcap_file_like_the_node(followed, tmp_path, capsys):
    folder, _ = followed
    assert to_rrd.main([str(folder / 'run'), '--split', '-o', str(tmp_path / 'out.rrd')]) == 0
    capsys.readouterr()
    for number in (1, 2, 3):
        converted = tmp_path / f'out_{number}.rrd'
        assert run_rerun('rrd', 'verify', converted).returncode == 0
        assert rrd_ball_steps(converted) == rrd_ball_steps(folder / f'run_{number}.rrd')
        (made, made_blueprints), (logged, blueprints) = (
            entities(converted), entities(folder / f'run_{number}.rrd'))
        assert made.keys() == logged.keys() and made_blueprints == blueprints == 1
        assert made['/arena/balls'] == logged['/arena/balls']


def test_a_writer_hands_its_parts_over_to_a_spare_and_exits(tmp_path, monkeypatch):
    """Each file the SDK writes leaves threads and memory behind in its process: a writer
    that has written long enough (here: at once) gives the next part to its spare, which was
    started beforehand, finishes its own part and exits. No part is lost or cut."""
    monkeypatch.setattr(rerun_process, 'WRITER_SECONDS', 0.0)
    parts = RrdParts(tmp_path / 'run.rrd', SplitRule(max_seconds=1.0))
    simulation = Simulation(PARAMS, sinks=[parts])
    stream = parts.sink._feeds[0].outlet.stream
    writers = set()
    for k in range(1, 81):
        simulation.step()
        if k % 10 == 0:  # each part's second flush: its spare ready by then (the node: 1 s)
            deadline = time.monotonic() + 120.0
            simulation.flush()
            while k % 20 == 10 and not getattr(stream._spare, 'ready', False) \
                    and time.monotonic() < deadline:
                time.sleep(0.2)
                simulation.flush()
        writers.add(stream.pid)
    simulation.close()
    assert len(writers) >= 2
    names = [name for _, name in part_names(tmp_path / 'run.rrd')]
    assert names == [f'run_{i}.rrd' for i in range(5)]  # the last holds step 80 alone
    steps = []
    for name in names:
        assert run_rerun('rrd', 'verify', tmp_path / name).returncode == 0, name
        [held] = rrd_ball_steps(tmp_path / name)
        steps += held
    assert steps == list(range(81))
    assert not rerun_process_children()  # the writers and the spare have all exited


def rerun_process_children():
    """This process's live rerun_process writers. A zombie (an ended child not yet reaped,
    here or by an earlier test of the same pytest process, as in `colcon test`) has no
    command line to read: psutil raises for it, so its status is asked first, and a child
    that ends between the two questions has ended."""
    import psutil
    found = []
    for child in psutil.Process().children(recursive=True):
        try:
            if (child.status() != psutil.STATUS_ZOMBIE
                    and 'rerun_process' in ' '.join(child.cmdline())):
                found.append(child)
        except (psutil.NoSuchProcess, psutil.ZombieProcess):
            continue
    return found
