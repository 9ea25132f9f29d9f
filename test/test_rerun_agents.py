"""Rerun draws each agent's heading as an arrow out of its disc, its name among the labels."""
import math

import numpy as np
import pytest
from test_rerun import read, shown_at

from ball_world.recording.rerun_agents import AGENTS, HEADING_RADII
from ball_world.recording.rerun_log import LABELS, RerunSink
from ball_world.recording.rerun_text import strokes
from ball_world.simulation import Simulation


def test_an_agent_is_drawn_with_its_heading_and_name(tmp_path):
    path = tmp_path / 'run.rrd'
    simulation = Simulation({'random.count': 6, 'agents': ['ball_2'],
                             'agent.cmd_timeout': 0.0}, sinks=[RerunSink(path)])
    radius = float(simulation.world.radii[2])
    simulation.command('ball_2', 0.5, 0.0, 1.5)
    records = [simulation.last_record]
    for _ in range(20):
        records.append(simulation.step()[0])
    simulation.close()
    _, content, _, _ = read(path)
    vectors = content[(f'/{AGENTS}', 'Arrows2D:vectors')]
    origins = content[(f'/{AGENTS}', 'Arrows2D:origins')]
    labels = content[(f'/{LABELS}', 'Points2D:labels')]
    assert not any(component.endswith(':labels') for entity, component in content
                   if entity == f'/{AGENTS}')  # the name is with the balls' names
    for step in (0, 7, 20):
        record = records[step]
        yaw = float(record.agents.yaws[0])
        assert yaw == pytest.approx(1.5 * step * simulation.dt_ns * 1e-9, abs=1e-12)
        casing, vector = shown_at(vectors, step)  # drawn twice: casing, then the arrow
        assert casing == vector
        assert vector == pytest.approx([HEADING_RADII * radius * math.cos(yaw),
                                        HEADING_RADII * radius * math.sin(yaw)], rel=1e-6)
        # from the edge of the disc, never over it (where it had 1.5:1 against the disc)
        origin = shown_at(origins, step)[1]
        edge = np.asarray(record.positions[2]) + radius * np.array([math.cos(yaw),
                                                                    math.sin(yaw)])
        assert origin == pytest.approx(edge.tolist(), rel=1e-6)
        assert shown_at(labels, step)[0] == 'ball_2'  # agents are named first


def test_a_world_without_agents_draws_no_arrows(tmp_path):
    path = tmp_path / 'run.rrd'
    simulation = Simulation({'random.count': 3}, sinks=[RerunSink(path)])
    simulation.step()
    simulation.close()
    _, content, _, _ = read(path)
    assert not any(entity == f'/{AGENTS}' for entity, _ in content)


def test_a_recording_converted_to_rrd_draws_its_agents(tmp_path, capsys):
    from ball_world.recording.mcap_writer import McapSink
    from ball_world.tools import to_rrd
    mcap = tmp_path / 'run.mcap'
    simulation = Simulation({'random.count': 6, 'agents': ['ball_2', 'ball_4'],
                             'agent.cmd_timeout': 0.0}, sinks=[McapSink(mcap)])
    simulation.command('ball_4', 0.3, 0.0, -2.0)
    records = [simulation.last_record] + [simulation.step()[0] for _ in range(10)]
    simulation.close()
    assert to_rrd.main([str(mcap), '-o', str(tmp_path / 'run.rrd')]) == 0
    _, content, _, _ = read(tmp_path / 'run.rrd')
    vectors = content[(f'/{AGENTS}', 'Arrows2D:vectors')]
    labels = content[(f'/{LABELS}', 'Points2D:labels')]
    assert shown_at(labels, 10)[:2] == ['ball_2', 'ball_4']
    yaw = float(records[10].agents.yaws[1])
    radius = float(records[10].radii[4])
    assert shown_at(vectors, 10)[1] == pytest.approx(
        [HEADING_RADII * radius * math.cos(yaw), HEADING_RADII * radius * math.sin(yaw)],
        rel=1e-6)


def test_a_bumper_hit_is_drawn_along_the_impulse_then_cleared(tmp_path):
    from ball_world.recording.rerun_agents import BUMPER_SHOWN, BUMPERS
    path = tmp_path / 'run.rrd'
    # ball_0 (an agent, heading 0.8 rad) hit head on by ball_1 coming along -x.
    simulation = Simulation({'rate_hz': 100.0, 'random.count': 0, 'arena': [],
                             'agents': ['ball_0'], 'balls.x': [0.0, 1.5],
                             'balls.y': [0.0, 0.0], 'balls.vx': [0.0, -3.0],
                             'balls.vy': [0.0, 0.0], 'balls.radius': [0.5, 0.5],
                             'balls.mass': [2.0, 1.0], 'agent.scan.samples': 0},
                            sinks=[RerunSink(path)])
    simulation.set_state('ball_0', 0.0, 0.0, 0.0, 0.0, yaw=0.8)
    hit = None
    for _ in range(120):
        record, _ = simulation.step()
        if record.agents.bumpers and hit is None:
            hit = record.step
    simulation.close()
    _, content, _, _ = read(path)
    vectors = content[(f'/{BUMPERS}', 'Arrows2D:vectors')]
    labels = content[(f'/{BUMPERS}', 'Arrows2D:labels')]
    casing, vector = shown_at(vectors, hit)  # cased (rerun_casing): casing, then arrow
    assert casing == vector
    assert vector[1] == pytest.approx(0.0, abs=1e-6) and vector[0] < 0.0  # pushed along -x
    assert shown_at(labels, hit) == ['', 'ball_0 hit 4 N s']  # 2 m1 m2 / (m1 + m2) x 3 m/s
    assert shown_at(vectors, hit + round(BUMPER_SHOWN * 100) + 1) in ([], None)
    # The label is kept, not shown: a tag under the arrow's middle draws it (rerun_text).
    assert content[(f'/{BUMPERS}', 'Arrows2D:show_labels')][hit] == [False, False]
    origin = shown_at(content[(f'/{BUMPERS}', 'Arrows2D:origins')], hit)[1]
    [centre] = shown_at(content[(f'/{BUMPERS}', 'Boxes2D:centers')], hit)
    assert centre[0] == pytest.approx(origin[0] + 0.5 * vector[0], abs=1e-5)
    assert centre[1] < origin[1] + 0.5 * vector[1]  # the tag hangs below the middle
    strips = shown_at(content[(f'/{BUMPERS}', 'LineStrips2D:strips')], hit)
    assert len(strips) == len(strokes('ball_0 hit 4 N s'))
    for key in ('Boxes2D:centers', 'LineStrips2D:strips'):
        assert shown_at(content[(f'/{BUMPERS}', key)],
                        hit + round(BUMPER_SHOWN * 100) + 1) in ([], None), key
