"""scripts/setup.sh's stamp of the package: `make run` reinstalls ball_world and recompiles its
numba kernels only when what they are made from changed. Checked on a copy of the tree, since
running set-up itself takes minutes (by hand, 2026-12-01 on the loaded 2-core machine: 1 min
55 s after a change, then 1.8 s and no output)."""
import os
from pathlib import Path
import shutil
import subprocess

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: What the stamp reads, and a few things it must not.
COPIED = ('ball_world', 'setup.py', 'setup.cfg', 'package.xml', 'resource', 'config', 'launch',
          'rviz', 'scripts/setup.sh', 'README.md', 'test/test_setup.py')


@pytest.fixture
def tree(tmp_path):
    for name in COPIED:
        source, target = ROOT / name, tmp_path / name
        if source.is_dir():
            shutil.copytree(source, target, ignore=shutil.ignore_patterns('__pycache__'))
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    return tmp_path


def stamp(tree):
    done = subprocess.run([str(tree / 'scripts' / 'setup.sh'), '--package-stamp'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stderr == '', done.stderr
    value = done.stdout.strip()
    assert len(value) == 64 and int(value, 16) >= 0, value
    return value


def test_stamp_stays_while_nothing_the_package_is_made_from_changes(tree):
    before = stamp(tree)
    assert stamp(tree) == before
    (tree / 'README.md').write_text('edited\n')
    (tree / 'test' / 'test_setup.py').write_text('edited\n')
    cache = tree / 'ball_world' / 'core' / '__pycache__'
    cache.mkdir()
    (cache / 'world.seed_step-1.py312.nbi').write_bytes(b'kernel')  # what warming writes
    assert stamp(tree) == before


@pytest.mark.parametrize('change', ['edit', 'touch', 'add', 'remove', 'config'])
def test_stamp_changes_with_any_installed_file(tree, change):
    module = tree / 'ball_world' / 'core' / 'rules.py'
    before = stamp(tree)
    if change == 'edit':  # same size, other content, and a later modification time
        text = module.read_text()
        module.write_text(text.replace('a', 'b', 1))
        os.utime(module, ns=(module.stat().st_atime_ns, module.stat().st_mtime_ns + 10**9))
    elif change == 'touch':  # numba's cache keys on the time: it would recompile
        os.utime(module, ns=(module.stat().st_atime_ns, module.stat().st_mtime_ns + 10**9))
    elif change == 'add':
        (tree / 'ball_world' / 'tools' / 'new_tool.py').write_text('"""A new tool."""\n')
    elif change == 'remove':
        (tree / 'ball_world' / 'tools' / 'sim.py').unlink()
    else:
        (tree / 'config' / 'ball_world.yaml').write_text('edited\n')
    assert stamp(tree) != before
