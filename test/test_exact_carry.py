"""Exact mode's carried state (core.exact_carry): a World rebuilt at step k from its arrays and
the state exported there steps on bit for bit as the World that was never interrupted.

The reference is the uninterrupted run itself (the determinism contract); a World rebuilt
from the arrays alone is stepped beside it, to show that in these gases the carried state
is what makes the difference (it drifts apart from the last bits up). Crafted states are
refused with a ValueError naming what is wrong, before the compiled kernel sees them.
"""
import dataclasses
import math

import numpy as np
import pytest

from ball_world.core import exact, exact_carry
from ball_world.core.scenario import arena_walls
from ball_world.core.world import World

BACKENDS = ('numpy', 'numba')


def gas(count, seed, backend, radii=(0.05,), area_fraction=0.5):
    """A dense gas in a box: count balls on a jittered lattice, radii drawn from `radii`,
    masses and velocities random (so collisions are many and chaotic)."""
    rng = np.random.default_rng(seed)
    radius = rng.choice(np.asarray(radii, dtype=np.float64), count)
    side = math.sqrt(float(np.sum(math.pi * radius * radius)) / area_fraction)
    per_row = math.ceil(math.sqrt(count))
    spacing = side / per_row
    lattice = np.stack(np.divmod(np.arange(count), per_row), axis=1)
    slack = np.maximum(spacing / 2.0 - radius, 0.0)[:, None]
    positions = (lattice + 0.5) * spacing + rng.uniform(-1.0, 1.0, (count, 2)) * slack * 0.9
    walls, _ = arena_walls({'arena': [0.0, 0.0, side, side]})
    return World(positions, rng.normal(0.0, 1.0, (count, 2)), radius,
                 rng.uniform(0.5, 2.0, count), walls=walls, backend=backend, mode='exact')


def copy_of(world):
    """A new World with the same arrays, walls, backend and mode (and nothing carried)."""
    return World(world.positions, world.velocities, world.radii, world.masses,
                 walls=world.walls.segments, backend=world.backend, mode='exact')


def same_bits(a, b):
    return a.shape == b.shape and bool((a.view(np.uint64) == b.view(np.uint64)).all())


def run_against_restored(world, dt, k, steps, edit=None):
    """Step `world` k steps, then (after `edit(world)`, if given) rebuild a World from its
    arrays plus its carried state and one from its arrays alone; step all three on.
    Returns (world, restored, rebuilt, collisions, carried)."""
    collisions = 0
    for _ in range(k):
        collisions += world.step(dt).ball_ball
    if edit is not None:
        edit(world)
    carried = world.carried_state()
    restored = copy_of(world)
    restored.restore_carried_state(carried)
    rebuilt = copy_of(world)
    for _ in range(steps - k):
        stats = world.step(dt)
        collisions += stats.ball_ball
        assert restored.step(dt) == stats
        rebuilt.step(dt)
    return world, restored, rebuilt, collisions, carried


@pytest.mark.parametrize('backend', BACKENDS)
def test_a_dense_gas_resumed_from_its_carried_state_is_bit_for_bit(backend):
    world, restored, rebuilt, collisions, carried = run_against_restored(
        gas(300, 1, backend), 0.02, 60, 300)
    assert carried.kept and len(carried) == 300 and not len(carried.edited)
    assert collisions > 20_000  # about 80 per step: every ball hit many times
    assert same_bits(restored.positions, world.positions)
    assert same_bits(restored.velocities, world.velocities)
    # From the arrays alone the same gas drifts away (chaos amplifies the last bits).
    assert not same_bits(rebuilt.positions, world.positions)


@pytest.mark.parametrize('backend', BACKENDS)
def test_two_radius_classes_resume_bit_for_bit(backend):
    world, restored, _, collisions, carried = run_against_restored(
        gas(300, 2, backend, radii=(0.02, 0.02, 0.02, 0.15), area_fraction=0.4), 0.02, 40,
        200)
    assert len(carried.tori) == 2  # two grids: a state with several classes is carried
    assert collisions > 5_000
    assert same_bits(restored.positions, world.positions)
    assert same_bits(restored.velocities, world.velocities)


def kick_and_teleport(world):
    world.apply_impulse(7, 0.3, -0.2)
    world.set_ball_state(11, world.positions[11] + 1e-3, (0.0, 0.0))


@pytest.mark.parametrize('backend', BACKENDS)
def test_edits_made_after_the_step_are_carried_as_edited(backend):
    world, restored, _, _, carried = run_against_restored(
        gas(200, 3, backend), 0.02, 30, 150, edit=kick_and_teleport)
    assert carried.edited.tolist() == [7, 11]
    assert same_bits(restored.positions, world.positions)
    assert same_bits(restored.velocities, world.velocities)


def test_the_restored_state_is_the_kept_one_but_for_bucket_order_and_counters():
    from ball_world.core import exact_kernel as kernel
    world = gas(200, 4, 'numba')
    for _ in range(25):
        world.step(0.02)
    kept = exact._states[world]
    twin = copy_of(world)
    twin.restore_carried_state(world.carried_state())
    restored = exact._states[twin]
    columns = [kernel.CELL_X, kernel.CELL_Y, kernel.LAST, kernel.HIT_KIND, kernel.HIT_PARTNER,
               kernel.EXIT, kernel.KIND, kernel.CLASS]
    assert np.array_equal(restored.balls[:, columns], kept.balls[:, columns])
    for name in ('grids', 'tree', 'wall_first', 'wall_items', 'global_walls'):
        assert np.array_equal(getattr(restored, name), getattr(kept, name)), name
    for name in ('hit_time', 'exit_time', 'event_time', 'seen_positions', 'seen_velocities'):
        assert same_bits(getattr(restored, name), getattr(kept, name)), name
    assert restored.unit == kept.unit and restored.leaves == kept.leaves
    # the same balls in each bucket
    for heads, balls in ((kept.heads, kept.balls), (restored.heads, restored.balls)):
        members = []
        for head in heads:
            found = []
            while head != kernel.NO_BALL:
                found.append(int(head))
                head = balls[head, kernel.NEXT]
            members.append(sorted(found))
        if heads is kept.heads:
            expected = members
    assert members == expected


def test_a_world_that_keeps_nothing_carries_nothing():
    world = gas(50, 5, 'numba')
    assert not world.carried_state().kept  # never stepped
    world.step(0.02)
    assert world.carried_state().kept
    exact.invalidate(world)
    nothing = world.carried_state()
    assert not nothing.kept
    twin = copy_of(world)
    twin.restore_carried_state(nothing)  # the next step builds from the arrays, as world's
    world.step(0.02)
    twin.step(0.02)
    assert same_bits(twin.positions, world.positions)
    seed = World([[0.0, 0.0]], [[1.0, 0.0]], [0.1], [1.0])
    assert seed.carried_state() is None
    with pytest.raises(ValueError, match='seed mode carries no state'):
        seed.restore_carried_state(nothing)


def changed(carried, **fields):
    """A copy of `carried` with some fields replaced (arrays copied, then edited)."""
    values = {field.name: getattr(carried, field.name) for field in
              dataclasses.fields(carried)}
    values = {name: value.copy() if isinstance(value, np.ndarray) else value
              for name, value in values.items()}
    for name, edit in fields.items():
        values[name] = edit(values[name])
    return exact_carry.CarriedState(**values)


def at(index, value):
    def edit(array):
        array[index] = value
        return array
    return edit


@pytest.fixture(scope='module')
def stepped():
    world = gas(120, 6, 'numba')
    for _ in range(20):
        world.step(0.02)
    return world, world.carried_state()


def first_of(carried, kind):
    return int(np.flatnonzero(carried.hit_kind == kind)[0])


@pytest.mark.parametrize('crafted, words', [
    (lambda c: changed(c, unit=lambda u: math.nan), 'cell width nan'),
    (lambda c: changed(c, unit=lambda u: 1e-3), 'narrower than the largest diameter'),
    (lambda c: changed(c, tori=at((0, 1), 60)), 'bucket torus of radius class 0'),
    (lambda c: changed(c, tori=at((0, 0), 6)), 'not a power-of-two table'),
    (lambda c: changed(c, tori=lambda t: np.zeros((2, 2), dtype=np.int64)), 'tori has shape'),
    (lambda c: changed(c, cells=at((5, 0), 10**12)), 'ball 5 is in cell'),
    (lambda c: changed(c, cells=lambda a: a[:-1]), 'cells has shape'),
    (lambda c: changed(c, hit_partner=at(first_of(c, exact_carry.PAIR), 120)),
     'impact names no other ball'),
    (lambda c: changed(c, hit_partner=at(first_of(c, exact_carry.PAIR), -5)),
     'impact names no other ball'),
    (lambda c: changed(c, hit_kind=at(3, 9)), 'ball 3: its impact is of no kind'),
    (lambda c: changed(c, last=at(4, -10**9)), 'latest collision names no other ball'),
    (lambda c: changed(c, exit_side=at(2, 7)), 'leaves its cell by no side'),
    (lambda c: changed(c, next_kind=at(1, 5)), 'next event is of no kind'),
    (lambda c: changed(c, hit_time=at(0, -1.0)), 'negative or NaN'),
    (lambda c: changed(c, exit_time=at(0, math.nan)), 'negative or NaN'),
    (lambda c: changed(c, edited=lambda e: np.array([9, 3])), 'ascending order'),
    (lambda c: changed(c, edited=lambda e: np.array([500])), 'edited is not a list'),
])
def test_a_crafted_carried_state_is_refused_naming_what_is_wrong(stepped, crafted, words):
    world, carried = stepped
    twin = copy_of(world)
    with pytest.raises(ValueError, match='^exact state: ') as raised:
        twin.restore_carried_state(crafted(carried))
    assert words in str(raised.value) and '\n' not in str(raised.value)
    twin.restore_carried_state(carried)  # the real one is taken, and steps as the original
    twin.step(0.02)
    reference = copy_of(world)
    reference.restore_carried_state(carried)
    reference.step(0.02)
    assert same_bits(twin.positions, reference.positions)


def test_a_carried_state_for_other_balls_is_refused(stepped):
    world, carried = stepped
    fewer = World(world.positions[:-1], world.velocities[:-1], world.radii[:-1],
                  world.masses[:-1], walls=world.walls.segments, mode='exact')
    with pytest.raises(ValueError, match='has shape'):
        fewer.restore_carried_state(carried)
    empty = World(np.zeros((0, 2)), np.zeros((0, 2)), [], [], mode='exact')
    with pytest.raises(ValueError, match='without balls'):
        empty.restore_carried_state(carried)


def test_the_codes_are_the_kernels():
    from ball_world.core import exact_kernel as kernel
    assert (exact_carry.PAIR, exact_carry.WALL, exact_carry.CROSSING, exact_carry.NOTHING,
            exact_carry.NO_SIDE, exact_carry.NO_PARTNER) == (
        kernel.PAIR, kernel.WALL, kernel.CROSSING, kernel.NOTHING, kernel.NO_PARTNER,
        kernel.NO_PARTNER)
