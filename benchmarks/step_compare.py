"""The seed step of a world without a map against the step before the static index, side by side.

Issue 33: the static index (commit 6c90059, core/static_geometry.py) slowed the step of a
plain box by 11-16%; a box must not pay for maps. This measures it in one run: the package as
it was at BEFORE (6c90059's parent, taken from git with `git archive` into runs/step_compare/,
nothing checked out) and the package of this checkout, each in a child process of its own
(two versions of one package cannot share a process), stepping the benchmark's scene
(benchmarks.scenes: equal balls at 20% area fraction in a box, numba backend). The children
run in alternating rounds (a busy core slows both alike) and time themselves in their
thread's CPU time (time.thread_time); the ratio of the medians is the figure. Each child also
steps a fresh copy of the scene a few hundred steps and reports the SHA-256 of the positions
and velocities: both must be equal, or the two steps do not follow the same trajectories.

    .venv/bin/python -m benchmarks.step_compare [--n 1000 10000 100000] [--rounds 7]

bench.py runs it as a section (`make bench`; `--compare-n` with no value skips it). The first
run compiles the old package's kernels into runs/step_compare/ (about 20 s); later runs find
them there.
"""
import argparse
import hashlib
import os
from pathlib import Path
import shutil
import statistics
import subprocess
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
#: The last commit before the static index: the step a plain box is compared with.
BEFORE = '6c90059^'
#: Steps of the trajectory check.
CHECK_STEPS = 300


def _child(n):
    """Serve the parent: 'run SECONDS' steps for about that much CPU time and prints steps per
    CPU second; 'check' prints the trajectory's digest; 'quit' ends."""
    from benchmarks.scenes import OurEngine, Scene
    from ball_world.core.world import World  # noqa: F401 - the package under test, loaded

    engine = OurEngine(Scene(n), backend='numba')
    engine.run(20)  # compiled and warm
    print('ready', flush=True)
    for line in sys.stdin:
        words = line.split()
        if words[0] == 'run':
            seconds = float(words[1])
            steps = 0
            start = time.thread_time()
            while True:
                engine.run(1)
                steps += 1
                spent = time.thread_time() - start
                if spent >= seconds:
                    break
            print(f'{steps / spent!r}', flush=True)
        elif words[0] == 'check':
            fresh = OurEngine(Scene(n), backend='numba')
            fresh.run(CHECK_STEPS)
            digest = hashlib.sha256(fresh.world.positions.tobytes()
                                    + fresh.world.velocities.tobytes()).hexdigest()
            print(digest, flush=True)
        else:
            return


class _Side:
    """One package's child process."""

    def __init__(self, name, package_root, n):
        self.name = name
        env = dict(os.environ, PYTHONPATH=os.pathsep.join((str(package_root), str(ROOT))))
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'benchmarks.step_compare', '--child', str(n)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=str(ROOT))
        self._expect('ready')

    def _expect(self, word=None):
        line = self.process.stdout.readline().strip()
        if not line or (word is not None and line != word):
            raise RuntimeError(f'the {self.name} step stopped (exit {self.process.wait()})')
        return line

    def ask(self, command):
        self.process.stdin.write(command + '\n')
        self.process.stdin.flush()
        return self._expect()

    def close(self):
        if self.process.poll() is None:
            self.process.stdin.write('quit\n')
            self.process.stdin.close()
            self.process.wait(timeout=30)


def export_before(folder=ROOT / 'runs' / 'step_compare'):
    """The package at BEFORE, exported from git into `folder` once (then reused, with its
    compiled kernels): (folder, None), or (None, why not)."""
    folder = Path(folder)
    if (folder / 'ball_world' / 'core' / 'world.py').is_file():
        return folder, None
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    try:
        archive = subprocess.run(['git', '-C', str(ROOT), 'archive', BEFORE, 'ball_world'],
                                 capture_output=True, check=True).stdout
        subprocess.run(['tar', '-x', '-C', str(folder)], input=archive, check=True)
    except (OSError, subprocess.CalledProcessError) as error:
        shutil.rmtree(folder, ignore_errors=True)
        return None, f'git archive {BEFORE} failed ({error}): not a git checkout?'
    return folder, None


def compare(sizes, rounds, seconds, out=print):
    """Rows (n, before steps/s, now steps/s, now/before, trajectories equal) measured side by
    side; None (and a line saying why) when the old package cannot be had."""
    before, why = export_before()
    if before is None:
        out(f'skipped: {why}')
        return None
    rows = []
    for n in sizes:
        sides = [_Side('before', before, n), _Side('now', ROOT, n)]
        try:
            rates = {side.name: [] for side in sides}
            for round_index in range(rounds):
                order = sides if round_index % 2 == 0 else sides[::-1]
                for side in order:
                    rates[side.name].append(float(side.ask(f'run {seconds}')))
            same = len({side.ask('check') for side in sides}) == 1
        finally:
            for side in sides:
                side.close()
        old = statistics.median(rates['before'])
        new = statistics.median(rates['now'])
        rows.append((n, old, new, new / old, same))
        out(f'{n:>7,} balls: before the static index {old:,.1f} steps/s, now {new:,.1f} '
            f'({new / old - 1.0:+.1%}); trajectories {"equal" if same else "DIFFER"}')
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.step_compare',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--n', type=int, nargs='+', default=[1000, 10000, 100000])
    parser.add_argument('--rounds', type=int, default=7, help='alternating timed rounds')
    parser.add_argument('--seconds', type=float, default=1.0, help='CPU seconds per round')
    parser.add_argument('--child', type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        _child(args.child)
        return
    print(f'The seed step (numba) of the benchmark scene against {BEFORE} (before '
          'core/static_geometry.py), alternating rounds, CPU time; medians:')
    compare(args.n, args.rounds, args.seconds)


if __name__ == '__main__':
    main()
