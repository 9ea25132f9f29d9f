"""A swarm (agent.topics none) and odometry at its own rate (agent.odom.rate_hz), recorded and
re-simulated bit for bit.

A swarm makes no per-agent message: its commands are recorded as one agent_commands message
a step (rows: ball, vx, vy, wz), its drives not at all (re-simulation makes them again from
the commands and must then match every ball to the bit), and `balls` carries each agent's
heading as its orientation. Odometry at a rate goes out, and is recorded, at the steps the
rate says, like the scans.
"""
import math

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from test_agent_recordings import record_run
from test_rerun import read

from ball_world.msgs.agent_cdr import encode_command_rows
from ball_world.recording.mcap_reader import Recording
from ball_world.recording.rerun_agents import AGENTS
from ball_world.recording.rerun_log import ENERGY, RerunSink
from ball_world.tools import resim, to_rrd


def decoded_topics(path):
    found = {}
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, ros in reader.iter_decoded_messages():
            found.setdefault(channel.topic, (schema.name, []))[1].append((message, ros))
    return found


@pytest.mark.parametrize('overrides', [{'physics.backend': 'numpy'}, {'physics.mode': 'exact'}],
                         ids=['numpy', 'exact'])
def test_a_swarm_records_its_commands_as_rows_and_resimulates_bit_for_bit(tmp_path, capsys,
                                                                          overrides):
    path = record_run(tmp_path / 'swarm.mcap', **{'agent.topics': 'none', **overrides})
    assert resim.main([str(path)]) == 0, capsys.readouterr()
    assert 'all 71 recorded steps re-simulate bit-identically' in capsys.readouterr().out
    topics = decoded_topics(path)
    assert not [t for t in topics if 'ball_' in t or 'rover' in t or t.startswith('/tf')]
    kind, messages = topics['/agent_commands']
    assert kind == 'std_msgs/msg/Float64MultiArray'
    # record_run's six commands: the one to 'rover' before its spawn is refused as before.
    rows = [list(ros.data) for _, ros in messages]
    assert [len(r) // 4 for r in rows] == [1, 1, 2, 1, 1]
    assert rows[0] == [0.0, 1.5, 0.0, 2.0]  # ball_0 (row 0) forward 1.5, turning 2
    assert messages[0][0].log_time == 2 * 20_000_000  # the step it took effect
    assert [d.label for d in messages[0][1].layout.dim] == ['command', 'ball_vx_vy_wz']
    # The drives are not recorded; the one push (step 40) is.
    assert len(topics['/impulse'][1]) == 1
    steps = list(Recording(path).steps())
    assert steps[45].odom is None and steps[45].command_rows is None


def test_balls_give_each_agent_its_heading_and_a_ball_the_identity(tmp_path):
    path = record_run(tmp_path / 'swarm.mcap', steps=45,
                      **{'agent.topics': 'none', 'physics.backend': 'numpy'})
    _, balls = decoded_topics(path)['/balls']
    last = balls[-1][1].poses
    # ball_3's heading was set to 2.5 rad at step 40 and it has had no yaw command since
    # step 3 (0.0 rad/s), so it is 2.5 still: the rotation by 2.5 about z.
    assert (last[3].orientation.z, last[3].orientation.w) == pytest.approx(
        (math.sin(1.25), math.cos(1.25)), abs=1e-15)
    assert (last[3].orientation.x, last[3].orientation.y) == (0.0, 0.0)
    plain = [pose.orientation for i, pose in enumerate(last) if i not in (0, 3)]
    assert all((q.x, q.y, q.z, q.w) == (0.0, 0.0, 0.0, 1.0) for q in plain[:-1])
    rover = last[-1].orientation  # spawned at step 30 as an agent, turning 1 rad/s since 35
    assert rover.z != 0.0 and rover.z ** 2 + rover.w ** 2 == pytest.approx(1.0, abs=1e-15)


def test_resim_notices_a_changed_swarm_command(tmp_path, capsys):
    path = record_run(tmp_path / 'swarm.mcap', **{'agent.topics': 'none',
                                                  'physics.backend': 'numpy'})
    original = encode_command_rows(np.array([[0.0, 1.5, 0.0, 2.0]]))
    changed = encode_command_rows(np.array([[0.0, 1.5000000000000002, 0.0, 2.0]]))
    from ball_world_testing.harness import rewrite_recording
    rewrite_recording(path, tmp_path / 'tampered.mcap',
                      data=lambda topic, log_time, data: changed if data == original else data)
    assert resim.main([str(tmp_path / 'tampered.mcap')]) == 1
    assert 'first difference: segment 0 step 2' in capsys.readouterr().out


def test_odometry_at_its_rate_is_recorded_at_those_steps_and_resimulates(tmp_path, capsys):
    # 50 Hz steps, odometry at 10 Hz: steps 0, 5, 10, ... (whole periods of 0.1 s).
    path = record_run(tmp_path / 'odom.mcap', **{'agent.odom.rate_hz': 10.0,
                                                 'physics.backend': 'numpy',
                                                 'agent.scan.samples': 0})
    assert resim.main([str(path)]) == 0, capsys.readouterr()
    topics = decoded_topics(path)
    times = [message.log_time for message, _ in topics['/ball_3/odom'][1]]
    assert times == [k * 20_000_000 for k in range(0, 71, 5)]
    assert [m.log_time for m, _ in topics['/tf'][1]] == times
    assert [m.log_time for m, _ in topics['/ball_3/ground_truth'][1]] == times
    assert len(topics['/ball_3/cmd_vel'][1]) == 2  # commands as every step takes them


def test_to_rrd_draws_a_swarms_headings_as_the_live_view_did(tmp_path):
    # The agents of a swarm are known from its parameters and edits (rover spawned at 30,
    # ball_3 turned at 40, ball_0 deleted at 60), their headings from `balls`.
    live = tmp_path / 'live.rrd'
    path = record_run(tmp_path / 'swarm.mcap', also=[RerunSink(str(live))],
                      **{'agent.topics': 'none', 'physics.backend': 'numpy'})
    converted = tmp_path / 'converted.rrd'
    assert to_rrd.main([str(path), '-o', str(converted)]) == 0
    logged, converted = read(live)[1], read(converted)[1]
    # the energy plot as live: its drives' part from the drives made again (not recorded)
    energy = {key: column for key, column in logged.items() if key[0].startswith(f'/{ENERGY}')}
    assert len(energy) >= 3
    for key, column in energy.items():
        assert converted[key] == column, key
    key = (f'/{AGENTS}', 'Arrows2D:vectors')
    drawn, made = logged[key], converted[key]
    assert made.keys() == drawn.keys() and len(drawn) > 60
    # two agents, then rover too, then without ball_0; each arrow over its dark casing
    assert [len(drawn[step]) for step in (10, 35, 65)] == [4, 6, 4]
    for step, vectors in drawn.items():
        assert np.allclose(made[step], vectors, atol=1e-6), step
