"""agent.drive: diff, the differential drive (unicycle), against closed forms.

dt is 1/64 s and the limits are powers of two, so v = a t is exact in binary. A wheeled base
cannot move sideways: commanded sideways it stays put, and a velocity a collision gave it
across its heading is gone after the next drive impulse.
"""
import math

import numpy as np
import pytest

from ball_world.core import parameters as table
from ball_world.simulation import Simulation

DT = 1.0 / 64


def diff_agent(**overrides):
    """One 1 kg agent at rest in an empty plane, differential drive."""
    parameters = {'rate_hz': 64.0, 'arena': [], 'random.count': 0, 'balls.x': [0.0],
                  'balls.y': [0.0], 'balls.vx': [0.0], 'balls.vy': [0.0],
                  'balls.radius': [0.5], 'balls.mass': [1.0], 'agents': ['ball_0'],
                  'physics.backend': 'numpy', 'agent.drive': 'diff',
                  'agent.cmd_timeout': 0.0}
    parameters.update(overrides)
    return Simulation(parameters)


def body_velocity(simulation, name='ball_0'):
    """(forward, left) of the agent's velocity in its own frame."""
    vx, vy = simulation.world.velocities[simulation.index_of[name]].tolist()
    yaw = simulation.agents.yaw(name)
    return (math.cos(yaw) * vx + math.sin(yaw) * vy, math.cos(yaw) * vy - math.sin(yaw) * vx)


@pytest.mark.parametrize('yaw', [0.0, 0.7, -2.5])
def test_commanded_sideways_a_diff_agent_stays_put(yaw):
    simulation = diff_agent()
    simulation.set_state('ball_0', 0.0, 0.0, 0.0, 0.0, yaw=yaw)
    simulation.command('ball_0', 0.0, 1.5, 0.0)
    for _ in range(200):
        record, _ = simulation.step()
        assert record.impulses == ()
    assert simulation.world.positions[0].tolist() == [0.0, 0.0]
    assert simulation.world.velocities[0].tolist() == [0.0, 0.0]


def test_an_omni_agent_commanded_sideways_moves_sideways():
    simulation = diff_agent(**{'agent.drive': 'omni'})
    simulation.command('ball_0', 0.0, 1.0, 0.0)
    for _ in range(64):
        simulation.step()
    assert simulation.world.velocities[0].tolist() == pytest.approx([0.0, 1.0], abs=1e-15)


def test_forward_speed_follows_max_accel_and_is_clamped_to_max_speed():
    simulation = diff_agent(**{'agent.max_speed': 2.0})
    simulation.set_state('ball_0', 0.0, 0.0, 0.0, 0.0, yaw=math.pi / 2)
    simulation.command('ball_0', -3.0, 5.0, 0.0)  # backward, beyond max_speed; left ignored
    for k in range(1, 40):
        simulation.step()
        forward, left = body_velocity(simulation)
        assert forward == pytest.approx(-min(4.0 * k * DT, 2.0), abs=1e-12)
        assert left == pytest.approx(0.0, abs=1e-15)


def test_turning_while_driving_keeps_the_velocity_along_the_heading():
    simulation = diff_agent()
    simulation.command('ball_0', 1.0, 0.0, 2.0)
    expected = 0.0
    for _ in range(1, 200):
        simulation.step()
        forward, left = body_velocity(simulation)
        assert left == pytest.approx(0.0, abs=1e-15)
        # The last velocity, seen from the heading turned by 2 dt, keeps its cosine along
        # it (the rest, across, is removed), then gains at most max_accel dt.
        expected = min(expected * math.cos(2.0 * DT) + 4.0 * DT, 1.0)
        assert forward == pytest.approx(expected, abs=1e-12)
    # At full speed each step moves 1 m/s x dt along the heading, which turns by 2 rad/s x dt
    # a step: the chords of a circle of radius 0.5 m.
    positions = [simulation.step()[0].positions[0].copy() for _ in range(20)]
    moves = np.diff(positions, axis=0)
    assert np.hypot(moves[:, 0], moves[:, 1]) == pytest.approx(np.full(19, DT), abs=1e-12)
    turns = np.diff(np.unwrap(np.arctan2(moves[:, 1], moves[:, 0])))
    assert turns == pytest.approx(np.full(18, 2.0 * DT), abs=1e-9)


def test_a_sideways_hit_is_removed_by_the_next_drive_impulse_whole():
    # ball_1 (1 kg) comes at the agent from its left at 2 m/s: the hit pushes the agent
    # sideways during that step; the next drive impulse takes the sideways velocity away at
    # once (not at max_accel), and changes the forward speed by at most max_accel dt.
    parameters = {'balls.x': [0.0, 0.0], 'balls.y': [0.0, 1.2], 'balls.vx': [0.0, 0.0],
                  'balls.vy': [0.0, -2.0], 'balls.radius': [0.5, 0.5],
                  'balls.mass': [1.0, 1.0]}
    simulation = diff_agent(**parameters)
    simulation.command('ball_0', 0.25, 0.0, 0.0)
    hit = None
    for _ in range(40):
        record, _ = simulation.step()
        if record.ball_ball:
            hit = body_velocity(simulation)
            break
    assert hit is not None and hit[1] < -1.0  # pushed to its right, across its heading
    record, _ = simulation.step()
    [impulse] = record.impulses  # the drive's (1 kg: the impulse is the change of velocity)
    assert impulse.jy == pytest.approx(-hit[1], abs=1e-15)  # heading 0: left is +y
    assert abs(impulse.jx) <= 4.0 * DT + 1e-15
    for _ in range(20):
        forward, left = body_velocity(simulation)
        assert abs(left) < 1e-15
        simulation.step()


def test_the_drive_parameter_takes_omni_and_diff_only():
    assert table.check('agent.drive', 'diff') == 'diff'
    assert table.DEFAULTS['agent.drive'] == 'omni'
    with pytest.raises(table.ParameterError, match='expected one of omni, diff'):
        table.check('agent.drive', 'tank')


def test_omni_is_still_the_default_drive_bit_for_bit():
    parameters = {'random.count': 30, 'agents': ['ball_0', 'ball_7'], 'random.seed': 3,
                  'physics.backend': 'numpy'}
    default = Simulation(parameters)
    omni = Simulation({**parameters, 'agent.drive': 'omni'})
    for simulation in (default, omni):
        simulation.command('ball_0', 1.5, 0.7, 1.0)
        simulation.command('ball_7', -0.5, -1.2, -0.3)
    moved = 0.0
    for _ in range(100):
        one, _ = default.step()
        other, _ = omni.step()
        assert one.state_cdr == other.state_cdr
        moved = max(moved, float(np.abs(one.velocities[0]).sum()))
    assert moved > 0.0
