"""Exact mode against closed forms: box paths, scattering angles, walls, end points, Newton's
cradle, near-contact cases, and a hard-disk gas against kinetic theory.

Every reference here is computed from the geometry of the case (unfolded reflections, contact
times from the initial gap, the textbook outgoing velocities), never from the kernel.
"""
import math

from benchmarks.exact_speed import bidisperse_worlds
from benchmarks.gas import enskog_collision_rate, Gas, henderson_z, Rates
from hypothesis import given, settings, strategies as st
from numba import njit
import numpy as np
import pytest

from ball_world.core import exact
from ball_world.core.scenario import arena_walls
from ball_world.core.world import World

#: Relative size of a rounding error that a position, velocity or energy may carry.
ROUNDING = 1e-12


def box(side):
    """The four walls of the square [0, side]^2."""
    walls, _ = arena_walls({'arena': [0.0, 0.0, side, side]})
    return walls


def run(world, dt, steps):
    """Step `steps` times; return the summed (ball_ball, ball_wall, events)."""
    totals = np.zeros(3, dtype=np.int64)
    for _ in range(steps):
        totals += exact.step(world, dt)
    return totals.tolist()


def folded(start, velocity, t, low, high):
    """Closed-form coordinate of a ball bouncing between low and high (unfolded reflection)."""
    span = high - low
    unfolded = math.fmod(start - low + velocity * t, 2.0 * span)
    if unfolded < 0.0:
        unfolded += 2.0 * span
    return low + (unfolded if unfolded <= span else 2.0 * span - unfolded)


@njit(cache=True)
def smallest_gaps(x, radii, side):
    """(smallest (distance - R_a - R_b) / (R_a + R_b) over pairs, smallest wall clearance / R)."""
    n = x.shape[0]
    closest = np.inf  # smallest distance^2 / (R_a + R_b)^2
    wall = np.inf
    for i in range(n):
        for j in range(i + 1, n):
            sigma = radii[i] + radii[j]
            dx = x[i, 0] - x[j, 0]
            dy = x[i, 1] - x[j, 1]
            closest = min(closest, (dx * dx + dy * dy) / (sigma * sigma))
        clearance = min(x[i, 0], x[i, 1], side - x[i, 0], side - x[i, 1]) - radii[i]
        wall = min(wall, clearance / radii[i])
    return math.sqrt(closest) - 1.0, wall


# One ball in a box ---------------------------------------------------------------------------

@pytest.mark.parametrize('speed', [1.0, 100.0, 1000.0, 100_000.0])
def test_one_ball_in_a_box_follows_the_unfolded_reflection_path(speed):
    side, radius, dt, steps = 10.0, 0.5, 1.0 / 60.0, 600
    heading = 0.3
    vx, vy = speed * math.cos(heading), speed * math.sin(heading)
    world = World([[3.0, 4.0]], [[vx, vy]], [radius], [1.0], walls=box(side))
    if speed > 1000.0:
        steps = 6  # still about 1,100 wall hits
    _, ball_wall, _ = run(world, dt, steps)
    t = steps * dt
    expected = [folded(3.0, vx, t, radius, side - radius),
                folded(4.0, vy, t, radius, side - radius)]
    assert np.abs(world.positions[0] - expected).max() < 1e-8
    np.testing.assert_allclose(np.abs(world.velocities[0]), [abs(vx), abs(vy)], rtol=ROUNDING)
    # Every crossing of a wall in the unfolded path is one collision.
    span = side - 2.0 * radius
    hits = sum(math.floor(abs(start - radius + v * t) / span) + (start - radius + v * t < 0)
               for start, v in ((3.0, vx), (4.0, vy)))
    assert ball_wall == hits


# Two balls -----------------------------------------------------------------------------------

@pytest.mark.parametrize('travel', [0.01, 0.1, 0.5, 1.0, 2.0])
@pytest.mark.parametrize('impact', [0.0, 0.5, 0.9, 0.99])
def test_equal_balls_scatter_at_asin_b_over_sigma(impact, travel):
    """A striker hits a resting ball of equal mass at impact parameter b = impact * sigma.

    The target leaves along the line of centres at contact, asin(b / sigma) from the
    incoming direction, with speed u cos; the striker at right angles with speed u sin.
    """
    radius, dt = 0.5, 0.01
    sigma = 2.0 * radius
    b = impact * sigma
    u = travel * radius / dt
    along = math.sqrt(sigma * sigma - b * b)  # striker's distance behind the target at contact
    t_contact = 0.37 * dt
    world = World([[-along - u * t_contact, b], [0.0, 0.0]], [[u, 0.0], [0.0, 0.0]],
                  [radius, radius], [1.0, 1.0])
    ball_ball, _, _ = exact.step(world, dt)
    assert ball_ball == 1
    alpha = math.asin(b / sigma)
    striker, target = world.velocities
    assert abs(math.atan2(target[1], target[0]) - (-alpha)) < 1e-9
    assert math.hypot(*target) == pytest.approx(u * math.cos(alpha), rel=ROUNDING)
    if impact > 0.0:
        assert abs(math.atan2(striker[1], striker[0]) - (math.pi / 2.0 - alpha)) < 1e-9
    assert math.hypot(*striker) == pytest.approx(u * math.sin(alpha), rel=ROUNDING,
                                                 abs=ROUNDING * u)
    after = dt - t_contact
    target_end = u * math.cos(alpha) * after * np.array([math.cos(alpha), -math.sin(alpha)])
    striker_end = np.array([-along, b]) + u * math.sin(alpha) * after * np.array(
        [math.sin(alpha), math.cos(alpha)])
    np.testing.assert_allclose(world.positions, [striker_end, target_end], rtol=0,
                               atol=ROUNDING * (1.0 + u * dt))


def test_unequal_masses_head_on():
    # m1 = 1 at x = -1 moving +3, m2 = 4 at x = +1 moving -1; radii 0.5 and 0.25.
    world = World([[-1.0, 0.0], [1.0, 0.0]], [[3.0, 0.0], [-1.0, 0.0]], [0.5, 0.25],
                  [1.0, 4.0])
    dt = 0.5
    t_contact = (2.0 - 0.75) / 4.0
    ball_ball, _, _ = exact.step(world, dt)
    assert ball_ball == 1
    # 1D elastic: v1' = ((m1 - m2) v1 + 2 m2 v2) / (m1 + m2), and symmetrically.
    v1 = ((1.0 - 4.0) * 3.0 + 2.0 * 4.0 * -1.0) / 5.0
    v2 = ((4.0 - 1.0) * -1.0 + 2.0 * 1.0 * 3.0) / 5.0
    np.testing.assert_allclose(world.velocities, [[v1, 0.0], [v2, 0.0]], rtol=0, atol=1e-14)
    x1 = -1.0 + 3.0 * t_contact + v1 * (dt - t_contact)
    x2 = 1.0 - t_contact + v2 * (dt - t_contact)
    np.testing.assert_allclose(world.positions, [[x1, 0.0], [x2, 0.0]], rtol=0, atol=1e-14)


def test_ball_hits_a_30_degree_wall_at_the_contact_time():
    w = np.array([math.cos(math.pi / 6.0), math.sin(math.pi / 6.0)])
    normal = np.array([-w[1], w[0]])
    radius, clearance = 0.5, 2.0
    start = 5.0 * w + clearance * normal
    v = np.array([0.3, -4.0])
    closing = -float(v @ normal)
    t_contact = (clearance - radius) / closing
    dt = 2.0 * t_contact
    world = World([start], [v], [radius], [1.0], walls=[[0.0, 0.0, *(20.0 * w)]])
    _, ball_wall, _ = exact.step(world, dt)
    assert ball_wall == 1
    reflected = 2.0 * (v @ w) * w - v
    np.testing.assert_allclose(world.velocities[0], reflected, rtol=0, atol=1e-14)
    end = start + v * t_contact + reflected * (dt - t_contact)
    np.testing.assert_allclose(world.positions[0], end, rtol=0, atol=1e-14)


def test_ball_hits_a_segment_end_point_about_the_end_to_centre_normal():
    # Segment from (-5, 0) to (0, 0); ball of radius 0.5 at height 0.3 moving in -x at 10 m/s
    # touches the end point when its centre is at (0.4, 0.3): normal (0.8, 0.6).
    world = World([[3.0, 0.3]], [[-10.0, 0.0]], [0.5], [1.0], walls=[[-5.0, 0.0, 0.0, 0.0]])
    dt = 0.5
    t_contact = (3.0 - 0.4) / 10.0
    _, ball_wall, _ = exact.step(world, dt)
    assert ball_wall == 1
    n = np.array([0.8, 0.6])
    reflected = np.array([-10.0, 0.0]) - 2.0 * (-10.0 * 0.8) * n
    np.testing.assert_allclose(world.velocities[0], reflected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(world.positions[0], [0.4, 0.3] + reflected * (dt - t_contact),
                               rtol=0, atol=1e-13)


@pytest.mark.parametrize('gap', [0.0, 1e-9])
@pytest.mark.parametrize('striker_gap', [0.0, 0.3])
def test_newtons_cradle(gap, striker_gap):
    """Five equal balls in a row; the far one leaves with the striker's speed, the rest rest.

    With gaps g between the resting balls, each of them has moved g by the time it stops,
    and the far ball leaves 3 g / u after the striker's impact.
    """
    radius, u, dt = 0.5, 1.0, 1.0
    sigma = 2.0 * radius
    x = [0.0, sigma + striker_gap]
    for _ in range(3):
        x.append(x[-1] + sigma + gap)
    world = World([[xi, 2.0] for xi in x], [[u, 0.0]] + [[0.0, 0.0]] * 4, [radius] * 5,
                  [1.0] * 5)
    ball_ball, _, _ = exact.step(world, dt)
    assert ball_ball == 4
    t_impact = striker_gap / u
    leave = t_impact + 3.0 * gap / u
    expected = [x[0] + u * t_impact, x[1] + gap, x[2] + gap, x[3] + gap,
                x[4] + u * (dt - leave)]
    np.testing.assert_allclose(world.positions[:, 0], expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(world.velocities[:4], 0.0, rtol=0, atol=ROUNDING)
    np.testing.assert_allclose(world.velocities[4], [u, 0.0], rtol=0, atol=ROUNDING)
    # And nothing more happens: the far ball flies on, the rest stay where they are.
    before = world.positions.copy()
    assert run(world, dt, 10)[:2] == [0, 0]
    np.testing.assert_array_equal(world.positions[:4], before[:4])


def test_worlds_wider_than_the_bucket_table_and_walls_longer_than_it():
    """Cells far apart share buckets and long walls are checked by every ball: exact still.

    Two head-on pairs 100 km apart, and a small ball hitting a 2 km wall (far more cells
    than the bucket table holds) at the closed-form time.
    """
    radius, dt = 0.01, 0.1
    pairs = [[0.0, 0.0], [0.1, 0.0], [1e5, 0.0], [1e5 + 0.1, 0.0]]
    ball = [[0.0, 5.0 + 0.5]]
    world = World(pairs + ball, [[1.0, 0.0], [-1.0, 0.0]] * 2 + [[0.0, -10.0]],
                  [radius] * 5, [1.0] * 5, walls=[[-1e3, 5.0, 1e3, 5.0]])
    ball_ball, ball_wall, _ = exact.step(world, dt)
    assert (ball_ball, ball_wall) == (2, 1)
    # Each pair meets after (0.1 - 0.02) / 2 s and swaps velocities.
    t_pair = 0.04
    for first in (0, 2):
        left = pairs[first][0] + t_pair - (dt - t_pair)
        np.testing.assert_allclose(world.positions[first:first + 2, 0],
                                   [left, left + 0.1 + 2 * (dt - 2 * t_pair)], atol=1e-9)
    t_wall = (0.5 - radius) / 10.0
    np.testing.assert_allclose(world.positions[4], [0.0, 5.0 + radius + 10.0 * (dt - t_wall)],
                               atol=1e-12)


# Near contact --------------------------------------------------------------------------------

def test_shallowest_graze_is_found_and_a_near_miss_is_not():
    radius, dt = 0.5, 0.01
    u = 2.0 * radius / dt  # two radii per step: a posteriori detection would see neither
    for offset, hits in ((1.0 - 1e-12, 1), (1.0 + 1e-12, 0)):
        world = World([[-0.99 - 0.5 * u * dt, offset], [0.0, 0.0]], [[u, 0.0], [0.0, 0.0]],
                      [radius, radius], [1.0, 1.0])
        assert run(world, dt, 3)[0] == hits
        assert (world.velocities[1, 0] > 0.0) == bool(hits)


def test_touching_balls_at_rest_stay_exactly_put():
    x = [[1.0, 1.0], [2.0, 1.0], [3.0, 1.0], [9.5, 5.0], [0.5, 0.5]]
    world = World(x, np.zeros((5, 2)), [0.5] * 5, [1.0] * 5, walls=box(10.0))
    assert run(world, 0.1, 100) == [0, 0, 0]
    np.testing.assert_array_equal(world.positions, x)


def test_ball_sliding_along_a_wall_keeps_touching_it():
    radius, u, dt, side = 0.5, 3.0, 0.05, 10.0
    world = World([[2.0, radius]], [[u, 0.0]], [radius], [1.0], walls=box(side))
    for k in range(1, 201):
        exact.step(world, dt)
        assert world.positions[0, 1] == radius and world.velocities[0, 1] == 0.0
    expected = folded(2.0, u, 200 * dt, radius, side - radius)
    assert abs(world.positions[0, 0] - expected) < 1e-12


@pytest.mark.parametrize('closing, hits', [(1.0, 1), (-1.0, 0), (0.0, 0)])
def test_overlapping_balls_part_without_sticking(closing, hits):
    # Built 20% overlapped: approaching, they collide once at once; otherwise never.
    world = World([[0.0, 0.0], [0.8, 0.0]], [[closing, 0.0], [-closing, 0.0]], [0.5, 0.5],
                  [1.0, 1.0])
    assert run(world, 0.1, 50)[0] == hits
    if closing:
        assert world.positions[1, 0] - world.positions[0, 0] > 0.8 + 49 * 0.1
    np.testing.assert_array_equal(world.velocities[:, 1], 0.0)


def hexagonal_cluster(rings, radius, centre):
    """A hexagonal patch of touching balls: 1 + 3 rings (rings + 1) centres."""
    points = []
    for q in range(-rings, rings + 1):
        for r in range(max(-rings, -q - rings), min(rings, -q + rings) + 1):
            points.append((centre[0] + 2.0 * radius * (q + 0.5 * r),
                           centre[1] + 2.0 * radius * (math.sqrt(3.0) / 2.0 * r)))
    return np.array(points)


def test_dense_touching_cluster_hit_hard_keeps_energy_and_never_overlaps():
    radius, side, dt = 0.5, 16.0, 0.01
    cluster = hexagonal_cluster(3, radius, (8.0, 8.0))  # 37 touching balls, rounding overlaps
    x = np.vstack((cluster, [[1.0, 8.3]]))
    v = np.zeros_like(x)
    v[-1] = (400.0, 0.0)  # eight radii per step
    world = World(x, v, np.full(len(x), radius), np.ones(len(x)), walls=box(side))
    energy = world.kinetic_energy()
    for _ in range(300):
        exact.step(world, dt)
        pair, wall = smallest_gaps(world.positions, world.radii, side)
        assert pair > -ROUNDING and wall > -ROUNDING
    assert world.kinetic_energy() == pytest.approx(energy, rel=ROUNDING)


def test_jammed_ball_raises_instead_of_hanging():
    # A ball exactly as wide as the corridor between two walls, moving across it: an
    # infinite number of collisions at one instant.
    world = World([[0.5, 0.0]], [[1.0, 0.0]], [0.5], [1.0],
                  walls=[[0.0, -5.0, 0.0, 5.0], [1.0, -5.0, 1.0, 5.0]])
    with pytest.raises(exact.EventBudgetExceeded, match='jammed'):
        exact.step(world, 0.1)


def test_non_finite_state_is_refused_in_one_line():
    world = World([[0.0, 0.0]], [[0.0, 0.0]], [0.5], [1.0])
    world.velocities[0, 0] = math.nan  # World refuses it; written past its checks
    with pytest.raises(ValueError, match='not finite'):
        exact.step(world, 0.1)


# Edits between steps -------------------------------------------------------------------------

def test_impulse_between_steps_is_taken_into_account():
    # Ball 0 flies away from resting ball 1: nothing to predict. An impulse turns it around;
    # it must then hit ball 1 head on and stop, ball 1 leaving at its speed.
    u, dt = 2.0, 0.1
    world = World([[1.0, 0.0], [-1.0, 0.0]], [[u, 0.0], [0.0, 0.0]], [0.5, 0.5], [1.0, 1.0])
    run(world, dt, 5)  # ball 0 at x = 2
    world.apply_impulse(0, -2.0 * u, 0.0)
    assert run(world, dt, 12)[0] == 1
    # Ball 0 travels 2 m back to contact at x = 0 (1 s), then ball 1 moves for 0.2 s.
    np.testing.assert_allclose(world.positions, [[0.0, 0.0], [-1.4, 0.0]], atol=1e-12)
    run(world, dt, 5)
    np.testing.assert_allclose(world.positions, [[0.0, 0.0], [-2.4, 0.0]], atol=1e-12)
    np.testing.assert_allclose(world.velocities, [[0.0, 0.0], [-u, 0.0]], atol=1e-12)


def test_teleported_ball_and_changed_ball_count_are_taken_into_account():
    dt = 0.1
    world = World([[0.0, 0.0], [5.0, 0.0]], [[1.0, 0.0], [0.0, 0.0]], [0.5, 0.5], [1.0, 1.0])
    run(world, dt, 2)
    world.positions[1] = (1.7, 0.0)  # now 1.5 m ahead of ball 0: contact after 0.5 s
    assert run(world, dt, 6)[0] == 1
    np.testing.assert_allclose(world.positions[:, 0], [0.7, 1.8], atol=1e-12)
    # A third ball appears in ball 1's path.
    world.positions = np.vstack((world.positions, [[3.2, 0.0]]))
    world.velocities = np.vstack((world.velocities, [[0.0, 0.0]]))
    world.radii = np.append(world.radii, 0.5)
    world.masses = np.append(world.masses, 1.0)
    assert run(world, dt, 10)[0] == 1
    # Ball 1 (at 1.8) reaches it after 0.4 s and stops; ball 2 moves for the other 0.6 s.
    np.testing.assert_allclose(world.positions[:, 0], [0.7, 2.2, 3.8], atol=1e-12)


def test_invalidate_rebuilds_from_the_world_alone():
    side, speed, dt = 10.0, 100.0, 1.0 / 60.0
    world = World([[3.0, 4.0]], [[speed * 0.6, speed * 0.8]], [0.5], [1.0], walls=box(side))
    for _ in range(120):
        exact.step(world, dt)
        exact.invalidate(world)
    t = 120 * dt
    expected = [folded(3.0, 60.0, t, 0.5, 9.5), folded(4.0, 80.0, t, 0.5, 9.5)]
    assert np.abs(world.positions[0] - expected).max() < 1e-8


# Invariants ----------------------------------------------------------------------------------

def random_world(seed, walls):
    """2 to 12 balls of mixed radii and masses placed without overlap in a 6 m box."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 13))
    radii = rng.uniform(0.1, 0.6, n)
    x = np.empty((n, 2))
    for i in range(n):
        while True:
            x[i] = rng.uniform(radii[i], 6.0 - radii[i], 2)
            if all(np.hypot(*(x[i] - x[j])) > radii[i] + radii[j] for j in range(i)):
                break
    v = rng.normal(0.0, 5.0, (n, 2))
    masses = rng.uniform(0.5, 5.0, n)
    return World(x, v, radii, masses, walls=box(6.0) if walls else ())


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dt=st.floats(1e-3, 0.5), walls=st.booleans())
def test_energy_momentum_no_overlap_and_determinism(seed, dt, walls):
    world = random_world(seed, walls)
    twin = random_world(seed, walls)
    energy = world.kinetic_energy()
    momentum = world.momentum()
    for _ in range(30):
        exact.step(world, dt)
        exact.step(twin, dt)
        pair, wall = smallest_gaps(world.positions, world.radii, 6.0)
        assert pair > -ROUNDING
        assert not walls or wall > -ROUNDING
    np.testing.assert_array_equal(world.positions, twin.positions)
    np.testing.assert_array_equal(world.velocities, twin.velocities)
    assert world.kinetic_energy() == pytest.approx(energy, rel=ROUNDING)
    if not walls:
        scale = float(np.abs(world.masses[:, None] * world.velocities).sum())
        np.testing.assert_allclose(world.momentum(), momentum, rtol=0, atol=ROUNDING * scale)


# A hard-disk gas against kinetic theory ------------------------------------------------------

@pytest.mark.parametrize('area_fraction', [0.1, 0.3, 0.5])
def test_gas_keeps_energy_never_overlaps_and_collides_at_the_enskog_rate(area_fraction):
    """400 disks (sigma = 1, m = 1, all at speed 1 at first) in a box, 10,000 steps.

    The hard-disk collision rate per disk (2D Enskog, derived in benchmarks/gas.py):

        omega = 2 n sigma g(sigma) sqrt(pi kT / m),  g(sigma) = (1 - 7 eta / 16) / (1 - eta)^2

    from the virial equation Z = 1 + 2 eta g(sigma) with Henderson's
    Z = (1 + eta^2 / 8) / (1 - eta)^2, eta = n pi sigma^2 / 4.

    Walls change the density within a few diameters of them, so the ball-ball rate is taken
    where the gas is bulk: per disk, over the disks that are at least 3 sigma from every wall
    at both ends of a step, against the Enskog rate at the density measured there. The wall
    rate has its own closed form: by the contact theorem the density at a hard wall is
    beta P = n Z, and disks at that density hit a unit length of wall n Z sqrt(kT / 2 pi m)
    times per second; the centres' walls are 4 (side - sigma) long.
    kT / m = E / N (two degrees of freedom), fixed by the start.
    """
    n_balls, steps, warm_up = 400, 10_000, 1000
    gas = Gas(n_balls, area_fraction, speed=1.0, radius=0.5, seed=3)
    sigma, side = 1.0, gas.side
    # About 300 collisions per disk: the statistical error is well under 1%.
    duration = 300.0 / enskog_collision_rate(4.0 * area_fraction / math.pi, sigma, 0.5)
    dt = duration / steps
    world = gas.world()
    energy = world.kinetic_energy()
    kt_over_m = energy / n_balls
    rates = Rates(gas, margin=0.5 * sigma + 3.0 * sigma)
    per_ball = np.zeros(n_balls, dtype=np.int64)
    for k in range(steps):
        before = world.positions.copy()
        counted = per_ball.copy()
        ball_ball, ball_wall, _ = exact.step(world, dt, per_ball)
        if k >= warm_up:
            rates.add(dt, before, world.positions, ball_ball, ball_wall, per_ball - counted)
        pair, wall = smallest_gaps(world.positions, world.radii, side)
        assert pair > -ROUNDING and wall > -ROUNDING
    assert world.kinetic_energy() == pytest.approx(energy, rel=ROUNDING)

    n_bulk = rates.bulk_density()
    expected = enskog_collision_rate(n_bulk, sigma, kt_over_m)
    assert rates.bulk_collision_rate() == pytest.approx(expected, rel=0.03)
    eta_bulk = n_bulk * math.pi * sigma * sigma / 4.0
    wall_rate = n_bulk * henderson_z(eta_bulk) * math.sqrt(kt_over_m / (2.0 * math.pi))
    assert rates.wall_rate() == pytest.approx(wall_rate * 4.0 * (side - sigma), rel=0.03)


def test_cells_are_one_ball_wide_in_an_even_gas_and_narrow_otherwise():
    """_cell_width widens cells only where that cannot crowd them: an even dilute gas gets
    about its area per ball, a cluster with one far ball and a line of balls keep cells a
    little over the largest diameter."""
    from ball_world.core.exact_kernel import _cell_width, _extent, CELL_MARGIN
    narrowest = 1.0 * CELL_MARGIN
    even = Gas(2000, 0.1, 1.0, 0.5).world('numba').positions
    low, high = even.min(axis=0), even.max(axis=0)
    per_ball = math.sqrt(np.prod(high - low) / len(even))
    assert per_ball > 2.0 * narrowest
    assert _cell_width(even, _extent(even), narrowest) == per_ball
    cluster = np.vstack((np.random.default_rng(1).uniform(0.0, 30.0, (2000, 2)), [[1e5, 1e5]]))
    assert _cell_width(cluster, _extent(cluster), narrowest) == narrowest
    line = np.column_stack((np.linspace(0.0, 1e4, 500), np.zeros(500)))
    assert _cell_width(line, _extent(line), narrowest) == narrowest
    one = np.array([[3.0, 4.0]])
    assert _cell_width(one, _extent(one), narrowest) == narrowest


# Radii 100 times apart: a grid per radius class ---------------------------------------------

def resting_field(count, spacing, corner):
    """count small balls (r = 1 cm) at rest on a square lattice from `corner`."""
    per_row = math.ceil(math.sqrt(count))
    cells = np.stack(np.divmod(np.arange(count), per_row), axis=1)
    return np.asarray(corner) + spacing * cells


@pytest.mark.parametrize('heading', [0.0, 0.5 * math.pi, 1.25 * math.pi, 1.9])
@pytest.mark.parametrize('mover', ['small', 'large'])
def test_a_small_and_a_large_ball_meet_from_afar_at_the_closed_form_time(mover, heading):
    """A ball of 1 cm and one of 1 m (grids of cells 128 times apart in width), 30 m apart,
    one moving head on at the other; 400 small balls rest off their line, filling the small
    grid. Neither is within reach of the other at first: they are found when the mover's
    cell crossings bring them into reach, and must meet at (30 m - 1.01 m) / speed and
    leave with the 1D elastic velocities."""
    u = np.array([math.cos(heading), math.sin(heading)])
    normal = np.array([-u[1], u[0]])
    distance, speed, small_mass, large_mass = 30.0, 10.0, 1.0, 100.0
    start = np.array([2.0, -3.0])
    target = start + distance * u
    # Lattice coordinates along the line (-5 to 5 m from its middle) and across it (4 to 14 m).
    field = resting_field(400, 0.5, [-5.0, 4.0])
    field = start + 15.0 * u + field @ np.stack((u, normal))
    if mover == 'small':
        masses = [small_mass, large_mass]
        radii = [0.01, 1.0]
    else:
        masses = [large_mass, small_mass]
        radii = [1.0, 0.01]
    positions = np.vstack(([start, target], field))
    velocities = np.zeros_like(positions)
    velocities[0] = speed * u
    world = World(positions, velocities, radii + [0.01] * len(field),
                  masses + [1.0] * len(field))
    dt, steps = 0.05, 70
    ball_ball, ball_wall, _ = run(world, dt, steps)
    assert (ball_ball, ball_wall) == (1, 0)
    t_contact = (distance - 1.01) / speed
    m1, m2 = masses
    after_mover = (m1 - m2) / (m1 + m2) * speed
    after_target = 2.0 * m1 / (m1 + m2) * speed
    end = dt * steps
    scale = distance * ROUNDING
    np.testing.assert_allclose(world.velocities[:2], [after_mover * u, after_target * u],
                               rtol=0, atol=speed * ROUNDING)
    np.testing.assert_allclose(world.positions[0], start + u * (speed * t_contact
                               + after_mover * (end - t_contact)), rtol=0, atol=scale)
    np.testing.assert_allclose(world.positions[1], target + u * after_target * (end - t_contact),
                               rtol=0, atol=scale)
    np.testing.assert_array_equal(world.positions[2:], field)


def polydisperse_world(kind, seed):
    """A few thousand balls with radii 100 times apart in a box, at area fraction 0.3:
    'spread' has radii log-uniform from 1 cm to 1 m (four radius classes), placed largest
    first without overlap; 'bidisperse' is benchmarks.exact_speed's (one 1 m ball among
    3,000 of 1 cm, each size at area fraction 0.2). Speeds normal, 1 m/s per axis."""
    if kind == 'bidisperse':
        return bidisperse_worlds(3000, seed)[0], None
    rng = np.random.default_rng(seed)
    radii = np.sort(np.exp(rng.uniform(math.log(0.01), math.log(1.0), 2500)))[::-1]
    side = math.sqrt(math.pi * (radii ** 2).sum() / 0.3)
    x = np.empty((len(radii), 2))
    for i, radius in enumerate(radii):
        while True:
            x[i] = rng.uniform(radius, side - radius, 2)
            if (np.hypot(*(x[:i] - x[i]).T) > radii[:i] + radius).all():
                break
    masses = radii ** 2 / 1e-4
    return World(x, rng.normal(0.0, 1.0, x.shape), radii, masses, walls=box(side)), side


def single_grid_run(world, dt, steps):
    """Step `world` as exact mode did before radius classes (one grid, cells at least one
    largest diameter wide); return each ball's ball-ball collisions."""
    from ball_world.core import exact_kernel as kernel
    geometry = kernel.geometry(world.static)
    state = kernel.build(world.positions, world.velocities, world.radii, *geometry, math.inf)
    assert len(state.grids) == 2  # one class, and the totals
    per_ball = np.zeros(len(world), dtype=np.int64)
    for _ in range(steps):
        status = kernel.advance(state, world.positions, world.velocities, world.radii,
                                world.masses, *geometry, dt, exact.event_budget(len(world)),
                                np.zeros(3, dtype=np.int64), per_ball)
        assert status == kernel.DONE
    return per_ball


@pytest.mark.parametrize('kind', ['spread', 'bidisperse'])
def test_radii_100_apart_keep_energy_never_overlap_and_match_the_single_grid(kind):
    """Both the class grids (exact.step) and the single grid step the same world for 30
    steps of 0.02 s (one or two collisions per ball). Energy holds to rounding, no pair or wall
    overlaps beyond it, and every ball takes part in the same collisions and ends where the
    single grid puts it: the two differ only in which cells they search, so only in the
    last bits of the impact times (prediction times differ)."""
    from ball_world.core.exact_kernel import _classes, CLASS_RATIO
    world, side = polydisperse_world(kind, seed=4)
    twin, _ = polydisperse_world(kind, seed=4)
    classes = _classes(world.radii, CLASS_RATIO)[1]
    assert classes == (4 if kind == 'spread' else 2)
    side = side or world.walls.segments.max()
    dt, steps = 0.02, 30
    energy = world.kinetic_energy()
    per_ball = np.zeros(len(world), dtype=np.int64)
    for _ in range(steps):
        exact.step(world, dt, per_ball)
        pair, wall = smallest_gaps(world.positions, world.radii, side)
        assert pair > -ROUNDING and wall > -ROUNDING
    assert world.kinetic_energy() == pytest.approx(energy, rel=ROUNDING)
    assert per_ball.mean() > 1.0  # collisions per ball
    np.testing.assert_array_equal(per_ball, single_grid_run(twin, dt, steps))
    np.testing.assert_allclose(world.positions, twin.positions, rtol=0, atol=1e-9)


def test_only_the_smallest_class_widens_its_cells():
    """A dilute even gas of small balls gets cells of its area per ball (the unit); two large
    balls far apart keep cells within twice their diameter (rounded up to the unit times a
    power of two), where widening would make each of their predictions search every small
    cell between them."""
    from ball_world.core.exact_kernel import _classes, _grids, CELL_MARGIN, CLASS_RATIO, SHIFT
    small = Gas(2000, 0.05, 1.0, 0.01).world('numba').positions
    x = np.vstack((small, [[-500.0, -500.0], [500.0, 500.0]]))
    radii = np.concatenate((np.full(len(small), 0.01), [1.0, 1.0]))
    classes, count = _classes(radii, CLASS_RATIO)
    assert count == 2 and classes[-2:].tolist() == [1, 1]
    unit, grids = _grids(x, radii, classes, count)
    assert unit > 4.0 * 0.01 * CELL_MARGIN  # the small gas's area per ball, wider than 2 r
    large = unit * 2 ** grids[1, SHIFT]
    assert 2.0 * CELL_MARGIN <= large < 2.0 * 2.0 * CELL_MARGIN
