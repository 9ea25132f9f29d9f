"""Odometry that drifts, ground truth that holds, bumpers that feel a hit.

The odometry motion model (core.odometry) is checked against its own definition: over many
independent runs of one true path, the spread of the odometry's error is the covariance the
model propagates. Through the Simulation: ground truth is the balls' pose bit for bit, /tf
carries the odometry's pose, a recording with noise re-simulates bit for bit (one file and
split files that resume mid-run), and a head-on hit gives the bumper the elastic impulse of
the closed form 2 m1 m2 / (m1 + m2) times the closing speed, in the agent's frame.
"""
import math

import numpy as np
import pytest

from ball_world.core import odometry
from ball_world.core.scenario import ScenarioError
from ball_world.msgs.agent_cdr import decode_odometry, decode_tf_message
from ball_world.msgs.cdr import decode_vector3_stamped
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.split_writer import SplitMcapSink
from ball_world.simulation import Simulation
from ball_world.tools import resim

NOISE = [0.05, 0.01, 0.08, 0.02]


def yaw_of(pose):
    return 2.0 * math.atan2(pose[5], pose[6])


def test_the_spread_of_the_drift_is_the_covariance_the_model_propagates():
    # 4,000 runs of one true path (forward while turning, then backward), each with its own
    # noise: the sample covariance of (x, y, yaw) errors at the end must be the propagated one.
    runs, steps, dt = 4000, 40, 0.05
    rng = np.random.default_rng(7)
    truth = np.zeros((runs, 3))
    poses = np.zeros((runs, 3))
    covariances = np.zeros((runs, 6))
    for k in range(steps):
        speed = 1.0 if k < 30 else -0.5
        after = truth.copy()
        after[:, 2] = truth[:, 2] + 0.6 * dt
        after[:, 0] += speed * dt * np.cos(after[:, 2])
        after[:, 1] += speed * dt * np.sin(after[:, 2])
        stepped = odometry.advance(NOISE, poses, covariances, truth, after,
                                   rng.standard_normal((runs, 3)), dt)
        poses, covariances, truth = stepped.poses, stepped.covariances, after
    errors = poses - truth
    errors[:, 2] = np.remainder(errors[:, 2] + math.pi, 2 * math.pi) - math.pi
    sample = np.cov(errors.T)
    predicted = covariances.mean(axis=0)
    expected = np.array([[predicted[0], predicted[1], predicted[2]],
                         [predicted[1], predicted[3], predicted[4]],
                         [predicted[2], predicted[4], predicted[5]]])
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    # 4,000 samples: a (co)variance is within about 3 sqrt(2 / n) = 7 % of its scale.
    assert np.abs(sample - expected) / scale == pytest.approx(np.zeros((3, 3)), abs=0.08)
    assert errors.mean(axis=0) == pytest.approx(np.zeros(3), abs=3 * np.sqrt(np.diag(
        expected) / runs).max())
    assert np.diag(expected).min() > 0.0


def test_variances_follow_the_book_with_rotations_folded_for_reverse():
    rot1 = np.array([0.0, 0.2, math.pi - 0.2, 0.0])
    trans = np.array([0.1, 0.1, 0.1, 0.0])
    rot2 = np.array([0.0, -0.1, 0.3, 0.5])
    got = odometry.variances([1.0, 2.0, 3.0, 4.0], rot1, trans, rot2)
    folded = np.array([0.0, 0.2, 0.2, 0.0])  # driving in reverse is not half a turn
    expected = np.stack((folded ** 2 + 2.0 * trans ** 2,
                         3.0 * trans ** 2 + 4.0 * (folded ** 2 + rot2 ** 2),
                         rot2 ** 2 + 2.0 * trans ** 2), axis=1)
    assert got == pytest.approx(expected, abs=1e-15)


def agents_driving(noise=None, **overrides):
    """Two agents in a 100 m box driving circles, far from each other and the walls."""
    parameters = {'rate_hz': 50.0, 'random.count': 0, 'arena': [0.0, 0.0, 100.0, 100.0],
                  'balls.x': [30.0, 70.0], 'balls.y': [50.0, 50.0], 'balls.vx': [0.0, 0.0],
                  'balls.vy': [0.0, 0.0], 'balls.radius': [0.5, 0.5],
                  'balls.mass': [1.0, 2.0], 'agents': ['ball_0', 'ball_1'],
                  'agent.cmd_timeout': 0.0, 'agent.scan.samples': 0, 'random.seed': 3,
                  **overrides}
    if noise is not None:
        parameters['agent.odom.noise'] = noise
    return parameters


def drive(simulation):
    simulation.command('ball_0', 1.0, 0.0, 0.5)
    simulation.command('ball_1', -0.8, 0.0, -0.3)


def test_without_noise_odom_is_the_ground_truth_bit_for_bit():
    simulation = Simulation(agents_driving())
    drive(simulation)
    for _ in range(60):
        record, _ = simulation.step()
        for row, (odom, truth) in enumerate(zip(record.agents.odom_cdr,
                                                record.agents.ground_truth_cdr)):
            odom, truth = decode_odometry(odom), decode_odometry(truth)
            assert odom.pose.tobytes() == truth.pose.tobytes()
            assert odom.twist.tobytes() == truth.twist.tobytes()
            assert not odom.pose_covariance.any() and not truth.pose_covariance.any()
            assert odom.frame_id == f'ball_{row}/odom' and truth.frame_id == 'world'
            assert truth.child_frame_id == f'ball_{row}/base_link'
            assert truth.pose[:2].tobytes() == record.positions[row].tobytes()


def test_with_noise_odom_drifts_tf_carries_it_and_ground_truth_holds():
    simulation = Simulation(agents_driving(NOISE))
    first = simulation.last_record.agents
    assert first.odom_cdr == tuple(
        decode_and_reframe(truth, row) for row, truth in enumerate(first.ground_truth_cdr))
    drive(simulation)
    drift = []
    for k in range(1, 301):
        record, _ = simulation.step()
        tf = decode_tf_message(record.agents.tf_cdr)
        for row, (odom, truth) in enumerate(zip(record.agents.odom_cdr,
                                                record.agents.ground_truth_cdr)):
            odom, truth = decode_odometry(odom), decode_odometry(truth)
            assert truth.pose[:2].tobytes() == record.positions[row].tobytes()
            assert tf.transforms[row].tobytes() == odom.pose.tobytes()  # /tf is odom
            assert tf.stamps_ns[row] == odom.stamp_ns == record.stamp_ns
            covariance = odom.pose_covariance.reshape(6, 6)
            assert np.allclose(covariance, covariance.T) and covariance[0, 0] > 0.0
            error = math.hypot(*(odom.pose[:2] - truth.pose[:2]))
            # The model's own bound: far below 5 standard deviations of its covariance.
            sigma = math.sqrt(covariance[0, 0] + covariance[1, 1])
            assert error <= 5.0 * sigma
            if k == 300:
                drift.append(error)
    assert min(drift) > 0.0  # it drifted
    # A second run draws the same noise: seeded by (random.seed, agent, step).
    again = Simulation(agents_driving(NOISE))
    drive(again)
    for _ in range(300):
        replayed, _ = again.step()
    assert replayed.agents.odom_cdr == record.agents.odom_cdr
    other = Simulation(agents_driving(NOISE, **{'random.seed': 4}))
    drive(other)
    for _ in range(300):
        changed, _ = other.step()
    assert changed.agents.odom_cdr != record.agents.odom_cdr
    assert changed.agents.ground_truth_cdr == record.agents.ground_truth_cdr


def decode_and_reframe(truth, row):
    """The odom bytes a ground truth message would be at step 0 (odom starts at the truth)."""
    from ball_world.msgs.agent_cdr import encode_odometry
    message = decode_odometry(truth)
    return encode_odometry(message.stamp_ns, [f'ball_{row}/odom'], [message.child_frame_id],
                           [message.pose[:2]], [yaw_of(message.pose)],
                           [[message.twist[0], message.twist[1], message.twist[5]]])[0]


def test_an_agent_at_rest_keeps_its_odometry_and_tf_static_can_be_left_out():
    simulation = Simulation(agents_driving(NOISE, **{'agent.odom.tf_static': False}))
    assert simulation.last_record.agents.tf_static_cdr is None
    start = simulation.last_record.agents.odom_cdr
    for _ in range(50):
        record, _ = simulation.step()
        assert record.agents.tf_static_cdr is None
    assert [decode_odometry(m).pose.tobytes() for m in record.agents.odom_cdr] == [
        decode_odometry(m).pose.tobytes() for m in start]


@pytest.mark.parametrize('noise', [[0.0] * 4, NOISE], ids=['exact', 'noisy'])
def test_a_recording_with_noise_resimulates_bit_for_bit_whole_and_file_by_file(
        tmp_path, capsys, noise):
    parameters = agents_driving(noise)
    whole = tmp_path / 'one.mcap'
    simulation = Simulation(parameters, sinks=[McapSink(whole)])
    drive(simulation)
    for _ in range(120):
        simulation.step()
    simulation.close()
    assert resim.main([str(whole)]) == 0, capsys.readouterr()
    directory = tmp_path / 'split'
    simulation = Simulation(parameters, sinks=[SplitMcapSink(directory, max_seconds=0.6)])
    drive(simulation)
    for _ in range(120):
        simulation.step()
    simulation.close()
    files = sorted(directory.glob('*.mcap'))
    assert len(files) >= 3
    for path in [directory, *files]:
        assert resim.main([str(path)]) == 0, (path, capsys.readouterr())
    out = capsys.readouterr().out
    assert 'bit-identically' in out


def test_resim_finds_a_tampered_ground_truth(tmp_path, capsys):
    from ball_world_testing.harness import rewrite_recording
    path = tmp_path / 'run.mcap'
    simulation = Simulation(agents_driving(NOISE), sinks=[McapSink(path)])
    drive(simulation)
    for _ in range(20):
        simulation.step()
    simulation.close()

    def shifted(topic, log_time, data):
        if topic != '/ball_1/ground_truth' or log_time != 10 * 20_000_000:
            return data
        return data[:-8] + b'\x01' + data[-7:]
    rewrite_recording(path, tmp_path / 'tampered.mcap', data=shifted)
    assert resim.main([str(tmp_path / 'tampered.mcap')]) == 1
    assert 'ground_truth ball_1' in capsys.readouterr().out


def head_on(yaw, mode='seed', backend='numpy'):
    """ball_0 (an agent, 2 kg, heading yaw, at rest) hit by ball_1 (1 kg) coming from the
    direction 0.4 rad at 3 m/s, head on (along the line of centres)."""
    direction = (math.cos(0.4), math.sin(0.4))
    return Simulation({
        'rate_hz': 100.0, 'random.count': 0, 'arena': [], 'agents': ['ball_0'],
        'balls.x': [0.0, 1.5 * direction[0]], 'balls.y': [0.0, 1.5 * direction[1]],
        'balls.vx': [0.0, -3.0 * direction[0]], 'balls.vy': [0.0, -3.0 * direction[1]],
        'balls.radius': [0.5, 0.5], 'balls.mass': [2.0, 1.0], 'agent.scan.samples': 0,
        'physics.mode': mode, 'physics.backend': backend}), yaw


@pytest.mark.parametrize('mode, backend', [('seed', 'numpy'), ('seed', 'numba'),
                                           ('exact', 'numba')])
@pytest.mark.parametrize('yaw', [0.0, 1.1, -2.7])
def test_a_head_on_hit_gives_the_bumper_the_elastic_impulse_in_its_frame(yaw, mode, backend):
    simulation, yaw = head_on(yaw, mode, backend)
    x, y = simulation.world.positions[0].tolist()
    simulation.set_state('ball_0', x, y, 0.0, 0.0, yaw=yaw)
    bumpers = []
    for _ in range(60):
        record, _ = simulation.step()
        bumpers += list(record.agents.bumpers)
    # 2 m1 m2 / (m1 + m2) x closing speed, pushing the agent away from ball_1 (along -0.4 rad).
    size = 2.0 * 2.0 * 1.0 / 3.0 * 3.0
    world = (-size * math.cos(0.4), -size * math.sin(0.4))
    body = (math.cos(yaw) * world[0] + math.sin(yaw) * world[1],
            math.cos(yaw) * world[1] - math.sin(yaw) * world[0])
    [bumper] = bumpers
    stamp_ns, frame_id, bx, by, bz = decode_vector3_stamped(bumper.cdr)
    assert frame_id == 'ball_0/base_link' and bumper.name == 'ball_0'
    assert (bx, by, bz) == pytest.approx((*body, 0.0), abs=1e-12)
    assert (bumper.x, bumper.y) == (bx, by)


def test_the_drive_and_pushes_never_ring_the_bumper_and_a_wall_does():
    simulation = Simulation(agents_driving(**{'balls.x': [98.0, 50.0]}))
    simulation.command('ball_0', 2.0, 0.0, 0.0)  # toward the wall at x = 100
    simulation.queue_impulse('ball_1', 0.5, 0.0)  # a push
    hits = []
    for _ in range(100):
        record, _ = simulation.step()
        hits += [(record.step, b) for b in record.agents.bumpers]
    # Only ball_0, at the wall (its drive takes it back there after each bounce); never
    # the drive's impulses of the steps before, nor the push of ball_1.
    assert hits and {b.name for _, b in hits} == {'ball_0'}
    step, bumper = hits[0]
    assert step > 25  # 0.5 s to reach 2 m/s, then 0.5 m more to the wall
    # 1 kg at 2 m/s into the wall head on: 2 m v back, along -x (its heading is +x).
    assert (bumper.x, bumper.y) == pytest.approx((-4.0, 0.0), abs=1e-12)


def test_bumpers_made_at_first_read_are_each_hits_closed_form_and_pickle():
    # agents.frames.Bumpers: made when first read, the same Bumpers every read, equal to a
    # tuple of them, the forward and left parts the impulse turned into base_link, the bytes
    # each hit's own Vector3Stamped (b'' when nobody takes them); a pickle reads the same.
    import pickle
    from ball_world.agents import frames
    from ball_world.msgs.cdr import encode_vector3_stamped
    names = ('a', 'b', 'c', 'd')
    bases = tuple(f'{name}/base_link' for name in names)
    yaws = np.array([0.0, 0.5, -2.0, 3.0])
    impulses = np.array([[1.0, 2.0], [0.0, 0.0], [-0.5, 0.25], [0.0, -3.0]])
    assert frames.bumpers(names, bases, yaws, np.zeros((4, 2)), 7) == ()
    for encode in (True, False):
        hits = frames.bumpers(names, bases, yaws, impulses, 7, encode)
        assert len(hits) == 3 and bool(hits)
        made = tuple(hits)
        assert [b.name for b in made] == ['a', 'c', 'd'] and made[1] is hits[1]
        for bumper, row in zip(made, (0, 2, 3)):
            jx, jy = impulses[row]
            cos, sin = math.cos(yaws[row]), math.sin(yaws[row])
            assert (bumper.x, bumper.y) == pytest.approx(
                (cos * jx + sin * jy, cos * jy - sin * jx), abs=1e-12)
            assert bumper.frame_id == bases[row]
            assert bumper.cdr == (encode_vector3_stamped(7, bases[row], bumper.x, bumper.y,
                                                         0.0) if encode else b'')
        assert hits == made and pickle.loads(pickle.dumps(hits)) == made


@pytest.mark.parametrize('value, words', [
    ([0.1, 0.1, 0.1], 'expected 4 numbers'), ([0.0, -0.1, 0.0, 0.0], 'entries must be between'),
    ([0.0, 0.0, 11.0, 0.0], 'entries must be between 0 and 10')])
def test_odometry_noise_refuses_what_is_no_model(value, words):
    with pytest.raises(ScenarioError, match=words):
        Simulation(agents_driving(value))


def test_the_largest_alphas_step_finite_and_re_simulate(tmp_path, capsys):
    path = tmp_path / 'edge.mcap'
    simulation = Simulation(agents_driving([10.0] * 4), sinks=[McapSink(path)])
    drive(simulation)
    for _ in range(50):
        record, _ = simulation.step()
    simulation.close()
    for data in record.agents.odom_cdr:
        odom = decode_odometry(data)
        assert np.isfinite(odom.pose).all() and np.isfinite(odom.pose_covariance).all()
    assert resim.main([str(path)]) == 0, capsys.readouterr()


@pytest.mark.skipif(not odometry.noise_kernel.available(), reason='compiled draws need numba')
def test_every_agents_noise_in_one_call_is_its_own_generators_draws():
    # Reference: numpy's default_rng([seed, key, step]).standard_normal(3), as the recording
    # format documents each agent's draws; names change between calls (spawn, delete).
    from ball_world.core.lidar import name_key
    noise = odometry.OdometryNoise(2**40 + 3)
    for names, step in ((['ball_0', 'ball_1', 'ball_7'], 0), (['ball_0', 'ball_7'], 5),
                        ([f'robot_{k}' for k in range(40)], 2**32 + 9)):
        rows = list(range(0, len(names), 2))
        drawn = noise.normals(names, step, rows)
        for row, name in enumerate(names):
            key = name_key(name + odometry.NOISE_KEY_SUFFIX)
            expected = (np.random.default_rng([2**40 + 3, key, step]).standard_normal(3)
                        if row in rows else np.zeros(3))
            assert drawn[row].tobytes() == expected.tobytes(), (name, step)
