"""The exact 2D lidar (core.lidar) against ranges computed by hand from each scene's geometry.

Every reference here is worked out from the scene (Pythagoras, similar triangles, the
distance to a box along a direction), never from the scanner's own formulas. Each scene runs
with both backends; random worlds check that they agree bit for bit, and a plain Python
loop over every ball and wall checks that the grid walk misses nothing.
"""
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from ball_world.core import lidar
from ball_world.core.lidar import Fan
from ball_world.core.scenario import arena_walls

BACKENDS = ('numpy', 'numba')
#: The issue's bound on a noise-free range's distance from the closed form.
EXACT = 1e-9


def fan(angles, range_min=0.1, range_max=12.0, noise=0.0):
    """A fan whose beams point along `angles` (evenly spaced, at least two)."""
    return Fan(angles[0], angles[1] - angles[0], len(angles), range_min, range_max, noise)


def box(xmin, ymin, xmax, ymax):
    walls, _ = arena_walls({'arena': [xmin, ymin, xmax, ymax]})
    return walls


def ranges(backend, positions, radii, walls, origin, yaw, beams, exclude=-1):
    return lidar.scan(np.array(positions, dtype=float).reshape(-1, 2),
                      np.array(radii, dtype=float), np.array(walls, dtype=float).reshape(-1, 4),
                      origin, yaw, beams, exclude, backend)


@pytest.mark.parametrize('backend', BACKENDS)
def test_tangent_beams_hit_at_the_tangent_point(backend):
    # From the origin, the circle (5, 1) of radius 1 is seen under half-angle asin(1/sqrt 26)
    # = atan(1/5), centred on atan(1/5): the tangents are at 0 and 2 atan(1/5), each 5 m long
    # (sqrt(26 - 1)); the middle beam hits at sqrt(26) - 1.
    alpha = math.atan2(1.0, 5.0)
    got = ranges(backend, [[5.0, 1.0]], [1.0], [], (0.0, 0.0), 0.0, fan([0.0, alpha]))
    assert got[0] == pytest.approx(5.0, abs=EXACT)
    assert got[1] == pytest.approx(math.sqrt(26.0) - 1.0, abs=EXACT)
    # The same scene seen with the beams laid out from a heading: the far tangent too.
    got = ranges(backend, [[5.0, 1.0]], [1.0], [], (0.0, 0.0), alpha,
                 fan([-alpha, 0.0, alpha]))
    assert got == pytest.approx([5.0, math.sqrt(26.0) - 1.0, 5.0], abs=EXACT)
    # A beam just outside the tangent (a micro-radian) misses.
    got = ranges(backend, [[5.0, 1.0]], [1.0], [], (0.0, 0.0), 0.0, fan([-1e-6, 0.0]))
    assert math.isinf(got[0]) and got[0] > 0.0


@pytest.mark.parametrize('backend', BACKENDS)
def test_a_ball_behind_a_ball(backend):
    # Ball A (3, 0) r 0.5 in front of ball B (6, 0) r 1.5. Along x the beam stops at A's
    # near side, 2.5 m. At sin(theta) = 0.2 it passes A at 3 * 0.2 = 0.6 > 0.5 and meets B,
    # whose centre is 6 * 0.2 = 1.2 from the beam: at 6 cos(theta) - sqrt(1.5^2 - 1.2^2).
    theta = math.asin(0.2)
    positions = [[3.0, 0.0], [6.0, 0.0]]
    got = ranges(backend, positions, [0.5, 1.5], [], (0.0, 0.0), 0.0, fan([0.0, theta]))
    assert got[0] == pytest.approx(2.5, abs=EXACT)
    assert got[1] == pytest.approx(6.0 * math.cos(theta) - math.sqrt(2.25 - 1.44), abs=EXACT)
    # Order in the arrays must not matter: B listed first, A still wins along x.
    got = ranges(backend, positions[::-1], [1.5, 0.5], [], (0.0, 0.0), 0.0, fan([0.0, theta]))
    assert got[0] == pytest.approx(2.5, abs=EXACT)


@pytest.mark.parametrize('backend', BACKENDS)
def test_a_wall_at_a_grazing_angle(backend):
    # The wall y = -0.01 + 0.001 (x - 1), from x = 1 to 21, meets the x axis at x = 11,
    # under an angle of 1 mrad. A beam at slope s < 0.001 meets it where
    # s x = 0.001 x - 0.011: x = 0.011 / (0.001 - s), at a range x / cos(atan s).
    wall = [1.0, -0.01, 21.0, 0.01]
    slopes = [0.0, -0.0001, 0.0002]
    angles = [math.atan(s) for s in slopes]
    got = lidar.scan(np.empty((0, 2)), np.empty(0), np.array([wall]), (0.0, 0.0), 0.0,
                     Fan(angles[0], 1.0, 1, 0.1, 30.0), backend=backend)
    assert got[0] == pytest.approx(11.0, abs=EXACT)
    for slope, angle in zip(slopes[1:], angles[1:]):
        got = lidar.scan(np.empty((0, 2)), np.empty(0), np.array([wall]), (0.0, 0.0), angle,
                         Fan(0.0, 1.0, 1, 0.1, 30.0), backend=backend)
        x = 0.011 / (0.001 - slope)
        assert got[0] == pytest.approx(x / math.cos(angle), abs=EXACT)
    # Parallel to the wall, a beam above it never meets it.
    got = lidar.scan(np.empty((0, 2)), np.empty(0), np.array([wall]), (0.0, 0.0),
                     math.atan(0.001), Fan(0.0, 1.0, 1, 0.1, 30.0), backend=backend)
    assert got[0] == np.inf


@pytest.mark.parametrize('backend', BACKENDS)
def test_range_limits_follow_rep_117(backend):
    # Beam 0 meets a ball 0.05 m away (closer than range_min 0.1): -inf. Beam 1 (at 90
    # degrees) meets one exactly at range_max 12: kept. Beam 2 (180) meets one at 12.5,
    # beyond range_max: +inf. Beam 3 (270) meets nothing: +inf.
    positions = [[0.3, 0.0], [0.0, 12.5], [-13.0, 0.0]]
    radii = [0.25, 0.5, 0.5]
    got = ranges(backend, positions, radii, [], (0.0, 0.0), 0.0,
                 fan([0.0, math.pi / 2, math.pi, 1.5 * math.pi]))
    assert got[0] == -np.inf
    assert got[1] == pytest.approx(12.0, abs=EXACT)
    assert got[2] == np.inf and got[3] == np.inf
    # range_min 0: the same near ball is a valid 0.05 m.
    got = ranges(backend, positions, radii, [], (0.0, 0.0), 0.0, fan([0.0, 1.0], range_min=0.0))
    assert got[0] == pytest.approx(0.05, abs=EXACT)


@pytest.mark.parametrize('backend', BACKENDS)
def test_empty_world_and_own_ball(backend):
    # Nothing at all: every beam +inf.
    full = Fan.full_turn(360)
    got = ranges(backend, np.empty((0, 2)), [], [], (1.0, 2.0), 0.3, full)
    assert np.all(got == np.inf)
    # The scanner sits at the centre of its own ball (r 0.3): excluded, the beams pass out of
    # it; included (exclude=-1), the beams start inside a ball: range 0, below range_min.
    positions = [[0.0, 0.0], [4.0, 0.0]]
    got = ranges(backend, positions, [0.3, 1.0], [], (0.0, 0.0), 0.0, full, exclude=0)
    assert got[180] == pytest.approx(3.0, abs=EXACT)  # beam 180 points along +x
    assert np.all(np.isposinf(np.delete(got, np.arange(160, 201))))
    got = ranges(backend, positions, [0.3, 1.0], [], (0.0, 0.0), 0.0, full)
    assert np.all(got == -np.inf)


@pytest.mark.parametrize('backend', BACKENDS)
def test_inside_a_box_every_beam_reaches_the_right_wall(backend):
    # From (3, 4) in the box [0, 10] x [0, 8] along (cos a, sin a), the range is the least
    # positive of (10 - 3) / cos a, (0 - 3) / cos a, (8 - 4) / sin a, (0 - 4) / sin a. 720
    # beams include the four corners' neighbourhoods and beams along the axes.
    beams = Fan.full_turn(720, range_max=20.0)
    got = ranges(backend, [[3.0, 4.0]], [0.2], box(0.0, 0.0, 10.0, 8.0), (3.0, 4.0), 0.0,
                 beams, exclude=0)
    for k, value in enumerate(got):
        a = beams.angle_min + k * beams.angle_increment
        c, s = math.cos(a), math.sin(a)
        candidates = [d for d in ((7.0 / c if c > 0 else math.inf),
                                  (-3.0 / c if c < 0 else math.inf),
                                  (4.0 / s if s > 0 else math.inf),
                                  (-4.0 / s if s < 0 else math.inf))]
        assert value == pytest.approx(min(candidates), abs=EXACT), k
    # A beam aimed exactly into a corner does not slip between its two walls.
    corner = math.atan2(4.0, 7.0)
    got = ranges(backend, [], [], box(0.0, 0.0, 10.0, 8.0), (3.0, 4.0), corner,
                 Fan(0.0, 1.0, 1, 0.1, 20.0))
    assert got[0] == pytest.approx(math.hypot(7.0, 4.0), abs=EXACT)


@pytest.mark.parametrize('backend', BACKENDS)
def test_scanner_inside_another_ball_sees_range_zero(backend):
    # Overlapping balls (the seed's a posteriori contacts allow a little overlap): the
    # scanner's centre lies inside ball 1, so every beam starts in it: -inf (0 < range_min).
    got = ranges(backend, [[0.0, 0.0], [0.5, 0.0]], [0.3, 0.6], [], (0.0, 0.0), 0.0,
                 Fan.full_turn(8), exclude=0)
    assert np.all(got == -np.inf)


def brute_force(positions, radii, walls, origin, yaw, beams, exclude):
    """Python loops over every ball and wall, quadratic and line equations solved plainly."""
    out = []
    px, py = origin
    for k in range(beams.samples):
        a = yaw + beams.angle_min + k * beams.angle_increment
        dx, dy = math.cos(a), math.sin(a)
        best = math.inf
        for i, ((cx, cy), r) in enumerate(zip(positions, radii)):
            if i == exclude:
                continue
            # |p + t d - c|^2 = r^2: t^2 - 2 b t + c = 0 with b = (c - p).d
            b = (cx - px) * dx + (cy - py) * dy
            c = (cx - px) ** 2 + (cy - py) ** 2 - r * r
            if c <= 0.0:
                best = 0.0
            elif b > 0.0 and b * b - c >= 0.0:
                best = min(best, b - math.sqrt(b * b - c))
        for x1, y1, x2, y2 in walls:
            det = dx * (y2 - y1) - dy * (x2 - x1)
            if det == 0.0:
                continue
            t = ((x1 - px) * (y2 - y1) - (y1 - py) * (x2 - x1)) / det
            u = ((x1 - px) * dy - (y1 - py) * dx) / det
            if t >= 0.0 and 0.0 <= u <= 1.0:
                best = min(best, t)
        out.append(best if best <= beams.range_max else math.inf)
    return np.array(out)


def random_world(rng, n):
    """A random world: balls of widely spread radii, an arena and a few loose walls."""
    positions = rng.uniform(0.0, 30.0, (n, 2))
    radii = np.exp(rng.uniform(math.log(0.02), math.log(1.5), n))
    loose = rng.uniform(0.0, 30.0, (8, 4))
    walls = np.concatenate((box(0.0, 0.0, 30.0, 30.0), loose))
    return positions, radii, walls


@pytest.mark.parametrize('seed', range(6))
def test_backends_agree_bit_for_bit_and_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    positions, radii, walls = random_world(rng, int(rng.integers(50, 600)))
    for trial in range(4):
        beams = Fan(float(rng.uniform(-4.0, 4.0)), float(rng.uniform(-0.05, 0.05)),
                    int(rng.integers(1, 400)), 0.0, float(rng.uniform(0.5, 25.0)))
        scanner = int(rng.integers(len(positions)))
        yaw = float(rng.uniform(-math.pi, math.pi))
        numpy_ranges = lidar.distances(positions, radii, walls, positions[scanner], yaw, beams,
                                       scanner, 'numpy')
        numba_ranges = lidar.distances(positions, radii, walls, positions[scanner], yaw, beams,
                                       scanner, 'numba')
        assert numpy_ranges.tobytes() == numba_ranges.tobytes()
        reference = brute_force(positions, radii, walls, positions[scanner], yaw, beams,
                                scanner)
        finite = np.isfinite(reference)
        assert np.array_equal(finite, np.isfinite(numba_ranges))
        assert np.max(np.abs(reference[finite] - numba_ranges[finite]), initial=0.0) < EXACT


def test_bearing_is_within_its_bound_of_atan2():
    # The numba scan picks each object's beams with this cheap atan2; its sectors are widened
    # by SECTOR_SLACK, which must stay far above the error (here against numpy's arctan2).
    from ball_world.core.lidar_kernel import BEARING_ERROR, bearing, SECTOR_SLACK
    angles = np.linspace(-math.pi, math.pi, 20001)
    for length in (1e-6, 1.0, 1e6):
        x = length * np.cos(angles)
        y = length * np.sin(angles)
        got = np.array([bearing(b, a) for a, b in zip(x, y)])
        error = np.abs(np.angle(np.exp(1j * (got - np.arctan2(y, x)))))
        assert error.max() < BEARING_ERROR
    assert 10.0 * BEARING_ERROR < SECTOR_SLACK


@pytest.mark.parametrize('increment, samples', [
    (0.0, 7), (1e-13, 5), (2.0 * math.pi / 360, 360), (-0.3, 40), (2.9, 9), (7.0, 3)])
def test_odd_fans_and_scanners_on_walls_agree_with_the_reference(increment, samples):
    # The numba scan tests each ball and wall against the beams of its sector, looked for on
    # every turn the fan makes; a fan of one direction (increment 0 or nearly), fans over
    # several turns, and scanners on a wall's line, at a wall's end or inside a wall's corner
    # take its other paths. The reference tests everything. (A scanner exactly on a wall
    # with range_min 0 sees range 0, whose sign the two may write differently: compared as
    # numbers.)
    rng = np.random.default_rng(samples)
    positions, radii, walls = random_world(rng, 300)
    ends = walls[:4, :2]
    on_line = walls[4, :2] + 1.7 * (walls[4, 2:] - walls[4, :2])
    on_wall = walls[5, :2] + 0.5 * (walls[5, 2:] - walls[5, :2])
    for origin in (*ends, on_line, on_wall, positions[0], np.array([15.0, 15.0])):
        for range_min in (0.0, 0.2):
            beams = Fan(float(rng.uniform(-4.0, 4.0)), increment, samples, range_min, 20.0)
            yaw = float(rng.uniform(-10.0, 10.0))
            numpy_ranges = lidar.distances(positions, radii, walls, origin, yaw, beams, 0,
                                           'numpy')
            numba_ranges = lidar.distances(positions, radii, walls, origin, yaw, beams, 0,
                                           'numba')
            assert np.array_equal(numpy_ranges, numba_ranges)
            if range_min > 0.0:
                assert numpy_ranges.tobytes() == numba_ranges.tobytes()


def test_noise_has_the_asked_mean_and_spread():
    # In the box [0, 10]^2 from its centre, the true ranges are known (5 / max(|cos|, |sin|));
    # 400 scans of 360 beams: 144,000 draws. The mean error is within 4 standard errors of 0
    # and the spread within 2% of the asked 0.01 m (the standard error of a sample standard
    # deviation is sigma / sqrt(2 n), 0.2% here).
    stddev = 0.01
    beams = Fan.full_turn(360, range_max=12.0, noise_stddev=stddev)
    angles = beams.angle_min + np.arange(360) * beams.angle_increment
    truth = 5.0 / np.maximum(np.abs(np.cos(angles)), np.abs(np.sin(angles)))
    walls = box(0.0, 0.0, 10.0, 10.0)
    errors = np.concatenate([
        lidar.scan(np.empty((0, 2)), np.empty(0), walls, (5.0, 5.0), 0.0, beams, seed=7,
                   name='ball_0', step=step) - truth for step in range(400)])
    assert abs(errors.mean()) < 4.0 * stddev / math.sqrt(len(errors))
    assert errors.std() == pytest.approx(stddev, rel=0.02)


def test_noise_is_reproducible_and_leaves_infinities_alone():
    beams = Fan.full_turn(90, range_max=6.0, noise_stddev=0.05)
    positions = np.array([[5.0, 5.0], [7.0, 5.0]])
    radii = np.array([0.3, 0.5])
    walls = box(0.0, 0.0, 10.0, 10.0)

    def one(name, step, seed=3):
        return lidar.scan(positions, radii, walls, positions[0], 0.2, beams, 0, seed=seed,
                          name=name, step=step)
    first = one('ball_0', 12)
    assert first.tobytes() == one('ball_0', 12).tobytes()
    for other in (one('ball_0', 13), one('ball_1', 12), one('ball_0', 12, seed=4)):
        assert not np.array_equal(first, other)
    exact = lidar.scan(positions, radii, walls, positions[0], 0.2, beams._replace(
        noise_stddev=0.0), 0)
    assert np.array_equal(np.isfinite(first), np.isfinite(exact))
    assert np.array_equal(first[~np.isfinite(first)], exact[~np.isfinite(exact)])
    # The name's key is the same in another process with another hash() salt.
    child = subprocess.run(
        [sys.executable, '-c', 'from ball_world.core import lidar; '
         'print(lidar.name_key("ball_0"))'], capture_output=True, text=True, check=True,
        env={**os.environ, 'PYTHONHASHSEED': '12345'})
    assert int(child.stdout) == lidar.name_key('ball_0')


def test_noise_seeds_draw_what_default_rng_draws():
    # Recordings hold noise drawn from np.random.default_rng([seed, key, step]); the cheaper
    # seeding must give the very same numbers, for seeds, keys and steps of one 32-bit word
    # and of two (SeedSequence takes an int as its words), and for one Generator reseeded
    # step after step.
    from ball_world.core.noise_seed import NoiseSeeds
    rng = np.random.default_rng(11)
    cases = [(0, 0, 0), (2**63 - 1, 2**64 - 1, 2**63 - 1), (5, 2**32, 2**32 - 1),
             (1, 7, 2**32), (0, lidar.name_key('ball_0'), 1)]
    cases += [(int(rng.integers(2**63)), int(rng.integers(2**63)), int(rng.integers(2**40)))
              for _ in range(60)]
    cases += [(int(rng.integers(2**31)), int(rng.integers(2**31)), int(rng.integers(10**6)))
              for _ in range(60)]
    for seed, key, step in cases:
        seeds = NoiseSeeds(seed, key)
        for at in (step, step + 1, step):
            expected = np.random.default_rng([seed, key, at]).normal(0.0, 0.01, 40)
            assert seeds.generator(at).normal(0.0, 0.01, 40).tobytes() == expected.tobytes()
    with pytest.raises(ValueError, match='non-negative'):
        NoiseSeeds(0, 1).generator(-1)


def test_hit_points_lie_on_what_was_hit():
    beams = Fan.full_turn(36)
    walls = box(0.0, 0.0, 10.0, 10.0)
    got = lidar.scan(np.empty((0, 2)), np.empty(0), walls, (5.0, 5.0), 0.0, beams)
    points = lidar.hit_points((5.0, 5.0), 0.0, beams, got)
    on_wall = np.minimum(np.minimum(points[:, 0], 10.0 - points[:, 0]),
                         np.minimum(points[:, 1], 10.0 - points[:, 1]))
    assert len(points) == 36 and np.all(np.abs(on_wall) < EXACT)


@pytest.mark.parametrize('bad, words', [
    (Fan(0.0, 0.1, 0, 0.1, 12.0), 'at least one beam'),
    (Fan(0.0, 0.1, 10, 5.0, 1.0), 'range_min'),
    (Fan(0.0, math.nan, 10, 0.1, 1.0), 'finite'),
    (Fan(0.0, 0.1, 10, 0.1, 1.0, -1.0), 'noise_stddev'),
])
def test_a_fan_that_cannot_scan_is_refused_by_name(bad, words):
    with pytest.raises(ValueError, match=words):
        bad.check()


def test_benchmark_times_a_scan_beside_a_step():
    # No timing is asserted (machines differ): a row per N, every figure a positive number.
    from benchmarks import lidar_speed
    [row] = lidar_speed.rows([300], 1)
    cells = [cell.strip().replace(',', '') for cell in row.strip('|').split('|')]
    n, within, step, numba_scan, numpy_scan, ratio = cells
    assert n == '300' and int(within) > 0
    assert all(float(value) > 0.0 for value in (step, numba_scan, numpy_scan, ratio))
