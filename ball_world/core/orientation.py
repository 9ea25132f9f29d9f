"""Planar headings as quaternions, in the conventions of REP 103.

An agent's heading is a yaw: the counter-clockwise angle about +z (up) from the world's +x axis
to the agent's forward axis, in a right-handed frame (REP 103: x forward, y left, z up). ROS
messages carry orientations as unit quaternions (x, y, z, w); a rotation by yaw about z is
(0, 0, sin(yaw / 2), cos(yaw / 2)). q and -q are the same rotation; the one with w >= 0 is
written, so equal headings always give equal bytes (what bit-for-bit re-simulation compares).

Vectorised: every function takes a float or an array of any shape and answers in kind.
"""
import math

import numpy as np

_TWO_PI = 2.0 * np.pi


def wrap_yaw(yaw):
    """The same direction as yaw, in [-pi, pi]: math.remainder(yaw, 2 pi) element-wise.

    Why the IEEE remainder: it is exact (yaw - n 2 pi with n the nearest integer, no rounding),
    so a yaw already in [-pi, pi] comes back unchanged, bit for bit, and the agents' headings
    (kept wrapped the same way) map to one quaternion each. Non-finite yaws give NaN.
    """
    yaw = np.array(yaw, dtype=np.float64)
    outside = ~(np.abs(yaw) <= np.pi)
    if np.any(outside):
        yaw[outside] = [math.remainder(value, _TWO_PI) if math.isfinite(value) else math.nan
                        for value in yaw[outside].tolist()]
    return yaw if yaw.ndim else float(yaw)


def yaw_to_quaternion(yaw):
    """Yaw (rad) -> quaternion components (..., 4) as (x, y, z, w), rotation about z, w >= 0.

    The yaw is wrapped to [-pi, pi] first, so the half angle is in [-pi/2, pi/2] and
    w = cos(half) >= 0. Non-finite yaws give non-finite components: callers refuse those
    before (a heading is always finite).
    """
    half = 0.5 * np.asarray(wrap_yaw(yaw))
    quaternion = np.zeros(half.shape + (4,))
    quaternion[..., 2] = np.sin(half)
    quaternion[..., 3] = np.cos(half)
    return quaternion


def quaternion_to_yaw(quaternion, tolerance=1e-9):
    """Quaternion (..., 4) as (x, y, z, w) -> yaw in [-pi, pi], for rotations about z only.

    The quaternion need not be normalised (the angle of (z, w) does not depend on the length).
    Raises ValueError naming what is wrong when it is not a rotation about z: a non-finite or
    zero quaternion, or x or y larger than `tolerance` times its length (a roll or pitch, which
    a planar world cannot hold).
    """
    quaternion = np.asarray(quaternion, dtype=np.float64)
    if quaternion.shape[-1:] != (4,):
        raise ValueError(f'a quaternion has 4 components (x, y, z, w), got shape '
                         f'{quaternion.shape}')
    if not np.all(np.isfinite(quaternion)):
        raise ValueError('quaternion has a non-finite component')
    length = np.sqrt(np.sum(quaternion * quaternion, axis=-1))
    if np.any(length == 0.0):
        raise ValueError('quaternion (0, 0, 0, 0) is no rotation')
    tilt = np.maximum(np.abs(quaternion[..., 0]), np.abs(quaternion[..., 1]))
    if np.any(tilt > tolerance * length):
        raise ValueError('quaternion is not a rotation about z only (x or y is not 0)')
    # 2 atan2(z, w) is in [-2 pi, 2 pi]; q and -q give angles 2 pi apart, wrapped to the same.
    return wrap_yaw(2.0 * np.arctan2(quaternion[..., 2], quaternion[..., 3]))
