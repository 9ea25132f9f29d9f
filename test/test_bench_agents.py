"""benchmarks.agents runs and reports a row per number of agents (no timing is asserted)."""
from benchmarks.agents import main


def test_agents_benchmark_reports_each_count_against_none(capsys):
    assert main(['--n', '300', '--agents', '5', '20', '--steps', '5']) == 0
    out = capsys.readouterr().out
    rows = [line.split('|')[1:-1] for line in out.splitlines() if line.startswith('| ')][1:]
    assert [int(row[0]) for row in rows] == [0, 5, 20]
    assert float(rows[0][2]) == 1.0 and all(float(row[1]) > 0.0 for row in rows)
