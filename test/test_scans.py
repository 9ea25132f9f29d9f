"""Agents' scans in a Simulation (ball_world.scans): when they are taken, what the LaserScan
bytes say (REP 117, the step's stamp, the agent's frame), and that a run repeats them bit for
bit. The ranges are checked against the box's closed form, not against core.lidar."""
import math

import numpy as np
import pytest

from ball_world.core.parameters import ParameterError
from ball_world.msgs.agent_cdr import decode_laser_scan
from ball_world.simulation import build, Simulation


class Records:
    """A sink that keeps every StepRecord."""

    def __init__(self):
        self.records = []

    def start_segment(self, world, info):
        pass

    def write_step(self, record):
        self.records.append(record)

    def flush(self):
        pass

    def close(self):
        pass


def agent_in_a_box(**overrides):
    """ball_0 (r 0.3), an agent at rest at (3, 4) in the box [0, 10] x [0, 8], alone."""
    parameters = {'rate_hz': 60.0, 'arena': [0.0, 0.0, 10.0, 8.0], 'random.count': 0,
                  'balls.x': [3.0], 'balls.y': [4.0], 'balls.vx': [0.0], 'balls.vy': [0.0],
                  'balls.radius': [0.3], 'balls.mass': [1.0], 'agents': ['ball_0'],
                  'physics.backend': 'numpy', 'agent.scan.noise_stddev': 0.0}
    parameters.update(overrides)
    sink = Records()
    simulation = Simulation(parameters, sinks=[sink])
    return simulation, sink.records


def box_range(angle):
    """From (3, 4) in [0, 10] x [0, 8] along `angle`: the nearest wall."""
    c, s = math.cos(angle), math.sin(angle)
    return min(d for d in ((7.0 / c if c > 0 else math.inf), (-3.0 / c if c < 0 else math.inf),
                           (4.0 / s if s > 0 else math.inf), (-4.0 / s if s < 0 else math.inf)))


def test_scans_at_the_scan_rate_of_simulated_time_stamped_and_framed():
    simulation, records = agent_in_a_box(frame_prefix='w1/')
    for _ in range(30):
        simulation.step()
    scanned = [record.step for record in records if record.agents.scans]
    # dt = 1/60 s, 10 Hz: step 0, then every sixth step (the end of step 6 is 0.1 s).
    assert scanned == [0, 6, 12, 18, 24, 30]
    record = records[12]
    (scan,) = record.agents.scans
    message = decode_laser_scan(scan.cdr)
    assert message.stamp_ns == record.stamp_ns == 12 * simulation.dt_ns
    assert message.frame_id == 'w1/ball_0/base_link'
    assert message.angle_min == pytest.approx(-math.pi)
    assert message.angle_increment == pytest.approx(2.0 * math.pi / 360)
    assert message.angle_max == pytest.approx(math.pi - 2.0 * math.pi / 360)
    assert len(message.ranges) == 360
    # range_min 0: 0.05 beyond the agent's radius; range_max the default 12 m.
    assert message.range_min == pytest.approx(0.35)
    assert message.range_max == pytest.approx(12.0)
    assert message.scan_time == pytest.approx(0.1)
    assert message.time_increment == 0.0
    # The box's closed form, to float32 (the message's type) and to 1e-9 m before it.
    angles = -math.pi + np.arange(360) * (2.0 * math.pi / 360)
    expected = np.array([box_range(a) for a in angles])
    assert np.max(np.abs(scan.ranges - expected)) < 1e-9
    assert np.array_equal(message.ranges, expected.astype(np.float32))


def test_the_heading_turns_the_scan():
    simulation, records = agent_in_a_box()
    simulation.command('ball_0', 0.0, 0.0, 1.0)
    for _ in range(6):
        simulation.step()
    yaw = float(records[6].agents.yaws[0])
    assert yaw != 0.0
    (scan,) = records[6].agents.scans
    position = records[6].positions[0]
    assert position == pytest.approx([3.0, 4.0], abs=1e-12)
    angles = yaw - math.pi + np.arange(360) * (2.0 * math.pi / 360)
    expected = np.array([box_range(a) for a in angles])
    assert np.max(np.abs(scan.ranges - expected)) < 1e-9


def test_noisy_scans_repeat_bit_for_bit_in_a_second_run():
    def run():
        simulation, records = agent_in_a_box(**{'agent.scan.noise_stddev': 0.01,
                                                'random.seed': 5})
        simulation.command('ball_0', 0.5, 0.0, 0.3)
        for _ in range(20):
            simulation.step()
        return [scan.cdr for record in records for scan in record.agents.scans]
    first = run()
    assert len(first) == 4
    assert first == run()
    assert len(set(first)) == 4  # every scan draws its own noise


def test_no_scanner_with_zero_samples():
    simulation, records = agent_in_a_box(**{'agent.scan.samples': 0})
    simulation.step()
    assert all(record.agents.scans == () for record in records)


def test_a_range_min_beyond_range_max_is_refused_by_name():
    parameters = {'random.count': 2, 'agents': ['ball_0'], 'agent.scan.range_min': 20.0}
    with pytest.raises(ParameterError, match='agent.scan.range_min'):
        build(parameters)


def test_rviz_draws_ball_0s_scan_with_the_publishers_qos():
    from pathlib import Path

    import yaml

    from ball_world.ros.agents import ODOM_QOS  # the QoS <name>/scan is published with
    rviz = yaml.safe_load((Path(__file__).parent.parent / 'rviz' / 'ball_world.rviz')
                          .read_text())
    (display,) = [d for d in rviz['Visualization Manager']['Displays']
                  if d['Class'] == 'rviz_default_plugins/LaserScan']
    assert display['Enabled'] is True and display['Topic']['Value'] == '/ball_0/scan'
    assert display['Topic']['Reliability Policy'].lower() == ODOM_QOS.reliability.name.lower()
    assert display['Topic']['Durability Policy'].lower() == ODOM_QOS.durability.name.lower()


def test_rerun_draws_each_scans_hit_points_in_the_arena(tmp_path):
    from ball_world_testing.harness import open_rrd

    from ball_world.recording.rerun_log import RerunSink, SCANS
    path = tmp_path / 'run.rrd'
    sink = RerunSink(path)
    records = Records()
    simulation = Simulation({'rate_hz': 60.0, 'arena': [0.0, 0.0, 10.0, 8.0],
                             'random.count': 0, 'balls.x': [3.0], 'balls.y': [4.0],
                             'balls.vx': [0.0], 'balls.vy': [0.0], 'balls.radius': [0.3],
                             'balls.mass': [1.0], 'agents': ['ball_0'],
                             'physics.backend': 'numpy', 'agent.scan.noise_stddev': 0.0},
                            sinks=[sink, records])
    for _ in range(12):
        simulation.step()
    simulation.close()
    reader = open_rrd(path)
    (store,) = reader.recordings()
    logged = {}
    for chunk in reader.stream(store=store):
        if chunk.entity_path == f'/{SCANS}/ball_0':
            batch = chunk.to_record_batch()
            for step, points in zip(batch.column('step').to_pylist(),
                                    batch.column('Points2D:positions').to_pylist()):
                logged[step] = np.array(points, dtype=np.float64).reshape(-1, 2)
    assert sorted(logged) == [0, 6, 12]
    # Every hit point of the lone agent's scan lies on the box's walls (float32 positions).
    points = logged[6]
    assert len(points) == 360
    on_wall = np.minimum(np.minimum(points[:, 0], 10.0 - points[:, 0]),
                         np.minimum(points[:, 1], 8.0 - points[:, 1]))
    assert np.all(np.abs(on_wall) < 1e-5)


@pytest.mark.parametrize('backend, mode', [('numpy', 'seed'), ('numba', 'seed'),
                                           ('numba', 'exact')])
def test_resim_checks_every_recorded_scan_bit_for_bit(tmp_path, monkeypatch, backend, mode):
    # The agent stays at rest (no command, so its drive pushes nothing); ball_1 moves, so
    # every scan differs from the last. Noise on: re-simulation must draw it again.
    from ball_world.core import lidar
    from ball_world.recording.mcap_reader import Recording
    from ball_world.recording.mcap_writer import McapSink
    from ball_world.tools.resim import resimulate
    path = tmp_path / 'run.mcap'
    parameters = {'rate_hz': 60.0, 'random.count': 0, 'balls.x': [3.0, 6.0],
                  'balls.y': [4.0, 4.0], 'balls.vx': [0.0, 1.0], 'balls.vy': [0.0, 0.5],
                  'balls.radius': [0.3, 0.3], 'balls.mass': [1.0, 1.0], 'agents': ['ball_0'],
                  'physics.backend': backend, 'physics.mode': mode, 'random.seed': 9}
    simulation = Simulation(parameters, sinks=[McapSink(path)])
    for _ in range(30):
        simulation.step()
    simulation.close()
    comparison = resimulate(Recording(path))
    assert comparison.identical
    # A re-simulation whose noise is drawn for another name differs at every scan, and says
    # which agent's scan at which step.
    monkeypatch.setattr(lidar, 'name_key', lambda name: 12345)
    comparison = resimulate(Recording(path))
    assert not comparison.identical
    assert 'scan ball_0' in comparison.first.what and comparison.first.step == 0
    assert comparison.count == 6  # steps 0, 6, 12, 18, 24, 30


def test_foxglove_3d_panel_draws_a_recorded_scan(tmp_path):
    import json
    from pathlib import Path

    from ball_world.recording.mcap_reader import Recording
    from ball_world.recording.mcap_writer import McapSink
    layout = json.loads((Path(__file__).parent.parent / 'foxglove' / 'ball_world.json')
                        .read_text())
    scene = layout['configById']['3D!world']
    assert scene['topics']['/ball_0/scan']['visible'] is True
    path = tmp_path / 'agent.mcap'
    simulation = Simulation({'random.count': 3, 'agents': ['ball_0'],
                             'physics.backend': 'numpy'}, sinks=[McapSink(path)])
    simulation.step()
    simulation.close()
    topics = Recording(path).topics
    assert topics['/ball_0/scan'].type == 'sensor_msgs/msg/LaserScan'
    assert topics['/tf'].type == 'tf2_msgs/msg/TFMessage'  # how Foxglove places the scan
