"""The maps benchmark: its generated warehouse is a nav2 map of a building, and it reports.

No timing is asserted (machines differ): the map must load with the package's loader as the
size the issue names (1-2 million cells, tens of thousands of boundary edges, occupied, free
and unknown cells), come out the same from the same seed, and the report must give a row per
case with positive figures.
"""
import argparse

from benchmarks import map_agents, map_speed, warehouse
import numpy as np
import pytest

from ball_world.core.static_geometry import boundary_runs
from ball_world.map_files import load_map_file


def test_the_warehouse_is_a_nav2_map_of_a_building_and_the_same_from_the_same_seed(tmp_path):
    path = warehouse.write(tmp_path / 'a')
    again = warehouse.write(tmp_path / 'b')
    assert (tmp_path / 'a' / 'warehouse.pgm').read_bytes() == \
        (tmp_path / 'b' / 'warehouse.pgm').read_bytes()
    assert path.read_text() == again.read_text()
    occupancy = load_map_file(str(path))
    data = np.asarray(occupancy.data)
    assert 1_000_000 <= data.size <= 2_000_000
    assert {-1, 0, 100} == set(np.unique(data).tolist())  # unknown, free and occupied
    cells = occupancy.solid_cells().checked()
    solid = cells.solid
    edges = (np.count_nonzero(solid[1:] != solid[:-1])
             + np.count_nonzero(solid[:, 1:] != solid[:, :-1]))
    assert edges > 20_000  # unit boundary edges inside the grid: tens of thousands
    assert len(boundary_runs(cells)) > 10_000


def test_the_report_gives_a_row_per_case(tmp_path):
    args = argparse.Namespace(balls=[300], modes=['seed', 'exact'], scan_balls=[300],
                              repeats=1, seed=1, keep=str(tmp_path))
    lines = map_speed.report(args)
    rows = [line for line in lines if line.startswith('| ') and not line.startswith('| map')
            and not line.startswith('| balls')]
    assert len(rows) == 4  # the load, two step rows and a scan row
    for row in rows:
        cells = [cell.strip().replace(',', '').rstrip('m').strip()
                 for cell in row.strip('|').split('|')]
        numbers = [float(cell.split(' ')[0]) for cell in cells
                   if cell.replace('.', '', 1).split(' ')[0].isdigit()]
        assert numbers and all(value > 0.0 for value in numbers)


@pytest.mark.parametrize('no_messages', [False, True])
def test_the_robots_case_scans_every_tenth_step_and_reports_each_figure(tmp_path, no_messages):
    """benchmarks.map_agents: its agents scan at 10 Hz of the 100 Hz steps (one step in ten,
    all agents at once, 360 beams each), with or without their messages' bytes, and the
    report gives every figure against the 10 ms step."""
    yaml_path = warehouse.write(tmp_path)
    args = argparse.Namespace(balls=40, agents=4, scan_rate=10.0, steps=30, warm_up=5, seed=1,
                              scan_threads=1, no_messages=no_messages)
    took, scanned, in_scans, wall = map_agents.run(yaml_path, args)
    assert len(took) == len(scanned) == len(in_scans) == len(wall) == 30
    assert all(seconds > 0.0 for seconds in wall)
    # Timed steps 6 to 35 (after 5 warm-up steps): scans at steps 10, 20 and 30.
    assert [k for k, scan in enumerate(scanned) if scan] == [4, 14, 24]
    assert all(seconds > 0.0 for seconds, scan in zip(in_scans, scanned) if scan)
    assert all(part <= whole for part, whole in zip(in_scans, took))  # scans within a step
    text = map_agents.report(took, scanned, in_scans, wall, args, '1.0 1.0 1.0')
    rows = [line for line in text.splitlines() if line.startswith('| ') and '---' not in line]
    assert len(rows) == 6  # the header and five figures
    assert 'real-time factor the step allows' in text
    assert ('no robot messages made' in text) == no_messages
