"""A start of the node cut short (a signal lands while it sets up, an error) leaves no stub
file behind to refuse the next start: found by a SIGTERM 5 s into a start on a loaded
machine, which left a 65-byte MCAP and a 1-byte .rrd."""
from ball_world_testing.harness import open_rrd, Probe, read_mcap, run_rerun
import pytest
from rclpy.parameter import Parameter

from ball_world.recording.mcap_reader import Recording
from ball_world.ros import node as node_module


def interrupted(where, monkeypatch):
    def stop(*args, **kwargs):
        raise KeyboardInterrupt  # what a signal raises in the middle of the start

    monkeypatch.setattr(node_module, where, stop)


def start(tmp_path):
    probe = Probe()
    overrides = [Parameter('record.mcap', value=str(tmp_path / 'run.mcap')),
                 Parameter('record.rerun', value=str(tmp_path / 'run.rrd')),
                 Parameter('random.count', value=3)]
    try:
        with pytest.raises(KeyboardInterrupt):
            node_module.BallWorld(context=probe.context, parameter_overrides=overrides)
    finally:
        probe.close()


def test_a_start_cut_before_the_first_segment_removes_its_files(tmp_path, monkeypatch):
    interrupted('Simulation', monkeypatch)
    start(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_a_start_cut_after_the_first_segment_closes_complete_recordings(tmp_path,
                                                                        monkeypatch):
    interrupted('SimulationInterfaces', monkeypatch)
    start(tmp_path)
    [(topic, log_time, _)] = read_mcap(tmp_path / 'run.mcap', ['/balls'])  # with a summary
    assert (topic, log_time) == ('/balls', 0)
    assert len(Recording(tmp_path / 'run.mcap').segments) == 1
    assert run_rerun('rrd', 'verify', tmp_path / 'run.rrd').returncode == 0
    assert open_rrd(tmp_path / 'run.rrd').recordings()


def test_a_recording_run_says_where_its_files_go():
    """A recording run printed no line saying where its files went: one line, absolute."""
    from pathlib import Path
    values = {'record.mcap': 'runs/scan.mcap', 'record.rerun': '', 'record.max_bytes': 0,
              'record.max_seconds': 0.0}
    assert node_module.recording_line(values) == \
        f"recording to {Path('runs/scan.mcap').resolve()}"
    values.update({'record.rerun': 'runs/scan.rrd', 'record.max_seconds': 60.0})
    line = node_module.recording_line(values)
    assert line.startswith(f"recording to {Path('runs/scan.mcap').resolve()} and "
                           f"{Path('runs/scan.rrd').resolve()} (split")
    assert node_module.recording_line({**values, 'record.mcap': '', 'record.rerun': ''}) \
        is None
