"""Split recordings (issue 23): a bag directory of MCAP files read as one run by every reader.

Runs are driven through Simulation with a SplitMcapSink next to a Truth sink (every record
kept in memory): the ground truth the files must hold bit for bit. Each file must also stand
alone (complete, indexed, re-simulable from its first step), metadata.yaml must say what the
files hold (checked against mcap's own reader), and the `rosbags` library must take the
directory as one rosbag2 recording.
"""
import base64
import errno
import json
import os
from pathlib import Path
import signal
import struct
import sys
import textwrap
import time

from ball_world_testing.harness import (DEADLINE, finish, rewrite_recording, ROSBAGS_TYPES,
                                        rrd_ball_steps, start_node, Truth)
from geometry_msgs.msg import PoseArray
from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.rosbag2.errors import ReaderError
import yaml

from ball_world.core.edits import Ball
from ball_world.recording.bag import claim_directory
from ball_world.recording.files import FileRefused
from ball_world.recording.recording_set import open_recording, RecordingSet
from ball_world.recording.split_writer import SplitMcapSink
from ball_world.recording.writer_thread import BackgroundSink
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.tools import info, repair, resim, to_rrd

ROOT = Path(__file__).resolve().parents[1]
RATE = 20.0
DT_NS = 50_000_000
PARAMS = {'rate_hz': RATE, 'random.count': 24, 'random.seed': 3}
SECOND = {'rate_hz': RATE, 'random.count': 16, 'random.seed': 9, 'arena': [0.0, 0.0, 6.0, 5.0]}


def bits_equal(a, b):
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    return a.shape == b.shape and bool((a.view(np.uint64) == b.view(np.uint64)).all())


def run(simulation, steps):
    """Steps with an impulse every 7th step, and world edits at fixed steps of segment 0."""
    for _ in range(steps):
        k = simulation.step_index + 1
        if k % 7 == 0:
            simulation.queue_impulse(f'ball_{k % 5}', 0.05, -0.03)
        if simulation.segment == 0 and k == 23:
            simulation.delete('ball_4')
        if simulation.segment == 0 and k == 31:
            # a generated name in a later file: a lone file must give the same one
            [name], _ = simulation.spawn([SpawnRequest('', True, Ball(
                x=0.3, y=0.3, vx=0.1, vy=0.0, radius=0.05, mass=0.2))])
            assert name == 'ball_24'
        simulation.step()


def record(directory, steps=70, reset_steps=25, **limits):
    """A split recording with impulses, edits and a reset; returns (Truth, removal lines)."""
    truth = Truth()
    said = []
    sink = SplitMcapSink(directory, report=said.append, **limits)
    simulation = Simulation(PARAMS, sinks=[sink, truth])
    run(simulation, steps)
    simulation.reset(SECOND)
    run(simulation, reset_steps)
    simulation.close()
    return truth, said


def metadata(directory):
    return yaml.safe_load((directory / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']


def summary(path):
    with open(path, 'rb') as stream:
        return make_reader(stream).get_summary()


@pytest.fixture(scope='module')
def by_time(tmp_path_factory):
    directory = tmp_path_factory.mktemp('split') / 'run.mcap'
    truth, _ = record(directory, max_seconds=1.0)
    return directory, truth


def test_files_each_span_at_most_max_seconds_and_are_complete_mcaps(by_time):
    directory, truth = by_time
    names = metadata(directory)['relative_file_paths']
    total_ns = truth.records[-1].log_time_ns - truth.records[0].log_time_ns
    assert names == [f'run_{i}.mcap' for i in range(len(names))]
    assert sorted(p.name for p in directory.iterdir()) == sorted(names + ['metadata.yaml'])
    # a file rolls at the first step 1 s after its first: 20 steps each, then the rest
    assert len(names) == total_ns // 1_000_000_000 + 1
    spans = []
    for name in names:
        stats = summary(directory / name).statistics  # indexed: mcap finds its summary
        spans.append(stats.message_end_time - stats.message_start_time)
    assert spans[:-1] == [1_000_000_000 - DT_NS] * (len(names) - 1)
    assert spans[-1] < 1_000_000_000


def test_metadata_yaml_matches_the_files(by_time):
    directory, _ = by_time
    meta = metadata(directory)
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    per_topic = {}
    starts, ends = [], []
    for entry in meta['files']:
        stats = summary(directory / entry['path']).statistics
        assert entry['message_count'] == stats.message_count
        assert entry['starting_time']['nanoseconds_since_epoch'] == stats.message_start_time
        assert entry['duration']['nanoseconds'] == (stats.message_end_time
                                                    - stats.message_start_time)
        starts.append(stats.message_start_time)
        ends.append(stats.message_end_time)
        channels = summary(directory / entry['path']).channels
        for channel_id, count in stats.channel_message_counts.items():
            topic = channels[channel_id].topic
            per_topic[topic] = per_topic.get(topic, 0) + count
    assert meta['relative_file_paths'] == [entry['path'] for entry in meta['files']]
    assert meta['message_count'] == sum(per_topic.values())
    assert meta['starting_time']['nanoseconds_since_epoch'] == min(starts)
    assert meta['duration']['nanoseconds'] == max(ends) - min(starts)
    listed = {entry['topic_metadata']['name']: entry for entry in
              meta['topics_with_message_count']}
    assert {topic: entry['message_count'] for topic, entry in listed.items()} == per_topic
    balls = listed['/balls']['topic_metadata']
    assert balls['type'] == 'geometry_msgs/msg/PoseArray'
    assert balls['serialization_format'] == 'cdr'
    assert balls['type_description_hash'].startswith('RIHS01_')
    assert balls['offered_qos_profiles'][0]['depth'] == 10


def test_rosbags_reads_the_directory_as_the_one_run(by_time):
    directory, truth = by_time
    with RosbagsReader(directory) as reader:
        assert reader.message_count == metadata(directory)['message_count']
        poses = [ROSBAGS_TYPES.deserialize_cdr(data, connection.msgtype)
                 for connection, _, data in reader.messages()
                 if connection.topic == '/balls']
    assert len(poses) == len(truth.records)
    for message, rec in zip(poses, truth.records):
        assert bits_equal([[p.position.x, p.position.y] for p in message.poses],
                          rec.positions)


def test_the_set_reads_back_every_record_in_order(by_time):
    directory, truth = by_time
    recording = open_recording(directory)
    assert isinstance(recording, RecordingSet)
    steps = list(recording.steps())
    assert [(s.segment, s.step) for s in steps] == [
        (0, k) for k in range(71)] + [(1, k) for k in range(26)]
    for step, rec in zip(steps, truth.records):
        assert bits_equal(step.positions, rec.positions)
        assert bits_equal(step.state[:, 2:], rec.velocities)
        assert [e.text for e in step.edits] == [e.text for e in rec.edits]
    times = [m.log_time_ns for m in recording.messages()]
    assert times == sorted(times)  # what replay plays, in order
    assert recording.message_count == metadata(directory)['message_count']


def test_resim_across_the_splits_and_of_each_file_alone(by_time, capsys):
    directory, _ = by_time
    assert resim.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert 'all 97 recorded steps re-simulate bit-identically' in out
    for name in metadata(directory)['relative_file_paths']:
        # each file starts with its segment and the state it resumes from
        assert resim.main([str(directory / name)]) == 0, name
        assert 'bit-identically' in capsys.readouterr().out


#: A dense exact-mode gas of two radius classes (radii 0.05 to 0.3 m): about 0.2 of the
#: arena covered, a collision per ball every few steps.
EXACT = {'rate_hz': RATE, 'random.count': 120, 'random.seed': 5, 'random.radius': [0.05, 0.3],
         'arena': [0.0, 0.0, 6.0, 6.0], 'physics.mode': 'exact'}


@pytest.fixture(scope='module')
def exact_split(tmp_path_factory):
    """An exact-mode run split every second (20 steps) into three files, with impulses and a
    set_state and a delete made just before a later file's first step."""
    directory = tmp_path_factory.mktemp('exact') / 'exact'
    sink = SplitMcapSink(directory, max_seconds=1.0)
    truth = Truth()
    simulation = Simulation(EXACT, sinks=[sink, truth])
    for _ in range(55):
        k = simulation.step_index + 1
        if k % 7 == 0 or k == 40:
            simulation.queue_impulse(f'ball_{k % 11}', 0.05, -0.03)
        if k == 40:
            x, y = simulation.world.positions[simulation.index_of['ball_3']]
            simulation.set_state('ball_3', x, y, 0.4, 0.1)  # where it is: nothing overlaps
            simulation.delete('ball_8')
        simulation.step()
    simulation.close()
    return directory, truth


def test_exact_mode_resims_across_the_splits_and_each_later_file_alone(exact_split, capsys):
    directory, truth = exact_split
    names = metadata(directory)['relative_file_paths']
    assert names == ['exact_0.mcap', 'exact_1.mcap', 'exact_2.mcap']
    assert sum(record.ball_ball for record in truth.records) > 400
    assert resim.main([str(directory)]) == 0
    assert 'all 56 recorded steps re-simulate bit-identically' in capsys.readouterr().out
    for name, steps, last in zip(names, (20, 20, 16), (19, 39, 55)):
        # each file from its first step: the later ones from the predictions they carry
        assert resim.main([str(directory / name)]) == 0, name
        out = capsys.readouterr().out
        assert f'segment 0: {steps} steps compared (last step {last})' in out, out
        assert 'bit-identically' in out


def test_exact_mode_split_by_size_through_the_writer_thread_resims_file_by_file(tmp_path,
                                                                                capsys):
    """As the node records: BackgroundSink(SplitMcapSink), rolled by bytes on its thread."""
    directory = tmp_path / 'sized'
    sink = BackgroundSink(SplitMcapSink(directory, max_bytes=60_000))
    assert sink.wants_carried_state
    simulation = Simulation({**EXACT, 'physics.backend': 'numpy'}, sinks=[sink])
    for _ in range(60):
        simulation.step()
    simulation.close()
    names = metadata(directory)['relative_file_paths']
    assert len(names) >= 3
    for name in names:
        assert resim.main([str(directory / name)]) == 0, (name, capsys.readouterr())
        assert 'bit-identically' in capsys.readouterr().out


def test_exact_mode_files_of_one_step_each_resim_alone(tmp_path, capsys):
    """A file after every step, the first after step 0 (whose world kept no predictions yet:
    resume_exact {}), each re-simulated alone."""
    directory = tmp_path / 'single'
    simulation = Simulation(EXACT, sinks=[SplitMcapSink(directory, max_bytes=1)])
    for _ in range(8):
        simulation.step()
    simulation.close()
    names = metadata(directory)['relative_file_paths']
    assert len(names) == 9
    assert open_recording(directory / names[1]).segments[0].resume.exact.kept is False
    assert open_recording(directory / names[2]).segments[0].resume.exact.kept
    for name in names:
        assert resim.main([str(directory / name)]) == 0, (name, capsys.readouterr())
        assert 'bit-identically' in capsys.readouterr().out


def test_exact_file_without_predictions_differs_or_is_refused(exact_split, tmp_path, capsys):
    directory, _ = exact_split
    # told that the world kept no predictions there, the file re-simulates from the balls
    # alone: the run is dense enough that this shows in the bits
    emptied = rewrite_recording(directory / 'exact_1.mcap', tmp_path / 'emptied.mcap',
                                metadata=lambda values: {**values, 'resume_exact': '{}'}
                                if 'resume_exact' in values else values)
    assert resim.main([str(emptied)]) == 1
    assert 'first difference: segment 0 step ' in capsys.readouterr().out
    # without the value (an older writer), refused in one line rather than compared
    older = rewrite_recording(directory / 'exact_1.mcap', tmp_path / 'older.mcap',
                              metadata=lambda values: {key: value for key, value in
                                                       values.items() if key != 'resume_exact'})
    assert resim.main([str(older)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'segment 0 is picked up at step 20 (a split file) in exact ' \
        'mode, but the file does not carry the collision predictions' in err[0], err


def crafted_exact(change):
    """A change to resume_exact, given its decoded JSON object (returns the new object)."""
    def rewrite(values):
        if 'resume_exact' in values:
            values['resume_exact'] = json.dumps(change(json.loads(values['resume_exact'])))
        return values
    return rewrite


def recoded(key, dtype, edit):
    """A change to one base64 array of resume_exact: edit(array) gives the new array."""
    def change(document):
        array = np.frombuffer(base64.b64decode(document[key]), dtype=dtype).copy()
        document[key] = base64.b64encode(edit(array).astype(dtype).tobytes()).decode()
        return document
    return change


def pointing_at(partner):
    """Every ball's predicted impact made a pair impact with `partner` (the codes say PAIR)."""
    def change(document):
        document = recoded('hit_partner', '<i4', lambda a: np.full_like(a, partner))(document)
        pair = np.array([0, 1, 1, 0]), np.array([0, 0, 0, 1])  # kinds PAIR, current
        return recoded('codes', 'u1', lambda c: c.reshape(-1, 4) * pair[0] + pair[1])(document)
    return change


@pytest.mark.parametrize('change, words', [
    (lambda d: 'not an object', "'resume_exact' is neither {} nor exactly"),
    (lambda d: {**d, 'extra': 1}, "'resume_exact' is neither {} nor exactly"),
    (lambda d: {**d, 'cells': '***'}, 'resume_exact cells is not base64 text'),
    (recoded('hit_time', '<f8', lambda a: a[:-1]), 'resume_exact hit_time holds'),
    (recoded('tori', '<i8', lambda a: np.tile(a, 40)), 'resume_exact tori holds'),
    (recoded('codes', 'u1', lambda a: a + 9), 'resume_exact codes holds a value that is no code'),
    (pointing_at(10**6), 'exact state: ball 0: its impact names no other ball'),
    (recoded('cells', '<i8', lambda a: a + 10**15), 'exact state: ball 0 is in cell'),
    (recoded('tori', '<i8', lambda a: a + 2**40), 'is not a power-of-two table'),
    (recoded('unit', '<f8', lambda a: a * np.nan), 'cell width nan'),
    (recoded('exit_time', '<f8', lambda a: -a), 'exact state: ball 0: an event time is '
                                                'negative or NaN'),
])
def test_a_crafted_exact_mode_state_is_refused_in_one_line(exact_split, tmp_path, capsys,
                                                           change, words):
    directory, _ = exact_split
    crafted = rewrite_recording(directory / 'exact_2.mcap', tmp_path / 'crafted.mcap',
                                metadata=crafted_exact(change))
    assert resim.main([str(crafted)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f'ball_world_resim: {crafted}: segment 0') \
        and words in err[0], err


def test_info_sums_the_files(by_time, capsys):
    directory, _ = by_time
    assert info.main([str(directory)]) == 0
    out = capsys.readouterr().out
    count = len(metadata(directory)['files'])
    assert f'split into:  {count} files' in out
    assert 'steps:       95 after the initial states (97 messages on /balls), in 2 segments' in out
    assert 'edits:       2 (1 spawn, 1 delete)' in out
    assert 'run_1.mcap:' in out


def test_to_rrd_converts_the_set(by_time, tmp_path, capsys):
    directory, truth = by_time
    output = tmp_path / 'set.rrd'
    assert to_rrd.main([str(directory), '-o', str(output)]) == 0
    assert f'wrote {output}: {len(truth.records)} steps, 2 segment' in capsys.readouterr().err
    assert output.stat().st_size > 0


def data_bytes(path):
    """Where a finished MCAP's summary starts (its footer says): the bytes of its data."""
    data = Path(path).read_bytes()
    opcode, length, summary_start = struct.unpack_from('<BQQ', data, len(data) - 8 - 29)
    assert (opcode, length) == (0x02, 20)
    return summary_start


def test_split_by_size_keeps_files_near_max_bytes_and_resims(tmp_path, capsys):
    directory = tmp_path / 'sized'
    limit = 50_000
    truth, _ = record(directory, steps=150, reset_steps=0, max_bytes=limit)
    names = metadata(directory)['relative_file_paths']
    assert len(names) >= 4
    sizes = [data_bytes(directory / name) for name in names]
    # A file rolls at the first step at which its bytes, the open chunk counted
    # uncompressed, reach the limit: so its data ends at most one step (about 6 kB here,
    # markers included) past it, and at most one chunk (16 KiB) short of it.
    assert all(limit - (16 << 10) <= size <= limit + (8 << 10) for size in sizes[:-1]), sizes
    assert sizes[-1] <= limit + (8 << 10)
    assert resim.main([str(directory)]) == 0
    assert f'all {len(truth.records)} recorded steps' in capsys.readouterr().out


def test_max_files_keeps_the_newest_and_says_so(tmp_path, capsys):
    directory = tmp_path / 'kept'
    truth, said = record(directory, steps=100, reset_steps=0, max_seconds=1.0, max_files=2)
    names = metadata(directory)['relative_file_paths']
    assert names == ['kept_4.mcap', 'kept_5.mcap']
    assert sorted(p.name for p in directory.iterdir()) == names + ['metadata.yaml']
    assert [line.rsplit('/', 1)[1] for line in said] == [f'kept_{i}.mcap' for i in range(4)]
    assert all(line.startswith('record.max_files 2: removed') for line in said)
    # what is left re-simulates from the state its first file resumes from
    assert resim.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert 'segment 0: 21 steps compared (last step 100)' in out
    steps = list(open_recording(directory).steps())
    assert steps[0].step == 80 and bits_equal(steps[0].positions, truth.records[80].positions)


def test_a_missing_middle_file_is_a_gap_resim_picks_the_run_up_after(tmp_path, capsys):
    directory = tmp_path / 'gap'
    truth, _ = record(directory, steps=50, reset_steps=0, max_seconds=1.0)
    (directory / 'gap_1.mcap').unlink()  # steps 20-39
    assert resim.main([str(directory)]) == 3
    out = capsys.readouterr().out
    assert 'segment 0: 20 steps compared (last step 19), ' in out
    assert ('segment 0: steps 20-39 NOT CHECKED: gap_1.mcap, listed in metadata.yaml, is '
            'missing') in out
    assert ('segment 0: 11 steps compared (last step 50), 1 impulses: identical (picked up '
            'at step 40 from the state a split file resumes from)') in out
    assert out.strip().endswith('NOT ALL STEPS COULD BE CHECKED (see above)')
    assert info.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert '  MISSING: gap_1.mcap, listed in metadata.yaml: the steps it held are lost' in out
    assert ('  GAP: segment 0: steps 20-39 are not in the set (gap_1.mcap, listed in '
            'metadata.yaml, is missing)') in out
    assert '  0: from log time 0 s, steps 0-19' in out and '  0: ' in out and 'steps 40-50' in out
    # to_rrd converts what is there, on the run's step timeline, and says what is not
    assert to_rrd.main([str(directory), '-o', str(tmp_path / 'gap.rrd')]) == 0
    err = capsys.readouterr().err
    assert 'warning: segment 0: steps 20-39 are not in the set' in err
    # (51: the reset's step 0, on the timeline after the last step)
    assert rrd_steps(tmp_path / 'gap.rrd') == list(range(20)) + list(range(40, 52))


def rrd_steps(path):
    """The steps of the balls' positions in an .rrd (one recording)."""
    [steps] = rrd_ball_steps(path)
    return steps


def crafted_resume(state):
    """A change to a resume state: (field, new value) given the decoded JSON object."""
    def change(values):
        if 'resume_state' in values:
            document = json.loads(values['resume_state'])
            key, value = state(document)
            document[key] = value
            values['resume_state'] = json.dumps(document)
        return values
    return change


def assert_resume_state_refused(crafted, words, capsys):
    """resim and info each refuse the file `crafted` (a crafted resume state) with exit 2 and
    one line naming the file, the segment and the state, with `words` in it."""
    for tool, prog in ((resim, 'ball_world_resim'), (info, 'ball_world_info')):
        assert tool.main([str(crafted)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(
            f"{prog}: {crafted}: segment 0: 'ball_world' metadata: the state it resumes "
            'from: ') and words in err[0], err


def nan_positions(document):
    count = len(document['names'])
    data = np.full((count, 2), np.nan).astype('<f8').tobytes()
    return 'positions', base64.b64encode(data).decode()


@pytest.mark.parametrize('state, words', [
    (nan_positions, 'positions holds a value that is not finite'),
    (lambda d: ('radii', 'no*base64!'), 'radii is not base64 text'),
    # 24 masses: 192 bytes, 256 base64 characters; 244 of them decode to 183 bytes
    (lambda d: ('masses', d['masses'][:-12]), 'masses holds 183 bytes, not 1 float64'),
    (lambda d: ('names', d['names'][:-1]), 'positions holds'),
    (lambda d: ('names', d['names'][:-1] + ['9lives']), "holds '9lives', which is no entity"),
    (lambda d: ('names', [d['names'][0]] * len(d['names'])), 'or one twice'),
])
def test_a_crafted_resume_state_is_refused_in_one_line(by_time, tmp_path, capsys,
                                                       state, words):
    directory, _ = by_time
    crafted = rewrite_recording(directory / 'run_1.mcap', tmp_path / 'crafted.mcap',
                                metadata=crafted_resume(state))
    assert_resume_state_refused(crafted, words, capsys)


def test_metadata_yaml_naming_a_path_outside_is_refused(tmp_path, capsys):
    directory = tmp_path / 'bag'
    record(directory, steps=30, reset_steps=0, max_seconds=1.0)
    text = (directory / 'metadata.yaml').read_text()
    (directory / 'metadata.yaml').write_text(text.replace('- bag_0.mcap', '- ../bag_0.mcap'))
    assert resim.main([str(directory)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"ball_world_resim: {directory}: metadata.yaml lists '../bag_0.mcap', which is not a "
        'file name in the directory')


def test_an_existing_directory_is_refused_unless_overwrite(tmp_path):
    directory = tmp_path / 'again'
    record(directory, steps=30, reset_steps=0, max_seconds=1.0)
    before = sorted(p.name for p in directory.iterdir())
    with pytest.raises(FileRefused) as refused:
        SplitMcapSink(directory, max_seconds=1.0)
    assert str(refused.value) == (f'{directory}: already exists; set record.overwrite:=true '
                                  'to replace it')
    assert sorted(p.name for p in directory.iterdir()) == before  # nothing touched
    (directory / 'notes.txt').write_text('mine')
    record_again = SplitMcapSink(directory, max_seconds=1.0, overwrite=True)
    # while it records, the directory is locked against a second recorder
    with pytest.raises(FileRefused) as refused:
        claim_directory(directory, overwrite=True)
    assert 'is being recorded by another process' in str(refused.value)
    record_again.close()  # nothing recorded: its files are gone, the old bag's too
    assert sorted(p.name for p in directory.iterdir()) == ['notes.txt']


def test_full_disk_while_finishing_a_file_loses_nothing_already_written(tmp_path):
    directory = tmp_path / 'full'
    sink = SplitMcapSink(directory, max_seconds=1.0)
    failures = []
    simulation = Simulation(PARAMS, sinks=[sink], on_sink_failure=failures.append)
    for _ in range(25):
        simulation.step()  # run_0 is finished at step 20; run_1 holds steps 20-25
    full = os.open('/dev/full', os.O_WRONLY)
    os.dup2(full, sink._sink._file.fileno())  # the disk fills up under the open file
    os.close(full)
    for _ in range(20):
        simulation.step()
    simulation.close()
    assert len(failures) == 1 and failures[0].error.errno == errno.ENOSPC
    assert str(failures[0].error).startswith(f'{directory / "full_1.mcap"}: ')
    assert simulation.step_index == 45
    assert metadata(directory)['relative_file_paths'] == ['full_0.mcap']
    recording = open_recording(directory)
    assert [s.step for s in recording.steps()] == list(range(20))


KILLED = textwrap.dedent("""
    import sys
    import time
    from ball_world.recording.split_writer import SplitMcapSink
    from ball_world.simulation import Simulation
    params = {'rate_hz': 20.0, 'random.count': 40, 'random.seed': 5}
    sim = Simulation(params, sinks=[SplitMcapSink(sys.argv[1], max_seconds=0.5)])
    while True:
        if sim.step_index == 17:
            sim.queue_impulse('ball_3', 0.2, 0.1)
        sim.step()
        if sim.step_index % 5 == 2:
            sim.flush()
            print(sim.step_index, flush=True)
            if sim.step_index == 37:
                time.sleep(3600)  # killed here, in the middle of a file, never between files
""")


def test_sigkill_mid_split_then_repair_then_resim(tmp_path, capsys, processes):
    directory = tmp_path / 'killed'
    child = processes.start([sys.executable, '-c', KILLED, str(directory)], cwd=ROOT,
                            stderr=None)
    try:
        flushed = [int(child.stdout.readline()) for _ in range(8)]
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    assert flushed == list(range(2, 40, 5))
    listed = metadata(directory)['relative_file_paths']
    assert len(listed) >= 3  # files 0-2 (steps 0-29) were finished before the kill
    last = f'killed_{len(listed)}.mcap'
    assert (directory / last).exists()
    with pytest.raises(ReaderError):
        RosbagsReader(directory / last).open()  # what repair is for
    assert f'{last} not listed in metadata.yaml' in open_recording(directory).problem

    assert repair.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert f'wrote {directory / "metadata.yaml"}' in out
    names = metadata(directory)['relative_file_paths']
    assert names == [f'killed_{i}.mcap' for i in range(len(listed) + 1)]
    with RosbagsReader(directory) as reader:
        assert reader.message_count == open_recording(directory).message_count
    steps = [s.step for s in open_recording(directory).steps()]
    assert steps == list(range(len(steps))) and len(steps) >= 38
    assert resim.main([str(directory)]) == 0
    assert 'bit-identically' in capsys.readouterr().out
    assert resim.main([str(directory / last)]) == 0  # the repaired file alone


# The node and the player ---------------------------------------------------------------------

NODE_TIMEOUT = 120.0  # generous: two noisy cores; a test fails only on a hang


def test_node_records_a_split_run_and_refuses_an_existing_bag(tmp_path, capsys):
    directory = tmp_path / 'node'
    run_node = ('max_steps:=45', 'rate_hz:=0.0', 'dt:=0.05', f'record.mcap:={directory}',
                'record.max_seconds:=1.0', 'record.max_files:=2')
    code, out, err = finish(start_node(*run_node), NODE_TIMEOUT)
    assert code == 0, err
    # steps 0-45 in files of 20 steps: three files, the oldest removed and said so
    assert metadata(directory)['relative_file_paths'] == ['node_1.mcap', 'node_2.mcap']
    assert f'record.max_files 2: removed the oldest split file {directory}/node_0.mcap' \
        in out + err
    assert [s.step for s in open_recording(directory).steps()] == list(range(20, 46))
    assert resim.main([str(directory)]) == 0
    assert 'all 26 recorded steps re-simulate bit-identically' in capsys.readouterr().out

    code, out, err = finish(start_node(*run_node), NODE_TIMEOUT)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and lines == [
        f"ball_world: parameter 'record.mcap': cannot record to {directory}: already exists; "
        'set record.overwrite:=true to replace it'], err
    assert metadata(directory)['relative_file_paths'] == ['node_1.mcap', 'node_2.mcap']


def test_replay_plays_the_files_in_order_with_their_timing(by_time, probe, processes):
    directory, truth = by_time
    received = probe.listen(PoseArray, '/balls', keep=lambda data: (time.monotonic(), data),
                            raw=True)
    env = dict(os.environ,
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    child = processes.start([sys.executable, '-m', 'ball_world.tools.replay', str(directory),
                             '--topics', '/balls', '--wait-for-subscribers', '--delay', '0.3'],
                            cwd=ROOT, env=env)
    assert probe.wait_for(lambda: len(received) >= len(truth.records), timeout=DEADLINE), \
        len(received)
    code, _, err = finish(child)
    assert code == 0, err
    assert [data for _, data in received] == [rec.balls_cdr for rec in truth.records]
    # steps 50 ms of log time apart, across the files and the reset (its log time goes on
    # at the next step): checked from below only, as for a single file (a loaded machine can
    # only make a replay later): the arrivals span at least half the recorded time
    arrivals = [t for t, _ in received]
    recorded_span = (len(truth.records) - 1) * DT_NS / 1e9
    assert arrivals[-1] - arrivals[0] >= 0.5 * recorded_span, arrivals[-1] - arrivals[0]


def test_repair_removes_a_file_killed_as_it_began_and_keeps_the_rest(tmp_path, capsys):
    directory = tmp_path / 'began'
    truth, _ = record(directory, steps=45, reset_steps=0, max_seconds=1.0)
    names = metadata(directory)['relative_file_paths']
    # killed during a roll: the next file holds its magic and header record, or nothing
    data = (directory / names[0]).read_bytes()
    header_end = 8 + 9 + struct.unpack_from('<Q', data, 9)[0]
    (directory / f'began_{len(names)}.mcap').write_bytes(data[:header_end])
    (directory / f'began_{len(names) + 1}.mcap').write_bytes(b'')
    assert repair.main([str(directory)]) == 0
    out = capsys.readouterr().out
    assert f'began_{len(names)}.mcap: removed, it held no complete message' in out
    assert f'began_{len(names) + 1}.mcap: removed, it held no complete message' in out
    assert metadata(directory)['relative_file_paths'] == names
    assert sorted(p.name for p in directory.iterdir()) == sorted(names + ['metadata.yaml'])
    assert [s.step for s in open_recording(directory).steps()] == [r.step for r in truth.records]
