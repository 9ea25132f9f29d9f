"""No writer follows a symlink or writes outside the folder it was given (issue 26, finding 2).

A symlink planted where a writer writes (its output, a bag directory's files, a temporary
file of the old metadata.yaml writer, a part of a split .rrd, the bag directory itself) must
leave what it points to untouched, and the writer must refuse with one line and a non-zero
exit, whether or not it was told to overwrite: the node (record.mcap, record.rerun, split or
not), ball_world_repair (a file, a bag directory, in place or not), ball_world_to_rrd (one
file or parts), and recording.files.write_file (the benchmarks' reports, exports).
"""
import os

from ball_world_testing.harness import finish, run_tool
import pytest

from ball_world.recording.files import FileRefused, Folder, plain_name, write_file
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.split_writer import SplitMcapSink
from ball_world.simulation import Simulation
from ball_world.tools import repair, to_rrd

EXIT_TIMEOUT = 120.0
PARAMS = {'rate_hz': 20.0, 'random.count': 5, 'random.seed': 1}
SECRET = b'a file of the user that no ball_world writer may touch'


@pytest.fixture
def victim(tmp_path):
    """A file outside the folders the writers are given; checked untouched at the end."""
    outside = tmp_path / 'elsewhere'
    outside.mkdir()
    path = outside / 'precious.txt'
    path.write_bytes(SECRET)
    before = path.stat()
    yield path
    after = path.stat()
    assert path.read_bytes() == SECRET
    assert (after.st_mtime_ns, after.st_size, after.st_ino) == (
        before.st_mtime_ns, before.st_size, before.st_ino)
    assert sorted(p.name for p in outside.iterdir()) == ['precious.txt']


def recorded(path, steps=5):
    simulation = Simulation(PARAMS, sinks=[McapSink(path)])
    for _ in range(steps):
        simulation.step()
    simulation.close()
    return path


def bag(directory, steps=50):
    """A split recording: files of 1 s at 20 Hz, the last one shorter."""
    simulation = Simulation(PARAMS, sinks=[SplitMcapSink(directory, max_seconds=1.0)])
    for _ in range(steps):
        simulation.step()
    simulation.close()
    return directory


def one_line(code, err):
    lines = [line for line in err.splitlines() if line.strip()]
    assert code != 0 and len(lines) == 1 and 'Traceback' not in err, (code, err)
    return lines[0]


# The node ----------------------------------------------------------------------------------

def test_the_node_never_records_through_a_planted_symlink(tmp_path, victim, processes):
    """Every path the node records to, told to overwrite: refused, started all at once."""
    single, rrd = tmp_path / 'run.mcap', tmp_path / 'run.rrd'
    single.symlink_to(victim)
    rrd.symlink_to(victim)
    reused = bag(tmp_path / 'reused')
    (reused / 'metadata.yaml').unlink()
    (reused / 'metadata.yaml').symlink_to(victim)
    legacy = bag(tmp_path / 'legacy')
    (legacy / 'metadata.yaml.tmp').symlink_to(victim)  # the old writer's temporary file
    linked_bag = tmp_path / 'linked'
    linked_bag.symlink_to(victim.parent)
    parts = tmp_path / 'parts.rrd'
    (tmp_path / 'parts_0.rrd').symlink_to(victim)
    cases = {
        'record.mcap': ([f'record.mcap:={single}'], f'{single}: is a symbolic link'),
        'record.rerun': ([f'record.rerun:={rrd}'], f'{rrd}: is a symbolic link'),
        'metadata.yaml': ([f'record.mcap:={reused}', 'record.max_seconds:=1.0'],
                          f'{reused}: holds metadata.yaml, a symbolic link'),
        'metadata.yaml.tmp': ([f'record.mcap:={legacy}', 'record.max_seconds:=1.0'],
                              f'{legacy}: holds metadata.yaml.tmp, a symbolic link'),
        'bag directory': ([f'record.mcap:={linked_bag}', 'record.max_seconds:=1.0'],
                          f'{linked_bag}: is a symbolic link'),
        '.rrd part': ([f'record.rerun:={parts}', 'record.max_seconds:=1.0'],
                      f'{tmp_path / "parts_0.rrd"}: is a symbolic link'),
    }
    runs = {name: processes.start_node('max_steps:=3', 'rate_hz:=0.0', 'dt:=0.01',
                                       'record.overwrite:=true', *parameters,
                                       ros_args=['-r', f'__ns:=/safety{k}'])
            for k, (name, (parameters, _)) in enumerate(cases.items())}
    for name, run in runs.items():
        code, _, err = finish(run, EXIT_TIMEOUT)
        line = one_line(code, err)
        assert code == 2 and cases[name][1] in line, (name, line)
        assert 'ball_world never writes through one' in line, (name, line)
    assert (legacy / 'metadata.yaml.tmp').is_symlink() and linked_bag.is_symlink()


# The tools ---------------------------------------------------------------------------------

def test_repair_of_a_bag_with_a_planted_symlink_is_refused(tmp_path, victim):
    for index, name in enumerate(('metadata.yaml', 'metadata.yaml.tmp',
                                  '.metadata.yaml.reserve', 'run_9.mcap')):
        (tmp_path / f'bag{index}').mkdir()
        directory = bag(tmp_path / f'bag{index}' / 'run')
        if (directory / name).exists():
            (directory / name).unlink()
        (directory / name).symlink_to(victim)
        before = sorted((p.name, p.stat(follow_symlinks=False).st_mtime_ns)
                        for p in directory.iterdir())
        code, out, err = run_tool('ball_world_repair', str(directory))
        assert one_line(code, err) == (
            f'ball_world_repair: {directory}: holds {name}, a symbolic link where the '
            "recorder's own files go; ball_world never writes through one: remove it")
        assert out == ''
        assert sorted((p.name, p.stat(follow_symlinks=False).st_mtime_ns)
                      for p in directory.iterdir()) == before
    linked = tmp_path / 'linked'
    linked.symlink_to(bag(tmp_path / 'real'))
    code, _, err = run_tool('ball_world_repair', str(linked))
    assert 'is a symbolic link' in one_line(code, err)


def test_repair_and_to_rrd_refuse_a_symlinked_output(tmp_path, victim, capsys):
    source = recorded(tmp_path / 'run.mcap')
    (tmp_path / 'run.repaired.mcap').symlink_to(victim)
    (tmp_path / 'in.mcap').symlink_to(source)
    for argv in ([str(source)], [str(source), '--force'],
                 [str(tmp_path / 'in.mcap'), '-o', str(tmp_path / 'in.mcap')]):
        code = repair.main(argv)
        assert 'is a symbolic link' in one_line(code, capsys.readouterr().err), argv
    (tmp_path / 'run.rrd').symlink_to(victim)
    for argv in ([str(source)], [str(source), '--force']):
        assert to_rrd.main(argv) == 2
        assert 'is a symbolic link' in one_line(2, capsys.readouterr().err)
    directory = bag(tmp_path / 'set')
    assert repair.main([str(directory)]) == 0  # its last file had no summary
    capsys.readouterr()
    (tmp_path / 'parts_1.rrd').symlink_to(victim)
    assert to_rrd.main([str(directory), '--split', '-o', str(tmp_path / 'parts.rrd')]) == 2
    line = one_line(2, capsys.readouterr().err)
    assert line.startswith(f'ball_world_to_rrd: error: {tmp_path / "parts_1.rrd"}: is a '
                           'symbolic link'), line
    assert not (tmp_path / 'parts_0.rrd').exists()  # all parts or none


def test_write_file_replaces_a_name_never_what_a_link_points_to(tmp_path, victim):
    report = tmp_path / 'bench.md'
    report.symlink_to(victim)
    for overwrite in (False, True):
        with pytest.raises(FileRefused, match='is a symbolic link'):
            write_file(report, 'table', overwrite=overwrite)
    (tmp_path / 'other.md').write_text('old')
    os.link(tmp_path / 'other.md', tmp_path / 'hard.md')
    write_file(tmp_path / 'other.md', 'new', overwrite=True)  # a new file under the name
    assert (tmp_path / 'other.md').read_text() == 'new'
    assert (tmp_path / 'hard.md').read_text() == 'old'  # the other name keeps the old one
    with pytest.raises(FileRefused, match='already exists; pass --force'):
        write_file(tmp_path / 'other.md', 'newer', hint='pass --force')
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        'bench.md', 'elsewhere', 'hard.md', 'other.md']  # no temporary file left


@pytest.mark.parametrize('name', ['', '.', '..', '../escape.txt', 'sub/file.txt', 'nul\0'])
def test_a_name_that_would_leave_its_folder_is_refused(tmp_path, name):
    with pytest.raises(FileRefused, match='is not a plain file name'):
        plain_name(name)
    with Folder(tmp_path) as folder:
        with pytest.raises(FileRefused, match='is not a plain file name'):
            folder.claim(name)
        with pytest.raises(FileRefused, match='is not a plain file name'):
            folder.write_atomically(name, b'data')
    assert list(tmp_path.iterdir()) == [] and not (tmp_path.parent / 'escape.txt').exists()


def test_max_files_removes_its_own_file_never_where_a_planted_link_points(tmp_path, victim):
    """A split file swapped for a symlink while the run goes on: its removal (the oldest
    beyond max_files) removes the link, never what it points to."""
    directory = tmp_path / 'kept'
    said = []
    sink = SplitMcapSink(directory, max_seconds=1.0, max_files=2, report=said.append)
    simulation = Simulation(PARAMS, sinks=[sink])
    for _ in range(25):
        simulation.step()  # kept_0 finished at step 20
    (directory / 'kept_0.mcap').unlink()
    (directory / 'kept_0.mcap').symlink_to(victim)
    for _ in range(40):
        simulation.step()
    simulation.close()
    assert not (directory / 'kept_0.mcap').exists() and not os.path.islink(
        directory / 'kept_0.mcap')
    assert said[0] == f'record.max_files 2: removed the oldest split file {directory}/kept_0.mcap'
