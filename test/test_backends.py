"""The numpy and numba backends give bit-identical trajectories on any world.

Both compute the seed-mode step of `core.stepping`; the numba one from the same formula
source (`core.rules`), compiled without fastmath. Random worlds here have oblique segment
walls, radii and masses that differ by up to 100x and 10,000x, dense clusters, overlapping
starts, fast balls, and impulses and edits between steps; after every step positions,
velocities and counters must be equal to the last bit.
"""
import os
import subprocess
import sys

from hypothesis import given, HealthCheck, settings, strategies as st
from numba import njit
import numpy as np

from ball_world.core import numba_backend, rules
from ball_world.core.world import StepStats, SubstepLimitExceeded, World

BOX_SIDE = 10.0
BOX = [[0.0, 0.0, BOX_SIDE, 0.0], [BOX_SIDE, 0.0, BOX_SIDE, BOX_SIDE],
       [BOX_SIDE, BOX_SIDE, 0.0, BOX_SIDE], [0.0, BOX_SIDE, 0.0, 0.0]]
DT = 1.0 / 60.0
#: Substeps after which a random run stops: worlds of tiny, fast balls need thousands per
#: step, and the numpy backend takes ~0.2 ms for each.
SUBSTEP_BUDGET = 3000


def lattice(rng, n, radius, spacing):
    """n centres of a jittered hexagonal lattice around the box centre (a dense cluster)."""
    side = int(np.ceil(np.sqrt(n)))
    i, j = np.divmod(np.arange(n), side)
    centres = np.stack((j + 0.5 * (i % 2), i * np.sqrt(0.75)), axis=1) * spacing * 2 * radius
    centres += BOX_SIDE / 2 - centres.mean(axis=0)
    return centres + rng.uniform(-0.01, 0.01, (n, 2)) * radius


def segment_distance(point, walls):
    """Distances from a point to each wall segment."""
    start = walls[:, 0:2]
    edge = walls[:, 2:4] - start
    t = np.clip(((point - start) * edge).sum(1) / (edge * edge).sum(1), 0.0, 1.0)
    return np.hypot(*(point - start - t[:, None] * edge).T)


def place(candidates, radii, walls, overlap_balls):
    """Keep the candidate centres that overlap no wall (and no kept ball, unless allowed)."""
    kept = []
    for k, (point, radius) in enumerate(zip(candidates, radii)):
        if segment_distance(point, walls).min() < radius:
            continue
        if not overlap_balls and any(np.hypot(*(point - candidates[j])) < radius + radii[j]
                                     for j in kept):
            continue
        kept.append(k)
    return np.array(kept, dtype=int)


def random_world(seed, n, layout, radius_ratio, mass_ratio, extra_walls):
    """Arrays of a random world; `layout` is 'gas', 'cluster', 'overlapping' or 'fast'.

    No ball starts overlapping a wall: a ball wedged between walls closer than its diameter
    bounces between them for MAX_ROUNDS rounds of every substep, a valid but slow world.
    """
    rng = np.random.default_rng(seed)
    starts = rng.uniform(1.0, BOX_SIDE - 1.0, (extra_walls, 2))
    ends = starts + rng.uniform(-4.0, 4.0, (extra_walls, 2))
    walls = np.concatenate((BOX, np.concatenate((starts, ends), axis=1)))
    largest = 0.4
    radii = largest / radius_ratio ** rng.uniform(0.0, 1.0, n)
    masses = mass_ratio ** rng.uniform(0.0, 1.0, n)
    velocities = rng.normal(0.0, 2.0, (n, 2))
    if layout == 'cluster':
        # Equal balls packed nearly touching, the cluster a third of the box wide.
        radii[:] = min(largest, BOX_SIDE / 6.0 / np.sqrt(n))
        positions = lattice(rng, n, radii[0], 1.0005)
        velocities[:] = 0.0
        velocities[0] = [40.0, 13.0]  # one fast ball into a still cluster: many rounds
    elif layout == 'overlapping':
        positions = rng.uniform(3.0, 7.0, (n, 2))
    else:
        positions = rng.uniform(0.5, BOX_SIDE - 0.5, (n, 2))
        if layout == 'fast':
            velocities[: max(1, n // 10)] *= 25.0
    kept = place(positions, radii, walls, overlap_balls=layout != 'gas')
    return (positions[kept], velocities[kept], radii[kept], masses[kept], walls)


def make_pair(arrays):
    return [World(*arrays[:4], walls=arrays[4], backend=b) for b in ('numpy', 'numba')]


def assert_identical(worlds, stats):
    reference, compiled = worlds
    assert stats[0] == stats[1]
    assert np.array_equal(reference.positions, compiled.positions)
    assert np.array_equal(reference.velocities, compiled.velocities)


def step_both(worlds):
    """Step both worlds; both must refuse or both must step. Returns the stats or None."""
    outcomes = []
    for world in worlds:
        try:
            outcomes.append(world.step(DT))
        except SubstepLimitExceeded:
            outcomes.append(None)
    assert outcomes[0] == outcomes[1]
    return outcomes


def free_spot(rng, walls, radius):
    """A random centre at least `radius` from every wall (balls may overlap balls)."""
    while True:
        point = rng.uniform(0.5, BOX_SIDE - 0.5, 2)
        if segment_distance(point, walls).min() >= radius:
            return point


def edit_both(worlds, rng):
    """One random edit between steps, applied identically to both worlds."""
    n = len(worlds[0])
    kind = rng.integers(0, 4) if n else 1
    walls = worlds[0].walls.segments
    if kind == 0:
        ball = int(rng.integers(0, n))
        jx, jy = rng.normal(0.0, 1.0, 2) * worlds[0].masses[ball]
        for world in worlds:
            world.apply_impulse(ball, jx, jy)
    elif kind == 1:
        radius = (worlds[0].radii.max() if n else 0.3) / rng.uniform(1.0, 3.0)
        position = free_spot(rng, walls, radius)
        velocity = rng.normal(0.0, 2.0, 2)
        for world in worlds:
            world.add_balls([position], [velocity], [radius], [1.0])
    elif kind == 2 and n > 2:
        balls = rng.choice(n, size=int(rng.integers(1, 3)), replace=False)
        for world in worlds:
            world.remove_balls(balls)
    else:
        ball = int(rng.integers(0, n))
        position = tuple(free_spot(rng, walls, worlds[0].radii[ball]))
        velocity = tuple(rng.normal(0.0, 3.0, 2))
        for world in worlds:
            world.set_ball_state(ball, position, velocity)


def run_pair(worlds, steps, rng, edit_every, substeps=SUBSTEP_BUDGET):
    """Step both worlds `steps` times (or `substeps` substeps) with edits between steps.

    Returns the summed counters and how many steps needed more rounds than substeps.
    """
    totals = np.zeros(len(StepStats._fields), dtype=np.int64)
    crowded = 0
    for k in range(steps):
        if edit_every and k % edit_every == edit_every - 1:
            edit_both(worlds, rng)
        stats = step_both(worlds)
        if stats[0] is None:
            break
        assert_identical(worlds, stats)
        totals += stats[0]
        crowded += stats[0].rounds > stats[0].substeps
        if totals[2] >= substeps:
            break
    return totals, crowded


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 50),
       layout=st.sampled_from(['gas', 'cluster', 'overlapping', 'fast']),
       radius_ratio=st.sampled_from([1.0, 3.0, 100.0]),
       mass_ratio=st.sampled_from([1.0, 10.0, 1e4]),
       extra_walls=st.integers(0, 10), edit_every=st.sampled_from([0, 7, 25]))
def test_random_worlds_step_bit_identically(seed, n, layout, radius_ratio, mass_ratio,
                                            extra_walls, edit_every):
    worlds = make_pair(random_world(seed, n, layout, radius_ratio, mass_ratio, extra_walls))
    run_pair(worlds, 150, np.random.default_rng(seed), edit_every)


def test_a_dense_cluster_needs_many_rounds_and_stays_identical():
    worlds = make_pair(random_world(7, 300, 'cluster', 1.0, 1.0, 4))
    totals, crowded = run_pair(worlds, 300, np.random.default_rng(7), 0)
    assert crowded > 20  # steps whose contacts needed several rounds in one substep
    assert totals[0] > 1000


def test_candidate_lists_that_outgrow_their_buffers_are_regrown_and_stay_identical():
    """A packed cluster has about 7 candidate pairs per ball (the buffer starts at 4), and
    balls running between rails have six ball-wall pairs each (the buffer starts at one):
    the step that outgrows a buffer still uses its lists, later steps rebuild into grown
    buffers, and the backends still agree to the bit."""
    rng = np.random.default_rng(3)
    packed = lattice(rng, 300, 0.1, 1.0)
    cluster = make_pair((packed, rng.normal(0.0, 0.05, (300, 2)), np.full(300, 0.1),
                         np.ones(300), BOX))
    n = 16
    rails = [[0.0, 5.0 + dy, BOX_SIDE, 5.0 + dy] for dy in (-0.25, -0.2, -0.15, 0.15, 0.2, 0.25)]
    between_rails = make_pair((np.column_stack((np.linspace(0.5, 9.5, n), np.full(n, 5.0))),
                               np.column_stack((rng.normal(0.0, 2.0, n), np.zeros(n))),
                               np.full(n, 0.1), np.ones(n), BOX + rails))
    for worlds, grown in ((cluster, numba_backend.PAIRS),
                          (between_rails, numba_backend.NEAR_WALLS)):
        run_pair(worlds, 60, rng, 0)
        pair_rows, wall_rows, lists = worlds[1]._stepper.buffers
        balls = len(worlds[1])
        assert lists[numba_backend.FRESH] == 1
        assert len(pair_rows) >= lists[numba_backend.PAIRS]
        assert len(wall_rows) >= lists[numba_backend.NEAR_WALLS]
        if grown == numba_backend.PAIRS:
            assert len(pair_rows) > 4 * balls and lists[grown] > 4 * balls
        else:
            assert len(wall_rows) > balls and lists[grown] > balls


def test_many_oblique_walls_unequal_masses_and_impulses_stay_identical():
    worlds = make_pair(random_world(11, 200, 'gas', 3.0, 1e4, 40))
    totals, _ = run_pair(worlds, 300, np.random.default_rng(11), 5)
    assert totals[1] > 100 and totals[0] > 50


# monkeypatch.context() undoes its change within each example.
@settings(max_examples=10, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 50),
       layout=st.sampled_from(['gas', 'cluster', 'fast']), extra_walls=st.integers(0, 10),
       edit_every=st.sampled_from([0, 7]))
def test_a_box_steps_the_same_by_its_direct_walls_and_by_the_static_index(
        seed, n, layout, extra_walls, edit_every, monkeypatch):
    """A world without a map finds its ball-wall candidates directly (DIRECT_WALLS: as the
    step did before the static index); with the index's search instead, and in numpy, the
    same contacts in the same order: the same bits."""
    arrays = random_world(seed, n, layout, 3.0, 10.0, extra_walls)
    direct = make_pair(arrays)
    # the direct path, prepared with the World (a world the walls left no ball in is
    # prepared by no step: a cluster can lose every ball to the walls)
    assert not len(direct[1]) or direct[1]._stepper._prepared[-2]
    with monkeypatch.context() as patch:
        patch.setattr(numba_backend, 'DIRECT_WALLS', -1)
        indexed = World(*arrays[:4], walls=arrays[4], backend='numba')
    assert not len(indexed) or not indexed._stepper._prepared[-2]
    worlds = [*direct, indexed]
    rng = np.random.default_rng(seed)
    for k in range(120):
        if edit_every and k % edit_every == edit_every - 1:
            edit_both(worlds, rng)  # the numpy world and both numba ones alike
        stats = step_both(worlds[:2])
        try:
            stats.append(worlds[2].step(DT))
        except SubstepLimitExceeded:
            stats.append(None)
        assert stats[2] == stats[1]
        if stats[0] is None:
            break
        assert_identical(worlds[:2], stats[:2])
        assert_identical(worlds[1:], stats[1:])


def test_many_walls_take_the_static_index():
    rng = np.random.default_rng(5)
    starts = rng.uniform(1.0, 9.0, (numba_backend.DIRECT_WALLS, 2))
    walls = BOX + np.concatenate((starts, starts + 0.5), axis=1).tolist()
    world = World([[0.5, 0.5]], [[1.0, 0.0]], [0.1], [1.0], walls=walls, backend='numba')
    assert not world._stepper._prepared[-2]


def test_both_backends_refuse_the_same_step():
    # A heavy fast ball hits a light one: the re-split would pass MAX_SUBSTEPS.
    arrays = ([[0.0, 0.0], [0.25, 0.0]], [[3000.0, 0.0], [0.0, 0.0]], [0.1, 0.1],
              [1e3, 1e-2], [])
    worlds = make_pair(arrays)
    assert step_both(worlds) == [None, None]
    assert_identical(worlds, [None, None])


@njit(cache=True)
def _respond_each(v, masses, rel, offsets, walls):
    """Each (2c, 2c+1) pair of v through the backend's pair response, each row 2c through its
    end-point reflection; returns the new velocities."""
    pairs = np.empty_like(v)
    pairs[:] = v
    ends = np.empty_like(v)
    ends[:] = v
    for c in range(rel.shape[0]):
        numba_backend.respond_pair(pairs, masses, 2 * c, 2 * c + 1, rel[c, 0], rel[c, 1])
        numba_backend.respond_wall(ends, 2 * c, walls, 0, offsets[c, 0], offsets[c, 1], False)
    return pairs, ends


def test_compiled_responses_round_exactly_like_numpy():
    # Fused multiply-adds or re-association would change the last bit of many of these.
    rng = np.random.default_rng(3)
    count = 100_000
    v = rng.normal(0.0, 1.0, (2 * count, 2)) * np.exp(rng.uniform(-10, 10, (2 * count, 1)))
    masses = np.exp(rng.uniform(-10, 10, 2 * count))
    rel = rng.normal(0.0, 1.0, (count, 2))
    offsets = rng.normal(0.0, 1.0, (count, 2))
    pairs, ends = _respond_each(v, masses, rel, offsets, np.zeros((1, 7)))
    a, b = v[0::2], v[1::2]
    expected = rules.pair_response(a[:, 0], a[:, 1], b[:, 0], b[:, 1], rel[:, 0], rel[:, 1],
                                   masses[0::2], masses[1::2])
    assert np.array_equal(pairs[0::2], np.stack(expected[:2], axis=1))
    assert np.array_equal(pairs[1::2], np.stack(expected[2:], axis=1))
    reflected = rules.reflect_off_end(a[:, 0], a[:, 1], offsets[:, 0], offsets[:, 1])
    assert np.array_equal(ends[0::2], np.stack(reflected, axis=1))


def test_kernel_cache_fingerprint_follows_the_shared_code(monkeypatch):
    assert numba_backend.ensure_fresh_cache() is False  # this process's kernels are current
    script = 'from ball_world.core import numba_backend as b; print(b.FINGERPRINT)'
    other = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                           check=True)
    assert int(other.stdout) == numba_backend.FINGERPRINT  # stable across processes
    monkeypatch.setattr(rules, 'advance', lambda x, v, h: x + h * v)
    assert numba_backend._fingerprint() != numba_backend.FINGERPRINT


def test_warm_entry_point_compiles_the_kernels():
    done = subprocess.run([sys.executable, '-m', 'ball_world.core.warm'],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert 'numba kernels (seed mode, exact mode and the lidar) ready' in done.stdout


def test_warming_for_a_run_leaves_a_default_run_nothing_to_compile(tmp_path):
    """scripts/setup.sh makes `make run` wait only for `--kernels run` (the rest compiles in
    the background): if a default world's steps needed a kernel that part leaves out, the
    first run would stall ~15 s compiling it. Every compile writes to numba's cache, so an
    unchanged cache after the steps means nothing was compiled."""
    environment = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    # Compiling from nothing takes ~30 s of CPU, many minutes on a loaded machine: the time-out
    # only stops a hang.
    done = subprocess.run([sys.executable, '-m', 'ball_world.core.warm', '--kernels', 'run'],
                          capture_output=True, text=True, timeout=1800, env=environment)
    assert done.returncode == 0, done.stderr
    assert 'numba kernels (seed mode) ready' in done.stdout

    def cache():
        return sorted((str(p), p.stat().st_size) for p in tmp_path.rglob('*') if p.is_file())

    warmed = cache()
    assert any(name.endswith('.nbi') for name, _ in warmed)
    script = ('from ball_world.core.scenario import build_world\n'
              "world = build_world({'physics.backend': 'numba'})\n"
              'for _ in range(120):\n'
              '    world.step(1 / 60)\n'
              'print(len(world))')
    stepped = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                             timeout=1800, env=environment)
    assert stepped.returncode == 0 and stepped.stdout.strip() == '20', stepped.stderr
    assert cache() == warmed
