"""core.world_batch: K worlds stepped in one compiled call, each bit for bit as alone.

The reference is each World stepped alone by World.step (itself tested against the numpy
reference and closed forms elsewhere): the batch must give the same positions and
velocities to the bit, through steps of some of the worlds only, edits (bind), candidate
lists that outgrow their buffers, in a map (seed_step) and in a walled box (box_step).
"""
import copy

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from ball_world.core.solid_cells import SolidCells
from ball_world.core.world import numba_installed, World
from ball_world.core.world_batch import supports, WorldBatch

pytestmark = pytest.mark.skipif(not numba_installed(), reason='WorldBatch needs numba')

BOX = [[0.0, 0.0, 5.0, 0.0], [5.0, 0.0, 5.0, 5.0], [5.0, 5.0, 0.0, 5.0],
       [0.0, 5.0, 0.0, 0.0]]


def room():
    """A 5 m square room of 0.25 m cells (origin 0) with a solid block in its middle."""
    mask = np.zeros((20, 20), dtype=bool)
    mask[8:12, 9:11] = True
    return SolidCells(0.0, 0.0, 0.25, mask).checked()


def placed(rng, count, radius):
    """`count` centres on a jittered lattice in the room's left part (x < 2: off the block),
    no two closer than 2 radius, none within a radius of the room's edge."""
    side = int(np.ceil(np.sqrt(count)))
    pitch = 1.8 / side
    assert pitch > 2.0 * radius
    cells = rng.permutation(side * side)[:count]
    slack = (pitch - 2.0 * radius) / 2.0
    centres = np.column_stack((0.1 + pitch * (cells % side + 0.5),
                               0.1 + pitch * (cells // side + 0.5) + 1.5))
    return centres + rng.uniform(-slack, slack, (count, 2)) * 0.99


def worlds_of(rng, count, balls, radius, walled):
    radii = np.full(balls, radius)
    radii[0] = 1.5 * radius  # two radius classes
    masses = rng.uniform(0.5, 2.0, balls)
    made = []
    for _ in range(count):
        positions = placed(rng, balls, float(radii.max()))
        velocities = rng.uniform(-2.0, 2.0, (balls, 2))
        options = {'walls': BOX} if walled else {'solid_cells': room()}
        made.append(World(positions, velocities, radii, masses, backend='numba', **options))
    return made


def assert_same(batch_world, alone):
    assert batch_world.positions.tobytes() == alone.positions.tobytes()
    assert batch_world.velocities.tobytes() == alone.velocities.tobytes()


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), walled=st.booleans())
def test_each_world_steps_as_alone_through_subsets_and_edits(seed, walled):
    rng = np.random.default_rng(seed)
    worlds = worlds_of(rng, 4, 9, 0.12, walled)
    alone = [copy.deepcopy(world) for world in worlds]
    initial = [world.velocities.copy() for world in worlds]
    batch = WorldBatch(worlds)
    for step in range(60):
        chosen = np.flatnonzero(rng.random(4) < 0.7).astype(np.int64)
        batch.step(chosen, 0.01)
        for index in chosen.tolist():
            alone[index].step(0.01)
        if step == 30:  # an edit: world 2 gets new balls, bound again
            positions = placed(rng, 9, float(worlds[2].radii.max()))
            velocities = rng.uniform(-2.0, 2.0, (9, 2))
            for world in (worlds[2], alone[2]):
                radii, masses = world.radii.copy(), world.masses.copy()
                world.remove_balls(np.arange(9))
                world.add_balls(positions, velocities, radii, masses)
            batch.bind(2)
    for world, reference in zip(worlds, alone):
        assert_same(world, reference)
    # Collisions happened (only they change a velocity here), so the kernel's rounds ran.
    assert any(not np.array_equal(world.velocities, before)
               for world, before in zip(worlds[:2] + worlds[3:], initial[:2] + initial[3:]))


def hexagonal(count, radius):
    """`count` centres of a hexagonal packing 5% looser than touching, from (0.3, 0.3)."""
    pitch = 2.1 * radius
    rows = int(np.ceil(np.sqrt(count)))
    index = np.arange(count)
    row, column = index // rows, index % rows
    return np.column_stack((0.3 + pitch * (column + 0.5 * (row % 2)),
                            0.3 + pitch * np.sqrt(3.0) / 2.0 * row))


def test_lists_that_outgrow_their_buffers_grow_and_keep_the_bits():
    # 64 balls packed hexagonally: each has about 6 candidate pairs, past the 4 rows a ball
    # the buffers start with.
    rng = np.random.default_rng(7)
    radii, masses = np.full(64, 0.05), rng.uniform(0.5, 2.0, 64)
    worlds = [World(hexagonal(64, 0.05), rng.uniform(-0.5, 0.5, (64, 2)), radii, masses,
                    backend='numba', solid_cells=room()) for _ in range(3)]
    alone = [copy.deepcopy(world) for world in worlds]
    batch = WorldBatch(worlds)
    first_rows = batch._pair_rows.shape[1]
    everyone = np.arange(3, dtype=np.int64)
    for _ in range(40):
        batch.step(everyone, 0.01)
        for reference in alone:
            reference.step(0.01)
    assert batch._pair_rows.shape[1] > first_rows  # the growth was exercised
    for world, reference in zip(worlds, alone):
        assert_same(world, reference)


def test_bound_worlds_read_the_batch_arrays():
    rng = np.random.default_rng(3)
    worlds = worlds_of(rng, 2, 5, 0.1, walled=True)
    batch = WorldBatch(worlds)
    batch.step(np.array([1], dtype=np.int64), 0.05)
    assert np.shares_memory(worlds[1].positions, batch.positions)
    assert worlds[1].positions.tobytes() == batch.positions[1].tobytes()
    assert worlds[0].kinetic_energy() == pytest.approx(
        0.5 * float(np.sum(worlds[0].masses[:, None] * batch.velocities[0] ** 2)))


def test_refuses_worlds_it_cannot_step_alike():
    rng = np.random.default_rng(5)
    box, = worlds_of(rng, 1, 5, 0.1, walled=True)
    mapped = World(box.positions, box.velocities, box.radii, box.masses, backend='numba',
                   solid_cells=room())
    with pytest.raises(ValueError, match='other static geometry'):
        WorldBatch([box, mapped])
    other = World(box.positions, box.velocities, box.radii * 0.9, box.masses, walls=BOX,
                  backend='numba')
    with pytest.raises(ValueError, match='other balls'):
        WorldBatch([box, other])
    numpy_world = World(box.positions, box.velocities, box.radii, box.masses, walls=BOX,
                        backend='numpy')
    assert not supports(numpy_world)
    with pytest.raises(ValueError, match='numba backend only'):
        WorldBatch([box, numpy_world])
