"""ball_world_bench runs end to end in its quick configuration and reports what it promises.

No timing is asserted (machines differ); only that every section is produced, that our
engine has a number at every N, and that its energy change is rounding noise.
"""
from benchmarks.bench import main

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
    by_n = {row[0]: row for row in rows}
    assert set(by_n) == {'100', '300'}
    for row in by_n.values():
        for column in ours:
            assert float(row[column].replace(',', '')) > 0.0

    printed = capsys.readouterr().out
    energy = [_cells(line) for line in _section(printed, 'Kinetic energy')
              if line.startswith('| ball_world (')]
    assert len(energy) == 2
    for row in energy:
        assert abs(float(row[3])) < 1e-12
