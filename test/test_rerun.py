"""The Rerun sink: files Rerun itself verifies and reads back to exactly what was simulated.

Files are read with Rerun's own reader (rerun.chunk.RrdReader) and checked with its CLI
(`rerun rrd verify`, `rerun rrd compare`), the programs users open them with.
"""
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
import rerun as rr

from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.rerun_log import (ARENA, ARROW_SECONDS, BALLS, COLLISIONS, ENERGY,
                                            IMPULSES, MOMENTUM, RerunSink, SIM_TIME, STEP, WALLS)
from ball_world.simulation import Simulation
from ball_world.tools import to_rrd

RERUN_CLI = Path(sys.executable).parent / 'rerun'
IMPULSES_AT = {1: (0, 0.1, 0.0), 10: (3, 0.0, -0.2)}  # before step k: ball, jx, jy


class Collector:
    """A sink keeping every StepRecord, to compare the file with."""

    def __init__(self):
        self.records = []
        self.worlds = []

    def start_segment(self, world, info):
        self.worlds.append(world)

    def write_step(self, record):
        self.records.append(record)

    def flush(self):
        pass

    def close(self):
        pass


def run(sinks, steps=30, parameters=None, reset_at=None, reset_parameters=None):
    """The default world with a couple of impulses; returns the Collector."""
    collector = Collector()
    simulation = Simulation(parameters or {}, sinks=[*sinks, collector])
    for k in range(1, steps + 1):
        if k in IMPULSES_AT:
            ball, jx, jy = IMPULSES_AT[k]
            simulation.queue_impulse(ball, jx, jy, f'ball_{ball}')
        if k == reset_at:
            simulation.reset(reset_parameters or {})
        simulation.step(real_time_factor=1.0 + k / 100)
    simulation.close()
    return collector


def rerun_cli(*args):
    return subprocess.run([str(RERUN_CLI), *args], capture_output=True, text=True, timeout=60)


def read(path):
    """The recording's content: {(entity, component): {step: value}}, static ones at None.

    Also returns the timelines seen and the sim_time of every step, from the chunks of
    the file's (only) recording store.
    """
    reader = rr.chunk.RrdReader(path)
    (store,) = reader.recordings()
    content = {}
    timelines = set()
    sim_time = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        names = batch.schema.names
        timelines.update(chunk.timeline_names)
        steps = [None] * batch.num_rows if chunk.is_static else batch.column(STEP).to_pylist()
        if not chunk.is_static:
            times = batch.column(SIM_TIME).cast('int64').to_pylist()
            sim_time.update(zip(steps, times))
        for index, field in enumerate(batch.schema):
            if (field.metadata or {}).get(b'rerun:kind') != b'data':
                continue
            column = content.setdefault((chunk.entity_path, names[index]), {})
            for step, value in zip(steps, batch.column(index).to_pylist()):
                assert step not in column, f'two values of {names[index]} at step {step}'
                column[step] = value
    return store, content, timelines, sim_time


def as_float32(points):
    return np.asarray(points, dtype=np.float32).tolist()


def test_recording_verifies_and_reads_back_exactly(tmp_path):
    path = tmp_path / 'run.rrd'
    collected = run([RerunSink(path)])
    result = rerun_cli('rrd', 'verify', str(path))
    assert result.returncode == 0, result.stdout + result.stderr

    store, content, timelines, sim_time = read(path)
    assert store.application_id == 'ball_world'
    assert timelines == {SIM_TIME, STEP}  # no wall-clock log_time, no log_tick
    assert rr.chunk.RrdReader(path).blueprints(), 'the blueprint travels with the file'
    records = collected.records
    world = collected.worlds[0]
    assert [r.step for r in records] == list(range(31))

    positions = content[(f'/{BALLS}', 'Points2D:positions')]
    assert sorted(positions) == [r.step for r in records]
    for record in records:
        # Rerun stores positions as float32: the file holds exactly the float32 positions.
        assert positions[record.step] == as_float32(record.positions)
        assert sim_time[record.step] == record.log_time_ns
    energy = content[(f'/{ENERGY}', 'Scalars:scalars')]
    assert energy == {r.step: [r.kinetic_energy] for r in records}
    momentum = content[(f'/{MOMENTUM}', 'Scalars:scalars')]
    assert momentum == {r.step: list(r.momentum) for r in records}
    collisions = content[(f'/{COLLISIONS}', 'Scalars:scalars')]
    assert collisions == {r.step: [r.ball_ball, r.ball_wall] for r in records}

    walls = content[(f'/{WALLS}', 'LineStrips2D:strips')]
    assert walls == {0: world.walls.reshape(-1, 2, 2).tolist()}
    assert content[(f'/{BALLS}', 'Points2D:radii')] == {0: as_float32(world.radii)}
    labels = content[(f'/{BALLS}', 'Points2D:labels')][0]
    assert labels == [f'ball_{i}' for i in range(len(world.radii))]
    assert (f'/{ARENA}', 'Transform3D:rotation_axis_angle') in content

    # Each impulse shows at its step, at its ball, and is gone at the next step.
    vectors = content[(f'/{IMPULSES}', 'Arrows2D:vectors')]
    origins = content[(f'/{IMPULSES}', 'Arrows2D:origins')]
    for applied_at, (ball, jx, jy) in IMPULSES_AT.items():
        (impulse,) = records[applied_at].impulses
        assert (impulse.ball, impulse.jx, impulse.jy) == (ball, jx, jy)
        assert origins[applied_at] == as_float32([records[applied_at].positions[ball]])
        kick = np.array([[jx, jy]]) / world.masses[ball] * ARROW_SECONDS  # velocity change
        assert vectors[applied_at] == as_float32(kick)
        assert vectors[applied_at + 1] == []


def test_identical_runs_give_identical_content(tmp_path):
    first, second = tmp_path / 'first.rrd', tmp_path / 'second.rrd'
    run([RerunSink(first)])
    run([RerunSink(second)])
    store_a, content_a, _, _ = read(first)
    store_b, content_b, _, _ = read(second)
    assert store_a.recording_id == store_b.recording_id
    assert content_a == content_b
    # Chunk boundaries and row ids may differ between runs; the data may not.
    result = rerun_cli('rrd', 'compare', '--unordered', str(first), str(second))
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_k_and_reset_keep_timelines_and_totals(tmp_path):
    path = tmp_path / 'sparse.rrd'
    collected = run([RerunSink(path, every=4)], steps=21, reset_at=15,
                    reset_parameters={'random.count': 5, 'random.seed': 3})
    _, content, _, sim_time = read(path)
    records = collected.records
    # The step timeline counts every step of the recording, across the reset.
    segment_starts = [i for i, r in enumerate(records) if r.step == 0]
    assert segment_starts == [0, 15]
    # Every 4th step of a segment, the impulse steps 1 and 10, the last steps 14 and 22.
    expected = {0, 1, 4, 8, 10, 12, 14, 15, 19, 22}
    positions = content[(f'/{BALLS}', 'Points2D:positions')]
    assert set(positions) == expected
    for global_step in expected:
        record = records[global_step]
        assert positions[global_step] == as_float32(record.positions)
        assert sim_time[global_step] == record.log_time_ns
    assert len(positions[22]) == 5 and len(positions[14]) == 20
    # Collisions of skipped steps are added to the next logged one: the totals stay right.
    collisions = content[(f'/{COLLISIONS}', 'Scalars:scalars')]
    assert np.sum(list(collisions.values()), axis=0).tolist() == [
        sum(r.ball_ball for r in records), sum(r.ball_wall for r in records)]


def test_mcap_converts_to_the_same_positions(tmp_path, capsys):
    live, mcap, converted = tmp_path / 'live.rrd', tmp_path / 'run.mcap', tmp_path / 'conv.rrd'
    run([RerunSink(live), McapSink(mcap)])
    assert to_rrd.main([str(mcap), '-o', str(converted)]) == 0
    assert '31/31 steps' in capsys.readouterr().err
    result = rerun_cli('rrd', 'verify', str(converted))
    assert result.returncode == 0, result.stdout + result.stderr
    _, live_content, _, live_times = read(live)
    _, converted_content, _, converted_times = read(converted)
    key = (f'/{BALLS}', 'Points2D:positions')
    assert converted_content[key] == live_content[key]
    assert converted_times == live_times
    arrows = (f'/{IMPULSES}', 'Arrows2D:vectors')
    assert converted_content[arrows] == live_content[arrows]


def test_converter_reports_unreadable_input(tmp_path, capsys):
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(b'not an mcap file')
    assert to_rrd.main([str(bad)]) == 2
    assert 'error' in capsys.readouterr().err


def test_sink_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError):
        RerunSink(tmp_path / 'x.rrd', every=0)
    with pytest.raises(OSError):
        RerunSink(tmp_path / 'missing' / 'x.rrd')
