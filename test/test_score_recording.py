"""ball_world_score on a real recording: an agent scanning a gas of balls, recorded to MCAP
by the node's own sink, scored with the example tracker and with tracks a "user" recorded
(an oracle that publishes every ball's true position: every figure must be 1), through the
command line's main() as a user runs it, with every input it takes made bad in turn."""
import io
import json
import os

from mcap_ros2.writer import Writer as Ros2Writer
import numpy as np
import pytest

from ball_world.core.edits import Ball
from ball_world.msgs.definitions import message_definition
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import score, score_recording

PARAMETERS = {'rate_hz': 60.0, 'random.count': 20, 'random.seed': 3, 'agents': ['ball_0'],
              'physics.backend': 'numpy'}
ONES = ('HOTA', 'DetA', 'AssA', 'LocA', 'IDF1', 'IDP', 'IDR', 'MOTA', 'MOTP')
MARKERS = 'visualization_msgs/msg/MarkerArray'
POSES = 'geometry_msgs/msg/PoseArray'


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """Six simulated seconds: ball_0 drives a circle; a second agent spawned as `xball_0`
    (whose /tf frame ends like ball_0's) turns the other way."""
    path = tmp_path_factory.mktemp('score') / 'run.mcap'
    simulation = Simulation(PARAMETERS, sinks=[McapSink(path)])
    other = Ball(9.5, 0.5, 0.0, 0.0, 0.15, 0.1)
    results, _ = simulation.spawn([SpawnRequest('xball_0', False, other, agent=True)])
    assert results == ['xball_0']
    for _ in range(6 * 60):
        simulation.command('ball_0', 0.5, 0.0, 0.4)
        simulation.command('xball_0', 0.0, 0.0, -1.0)
        simulation.step()
    simulation.close()
    return path


@pytest.fixture(scope='module')
def run(recording):
    segments = score_recording.read_run(recording, 'ball_0')
    assert len(segments) == 1
    return segments[0]


def run_main(capsys, *argv):
    code = score.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_tracks(path, run, kind=MARKERS, offset_ns=0, frame='world', shuffle=False,
                 topic='/my/tracks', count=None):
    """An MCAP of every ball's true position at each scan (an oracle tracker), stamped
    with the scan's stamp plus offset_ns, in `frame` (world or ball_0/base_link)."""
    rng = np.random.default_rng(0)
    with open(path, 'wb') as stream:
        writer = Ros2Writer(stream)
        schema = writer.register_msgdef(kind, message_definition(kind))
        for scan in run.scans[:count]:
            stamp = scan.stamp_ns + offset_ns
            header = {'stamp': {'sec': stamp // 10**9, 'nanosec': stamp % 10**9},
                      'frame_id': frame}
            xy = scan.positions
            if frame != 'world':  # into the scanner's frame
                x, y, yaw = scan.pose
                c, s = np.cos(yaw), np.sin(yaw)
                d = xy - (x, y)
                xy = np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))
            order = rng.permutation(len(xy)) if shuffle else range(len(xy))
            poses = [{'position': {'x': float(xy[i, 0]), 'y': float(xy[i, 1]), 'z': 0.0},
                      'orientation': {'w': 1.0}} for i in order]
            if kind == POSES:
                message = {'header': header, 'poses': poses}
            else:
                message = {'markers': [{'header': header, 'action': 3}] + [
                    {'header': header, 'ns': 'oracle', 'id': 500 + i, 'action': 0,
                     'pose': pose} for i, pose in zip(order, poses)]}
            writer.write_message(topic, schema, message, stamp, stamp)
        writer.finish()
    return path


def test_the_example_tracker_scores_and_reports_as_text_and_json(recording, capsys):
    code, out, err = run_main(capsys, recording, '--json')
    assert code == 0 and err == ''
    report = json.loads(out)
    figures = report['figures']
    assert report['scans'] == 61 and report['tracks']['kind'] == 'tracks'  # 10 Hz, and step 0
    assert figures['HOTA'] > 0.5 and figures['MOTA'] > 0.7 and figures['IDF1'] > 0.5, figures
    assert figures['mean_distance_m'] < 0.06
    code, out, _ = run_main(capsys, recording)
    assert code == 0
    assert f"HOTA {figures['HOTA']:.4f}" in out and f"MOTA {figures['MOTA']:.4f}" in out


def test_an_oracle_scores_one_on_every_metric(recording, run, tmp_path, capsys):
    tracks = write_tracks(tmp_path / 'oracle.mcap', run)
    code, out, err = run_main(capsys, recording, '--tracks', tracks, '/my/tracks', '--json')
    assert code == 0, err
    report = json.loads(out)
    for name in ONES:
        assert report['figures'][name] == 1.0, name
    assert report['figures']['IDSW'] == 0 and report['figures']['CLR_FN'] == 0
    # Every hidden ball (the agent's own too) was published: all don't-care, none an FP.
    assert report['dont_care'] == report['truth']['hidden'] > 0
    assert report['stamps']['unpaired'] == 0 and report['stamps']['note'] is None


def test_tracks_in_the_scanners_frame_go_through_the_recorded_tf(recording, run, tmp_path,
                                                                 capsys):
    tracks = write_tracks(tmp_path / 'local.mcap', run, frame='ball_0/base_link')
    code, out, err = run_main(capsys, recording, '--tracks', tracks, '/my/tracks', '--json')
    assert code == 0, err
    figures = json.loads(out)['figures']
    for name in ONES:
        assert figures[name] == pytest.approx(1.0, abs=1e-9), name


def test_late_stamps_are_reported_not_scored_and_a_tolerance_pairs_them(recording, run,
                                                                        tmp_path, capsys):
    tracks = write_tracks(tmp_path / 'late.mcap', run, offset_ns=1_000_000)
    code, out, err = run_main(capsys, recording, '--tracks', tracks, '/my/tracks')
    assert code == 1 and out == ''
    assert err.count('\n') == 1 and 'no track message pairs with a scan' in err
    assert '61 of 61 track messages' in err and '1.000 ms after the nearest scan' in err
    code, out, err = run_main(capsys, recording, '--tracks', tracks, '/my/tracks',
                              '--stamp-tolerance', '0.002', '--json')
    assert code == 0 and err == ''
    assert json.loads(out)['figures']['HOTA'] == 1.0


def test_some_late_stamps_are_scored_with_a_warning(recording, run, tmp_path, capsys):
    path = tmp_path / 'mixed.mcap'
    write_tracks(path, run, count=30)
    # Append the other scans 1 ms late: a second file is simpler than splicing one.
    late = write_tracks(tmp_path / 'late_part.mcap', run, offset_ns=1_000_000)
    os.makedirs(tmp_path / 'bag')
    os.replace(path, tmp_path / 'bag' / 'a.mcap')
    os.replace(late, tmp_path / 'bag' / 'b.mcap')
    (tmp_path / 'bag' / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  relative_file_paths: [a.mcap, b.mcap]\n')
    code, out, err = run_main(capsys, recording, '--tracks', tmp_path / 'bag', '/my/tracks')
    assert code == 0, err
    assert 'warning: 61 of 91 track messages match no scan stamp exactly' in out
    assert '31 of 61 scans had no track message' in out


def test_a_pose_array_has_no_ids_and_is_scored_as_detections(recording, run, tmp_path,
                                                             capsys):
    tracks = write_tracks(tmp_path / 'poses.mcap', run, kind=POSES, shuffle=True)
    code, out, err = run_main(capsys, recording, '--tracks', tracks, '/my/tracks')
    assert code == 0, err
    assert 'has no track ids: scored as detections' in out
    assert 'DetA 1.0000' in out and 'MODA 1.0000' in out and 'IDF1 ' not in out
    code, out, _ = run_main(capsys, recording, '--tracks', tracks, '/my/tracks', '--json')
    figures = json.loads(out)['figures']
    assert figures['Precision'] == figures['Recall'] == 1.0 and 'IDSW' not in figures


def test_the_scans_pose_is_the_agents_own_frame_not_one_that_ends_like_it(run, recording):
    # xball_0 turns the other way: a yaw read from it would differ from ball_0's odometry.
    from ball_world.msgs.agent_cdr import decode_odometry
    from ball_world.recording.mcap_reader import Recording
    from ball_world.scoring.planar_tf import yaw_of
    odometry = {m.log_time_ns: decode_odometry(m.data)
                for m in Recording(recording).messages(['/ball_0/odom'])}
    for scan in run.scans:
        pose = odometry[scan.stamp_ns].pose
        assert scan.pose == (pose[0], pose[1], yaw_of(*pose[3:7]))
    other = score_recording.read_run(recording, 'xball_0')[0]
    assert [s.pose[2] for s in other.scans] != [s.pose[2] for s in run.scans]


@pytest.mark.parametrize('damage', ['not_mcap', 'empty', 'truncated', 'fifo', 'missing'])
def test_a_bad_tracks_file_is_one_line(recording, run, tmp_path, capsys, damage):
    path = tmp_path / 'tracks.mcap'
    if damage == 'not_mcap':
        path.write_text('hello\n')
    elif damage == 'empty':
        path.write_bytes(b'')
    elif damage == 'truncated':
        data = write_tracks(tmp_path / 'whole.mcap', run).read_bytes()
        path.write_bytes(data[:len(data) // 2])
    elif damage == 'fifo':
        os.mkfifo(path)
    code, out, err = run_main(capsys, recording, '--tracks', path, '/my/tracks')
    assert code == 1 and out == ''
    assert err.count('\n') == 1 and err.startswith('ball_world_score: '), err
    assert 'Traceback' not in err
    expected = {'not_mcap': 'not an MCAP file', 'empty': 'is empty', 'truncated': 'cut off',
                'fifo': 'FIFO', 'missing': 'No such file'}[damage]
    assert expected in err, err


def test_a_missing_topic_or_another_type_is_one_line(recording, run, tmp_path, capsys):
    tracks = write_tracks(tmp_path / 'oracle.mcap', run)
    code, _, err = run_main(capsys, recording, '--tracks', tracks, '/other')
    assert code == 1 and err.count('\n') == 1
    assert 'has no topic /other; its topics: /my/tracks' in err
    with open(tmp_path / 'strings.mcap', 'wb') as stream:
        writer = Ros2Writer(stream)
        schema = writer.register_msgdef('std_msgs/msg/String',
                                        message_definition('std_msgs/msg/String'))
        writer.write_message('/my/tracks', schema, {'data': 'x'}, 0, 0)
        writer.finish()
    code, _, err = run_main(capsys, recording, '--tracks', tmp_path / 'strings.mcap',
                            '/my/tracks')
    assert code == 1 and 'is a std_msgs/msg/String; expected a' in err


def test_bad_arguments_and_recordings_are_one_line(recording, tmp_path, capsys):
    code, _, err = run_main(capsys, recording, '--agent', 'ball_7')
    assert code == 1 and err.count('\n') == 1
    assert "no scan of 'ball_7'" in err and 'its scanning agents: ball_0, xball_0' in err
    code, _, err = run_main(capsys, tmp_path / 'nothing.mcap')
    assert code == 1 and err.count('\n') == 1
    (tmp_path / 'text.mcap').write_text('not a recording')
    code, _, err = run_main(capsys, tmp_path / 'text.mcap')
    assert code == 1 and err.count('\n') == 1 and 'not an MCAP file' in err
    for bad in (['--gate', 'nan'], ['--gate', '-1'], ['--stamp-tolerance', '0.1'],
                ['--tracker', 'x:Y'], ['--seeds', '0:2']):
        with pytest.raises(SystemExit) as stop:
            score.main([str(recording), *bad])
        assert stop.value.code == 2
    capsys.readouterr()


def test_the_frames_export_as_csv_and_the_run_as_rerun(recording, run, tmp_path, capsys):
    csv_path, rrd_path = tmp_path / 'frames.csv', tmp_path / 'scored.rrd'
    code, _, err = run_main(capsys, recording, '--csv', csv_path, '--rerun', rrd_path)
    assert code == 0, err
    lines = csv_path.read_text().splitlines()
    assert lines[0] == 'segment,scan,stamp_ns,source,id,x,y,radius,visible,dont_care,matched'
    rows = [line.split(',') for line in lines[1:]]
    truth = [row for row in rows if row[3] == 'truth']
    assert len(truth) == 20 + 60 * 21  # every ball at every scan, xball_0 from step 1 on
    assert sum(int(row[8]) for row in truth) == sum(int(s.visible.sum()) for s in run.scans)
    assert {row[3] for row in rows} == {'truth', 'track'}
    assert rrd_path.read_bytes()[:4] == b'RRF2'
    # An existing file is kept unless --force; a symlink is never written through, nor
    # replaced, even with --force (recording.files: one hardened path for every file).
    code, _, err = run_main(capsys, recording, '--csv', csv_path)
    assert code == 1 and 'already exists; pass --force' in err
    target = tmp_path / 'elsewhere.txt'
    target.write_text('keep')
    link = tmp_path / 'link.csv'
    os.symlink(target, link)
    code, _, err = run_main(capsys, recording, '--csv', link)
    assert code == 1 and 'is a symbolic link' in err and target.read_text() == 'keep'
    code, _, err = run_main(capsys, recording, '--csv', link, '--force')
    assert code == 1 and 'is a symbolic link' in err and len(err.splitlines()) == 1
    assert target.read_text() == 'keep' and link.is_symlink()


def test_per_track_breakdown_sums_to_the_figures(recording, capsys):
    code, out, _ = run_main(capsys, recording, '--per-track', '--json')
    report = json.loads(io.StringIO(out).read())
    assert code == 0
    assert sum(row['switches'] for row in report['per_ball']) == report['figures']['IDSW']
    assert sum(row['false_positives'] for row in report['per_track']) == \
        report['figures']['CLR_FP']
    assert all(row['lifetime_s'] >= 0.0 for row in report['per_track'])
