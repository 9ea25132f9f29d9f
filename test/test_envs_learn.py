"""Navigate-v0's observation outside the environment: what a controller builds from plain
arrays (a scan, a pose, a goal, a twist) is the environment's bit for bit."""
import numpy as np
import pytest

from ball_world.core.agents import world_to_body
from ball_world.envs.navigate import NavigateEnv
from ball_world.envs.observations import navigate_observation

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
