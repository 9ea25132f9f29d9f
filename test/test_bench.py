"""ball_world_bench runs end to end in its quick configuration and reports what it promises.

No timing is asserted (machines differ); only that every section is produced, that both
backends have a number at every N, that exact mode is timed beside seed mode on every gas
scene, that the default backend is named, and that the energy change is rounding noise.
"""
from pathlib import Path

from benchmarks.bench import (bench_worst_case, main, many_walls_world, parse_args,
                              radius_spread_world)
import numpy as np

from ball_world.core import limits
from ball_world.core.broadphase import grid_pairs

PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def _section(text, heading):
    """Lines of the markdown section whose heading starts with `heading`."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f'## {heading}'))
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith('## ')),
               len(lines))
    return lines[start:end]


def _cells(line):
    return [cell.strip() for cell in line.strip().strip('|').split('|')]


def test_quick_benchmark_writes_table_and_plot(tmp_path, capsys):
    png = tmp_path / 'b.png'
    table = tmp_path / 'b.md'

    assert main(['--quick', '--plot', str(png), '--markdown', str(table)]) == 0

    assert png.read_bytes().startswith(PNG_SIGNATURE)
    text = table.read_text()
    rates = [_cells(line) for line in _section(text, 'Steps per second')
             if line.startswith('| ')]
    header, rows = rates[0], rates[1:]
    ours = [header.index('ball_world (numpy)'), header.index('ball_world (numba)')]
    ratios = [header.index('ball_world (numpy) / pymunk'),
              header.index('ball_world (numba) / pymunk')]
    by_n = {row[0]: row for row in rows}
    assert set(by_n) == {'100', '300'}
    for row in by_n.values():
        for column in ours + ratios:
            assert float(row[column].replace(',', '')) > 0.0
    assert '- Default backend: physics.backend auto = numba' in text

    exact = [_cells(line) for line in _section(text, 'Exact mode beside seed mode')
             if line.startswith('| ')]
    header, rows = exact[0], exact[1:]
    seed_column, exact_column, ratio_column = (header.index('seed (numba) steps/s'),
                                               header.index('exact steps/s'),
                                               header.index('exact / seed'))
    assert [(row[0].split(' (')[0], row[1]) for row in rows] == [
        ('dilute', '300'), ('dense, fast', '300'), ('node scene', '10,000')]
    for row in rows:
        seed_rate, exact_rate, ratio = (float(row[column].replace(',', ''))
                                        for column in (seed_column, exact_column, ratio_column))
        assert seed_rate > 0.0 and exact_rate > 0.0
        assert abs(ratio - exact_rate / seed_rate) <= 0.01 * ratio + 0.01  # rounding only

    scans = [_cells(line) for line in _section(text, 'Lidar: one 360-beam scan')
             if line.startswith('| ')]
    assert [row[0] for row in scans[1:]] == ['300']

    agents = [_cells(line) for line in _section(text, 'Agents at 300 balls')
              if line.startswith('| ')]
    assert [row[0] for row in agents[1:]] == ['0', '10', '100']
    assert agents[1][2] == '1.00'  # the row without agents is the unit
    assert all(float(row[1]) > 0.0 for row in agents[1:])

    printed = capsys.readouterr().out
    energy = [_cells(line) for line in _section(printed, 'Kinetic energy')
              if line.startswith('| ball_world (')]
    assert len(energy) == 2
    for row in energy:
        assert abs(float(row[3])) < 1e-12


def test_worst_case_worlds_are_inside_the_limits_and_step_on_both_backends(capsys):
    for make in (radius_spread_world, many_walls_world):
        positions, velocities, radii, masses, walls = make(2000, np.random.default_rng(0))
        assert len(positions) > 1000
        assert radii.max() <= limits.MAX_RADIUS_RATIO * radii.min()
        assert len(walls) <= limits.MAX_WALLS
        a, _, _ = grid_pairs(positions, radii, 0.0)
        assert len(a) == 0  # nothing overlaps at the start
    rows = bench_worst_case(2000, 2, seed=0)
    assert [(row[0], row[3]) for row in rows] == [
        ('radius ratio 100', 'numba'), ('radius ratio 100', 'numpy'),
        (f'{limits.MAX_WALLS:,} walls', 'numba'), (f'{limits.MAX_WALLS:,} walls', 'numpy')]
    assert all(row[5] > 0.0 for row in rows)


def test_results_go_to_runs_unless_the_docs_are_asked_for():
    # `make bench` for one's own numbers must not dirty the tracked docs/bench.md and .png.
    default = parse_args([])
    assert (default.markdown, default.plot) == (Path('runs/bench.md'), Path('runs/bench.png'))
    docs = parse_args(['--docs'])
    assert (docs.markdown, docs.plot) == (Path('docs/bench.md'), Path('docs/bench.png'))
    chosen = parse_args(['--docs', '--markdown', 'a.md'])
    assert (chosen.markdown, chosen.plot) == (Path('a.md'), Path('docs/bench.png'))
