"""Planar headings as quaternions (core/orientation.py), against closed forms of REP 103.

REP 103: right-handed, x forward, y left, z up; a positive yaw turns x toward y. A unit
quaternion q rotates a vector v to q v q*; for a rotation about z that is the 2D rotation by
the yaw, which the tests use as the reference, with the exact half-angle values at multiples of
pi/4 and pi/3.
"""
import math

import numpy as np
import pytest

from ball_world.core.orientation import quaternion_to_yaw, wrap_yaw, yaw_to_quaternion

SQRT_HALF = math.sqrt(0.5)


def _rotate(quaternion, vector):
    """q v q* for a unit quaternion (x, y, z, w): the textbook formula, written out."""
    x, y, z, w = quaternion
    u = np.array([x, y, z])
    v = np.asarray(vector, dtype=np.float64)
    return 2.0 * np.dot(u, v) * u + (w * w - np.dot(u, u)) * v + 2.0 * w * np.cross(u, v)


@pytest.mark.parametrize('yaw, expected', [
    (0.0, (0.0, 0.0, 0.0, 1.0)),
    (math.pi / 2, (0.0, 0.0, SQRT_HALF, SQRT_HALF)),
    (-math.pi / 2, (0.0, 0.0, -SQRT_HALF, SQRT_HALF)),
    (math.pi / 3, (0.0, 0.0, 0.5, math.sqrt(3) / 2)),
    (-2 * math.pi / 3, (0.0, 0.0, -math.sqrt(3) / 2, 0.5)),
    (math.pi, (0.0, 0.0, 1.0, 0.0)),
])
def test_yaw_to_quaternion_closed_forms(yaw, expected):
    np.testing.assert_allclose(yaw_to_quaternion(yaw), expected, rtol=0, atol=1e-15)


def test_positive_yaw_turns_x_toward_y_as_rep_103_says():
    forward = _rotate(yaw_to_quaternion(math.pi / 2), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(forward, [0.0, 1.0, 0.0], atol=1e-15)
    for yaw in np.linspace(-math.pi, math.pi, 13):
        quaternion = yaw_to_quaternion(yaw)
        np.testing.assert_allclose(_rotate(quaternion, [1.0, 0.0, 0.0]),
                                   [math.cos(yaw), math.sin(yaw), 0.0], atol=1e-15)
        np.testing.assert_allclose(_rotate(quaternion, [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0],
                                   atol=1e-15)
        assert math.isclose(np.dot(quaternion, quaternion), 1.0, rel_tol=0, abs_tol=1e-15)


def test_w_is_never_negative_and_equal_headings_give_equal_quaternions():
    yaws = np.random.default_rng(0).uniform(-50.0, 50.0, size=10_000)
    quaternions = yaw_to_quaternion(yaws)
    assert quaternions.shape == (10_000, 4)
    assert (quaternions[:, 3] >= 0.0).all()
    assert not quaternions[:, :2].any()
    # yaw and yaw + 2 pi k are one heading: one quaternion (to rounding of the + 2 pi k).
    np.testing.assert_allclose(yaw_to_quaternion(yaws + 4 * math.pi), quaternions,
                               rtol=0, atol=1e-13)


def test_a_wrapped_yaw_maps_to_its_quaternion_bit_for_bit():
    """Headings already in [-pi, pi] are not touched by the wrap: the quaternion is exactly
    (0, 0, sin(yaw/2), cos(yaw/2)) of the yaw given, what odometry and resim compare."""
    yaws = np.random.default_rng(1).uniform(-math.pi, math.pi, size=1000)
    assert (wrap_yaw(yaws) == yaws).all()
    quaternions = yaw_to_quaternion(yaws)
    assert (quaternions[:, 2] == np.sin(yaws / 2)).all()
    assert (quaternions[:, 3] == np.cos(yaws / 2)).all()


def test_wrap_yaw_is_the_ieee_remainder():
    for yaw in (3.5, -3.5, 7.0, 1e6, -1e6, 2 * math.pi, 123.456):
        assert wrap_yaw(yaw) == math.remainder(yaw, 2 * math.pi)
        assert -math.pi <= wrap_yaw(yaw) <= math.pi
    assert math.isnan(wrap_yaw(math.inf)) and math.isnan(wrap_yaw(math.nan))


def test_quaternion_to_yaw_inverts_yaw_to_quaternion():
    yaws = np.random.default_rng(2).uniform(-math.pi, math.pi, size=1000)
    np.testing.assert_allclose(quaternion_to_yaw(yaw_to_quaternion(yaws)), yaws,
                               rtol=0, atol=4e-16)
    quarter_turn = quaternion_to_yaw([0.0, 0.0, SQRT_HALF, SQRT_HALF])
    assert quarter_turn == pytest.approx(math.pi / 2, abs=1e-15)


def test_quaternion_to_yaw_takes_either_sign_and_any_length():
    quaternion = yaw_to_quaternion(2.5)
    assert quaternion_to_yaw(-quaternion) == pytest.approx(2.5, abs=1e-15)
    assert quaternion_to_yaw(7.0 * quaternion) == pytest.approx(2.5, abs=1e-15)
    # Half-turns: w 0, both signs of z, are yaw pi or -pi, the same heading.
    assert abs(quaternion_to_yaw([0.0, 0.0, 1.0, 0.0])) == pytest.approx(math.pi)
    assert abs(quaternion_to_yaw([0.0, 0.0, -1.0, 0.0])) == pytest.approx(math.pi)


@pytest.mark.parametrize('quaternion, says', [
    ([1.0, 0.0, 0.0, 0.0], 'about z'),            # a roll of pi
    ([0.0, 0.1, 0.0, 0.99], 'about z'),           # a pitch
    ([0.0, 0.0, 0.0, 0.0], 'no rotation'),
    ([0.0, 0.0, math.nan, 1.0], 'non-finite'),
    ([0.0, 0.0, 1.0], '4 components'),
])
def test_quaternion_to_yaw_refuses_what_is_not_a_planar_heading(quaternion, says):
    with pytest.raises(ValueError, match=says):
        quaternion_to_yaw(quaternion)
