"""What make learn stands on, without stable-baselines3 or torch: the observation a controller
builds from plain arrays is the environment's bit for bit; the SB3 adapter (envs.sb3) plays
Navigate-v0's own episodes with SB3's same-step resets; the evaluation counts each seeded
episode once; a saved policy's actions come back in the robot's units; and what cannot be
used is refused in one line."""
import math
import sys

import gymnasium
import numpy as np
import pytest

from ball_world.core.agents import world_to_body
import ball_world.envs  # noqa: F401 - registers Navigate-v0
from ball_world.envs.evaluate import evaluate
from ball_world.envs.navigate import NavigateEnv
from ball_world.envs.observations import navigate_observation
from ball_world.envs.policy import load_policy, Policy, PolicyError
from ball_world.envs.sb3 import NavigateSB3Env, PolicyScale
from ball_world.tools import learn

NAVIGATE = 'ball_world/Navigate-v0'
#: A small walled world (no map: cheap), noisy scans (the clip to range_max is exercised).
BOX = {'arena': [-2.0, -1.5, 2.0, 1.5], 'random.count': 5, 'random.radius': [0.08, 0.15],
       'random.speed': 0.6, 'agent.max_speed': 0.4, 'agent.max_yaw_rate': 2.0,
       'agent.scan.range_max': 3.0, 'agent.scan.noise_stddev': 0.05}
BEAMS = 24


def test_a_controller_builds_the_envs_observation_bit_for_bit_from_plain_arrays():
    env = NavigateEnv(world=BOX, beams=BEAMS)
    observed, _ = env.reset(seed=3)
    env.action_space.seed(3)
    arenas = env.task.arenas
    clipped = 0
    for step in range(25):
        if step:
            observed, *_ = env.step(env.action_space.sample())
        positions, yaws, velocities = arenas.robot_state()
        yaw = float(yaws[0])
        # What a node has: the LaserScan's float32 ranges (REP 117's infinities kept), the
        # pose, the goal and odom's body twist.
        ranges = arenas.scans([0])[0].astype(np.float32)
        forward, _ = world_to_body(yaw, *velocities[0].tolist())
        built = navigate_observation(ranges, (*positions[0].tolist(), yaw), arenas.goals[0],
                                     (forward, float(arenas.yaw_rates()[0])),
                                     env.observation_space)
        assert built.keys() == observed.keys()
        for key in observed:
            assert built[key].dtype == observed[key].dtype
            assert built[key].tobytes() == observed[key].tobytes(), (step, key)
        clipped += int((ranges > 3.0).sum())
    assert clipped  # noise pushed ranges past range_max, and both clipped them alike
    with pytest.raises(ValueError, match='23 ranges for a 24-beam scan'):
        navigate_observation(ranges[:-1], (0.0, 0.0, 0.0), (1.0, 1.0), (0.0, 0.0),
                             env.observation_space)


def test_the_sb3_adapter_plays_navigates_episodes_with_same_step_resets():
    # Half-second steps: goals are reached (terminated) within the 12 steps, or not (truncated).
    options = dict(world=BOX, beams=BEAMS, control_hz=2.0, max_episode_steps=12,
                   terminate_on_collision=True)
    count = 2
    ours = NavigateSB3Env(count, **options)
    singles = [gymnasium.make(NAVIGATE, **options) for _ in range(count)]
    scale = ours.scale
    assert ours.seed(40) == [40, 41]
    inputs = ours.reset()
    wanted = [env.reset(seed=40 + world)[0] for world, env in enumerate(singles)]
    assert inputs.dtype == np.float32 and inputs.shape == (count, BEAMS + 4)
    for world in range(count):
        assert inputs[world].tobytes() == scale.inputs(batch(wanted[world]))[0].tobytes()
    rng = np.random.default_rng(1)
    ends = truncations = 0
    for _ in range(40):
        # Toward the goal, with noise beyond [-1, 1] (clipped as SB3 clips PPO's actions).
        actions = steer(inputs) + rng.normal(0.0, 0.4, (count, 2)).astype(np.float32)
        inputs, rewards, dones, infos = ours.step(actions)
        assert rewards.dtype == np.float32 and dones.dtype == bool
        for world, env in enumerate(singles):
            command = np.clip(actions[world], -1.0, 1.0) * np.array([0.4, 2.0])
            observed, reward, terminated, truncated, info = env.step(command)
            assert rewards[world] == np.float32(reward)
            assert dones[world] == (terminated or truncated)
            assert infos[world]['success'] == info['success']
            last = scale.inputs(batch(observed))[0]
            if terminated or truncated:
                ends += 1
                truncations += truncated and not terminated
                assert infos[world]['terminal_observation'].tobytes() == last.tobytes()
                assert infos[world]['TimeLimit.truncated'] == (truncated and not terminated)
                observed, _ = env.reset()  # the episode after it, from the same generator
                last = scale.inputs(batch(observed))[0]
            else:
                assert 'terminal_observation' not in infos[world]
            assert inputs[world].tobytes() == last.tobytes()
    assert truncations >= 4 and ends > truncations  # both ends were met, and reset after


def batch(observed):
    return {key: value[None] for key, value in observed.items()}


def steer(inputs):
    """A scripted policy on policy inputs: turn toward the goal, drive when facing it."""
    bearing = inputs[:, BEAMS + 1] * math.pi
    return np.stack((np.where(np.abs(bearing) < 0.3, 1.0, 0.0),
                     np.clip(bearing, -1.0, 1.0)), axis=1).astype(np.float32)


def test_the_evaluation_counts_each_seeded_episode_once_as_the_single_env_ends_it():
    options = dict(world=BOX, beams=BEAMS, max_episode_steps=60)
    result = evaluate(steer, 6, 70, **options)
    scale = NavigateSB3Env(1, **options).scale
    env = gymnasium.make(NAVIGATE, **options)
    success, steps, returns = [], [], []
    for seed in range(70, 76):
        observed, _ = env.reset(seed=seed)
        total, count = 0.0, 0
        while True:
            move = scale.commands(steer(scale.inputs(batch(observed))))[0]
            observed, reward, terminated, truncated, info = env.step(move)
            total += np.float32(reward)
            count += 1
            if terminated or truncated:
                break
        success.append(info['success'])
        steps.append(count)
        returns.append(total)
    assert result.success.tolist() == success
    assert result.steps.tolist() == steps
    assert np.allclose(result.returns, returns)
    assert 0 < sum(success) < 6  # some reached their goal within 60 steps, some did not
    assert result.rate == sum(success) / 6


class Fixed:
    """A stand-in for an SB3 model: the same action whatever it is shown."""

    def __init__(self, action):
        self.action = np.array([action], np.float32)
        self.shown = []

    def predict(self, inputs, deterministic=False):
        self.shown.append((inputs, deterministic))
        return self.action, None


def test_a_policy_takes_the_envs_observation_and_returns_the_robots_units():
    env = NavigateEnv(world=BOX, beams=BEAMS)
    observed, _ = env.reset(seed=5)
    scale = PolicyScale.of(env.task)
    model = Fixed([0.5, -2.0])
    policy = Policy(model, scale, env.observation_space, {'world': BOX})
    assert policy(observed) == (0.5 * 0.4, -1.0 * 2.0)  # clipped to [-1, 1], then scaled
    inputs, deterministic = model.shown[0]
    assert deterministic and inputs.tobytes() == scale.inputs(batch(observed)).tobytes()
    assert inputs[0, 0] == np.float32(observed['scan'][0] / 3.0)
    assert inputs[0, BEAMS:].tolist() == pytest.approx(
        [observed['goal'][0] / scale.reach, observed['goal'][1] / math.pi,
         observed['twist'][0] / 0.4, observed['twist'][1] / 2.0], rel=1e-6)
    with pytest.raises(ValueError, match='23 ranges for a policy of 24 beams'):
        policy({**observed, 'scan': observed['scan'][:-1]})
    # Many robots at once (a swarm's controller): each row as alone.
    model.action = np.array([[0.25, 1.0], [-1.5, 0.1]], np.float32)
    both = {key: np.stack([value, value]) for key, value in observed.items()}
    assert policy.commands(both).tolist() == [[0.1, 2.0], [-0.4, float(np.float32(0.1)) * 2.0]]
    assert model.shown[-1][0].tobytes() == np.concatenate([inputs, inputs]).tobytes()


def test_what_cannot_be_used_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    with pytest.raises(PolicyError, match="no policy file '.*nothing.zip'"):
        load_policy(tmp_path / 'nothing.zip')
    with pytest.raises(SystemExit) as stop:
        learn.main(['evaluate', str(tmp_path / 'nothing.zip')])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith('ball_world_learn: no policy file') and err.count('\n') == 1
    (tmp_path / 'policy.zip').write_bytes(b'not a zip')
    monkeypatch.setitem(sys.modules, 'stable_baselines3', None)  # as if not installed
    with pytest.raises(SystemExit):
        learn.main(['evaluate', str(tmp_path / 'policy.zip')])
    err = capsys.readouterr().err
    assert 'stable-baselines3 is not installed' in err and 'make learn' in err
    assert err.count('\n') == 1
    with pytest.raises(ValueError, match='episodes must be a whole number >= 1'):
        evaluate(steer, 0, world=BOX)
