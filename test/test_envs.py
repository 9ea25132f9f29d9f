"""ball_world/Navigate-v0 (ball_world.envs): Gymnasium's own checker, seeds that replay an
episode bit for bit, an episode that is a ball_world run (the node's Simulation, driven with
the same commands, steps through the same states and scans the same ranges), the rewards'
closed forms, truncation, and every bad option refused in one line."""
import math
import warnings

import gymnasium
from gymnasium.utils.env_checker import check_env
from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

import ball_world.envs  # noqa: F401 - registers Navigate-v0
from ball_world.envs import layout, rewards
from ball_world.envs.navigate import NavigateEnv
from ball_world.envs.runs import episode_parameters, initial_headings
from ball_world.simulation import Simulation

NAVIGATE = 'ball_world/Navigate-v0'
#: A small walled world (no map: cheap to build): one fixed ball, five random ones.
BOX = {'arena': [-2.0, -1.5, 2.0, 1.5], 'balls.x': [1.2], 'balls.y': [0.9],
       'balls.vx': [0.3], 'balls.vy': [-0.2], 'balls.radius': [0.15], 'balls.mass': [0.5],
       'random.count': 5, 'random.radius': [0.08, 0.15], 'random.speed': 0.6,
       'random.seed': 4, 'agent.max_speed': 0.4, 'agent.max_yaw_rate': 2.0,
       'agent.scan.range_max': 3.5}
#: The only warning Gymnasium's checker gives: the action is (m/s, rad/s) within the
#: robot's limits, as the interface fixes it, not a normalised [-1, 1].
ACTION_WARNING = 'symmetric and normalized space'
#: One environment the property test reuses across its examples (a reset per example).
SHARED = {}


def actions(env, count, seed):
    space = env.action_space
    space.seed(seed)
    return [space.sample() for _ in range(count)]


def run(env, seed, moves):
    """(observations, rewards, ends) of an episode from reset(seed) under `moves`, resetting
    (unseeded) whenever an episode ends."""
    observed, _ = env.reset(seed=seed)
    seen, paid, ends = [observed], [], []
    for move in moves:
        observed, reward, terminated, truncated, _ = env.step(move)
        seen.append(observed)
        paid.append(reward)
        ends.append((terminated, truncated))
        if terminated or truncated:
            observed, _ = env.reset()
            seen.append(observed)
    return seen, paid, ends


def same(first, second):
    """Whether two runs are equal bit for bit."""
    seen_a, paid_a, ends_a = first
    seen_b, paid_b, ends_b = second
    return (len(seen_a) == len(seen_b) and ends_a == ends_b
            and np.array_equal(np.array(paid_a), np.array(paid_b))
            and all(a[key].tobytes() == b[key].tobytes() for a, b in zip(seen_a, seen_b)
                    for key in a))


def test_gymnasium_checker_passes_on_the_sandbox():
    env = gymnasium.make('ball_world.envs:' + NAVIGATE)  # the default world: the sandbox
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        check_env(env.unwrapped)
    others = [str(w.message) for w in caught if ACTION_WARNING not in str(w.message)]
    assert not others
    space = env.observation_space
    assert space['scan'].shape == (90,) and space['scan'].high[0] == np.float32(3.5)
    assert env.action_space.high.tolist() == [np.float32(0.22), np.float32(2.84)]
    observed, _ = env.reset(seed=1)
    assert space.contains(observed)
    env.close()


def test_the_same_seed_gives_the_same_episodes_bit_for_bit():
    first = gymnasium.make(NAVIGATE, world=BOX, max_episode_steps=25)
    second = gymnasium.make(NAVIGATE, world=BOX, max_episode_steps=25)
    moves = actions(first, 60, 3)
    reference = run(first, 11, moves)
    assert sum(end != (False, False) for end in reference[2]) >= 2  # resets inside
    run(second, 12, moves[:7])  # another episode first: nothing of it may remain
    assert same(run(second, 11, moves), reference)
    assert not same(run(second, 12, moves), reference)


@pytest.mark.parametrize('mode, seed', [('seed', 5), ('exact', 6)])
def test_an_episode_is_a_ball_world_run(mode, seed):
    """A Simulation of the episode's parameters, driven by the same commands, passes through
    the episode's states bit for bit and its agent scans the observed ranges (seed-mode and
    exact physics)."""
    env = NavigateEnv(world={**BOX, 'physics.mode': mode}, beams=30, control_hz=10.0)
    observed, _ = env.reset(seed=seed)
    task = env.task
    arenas = task.arenas
    simulation = Simulation(episode_parameters(task))
    for name, x, y, yaw in initial_headings(task):
        simulation.set_state(name, x, y, 0.0, 0.0, yaw=yaw)
    world = arenas.worlds[0]
    assert simulation.world.positions.tobytes() == world.positions.tobytes()
    for move in actions(env, 40, 8):
        observed, _, terminated, _, _ = env.step(move)
        forward, turn = arenas.commands[0].tolist()
        simulation.command('ball_0', forward, 0.0, turn)
        for _ in range(arenas.substeps):
            record, rejected = simulation.step()
            assert not rejected
        assert record.positions.tobytes() == world.positions.tobytes()
        assert record.velocities.tobytes() == world.velocities.tobytes()
        assert simulation.agents.yaws().tobytes() == arenas.agents.yaws().tobytes()
        (scan,) = record.agents.scans
        ranges = np.clip(np.nan_to_num(scan.ranges, posinf=3.5, neginf=0.0), 0.0, 3.5)
        assert ranges.astype(np.float32).tobytes() == observed['scan'].tobytes()
        if terminated:
            break


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_every_episode_starts_clear_and_observes_within_its_space(seed):
    """Whatever the seed: the robot starts clear of walls and balls, its goal at least
    MIN_GOAL_DISTANCE away and clear of the walls, and the observation lies in the space."""
    env = SHARED.setdefault('env', NavigateEnv(world=BOX, beams=12))
    observed, _ = env.reset(seed=seed)
    assert env.observation_space.contains(observed)
    arenas = env.task.arenas
    world = arenas.worlds[0]
    robot, others = world.positions[0], world.positions[1:]
    gaps = np.hypot(*(others - robot).T) - world.radii[1:] - world.radii[0]
    assert gaps.min() >= layout.CLEARANCE
    xmin, ymin, xmax, ymax = BOX['arena']
    for x, y in (robot, arenas.goals[0]):
        reach = world.radii[0] + layout.CLEARANCE
        assert xmin + reach <= x <= xmax - reach and ymin + reach <= y <= ymax - reach
    assert np.hypot(*(arenas.goals[0] - robot)) >= layout.MIN_GOAL_DISTANCE
    observed, *_ = env.step(env.action_space.sample())
    assert env.observation_space.contains(observed)


def test_reward_closed_forms():
    before = np.array([2.0, 1.0, 0.3, 1.0])
    after = np.array([1.9, 1.1, 0.15, 1.0])
    impulses = np.array([0.0, 0.0, 0.0, 0.44])  # the last: a 1 kg robot bouncing at 0.22 m/s
    outcome = rewards.outcome(before, after, impulses, 1.0, 0.22, False)
    expected = [10.0 * 0.1 - 0.01, -10.0 * 0.1 - 0.01, 10.0 * 0.15 - 0.01 + 10.0,
                -2.0 - 0.01]
    assert outcome.reward == pytest.approx(expected, abs=1e-12)
    assert outcome.terminated.tolist() == [False, False, True, False]
    assert outcome.hard.tolist() == [False, False, False, True]
    hard = rewards.outcome(before, after, impulses, 1.0, 0.22, True)
    assert hard.terminated.tolist() == [False, False, True, True]


def test_a_robot_driven_at_its_goal_reaches_it_and_the_episode_ends():
    env = NavigateEnv(world={**BOX, 'random.count': 0, 'balls.x': [], 'balls.y': [],
                             'balls.vx': [], 'balls.vy': [], 'balls.radius': [],
                             'balls.mass': []}, control_hz=5.0)
    observed, _ = env.reset(seed=2)
    start = float(observed['goal'][0])
    total = 0.0
    for _ in range(200):
        distance, bearing = observed['goal'].tolist()
        move = np.array([0.4 if abs(bearing) < 0.3 else 0.0, 3.0 * bearing], np.float32)
        observed, reward, terminated, truncated, info = env.step(move)
        total += reward
        if terminated:
            break
    assert terminated and info['success'] and not truncated
    assert observed['goal'][0] <= rewards.GOAL_TOLERANCE
    # Progress pays the distance covered (start to the end's distance), once.
    assert total > rewards.PROGRESS * (start - rewards.GOAL_TOLERANCE) + rewards.SUCCESS - 2.0


def test_max_episode_steps_truncates():
    env = gymnasium.make(NAVIGATE, world=BOX, max_episode_steps=3)
    env.reset(seed=0)
    stay = np.zeros(2, np.float32)
    ends = [env.step(stay)[3] for _ in range(3)]
    assert ends == [False, False, True]


@pytest.mark.parametrize('options, words', [
    ({'control_hz': 7.0}, 'control_hz 7'),
    ({'control_hz': 0}, 'control_hz must be a number > 0'),
    ({'beams': 0}, 'beams must be a whole number >= 1'),
    ({'world': 'no/such/world.yaml'}, 'cannot read it'),
    ({'world': 'atlantis'}, "world 'atlantis': no such file"),
    ({'world': {'arena': [], 'random.count': 0}}, 'need a bounded world'),
    ({'world': {**BOX, 'random.count': 500}}, 'random.count'),
    ({'world': {**BOX, 'random.speed': 230.0, 'dt': 0.05}}, 'lower random.speed'),
    ({'world': {**BOX, 'agent.max_speed': 1e4}}, 'agent.max_speed'),
])
def test_bad_options_are_refused_in_one_line(options, words):
    with pytest.raises(ValueError) as caught:
        NavigateEnv(**{'world': BOX, **options})
    message = str(caught.value)
    assert words in message and '\n' not in message


def test_a_bad_action_is_refused_in_one_line():
    env = NavigateEnv(world=BOX)
    env.reset(seed=0)
    with pytest.raises(ValueError, match='actions must be finite'):
        env.step(np.array([math.nan, 0.0]))
