"""Odometry that drifts: the odometry motion model of Probabilistic Robotics, run forward.

Why: localization and SLAM code needs odometry that is wrong the way wheel odometry is.
Thrun, Burgard and Fox (Probabilistic Robotics, 2005, 5.4, Table 5.6,
sample_motion_model_odometry) describe a step of motion from pose (x, y, theta) to
(x', y', theta') as a first rotation, a translation and a second rotation,

    rot1  = atan2(y' - y, x' - x) - theta      (0 when the agent did not move)
    trans = sqrt((x' - x)^2 + (y' - y)^2)
    rot2  = theta' - theta - rot1,

and odometry as that motion with each part perturbed by zero-mean Gaussian noise whose
*variance* (the book's sample(b^2) draws with variance b^2; nav2_amcl's motion model takes the
square root of the same sums as its standard deviation) is

    var(rot1)  = alpha1 rot1^2 + alpha2 trans^2
    var(trans) = alpha3 trans^2 + alpha4 (rot1^2 + rot2^2)
    var(rot2)  = alpha1 rot2^2 + alpha2 trans^2.

Here the model runs forward, as Stage and Gazebo run theirs: each step the true motion of an
agent (its pose at the end of the step against its pose when the step began, after the
edits before it: a set_state moves the truth, not the wheels) is perturbed that way and
added to the agent's odometry pose, which therefore drifts from the truth and never comes
back. As in nav2_amcl, the rotations that set the noise are folded to the nearer of forward
and backward (min(|rot|, pi - |rot|)), so driving in reverse is not charged a half turn of
rotation noise; the motion itself keeps its sign. The alphas are per step, so the drift over
a path shrinks as dt does (the model's own property): the variance of a path of n equal
steps is n times that of one step of 1/n of it.

The noise is seeded by (random.seed, the agent's name, the step) with the lidar's generator
(core.noise_seed) under a key of its own (the name with '/odom'), so a re-simulation draws it
again and no scan shares its numbers. Three standard normals per agent and step, drawn only
for an agent that moved (a step whose variances are all 0 adds nothing).

The covariance the odometry message carries is the model's, propagated as an EKF predicts
(Probabilistic Robotics 7.4): Sigma' = G Sigma G^T + V M V^T, with G and V the Jacobians of
the pose update with respect to the pose and to the motion (rot1, trans, rot2), evaluated at
the odometry's own values, and M the diagonal of the three variances. It starts at 0 (the
odometry frame is where the agent starts) and grows as the drift does. The twist is the true
body velocity plus the step's error divided by dt (its covariance the step's, in the same
way), so that a filter fusing odometry's velocity sees noise too.

All alphas 0 is not this model at all: odometry is then the ground truth, bit for bit, as it
always was (the caller does not integrate anything).
"""
import math

import numpy as np

from ball_world.core import noise_kernel
from ball_world.core.lidar import name_key
from ball_world.core.noise_seed import EntropyRows, NoiseSeeds
from ball_world.core.orientation import wrap_yaw

#: The key appended to an agent's name for its odometry's noise (its lidar uses the name).
NOISE_KEY_SUFFIX = '/odom'
#: Covariance entries kept per agent, of the symmetric 3x3 over (x, y, yaw), in this order.
COVARIANCE_ENTRIES = ('xx', 'xy', 'xyaw', 'yy', 'yyaw', 'yawyaw')


def enabled(alphas):
    """Whether the alphas make noisy odometry (any of them above 0)."""
    return any(float(alpha) > 0.0 for alpha in alphas)


def motion(before, after):
    """(rot1, trans, rot2) of each row of poses (x, y, yaw) `before` -> `after`."""
    dx = after[:, 0] - before[:, 0]
    dy = after[:, 1] - before[:, 1]
    trans = np.hypot(dx, dy)
    moved = trans > 0.0
    rot1 = np.where(moved, np.arctan2(dy, dx) - before[:, 2], 0.0)
    rot1 = np.asarray(wrap_yaw(rot1), dtype=np.float64).reshape(-1)
    rot2 = np.asarray(wrap_yaw(after[:, 2] - before[:, 2] - rot1),
                      dtype=np.float64).reshape(-1)
    return rot1, trans, rot2


def variances(alphas, rot1, trans, rot2):
    """The variances (A, 3) of rot1, trans and rot2 under alpha1..alpha4."""
    a1, a2, a3, a4 = (float(alpha) for alpha in alphas)
    turn1 = _folded(rot1)
    turn2 = _folded(rot2)
    trans2 = trans * trans
    result = np.empty((len(trans), 3))
    result[:, 0] = a1 * turn1 * turn1 + a2 * trans2
    result[:, 1] = a3 * trans2 + a4 * (turn1 * turn1 + turn2 * turn2)
    result[:, 2] = a1 * turn2 * turn2 + a2 * trans2
    return result


def _folded(rotation):
    """|rotation| folded to the nearer of forward and backward: min(|r|, pi - |r|)."""
    size = np.abs(rotation)
    return np.minimum(size, math.pi - size)


class OdometryNoise:
    """The seeded standard normals of each agent's odometry, three per step."""

    def __init__(self, seed):
        self.seed = int(seed)
        self._seeds = {}  # agent name -> NoiseSeeds (the per-agent draws, without numba)
        self._table = None  # (names, EntropyRows of them): the compiled draws' seeds

    def normals(self, names, step, rows):
        """(A, 3) standard normals of step `step`: drawn for the agents at `rows`, 0 else.

        Each agent's are default_rng([random.seed, its key, step]).standard_normal(3): with
        numba all agents' in one compiled call (core.noise_kernel, the same bits), which a
        swarm of 10,000 noisy robots needs (a generator each costs several microseconds)."""
        out = np.zeros((len(names), 3))
        if not len(rows):
            return out
        if noise_kernel.available() and 0 <= step < 2**63:
            rows = np.asarray(rows, dtype=np.int64)
            out[rows] = self._entropy(names).standard_normals(rows, step, 3)
            return out
        for row in rows:
            out[row] = self._generator(names[row], step).standard_normal(3)
        return out

    def _generator(self, name, step):
        seeds = self._seeds.get(name)
        if seeds is None:
            seeds = self._seeds[name] = NoiseSeeds(self.seed, self._key(name))
        return seeds.generator(step)

    @staticmethod
    def _key(name):
        return name_key(name + NOISE_KEY_SUFFIX)

    def _entropy(self, names):
        """The EntropyRows of `names` in their order, kept while the names stay the same."""
        if self._table is None or self._table[0] != list(names):
            names = list(names)
            self._table = (names, EntropyRows.of((self.seed, self._key(name))
                                                 for name in names))
        return self._table[1]

    def forget(self, keep):
        """Drop the generators of agents not in `keep` (deleted ones)."""
        self._seeds = {name: seeds for name, seeds in self._seeds.items() if name in keep}


class Step:
    """One step of noisy odometry for every agent: what advance() returns."""

    __slots__ = ('poses', 'covariances', 'twist_errors', 'twist_covariances')

    def __init__(self, poses, covariances, twist_errors, twist_covariances):
        self.poses = poses  # (A, 3) odometry poses after the step
        self.covariances = covariances  # (A, 6) COVARIANCE_ENTRIES of the pose
        self.twist_errors = twist_errors  # (A, 3) vx, vy, wz to add to the true body twist
        self.twist_covariances = twist_covariances  # (A, 6) of (vx, vy, wz)


def advance(alphas, odometry, covariances, before, after, normals, dt):
    """Add each agent's noisy motion `before` -> `after` (true poses) to its odometry.

    odometry (A, 3) and covariances (A, 6) are the state before the step; normals (A, 3)
    the step's standard normals (OdometryNoise). Returns a Step.
    """
    rot1, trans, rot2 = motion(before, after)
    spread = variances(alphas, rot1, trans, rot2)
    errors = np.sqrt(spread) * normals
    noisy1 = rot1 - errors[:, 0]
    noisy_trans = trans - errors[:, 1]
    noisy2 = rot2 - errors[:, 2]
    heading = odometry[:, 2] + noisy1
    cos, sin = np.cos(heading), np.sin(heading)
    poses = np.empty_like(odometry)
    poses[:, 0] = odometry[:, 0] + noisy_trans * cos
    poses[:, 1] = odometry[:, 1] + noisy_trans * sin
    poses[:, 2] = np.asarray(wrap_yaw(heading + noisy2), dtype=np.float64).reshape(-1)
    # Jacobians at the odometry's values: column (a, b, 1) is d(pose)/d(heading) and
    # d(pose)/d(rot1); (cos, sin, 0) is d(pose)/d(trans); (0, 0, 1) is d(pose)/d(rot2).
    a = -noisy_trans * sin
    b = noisy_trans * cos
    grown = _through_heading(covariances, a, b)
    zero = np.zeros_like(a)
    one = np.ones_like(a)
    added = _sandwich(((a, b, one), (cos, sin, zero), (zero, zero, one)), spread)
    # The twist: the step's error in the end frame (the true turn undone), per second.
    turn = rot1 + rot2
    back_cos, back_sin = np.cos(turn), np.sin(turn)
    ex = noisy_trans * np.cos(noisy1) - trans * np.cos(rot1)
    ey = noisy_trans * np.sin(noisy1) - trans * np.sin(rot1)
    twist_errors = np.empty_like(odometry)
    twist_errors[:, 0] = (back_cos * ex + back_sin * ey) / dt
    twist_errors[:, 1] = (back_cos * ey - back_sin * ex) / dt
    twist_errors[:, 2] = ((noisy1 + noisy2) - turn) / dt
    # d(displacement in the end frame)/d(rot1), /d(trans): the start frame's, turned back.
    r1x, r1y = -noisy_trans * np.sin(noisy1), noisy_trans * np.cos(noisy1)
    tx, ty = np.cos(noisy1), np.sin(noisy1)
    columns = ((back_cos * r1x + back_sin * r1y, back_cos * r1y - back_sin * r1x, one),
               (back_cos * tx + back_sin * ty, back_cos * ty - back_sin * tx, zero),
               (zero, zero, one))
    twist_covariances = _sandwich(columns, spread) / (dt * dt)
    return Step(poses, grown + added, twist_errors, twist_covariances)


def _through_heading(covariances, a, b):
    """G Sigma G^T for G the identity with its last column (a, b, 1): entries as stored."""
    xx, xy, xt, yy, yt, tt = covariances.T
    out = np.empty_like(covariances)
    out[:, 0] = xx + 2.0 * a * xt + a * a * tt
    out[:, 1] = xy + a * yt + b * xt + a * b * tt
    out[:, 2] = xt + a * tt
    out[:, 3] = yy + 2.0 * b * yt + b * b * tt
    out[:, 4] = yt + b * tt
    out[:, 5] = tt
    return out


def _sandwich(columns, spread):
    """V diag(spread) V^T for V of the three given columns (each three (A,) arrays)."""
    out = np.zeros((len(spread), 6))
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for k, column in enumerate(columns):
        weight = spread[:, k]
        for entry, (i, j) in enumerate(pairs):
            out[:, entry] += weight * column[i] * column[j]
    return out


def message_covariance(entries):
    """(A, 36) row-major 6x6 covariances over (x, y, z, roll, pitch, yaw) from (A, 6)
    COVARIANCE_ENTRIES: the planar terms placed, z, roll and pitch 0 (exactly known: the
    world is a plane)."""
    out = np.zeros((len(entries), 36))
    xx, xy, xt, yy, yt, tt = entries.T
    out[:, 0] = xx
    out[:, 1] = out[:, 6] = xy
    out[:, 5] = out[:, 30] = xt
    out[:, 7] = yy
    out[:, 11] = out[:, 31] = yt
    out[:, 35] = tt
    return out
