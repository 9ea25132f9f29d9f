"""The code follows ament's flake8 conventions (line length 99, single quotes, google imports)."""
from pathlib import Path
import subprocess
import sys

ROOT = Path(__file__).resolve().parents[1]


def test_flake8_is_clean():
    targets = [t for t in ('ball_world', 'ball_world_testing', 'test', 'benchmarks', 'launch',
                           'setup.py')
               if (ROOT / t).exists()]
    result = subprocess.run(
        [sys.executable, '-m', 'flake8', *targets], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
