"""The seed's collision rules on hand-computed cases, and the core's invariants."""
import functools
import math

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from ball_world.core.broadphase import grid_pairs, wall_pairs
from ball_world.core.scenario import build_world
from ball_world.core.world import BACKENDS, Walls, World

BOX = [[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 10.0], [10.0, 10.0, 0.0, 10.0],
       [0.0, 10.0, 0.0, 0.0]]


@pytest.fixture(params=BACKENDS)
def world(request):
    """World, once per backend: every rule must hold for numpy and for the numba kernels."""
    return functools.partial(World, backend=request.param)


def one_ball(world, x, y, vx, vy, walls, radius=0.5):
    return world([[x, y]], [[vx, vy]], [radius], [1.0], walls=walls)


# Ball and wall -------------------------------------------------------------------------

@pytest.mark.parametrize('side', [-1.0, 1.0])
def test_vertical_wall_reflects_vx_from_either_side(world, side):
    # Wall x = 5; ball 0.55 m away on either side, moving towards it at 1 m/s.
    world = one_ball(world, 5.0 + side * 0.55, 2.0, -side * 1.0, 0.3, [[5.0, 0.0, 5.0, 10.0]])
    stats = world.step(0.1)  # moves 0.1 m: |r_x - x_w| = 0.45 < 0.5, approaching
    assert stats.ball_wall == 1
    np.testing.assert_array_equal(world.velocities[0], [side * 1.0, 0.3])


@pytest.mark.parametrize('side', [-1.0, 1.0])
def test_horizontal_wall_reflects_vy_from_either_side(world, side):
    world = one_ball(world, 3.0, 5.0 + side * 0.55, 0.7, -side * 1.0, [[0.0, 5.0, 10.0, 5.0]])
    stats = world.step(0.1)
    assert stats.ball_wall == 1
    np.testing.assert_array_equal(world.velocities[0], [0.7, side * 1.0])


def test_oblique_wall_uses_v_prime_equals_2_v_dot_w_w_minus_v(world):
    # Wall along w = (1, 1)/sqrt(2) through the origin; ball just off it, moving at it.
    w = np.array([1.0, 1.0]) / math.sqrt(2.0)
    v = np.array([1.0, -2.0])
    normal = np.array([-1.0, 1.0]) / math.sqrt(2.0)
    start = np.array([5.0, 5.0]) + normal * 0.48 - v * 0.01
    world = one_ball(world, *start, *v, [[0.0, 0.0, 10.0, 10.0]])
    stats = world.step(0.01)
    assert stats.ball_wall == 1
    expected = 2.0 * np.dot(v, w) * w - v
    np.testing.assert_allclose(world.velocities[0], expected, rtol=0, atol=1e-15)
    assert np.dot(world.velocities[0], normal) > 0  # now leaving the wall


def test_segment_end_point_reflects_about_end_to_centre_normal(world):
    # Segment from (0, 0) to (5, 0); a ball beyond its end (5, 0), moving left-down.
    v = np.array([-1.0, -1.0])
    centre_after = np.array([5.3, 0.3])  # |s| = 0.424 < 0.5 from the end point
    world = one_ball(world, *(centre_after - v * 0.01), *v, [[0.0, 0.0, 5.0, 0.0]])
    stats = world.step(0.01)
    assert stats.ball_wall == 1
    n = np.array([0.3, 0.3]) / math.hypot(0.3, 0.3)
    np.testing.assert_allclose(world.velocities[0], v - 2 * np.dot(v, n) * n, atol=1e-15)
    np.testing.assert_allclose(world.velocities[0], [1.0, 1.0], atol=1e-15)


def test_ball_past_the_end_of_a_segment_does_not_collide(world):
    world = one_ball(world, 6.0, 0.3, 0.0, -1.0, [[0.0, 0.0, 5.0, 0.0]])
    world.step(0.01)
    assert world.velocities[0].tolist() == [0.0, -1.0]


def test_touching_but_leaving_a_wall_is_left_alone(world):
    world = one_ball(world, 5.3, 2.0, 1.0, 0.0, [[5.0, 0.0, 5.0, 10.0]])  # overlapping, separating
    stats = world.step(0.01)
    assert stats.ball_wall == 0
    assert world.velocities[0].tolist() == [1.0, 0.0]


# Ball and ball -------------------------------------------------------------------------

def test_head_on_unequal_masses_match_momentum_and_energy(world):
    m1, m2, u1, u2 = 1.0, 3.0, 2.0, -1.0
    world = world([[0.0, 0.0], [1.05, 0.0]], [[u1, 0.0], [u2, 0.0]], [0.5, 0.5], [m1, m2])
    stats = world.step(0.02)  # gap closes by 0.06 m: touching and approaching
    assert stats.ball_ball == 1
    # 1D elastic collision, from conservation of momentum and kinetic energy.
    v1 = ((m1 - m2) * u1 + 2 * m2 * u2) / (m1 + m2)
    v2 = ((m2 - m1) * u2 + 2 * m1 * u1) / (m1 + m2)
    np.testing.assert_allclose(world.velocities, [[v1, 0.0], [v2, 0.0]], atol=1e-15)
    assert (v1, v2) == (-2.5, 0.5)


def test_glancing_hit_of_equal_masses_leaves_perpendicular_velocities(world):
    world = world([[0.0, 0.0], [0.8, 0.5]], [[1.0, 0.0], [0.0, 0.0]], [0.5, 0.5], [2.0, 2.0])
    stats = world.step(0.01)
    assert stats.ball_ball == 1
    va, vb = world.velocities
    assert abs(np.dot(va, vb)) < 1e-15
    np.testing.assert_allclose(va + vb, [1.0, 0.0], atol=1e-15)
    # The struck ball moves along the line of centres at the moment of detection.
    rel = world.positions[1] - world.positions[0]
    assert abs(rel[0] * vb[1] - rel[1] * vb[0]) < 1e-15


def test_seed_formula_on_an_arbitrary_pair(world):
    ra, rb = np.array([0.0, 0.0]), np.array([0.6, 0.7])
    va, vb = np.array([1.5, 0.2]), np.array([-0.4, -0.9])
    ma, mb = 1.3, 0.7
    h = 1e-3
    world = world([ra - va * h, rb - vb * h], [va, vb], [0.5, 0.5], [ma, mb])
    world.step(h)
    d = world.positions[0] - world.positions[1]
    exp_a = va - 2 * mb / (ma + mb) * np.dot(va - vb, d) / np.dot(d, d) * d
    exp_b = vb - 2 * ma / (ma + mb) * np.dot(vb - va, -d) / np.dot(d, d) * -d
    np.testing.assert_allclose(world.velocities, [exp_a, exp_b], atol=1e-15)


def test_overlapping_but_separating_pair_is_left_alone(world):
    world = world([[0.0, 0.0], [0.8, 0.0]], [[-1.0, 0.0], [1.0, 0.0]], [0.5, 0.5], [1.0, 1.0])
    stats = world.step(0.01)
    assert stats.ball_ball == 0
    assert world.velocities.tolist() == [[-1.0, 0.0], [1.0, 0.0]]


def test_three_ball_contact_resolves_pairwise_and_conserves_energy(world):
    # A ball hits two touching balls at once (Newton's cradle in a line).
    world = world([[0.0, 0.0], [0.99, 0.0], [1.98, 0.0]], [[1.0, 0.0], [0.0, 0.0], [0.0, 0.0]],
                  [0.5, 0.5, 0.5], [1.0, 1.0, 1.0])
    e0 = world.kinetic_energy()
    world.step(0.001)
    np.testing.assert_allclose(world.velocities, [[0, 0], [0, 0], [1, 0]], atol=1e-15)
    assert world.kinetic_energy() == pytest.approx(e0, rel=1e-15)


def test_impulse_changes_velocity_by_j_over_m(world):
    world = world([[1.0, 1.0]], [[0.5, 0.0]], [0.2], [4.0])
    world.apply_impulse(0, 2.0, -1.0)
    assert world.velocities[0].tolist() == [1.0, -0.25]


# Tunnelling ----------------------------------------------------------------------------

def test_ball_at_1000_m_per_s_stays_in_a_10_m_box(world):
    world = world([[5.0, 5.0]], [[1000.0, 371.0]], [0.1], [1.0], walls=BOX)
    for _ in range(500):
        world.step(0.01)
        assert np.all(world.positions > 0.0) and np.all(world.positions < 10.0)
    assert np.hypot(*world.velocities[0]) == pytest.approx(math.hypot(1000.0, 371.0))


def test_fast_balls_never_pass_through_each_other(world):
    # Head-on at 500 m/s each; without substeps they would swap sides in one step.
    world = world([[2.0, 5.0], [8.0, 5.0]], [[500.0, 0.0], [-500.0, 0.0]], [0.2, 0.2],
                  [1.0, 1.0], walls=BOX)
    world.step(0.01)
    assert world.positions[0, 0] < world.positions[1, 0]
    assert world.velocities[0, 0] < 0 < world.velocities[1, 0]


# Broadphase ----------------------------------------------------------------------------

@settings(max_examples=30, deadline=None)
@given(st.integers(0, 300), st.integers(0, 2**31), st.floats(0.0, 1.0))
def test_grid_pairs_equal_all_pairs(n, seed, margin):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-5, 5, (n, 2))
    radii = rng.uniform(0.05, 0.4, n)
    a, b, _ = grid_pairs(positions, radii, margin)
    got = set(zip(a.tolist(), b.tolist()))
    d = np.sqrt(((positions[:, None] - positions[None]) ** 2).sum(-1))
    reach = radii[:, None] + radii[None] + margin
    i, j = np.nonzero(np.triu(d < reach, k=1))
    assert got == set(zip(i.tolist(), j.tolist()))
    assert len(got) == len(a)
    # Reusing the previous cell order after the balls moved gives the same pairs.
    moved = positions + rng.uniform(-0.3, 0.3, (n, 2))
    a2, b2, _ = grid_pairs(moved, radii, margin, grid_pairs(positions, radii, margin)[2])
    d2 = np.sqrt(((moved[:, None] - moved[None]) ** 2).sum(-1))
    i2, j2 = np.nonzero(np.triu(d2 < reach, k=1))
    assert set(zip(a2.tolist(), b2.tolist())) == set(zip(i2.tolist(), j2.tolist()))


def test_wall_pairs_find_balls_near_walls_and_segment_ends():
    walls = Walls([[0.0, 0.0, 10.0, 0.0], [5.0, 5.0, 5.0, 6.0]])
    positions = np.array([[3.0, 0.4], [3.0, 0.6], [5.3, 6.2], [5.0, 6.6], [-0.2, -0.2]])
    ball, wall = wall_pairs(positions, np.full(5, 0.25), walls, 0.2)
    assert sorted(zip(ball.tolist(), wall.tolist())) == [(0, 0), (2, 1), (4, 0)]


# Invariants over long random runs ------------------------------------------------------

def random_world(seed, backend, count=60):
    return build_world({'random.count': count, 'random.seed': seed, 'random.speed': 8.0,
                        'physics.backend': backend,
                        'random.radius': [0.1, 0.6],
                        'walls': [2.0, 2.0, 4.0, 3.0, 7.0, 8.0, 7.5, 6.0]})


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 10_000))
@pytest.mark.parametrize('backend', BACKENDS)
def test_long_run_conserves_energy_momentum_free_and_stays_inside(backend, seed):
    world = random_world(seed, backend)
    e0 = world.kinetic_energy()
    collisions = 0
    for _ in range(1500):
        stats = world.step(1 / 60)
        collisions += stats.ball_ball + stats.ball_wall
        assert stats.unresolved == 0
    assert collisions > 100  # the run really exercised collisions
    assert np.all(np.isfinite(world.positions)) and np.all(np.isfinite(world.velocities))
    assert np.all(world.positions > 0.0) and np.all(world.positions < 10.0)
    assert abs(world.kinetic_energy() - e0) <= 1e-12 * e0


def test_momentum_is_conserved_without_walls(world):
    boxed = build_world({'random.count': 80, 'random.seed': 3, 'random.speed': 5.0})
    walls_free = world(boxed.positions, boxed.velocities, boxed.radii, boxed.masses)
    p0 = walls_free.momentum()
    collisions = 0
    for _ in range(200):
        collisions += walls_free.step(1 / 60).ball_ball
    assert collisions > 10
    np.testing.assert_allclose(walls_free.momentum(), p0, rtol=0, atol=1e-12)


@pytest.mark.parametrize('backend', BACKENDS)
def test_identical_inputs_give_bit_identical_trajectories(backend):
    runs = []
    for _ in range(2):
        world = random_world(42, backend)
        for k in range(600):
            if k == 100:
                world.apply_impulse(3, 0.5, -0.25)
            world.step(1 / 60)
        runs.append((world.positions.tobytes(), world.velocities.tobytes()))
    assert runs[0] == runs[1]


def test_backends_agree_where_the_contact_order_cannot_matter():
    # Isolated pairwise collisions: one contact at a time, so both backends must apply the
    # same seed formula to the same numbers.
    worlds = [World([[0.0, 0.0], [1.05, 0.1], [5.0, 5.0]], [[2.0, 0.0], [-1.0, 0.3], [0, 1]],
                    [0.5, 0.5, 0.2], [1.0, 3.0, 1.0], walls=BOX, backend=b) for b in BACKENDS]
    collisions = 0
    for _ in range(200):
        stats = [w.step(0.02) for w in worlds]
        assert stats[0].ball_ball == stats[1].ball_ball
        assert stats[0].ball_wall == stats[1].ball_wall
        collisions += stats[0].ball_ball + stats[0].ball_wall
    assert collisions >= 3
    assert worlds[0].positions.tolist() == worlds[1].positions.tolist()
    assert worlds[0].velocities.tolist() == worlds[1].velocities.tolist()
