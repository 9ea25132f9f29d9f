"""ball_world_score's benchmark over many scenes: repeatable bit for bit whatever the number
of processes, scoring a simulated scene exactly as a recording of it is scored, running any
tracker class, and saying in one line what is wrong with a bad one."""
import json

import pytest

from ball_world.recording.mcap_writer import McapSink
from ball_world.scoring import figures
from ball_world.simulation import Simulation
from ball_world.tools import score, score_bench
from ball_world.tools.score_frames import frames_with_tracker
from ball_world.tools.score_recording import read_run
from ball_world.tools.tracker import ScanTracker

TRACKERS = '''
class Still:
    """Sees nothing."""
    def update(self, scan, pose):
        return []


class Broken:
    def update(self, scan, pose):
        return 1 / 0


class Wrong:
    def update(self, scan, pose):
        return 5
'''


def bench(capsys, *argv):
    code = score.main(['--json', *map(str, argv)])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if code == 0 else None), err


def test_seeds_are_repeatable_bit_for_bit_on_one_or_two_processes(capsys):
    code, two, err = bench(capsys, '--seeds', '1:4', '--duration', '2', '--jobs', '2')
    assert code == 0, err
    assert two['jobs'] == 2 and two['scenes'] == 3
    code, one, _ = bench(capsys, '--seeds', '1:4', '--duration', '2', '--jobs', '1')
    for report in (one, two):
        del report['seconds'], report['jobs']
    assert one == two
    assert [row['scene'] for row in one['per_scene']] == ['seed 1', 'seed 2', 'seed 3']
    hota = one['summary']['HOTA']
    assert 0.4 < hota['mean'] < 1.0 and hota['ci95'] > 0.0 and hota['scenes'] == 3
    assert len(one['worst']) == 3


def test_a_scene_scores_as_its_recording_scores(tmp_path):
    scene = score_bench.seed_scenes([7], 3.0)[0]
    simulated = figures.score_tracks(
        frames_with_tracker(score_bench.simulated_scans(scene), ScanTracker()), 0.5)
    path = tmp_path / 'scene.mcap'
    simulation = Simulation(scene.parameters, sinks=[McapSink(path)])
    for _ in range(scene.steps):
        simulation.command(scene.agent, *scene.command)
        simulation.step()
    simulation.close()
    segment, = read_run(path, scene.agent)
    recorded = figures.score_tracks(frames_with_tracker(segment.scans, ScanTracker()), 0.5)
    assert simulated.figures() == recorded.figures()


def test_a_tracker_class_from_a_file_runs_and_a_bad_one_is_one_line(tmp_path, capsys):
    module = tmp_path / 'my_trackers.py'
    module.write_text(TRACKERS)
    code, report, err = bench(capsys, '--seeds', '2', '--duration', '1', '--jobs', '1',
                              '--tracker', f'{module}:Still')
    assert code == 0, err
    assert report['summary']['MOTA']['mean'] == 0.0
    assert report['summary']['CLR_FP']['mean'] == 0.0 and report['tracker'].endswith(':Still')
    for spec, expected in ((f'{module}:Broken', 'ZeroDivisionError: division by zero (at '
                                                'my_trackers.py:'),
                           (f'{module}:Wrong', 'not rows (id, x, y, ...)'),
                           (f'{module}:Missing', 'has no class Missing'),
                           ('no_such_module:X', "No module named 'no_such_module'")):
        code, _, err = bench(capsys, '--seeds', '1', '--duration', '1', '--jobs', '1',
                             '--tracker', spec)
        assert code == 1 and err.count('\n') == 1 and expected in err, err


def test_worlds_from_a_file_and_its_mistakes(tmp_path, capsys):
    worlds = tmp_path / 'worlds.yaml'
    worlds.write_text('duration: 1\nworlds:\n  - name: few\n    seeds: 0:2\n'
                      '    parameters: {random.count: 8}\n'
                      '  - name: many\n    parameters: {random.count: 30}\n')
    code, report, err = bench(capsys, '--worlds', worlds, '--jobs', '1')
    assert code == 0, err
    assert [row['scene'] for row in report['per_scene']] == ['few seed 0', 'few seed 1',
                                                             'many']
    for text, expected in (('worlds: []\n', 'non-empty list `worlds`'),
                           ('worlds:\n  - parameters: {random.cont: 3}\n',
                            "'random.cont': no such parameter"),
                           ('worlds: [{}]\nspeed: 3\n', "unknown key 'speed'"),
                           ('worlds: [{}\n', 'worlds.yaml'),
                           # Each message states the input as written and the real rule.
                           ('duration: 1e308\nworlds: [{}]\n',
                            'duration is 1e308; it must be in (0, 3600] s'),
                           ('duration: 1.0e400\nworlds: [{}]\n',
                            'duration is 1.0e400, beyond the largest float'),
                           ('duration: .nan\nworlds: [{}]\n', 'duration is .nan; it must be a '
                                                              'number, not nan'),
                           ('x: &a 3\nduration: *a\nworlds: [{}]\n',
                            'YAML aliases (*name) are not accepted in a --worlds file (line 2)'),
                           ('agent: 3\nworlds: [{}]\n', 'agent is 3; it must be an entity '
                                                        'name'),
                           ('cmd_vel: [1, 2]\nworlds: [{}]\n',
                            'cmd_vel is [1, 2]; it must be [vx, vy, wz]'),
                           ('worlds: [{nme: x}]\n', "world 0: unknown key 'nme'"),
                           ('worlds: 3\n', 'got `worlds: 3`'),
                           ('duration: yes\nworlds: [{}]\n', "duration is 'yes'; it must be a "
                                                             'number')):
        worlds.write_text(text)
        code, _, err = bench(capsys, '--worlds', worlds, '--jobs', '1')
        assert code == 1 and err.count('\n') == 1 and expected in err, err


def test_worlds_files_read_numbers_as_yaml_1_2_does(tmp_path, capsys):
    """YAML 1.1 (PyYAML's) reads `seeds: 5:7` as 307 (base 60) and 1e308 as text."""
    from ball_world.tools.score_bench import world_scenes
    worlds = tmp_path / 'worlds.yaml'
    worlds.write_text('duration: 2e-1\ncmd_vel: [1e-1, 0, 017]\n'
                      'worlds: [{name: w, seeds: 5:7}]\n')
    scenes = world_scenes(str(worlds), None)
    assert [scene.label for scene in scenes] == ['w seed 5', 'w seed 6']
    assert tuple(scenes[0].command) == (0.1, 0.0, 17.0) and scenes[0].steps == 12


@pytest.mark.parametrize('argv', [
    ['--seeds', '3:1'], ['--seeds', 'x'], ['--seeds', '0:2', '--jobs', '0'],
    ['--seeds', '0:2', '--duration', 'inf'], ['--seeds', '0:2', '--worlds', 'w.yaml'],
    ['--seeds', '0:2', '--csv', 'x.csv']])
def test_bad_benchmark_arguments_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        score.main(argv)
    assert stop.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith('ball_world_score: error: ')


@pytest.mark.parametrize('argv, expected', [
    (['--duration', '1e400'], '--duration is 1e400; it must be in (0, 3600] s'),
    (['--duration', 'x'], "--duration: expected a number, got 'x'"),
    (['--timeout', '0'], '--timeout is 0; it must be in (0, 86400] s'),
    (['--worst', '-1'], '--worst is -1; it must be in [0, 100000]'),
    (['--jobs', '0'], '--jobs is 0; it must be in [1, 1024]'),
    (['--seeds', '0:99999999999999999999'], 'expected 0 <= A < B <= 2**63, got'),
])
def test_argument_messages_state_the_input_and_the_rule(argv, expected, capsys):
    with pytest.raises(SystemExit):
        score.main(['--seeds', '2', *argv])
    assert expected in capsys.readouterr().err.splitlines()[-1]


def test_scenes_recorded_with_a_tracker_node_score_as_a_benchmark(tmp_path, capsys):
    from ball_world_testing.harness import executable, run_tool
    out_dir = tmp_path / 'scenes'
    code, out, err = run_tool('ball_world_score_scenes', '--seeds', '4:5', '--out', out_dir,
                              '--tracks-topic', '/ball_0/tracks', '--duration', '2', '--',
                              executable('ball_world_tracker'), '--ros-args',
                              '-p', 'agent:=ball_0')
    assert code == 0, err
    assert 'seed 4:' in out and (out_dir / 'seed_4' / 'tracks.mcap').is_file()
    code, report, err = bench(capsys, '--scenes', out_dir, '--jobs', '1')
    assert code == 0, err
    # Each scene scores as its two files do (a live tracker on a loaded machine may skip
    # scans, so the figures themselves vary from run to run); every message the example
    # node published carried its scan's stamp.
    assert report['scenes'] == 1 and report['stamp_notes'] == []
    assert report['pooled']['CLR_TP'] > 0
    scene = out_dir / 'seed_4'
    code, single, err = bench(capsys, scene / 'world.mcap', '--tracks', scene / 'tracks.mcap',
                              '/ball_0/tracks')
    assert code == 0, err
    assert single['figures'] == report['pooled']
    # The same seeds again into the same directory: refused, nothing overwritten.
    code, _, err = run_tool('ball_world_score_scenes', '--seeds', '4:5', '--out', out_dir,
                            '--tracks-topic', '/ball_0/tracks', '--', 'true')
    assert code == 1 and 'already holds seed_4' in err


def test_a_tracker_that_repeats_an_id_is_one_line(tmp_path, capsys):
    module = tmp_path / 'twice.py'
    module.write_text('class Twice:\n    def update(self, scan, pose):\n'
                      '        return [(1, 0.0, 0.0), (1, 1.0, 1.0)]\n')
    code, _, err = bench(capsys, '--seeds', '1', '--duration', '0.5', '--jobs', '1',
                         '--tracker', f'{module}:Twice')
    assert code == 1 and err.count('\n') == 1 and 'track id 1 appears twice' in err


def test_the_score_modules_import_each_other_without_a_circle():
    """Lazy imports included: a circle only delayed is still a circle."""
    import ast
    from pathlib import Path
    root = Path(score.__file__).resolve().parents[2]
    paths = [*root.glob('ball_world/tools/score*.py'), *root.glob('ball_world/scoring/*.py'),
             *root.glob('ball_world/user_code/*.py'), root / 'ball_world/tools/tracker.py']
    modules = {'.'.join(p.relative_to(root).with_suffix('').parts): p for p in paths}
    graph = {}
    for name, path in modules.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                found |= {node.module, *(f'{node.module}.{a.name}' for a in node.names)}
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names}
        graph[name] = found & set(modules) - {name}
    assert 'ball_world.tools.score_one' in graph['ball_world.tools.score']
    done, trail = set(), []

    def visit(name):
        assert name not in trail, ' -> '.join(trail[trail.index(name):] + [name])
        if name not in done:
            trail.append(name)
            for other in sorted(graph[name]):
                visit(other)
            trail.pop()
            done.add(name)

    for name in sorted(graph):
        visit(name)


def test_a_scenes_directory_description_is_checked_in_one_line(tmp_path, capsys):
    for text, expected in (('agent: ball_0\n', 'tracks_topic is None; it must be a topic name'),
                           ('tracks_topic: 5\n', 'tracks_topic is 5;'),
                           ('t: &a x\ntracks_topic: *a\n',
                            'YAML aliases (*name) are not accepted in scenes.yaml of a scenes '
                            'directory')):
        (tmp_path / 'scenes.yaml').write_text(text)
        code, _, err = bench(capsys, '--scenes', tmp_path, '--jobs', '1')
        assert code == 1 and err.count('\n') == 1 and expected in err, err
