"""A trained policy off its environment: the observation built from a robot's ROS messages
(the node's own LaserScan and Odometry bytes) and from a controller's arrays equals the
environment's bit for bit; a lidar the policy was not trained on, a missing policy file and
the navigate node's bad parameters are each one line. No stable-baselines3 needed."""
import math

from ball_world_testing.harness import run_tool
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import LaserScan

from ball_world.agents import frames
from ball_world.agents.control import Observation
from ball_world.envs.deploy import check_fan, FanMismatch, from_controller, from_messages
from ball_world.envs.navigate import NavigateEnv
from ball_world.msgs.agent_cdr import encode_laser_scan
from ball_world.user_code.controller import ControllerProcess
from ball_world.user_code.describe import UserCodeError

BOX = {'arena': [-2.0, -1.5, 2.0, 1.5], 'random.count': 5, 'random.radius': [0.08, 0.15],
       'random.speed': 0.6, 'agent.max_speed': 0.4, 'agent.max_yaw_rate': 2.0,
       'agent.scan.range_max': 3.0, 'agent.scan.noise_stddev': 0.05}
BEAMS = 24


def node_messages(arenas, stamp_ns):
    """The robot's LaserScan and Odometry as the node encodes them for this state (its
    agents/frames and msgs.agent_cdr), read back by rclpy as a subscriber gets them."""
    positions, yaws, velocities = arenas.robot_state()
    names = frames.FrameNames('')
    names.update(('ball_0',), 'world')
    twists = frames.body_twists(yaws[:1], velocities[:1], arenas.yaw_rates()[:1])
    odom = frames.odometry_messages(stamp_ns, names, positions[:1], yaws[:1], twists)[0]
    fan = arenas.fan
    ranges = arenas.scans([0])[0]
    scan = encode_laser_scan(stamp_ns, names.base[0], fan.angle_min, fan.angle_max,
                             fan.angle_increment, 0.0, 0.1, fan.range_min, fan.range_max,
                             ranges)
    return deserialize_message(scan, LaserScan), deserialize_message(odom, Odometry), ranges


def test_the_observation_from_the_robots_messages_and_from_a_controller_is_the_envs():
    env = NavigateEnv(world=BOX, beams=BEAMS)
    observed, _ = env.reset(seed=5)
    env.action_space.seed(5)
    arenas = env.task.arenas
    for step in range(30):
        if step:
            observed, *_ = env.step(env.action_space.sample())
        goal = tuple(arenas.goals[0].tolist())
        scan, odom, ranges = node_messages(arenas, step * 100_000_000)
        built = from_messages(scan, odom, goal, env.observation_space)
        positions, yaws, velocities = arenas.robot_state()
        twist = frames.body_twists(yaws[:1], velocities[:1], arenas.yaw_rates()[:1])
        fan = arenas.fan
        seen = Observation(step * 0.1, ('ball_0',), np.column_stack((positions[:1], yaws[:1])),
                           np.column_stack((positions[:1], yaws[:1])), twist,
                           ranges[None].astype(np.float32), np.zeros(1), np.zeros((1, 2)),
                           (fan.angle_min, fan.angle_increment, fan.range_min, fan.range_max))
        controlled = from_controller(seen, [goal], env.observation_space)
        for key in observed:
            assert built[key].tobytes() == observed[key].tobytes(), (step, key)
            assert controlled[key][0].tobytes() == observed[key].tobytes(), (step, key)


def test_a_lidar_the_policy_was_not_trained_on_is_refused_in_one_line():
    space = NavigateEnv(world=BOX, beams=BEAMS).observation_space
    with pytest.raises(FanMismatch) as refused:
        check_fan(-math.pi, 2 * math.pi / 360, 360, space)
    assert str(refused.value) == (
        'the policy was trained on 24 beams from -3.14159 rad every 0.261799 rad; the scan '
        'has 360 from -3.14159 every 0.0174533: set agent.scan.samples:=24 '
        'agent.scan.angle_min:=-3.141592653589793 agent.scan.angle_max:=2.879793265790643')
    check_fan(-math.pi, 2 * math.pi / BEAMS, BEAMS, space)  # the environment's: taken


def test_a_missing_policy_is_one_line_for_the_controller_and_for_the_navigate_node(tmp_path):
    with pytest.raises(UserCodeError) as failed:
        ControllerProcess('ball_world.controllers.navigate:Navigate', deadline_s=30.0)
    assert "no policy file 'runs/navigate_ppo.zip' (ball_world_learn train saves one)" in str(
        failed.value) and '\n' not in str(failed.value)
    code, _, err = run_tool('ball_world_navigate', '--ros-args', '-p',
                            f'policy:={tmp_path / "none.zip"}')
    assert code == 2 and err.count('\n') == 1 and 'no policy file' in err, err
    code, _, err = run_tool('ball_world_navigate', '--ros-args', '-p', 'goal:=[1.0]')
    assert code == 2 and err == ("ball_world_navigate: parameter 'goal': expected [x, y] in "
                                 'm (or more pairs x, y), got [1.0]\n'), err
