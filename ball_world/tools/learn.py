"""ball_world_learn: PPO (stable-baselines3) on ball_world/Navigate-v0, trained and evaluated.

    ball_world_learn train [--out runs/navigate_ppo.zip] [--minutes 12] ...
    ball_world_learn evaluate runs/navigate_ppo.zip [--episodes 100] [--seed 1000000]

`train` trains PPO in the TurtleBot3 sandbox (or --world) within a budget of wall time and
env steps, saves the policy, then evaluates it; `evaluate` evaluates a saved one: the success
rate over --episodes seeded episodes (seeds --seed on, deterministic actions) and the wall
times. `make learn` installs stable-baselines3 and torch (requirements/learn.txt) and runs
`train` (docs/learning.md). Without them, or with a missing or foreign policy file, it says
so in one line.
"""
import argparse
from pathlib import Path
import sys
import time

PROG = 'ball_world_learn'
#: The first evaluation seed: far from the training worlds' seeds 0 .. envs - 1.
EVAL_SEED = 1_000_000


def fail(message):
    print(f'{PROG}: {message}', file=sys.stderr)
    raise SystemExit(2)


def parser():
    top = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n')[0])
    commands = top.add_subparsers(dest='command', required=True)
    train = commands.add_parser('train', help='train PPO, save the policy, evaluate it')
    train.add_argument('--out', default='runs/navigate_ppo.zip', help='the policy file')
    train.add_argument('--minutes', type=float, default=15.0,
                       help='most wall minutes of training, whatever --timesteps (default 15)')
    train.add_argument('--timesteps', type=int, default=800_000,
                       help='env steps of training (default 800,000)')
    train.add_argument('--envs', type=int, default=16, help='worlds stepped at once')
    train.add_argument('--seed', type=int, default=0, help='training seed')
    train.add_argument('--threads', type=int, default=1, help="torch's threads")
    train.add_argument('--world', default='sandbox', help="Navigate-v0's world")
    train.add_argument('--beams', type=int, default=90, help='lidar beams')
    for command in (train, commands.add_parser('evaluate', help='evaluate a saved policy')):
        if command is not train:
            command.add_argument('policy', help='a policy file ball_world_learn train saved')
        command.add_argument('--episodes', type=int, default=100,
                             help='seeded evaluation episodes (default 100)')
        command.add_argument('--eval-seed', type=int, default=EVAL_SEED,
                             help=f'the first evaluation seed (default {EVAL_SEED})')
    return top


def report(policy, episodes, seed):
    """Evaluate `policy` and print its success rate and the wall time it took."""
    from ball_world.envs.evaluate import evaluate
    began = time.monotonic()
    result = evaluate(policy.batch, episodes, seed, **policy.options)
    seconds = time.monotonic() - began
    print(f'{PROG}: success {result.success.sum()}/{episodes} episodes ({result.rate:.0%}), '
          f'seeds {seed}..{seed + episodes - 1}, deterministic actions; mean steps '
          f'{result.steps.mean():.0f}, mean return {result.returns.mean():.1f}; '
          f'evaluation {seconds:.0f} s wall')
    return result


def main(args=None):
    options = parser().parse_args(args)
    from ball_world.envs.policy import load_policy, PolicyError
    try:
        if options.command == 'evaluate':
            report(load_policy(options.policy), options.episodes, options.eval_seed)
            return 0
        from ball_world.envs.ppo import train
        if not options.minutes > 0 or options.timesteps < 1 or options.threads < 1:
            fail('--minutes must be > 0, and --timesteps and --threads >= 1')
        out = Path(options.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        _, steps, seconds = train(out, options.minutes, options.timesteps, options.envs,
                                  options.seed, options.threads,
                                  log=lambda line: print(line, flush=True),
                                  world=options.world, beams=options.beams)
        print(f'{PROG}: trained {steps:,} env steps in {seconds / 60:.1f} min wall '
              f'({options.envs} worlds, {options.threads} torch thread(s)); saved {out}')
        report(load_policy(out), options.episodes, options.eval_seed)
    except (PolicyError, ValueError) as error:
        fail(error)
    return 0


if __name__ == '__main__':
    sys.exit(main())
