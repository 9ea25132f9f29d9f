"""Rerun draws each agent's heading as an arrow from its centre, labelled with its name."""
import math

import numpy as np
import pytest
from test_rerun import read, shown_at

from ball_world.recording.rerun_agents import AGENTS, HEADING_RADII
from ball_world.recording.rerun_log import RerunSink
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
    labels = content[(f'/{AGENTS}', 'Arrows2D:labels')]
    for step in (0, 7, 20):
        record = records[step]
        yaw = float(record.agents.yaws[0])
        assert yaw == pytest.approx(1.5 * step * simulation.dt_ns * 1e-9, abs=1e-12)
        [vector] = shown_at(vectors, step)
        assert vector == pytest.approx([HEADING_RADII * radius * math.cos(yaw),
                                        HEADING_RADII * radius * math.sin(yaw)], rel=1e-6)
        assert shown_at(origins, step) == np.asarray(record.positions[2:3],
                                                     dtype=np.float32).tolist()
        assert shown_at(labels, step) == ['ball_2']


def test_a_world_without_agents_draws_no_arrows(tmp_path):
    path = tmp_path / 'run.rrd'
    simulation = Simulation({'random.count': 3}, sinks=[RerunSink(path)])
    simulation.step()
    simulation.close()
    _, content, _, _ = read(path)
    assert not any(entity == f'/{AGENTS}' for entity, _ in content)
