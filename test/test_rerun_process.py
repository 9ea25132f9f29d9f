"""The .rrd written by a child process (recording.rerun_process), as the node writes it.

The child holds the SDK's per-chunk index of the file, which grows with the recording, so
that the node's memory stays flat; what it writes must be what the in-process stream writes,
and its failures must be reported like the in-process stream's, once, in one line, without
touching the other recordings.
"""
import os
import signal

from ball_world_testing.harness import open_rrd, rrd_ball_steps, run_rerun
import numpy as np
import pytest
import rerun as rr
from test_rerun import read

from ball_world.recording.mcap_reader import Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.rerun_log import RerunSink
from ball_world.recording.rerun_process import GATHER_SECONDS, Gathered, ProcessStream
from ball_world.simulation import Simulation

STEPS = 150


def simulate(sinks, steps=STEPS, between=None, on_sink_failure=None):
    """The default world with an impulse, a reset and a flush every 30 steps; between(k) is
    called after step k's flush."""
    simulation = Simulation({}, sinks=sinks, on_sink_failure=on_sink_failure)
    for k in range(1, steps + 1):
        if k == 5:
            simulation.queue_impulse('ball_1', 0.1, 0.0)
        if k == 90:
            simulation.reset({})
        simulation.step(real_time_factor=1.0)
        if k % 30 == 0:
            simulation.flush()
            if between is not None:
                between(k)
    simulation.close()
    return simulation


def writer_of(sink):
    """The ProcessStream of a RerunSink's file."""
    (feed,) = sink._feeds
    stream = feed.outlet.stream
    assert isinstance(stream, ProcessStream)
    return stream


def balls_chunks(path):
    reader = open_rrd(path)
    (store,) = reader.recordings()
    return sum(chunk.entity_path == '/arena/balls' and not chunk.is_static
               for chunk in reader.stream(store=store))


def test_the_child_writes_what_the_sdk_writes_in_process(tmp_path):
    """Same run, same recording id: Rerun's reader finds the same data. The child
    is out of a terminal's Ctrl-C (it goes to the foreground process group): the node stops
    first, and closes the file."""
    inline, child = tmp_path / 'inline.rrd', tmp_path / 'child.rrd'
    simulate([RerunSink(inline, velocities=True)])
    sink = RerunSink(child, velocities=True, file_process=True)
    groups = []
    simulate([sink], between=lambda k: groups.append(os.getpgid(writer_of(sink).pid)))
    assert groups[0] == writer_of(sink).pid != os.getpgid(0)
    verified = run_rerun('rrd', 'verify', child)
    assert verified.returncode == 0, verified.stderr
    # The child gathers the node's columns into fewer chunks: the data, read per entity,
    # component and step, is the same.
    assert read(inline)[1] == read(child)[1]
    assert balls_chunks(child) < balls_chunks(inline)
    # one recording, every step in order across the reset (the step timeline goes on)
    assert rrd_ball_steps(child) == [list(range(STEPS + 2))]


def test_a_killed_writer_is_reported_once_in_one_line_and_the_mcap_goes_on(tmp_path):
    rrd, mcap = tmp_path / 'run.rrd', tmp_path / 'run.mcap'
    sink = RerunSink(rrd, file_process=True)
    failures = []

    def kill_writer(k):
        if k == 60:
            stream = writer_of(sink)
            os.kill(stream.pid, signal.SIGKILL)

    simulate([McapSink(mcap), sink], between=kill_writer, on_sink_failure=failures.append)
    assert len(failures) == 1
    line = str(failures[0].error)
    assert '\n' not in line
    assert line.startswith(f'file {str(rrd)!r}: the .rrd writer process (pid ')
    assert 'was killed by SIGKILL' in line
    steps = [step.step for step in Recording(mcap).steps()]
    assert Recording(mcap).has_summary and len(steps) == STEPS + 2  # both segments' step 0


def test_a_write_error_in_the_child_is_raised_like_the_sdks(tmp_path):
    """An SDK call the child cannot run (a directory removed after the start's check) ends
    it with the SDK's message, as one line, raised again if asked again (no hang)."""
    stream = ProcessStream().open('ball_world', 'some-id')
    stream.save(str(tmp_path / 'gone' / 'x.rrd'))
    stream.set_time('step', sequence=0)
    with pytest.raises(OSError) as raised:
        stream.flush(timeout_sec=2.0)
    line = str(raised.value)
    assert line.startswith('Failed to create file: No such file or directory') and '\n' not in line
    with pytest.raises(OSError) as again:
        stream.flush(timeout_sec=2.0)
    assert str(again.value) == line


def test_only_a_streams_calls_are_taken():
    stream = ProcessStream().open('ball_world', 'some-id')
    try:
        with pytest.raises(AttributeError):
            stream.spawn
    finally:
        stream.disconnect()


def test_bad_file_is_still_refused_at_start(tmp_path):
    with pytest.raises(OSError, match='missing/run.rrd: No such file or directory'):
        RerunSink(tmp_path / 'missing' / 'run.rrd', file_process=True)


class Recorder:
    """A stream that keeps what send_columns was given, as plain lists."""

    def __init__(self):
        self.sent = []

    def send_columns(self, entity, indexes, columns):
        self.sent.append((entity, {i.timeline_name(): i.as_arrow_array().to_pylist()
                                   for i in indexes},
                          {c.component_descriptor().component: c.as_arrow_array().to_pylist()
                           for c in columns}))


def test_columns_are_gathered_per_entity_until_due_and_sent_whole():
    now = [0.0]
    stream = Recorder()
    gathered = Gathered(stream, clock=lambda: now[0])

    def add(entity, steps, values):
        gathered.add(entity, [rr.TimeColumn('step', sequence=steps)],
                     rr.Scalars.columns(scalars=np.array(values, dtype=np.float64)))
        gathered.send_due()

    add('a', [0, 1], [0.5, 1.5])
    add('b', [0], [7.0])
    now[0] = GATHER_SECONDS - 0.1
    add('a', [2], [2.5])
    assert stream.sent == []  # nothing is due yet
    now[0] = GATHER_SECONDS
    add('b', [1], [8.0])
    assert stream.sent == [('a', {'step': [0, 1, 2]}, {'Scalars:scalars': [[0.5], [1.5], [2.5]]}),
                           ('b', {'step': [0, 1]}, {'Scalars:scalars': [[7.0], [8.0]]})]
    add('a', [3], [3.5])
    gathered.add('a', [rr.TimeColumn('other', sequence=[4])],  # another layout: sent apart
                 rr.Scalars.columns(scalars=np.array([4.5])))
    gathered.send_all()
    assert stream.sent[2:] == [('a', {'step': [3]}, {'Scalars:scalars': [[3.5]]}),
                               ('a', {'other': [4]}, {'Scalars:scalars': [[4.5]]})]
    assert gathered.held == {}
