"""How fast Navigate-v0 steps vectorized: ball_world's own VectorEnv against Gymnasium's
SyncVectorEnv of the single env, side by side (issue 36's figure).

Both hold K worlds of the same world file (the TurtleBot3 sandbox unless --world) with a
--beams lidar, reset with the same seed and driven by the same random actions (autoresets
included), so they do the same work and give the same bits (test/test_envs_vector.py); what
differs is only how the K worlds are stepped. Timed in alternating rounds of --steps
vector steps each (a busy core slows both alike), in the thread's CPU time
(time.thread_time) and in wall time; env steps per second = K x vector steps / time.
Never a timed assertion: this prints a table for docs/learning.md.

The scans' noise is drawn for all robots in one compiled call (core.noise_kernel);
--per-scan-noise adds a third contender, the vector env with the noise drawn as before it:
a reseeded Generator per robot per scan (benchmarks.swarm_speed.per_scan_noise, the same
numbers).

`python -m benchmarks.learning_speed` (options: --envs, --beams, --steps, --rounds, --world,
--per-scan-noise, --profile to print where the vector env's time goes).
"""
import argparse
import contextlib
import statistics
import time

from benchmarks.swarm_speed import per_scan_noise
import gymnasium
import numpy as np

import ball_world.envs  # noqa: F401 - registers Navigate-v0

NAVIGATE = 'ball_world/Navigate-v0'
PER_SCAN = 'VectorEnv, noise per scan'


def parse(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.learning_speed',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--envs', type=int, default=64, help='worlds (default 64)')
    parser.add_argument('--beams', type=int, default=90, help='lidar beams (default 90)')
    parser.add_argument('--steps', type=int, default=100,
                        help='vector steps per round (default 100)')
    parser.add_argument('--rounds', type=int, default=3, help='rounds of each (default 3)')
    parser.add_argument('--world', default=None, help='world file or name (default sandbox)')
    parser.add_argument('--per-scan-noise', action='store_true',
                        help='also time the vector env with the noise drawn scan by scan')
    parser.add_argument('--profile', action='store_true',
                        help="print cProfile's top entries of one round of the vector env")
    return parser.parse_args(argv)


def make(mode, args):
    options = {} if args.world is None else {'world': args.world}
    return gymnasium.make_vec(NAVIGATE, num_envs=args.envs, vectorization_mode=mode,
                              beams=args.beams, **options)


def moves(env, count, seed):
    env.action_space.seed(seed)
    return [env.action_space.sample() for _ in range(count)]


def timed(env, actions):
    """(CPU s, wall s) of stepping `env` through `actions`."""
    cpu, wall = time.thread_time(), time.perf_counter()
    for action in actions:
        env.step(action)
    return time.thread_time() - cpu, time.perf_counter() - wall


def main(argv=None):
    args = parse(argv)
    envs = {'ball_world VectorEnv': make('vector_entry_point', args),
            'SyncVectorEnv': make('sync', args)}
    # Which env draws its noise scan by scan: the patch is open whenever it resets or steps.
    noise = {name: contextlib.nullcontext for name in envs}
    if args.per_scan_noise:
        with per_scan_noise():
            envs[PER_SCAN] = make('vector_entry_point', args)
        noise[PER_SCAN] = per_scan_noise
    actions = moves(envs['SyncVectorEnv'], args.steps, 0)
    for name, env in envs.items():
        with noise[name]():
            env.reset(seed=0)
            timed(env, actions[:5])  # warm: compiled kernels, caches
    times = {name: [] for name in envs}
    for _ in range(args.rounds):
        for name, env in envs.items():
            with noise[name]():
                times[name].append(timed(env, actions))
    rates = {}
    print(f'Navigate-v0, {args.envs} worlds, {args.beams} beams, {args.steps} vector steps '
          f'x {args.rounds} rounds')
    print(f'{"":24} {"env steps/s (CPU)":>18} {"env steps/s (wall)":>19}')
    for name, runs in times.items():
        cpu = statistics.median(run[0] for run in runs)
        wall = statistics.median(run[1] for run in runs)
        rates[name] = args.envs * args.steps / cpu
        print(f'{name:24} {rates[name]:18,.0f} {args.envs * args.steps / wall:19,.0f}')
    print(f'ratio (CPU): {rates["ball_world VectorEnv"] / rates["SyncVectorEnv"]:.2f}x')
    if PER_SCAN in rates:
        print(f'noise in one call / per scan (CPU): '
              f'{rates["ball_world VectorEnv"] / rates[PER_SCAN]:.2f}x')
    if args.profile:
        import cProfile
        import pstats
        env = envs['ball_world VectorEnv']
        profile = cProfile.Profile()
        profile.runcall(timed, env, actions)
        pstats.Stats(profile).sort_stats('tottime').print_stats(20)
    return np.float64(0)


if __name__ == '__main__':
    main()
