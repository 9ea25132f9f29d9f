"""A scanner for swarms: every agent's scan in one compiled call (core.lidar.scan_many).

The short-range ring of few beams (ARGoS's proximity ring, Stage's sonar ring) is the lidar
with another fan, so it is held to the lidar's rules: closed forms for what a beam meets,
REP 117's infinities, and the compiled batch equal bit for bit to the numpy reference, one
agent at a time, and to the single scanner, with balls in the cells around each scanner
only (lidar.ball_cells) and walls and a map's cells.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from ball_world.core import lidar
from ball_world.core.lidar import Fan, scan_many
from ball_world.core.solid_cells import SolidCells
from ball_world.core.static_geometry import ScanGrid
from ball_world.map_files import load_map_file
from ball_world.msgs.agent_cdr import encode_laser_scan
from ball_world.scans import ScanPool
from ball_world.simulation import Simulation

MAPS = Path(__file__).resolve().parents[1] / 'maps'
RING = Fan.full_turn(8, 0.0, 2.0)  # beam k at -pi + k pi / 4: beam 4 ahead, beam 6 left
BACKENDS = ['numpy', 'numba']


@pytest.mark.parametrize('backend', BACKENDS)
def test_a_ring_sees_the_closed_forms_and_nothing_beyond_its_range(backend):
    # Scanner 0 at the origin heading +x; ball 1 ahead at 1.5 m (radius 0.5: its surface
    # at 1.0); a wall on the left at y = 1.25, short enough that only the beam straight at it
    # meets it (the 45-degree ones pass its ends); ball 2 behind at 2.75 (surface 2.5:
    # beyond range_max 2). Scanner 3 at (10, 0) heading +y, a wall of its own ahead.
    positions = np.array([[0.0, 0.0], [1.5, 0.0], [-2.75, 0.0], [10.0, 0.0]])
    radii = np.array([0.25, 0.5, 0.25, 0.25])
    walls = np.array([[-0.5, 1.25, 0.5, 1.25], [9.5, 1.25, 10.5, 1.25]])
    out = scan_many(positions, radii, walls, [0, 3], [0.0, 0.5 * math.pi], RING, [0.3, 0.3],
                    backend)
    expected = np.full(8, np.inf)
    expected[4] = 1.0  # ahead: 1.5 - 0.5
    expected[6] = 1.25  # left: the wall
    assert out[0].tolist() == expected.tolist()
    assert out[1].tolist() == [math.inf] * 4 + [1.25] + [math.inf] * 3  # its wall ahead
    # Closer than range_min: -inf (REP 117).
    near = scan_many(positions, radii, walls, [0], [0.0], RING, [1.1], backend)
    assert near[0, 4] == -math.inf and near[0, 6] == 1.25


def random_world(seed, count=600, side=40.0):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0.0, side, (count, 2))
    radii = rng.uniform(0.05, 0.3, count)
    walls = np.array([[0.0, 0.0, side, 0.0], [side, 0.0, side, side], [5.0, 5.0, 15.0, 22.0]])
    mask = (rng.random((60, 60)) < 0.03).astype(np.uint8)
    grid = ScanGrid(SolidCells(-1.0, -1.0, 0.7, mask).checked())
    agents = rng.choice(count, count // 2, replace=False)
    yaws = rng.uniform(-math.pi, math.pi, len(agents))
    return positions, radii, walls, grid, agents, yaws


@pytest.mark.parametrize('seed', [1, 2, 3])
@pytest.mark.parametrize('fan', [Fan.full_turn(16, 0.0, 2.0), Fan(-1.0, 0.25, 9, 0.0, 1.0),
                                 Fan.full_turn(24, 0.0, 6.0)], ids=['ring16', 'arc9', 'ring24'])
def test_the_batch_is_one_scan_per_agent_bit_for_bit(seed, fan):
    positions, radii, walls, grid, agents, yaws = random_world(seed)
    range_mins = radii[agents] + 0.05
    compiled = scan_many(positions, radii, walls, agents, yaws, fan, range_mins, 'numba', grid)
    reference = scan_many(positions, radii, walls, agents, yaws, fan, range_mins, 'numpy',
                          grid)
    assert compiled.tobytes() == reference.tobytes()
    one = [lidar.Scanner(fan._replace(range_min=low), 'numba').distances(
        positions, radii, walls, positions[ball], yaw, ball, grid)
        for ball, yaw, low in zip(agents.tolist(), yaws.tolist(), range_mins.tolist())]
    assert compiled.tobytes() == np.array(one).tobytes()
    assert np.isfinite(compiled).any() and np.isinf(compiled).any()  # the scene is seen


def test_balls_far_apart_make_few_cells_and_every_ball_one_cell():
    positions = np.array([[0.0, 0.0], [1e5, 3.0], [5e4, -2e4]])
    first, balls, grid = lidar.ball_cells(positions, np.array([0.1, 0.1, 0.1]), 2.0)
    assert grid[3] * grid[4] <= 16 and first[-1] == 3 and sorted(balls.tolist()) == [0, 1, 2]
    assert grid[2] >= 2.1


def test_agents_scans_in_a_simulation_are_the_single_scanners():
    parameters = {'random.count': 200, 'arena': [0.0, 0.0, 20.0, 20.0], 'random.seed': 9,
                  'agents': [f'ball_{i}' for i in range(0, 200, 3)], 'agent.scan.samples': 16,
                  'agent.scan.range_max': 2.0, 'agent.scan.angle_min': -math.pi,
                  'agent.scan.angle_max': math.pi - 2.0 * math.pi / 16}
    simulation = Simulation(parameters)
    record, _ = simulation.step()
    world = simulation.world
    scans = simulation.agents.scans
    for scan, index, yaw in zip(record.agents.scans, record.agents.indices, record.agents.yaws):
        scanner = scans.scanner(scan.name, float(world.radii[index]))
        alone = scanner.scan(world.positions, world.radii, world.walls, world.positions[index],
                             float(yaw), int(index), record.step, world.static.scan_grid)
        assert scan.ranges.tobytes() == alone.tobytes()


@pytest.mark.parametrize('samples, threads', [(24, 1), (720, 2)])
def test_a_swarms_noisy_scans_are_the_single_scanners_encoded_or_not(samples, threads):
    # Every agent's noise in one compiled call (core.noise_kernel) draws what each agent's
    # Scanner draws, whether the scans are encoded or kept as a table, at a step past 2**32
    # (two entropy words) too; with a pool, each run's noise is drawn by the thread that
    # scanned it (15 agents of 720 beams: two runs).
    parameters = {'random.count': 60, 'arena': [0.0, 0.0, 10.0, 10.0], 'random.seed': 2**40,
                  'agents': [f'ball_{i}' for i in range(0, 60, 4)],
                  'agent.scan.samples': samples, 'agent.scan.range_max': 3.0,
                  'agent.scan.noise_stddev': 0.03, 'agent.scan.rate_hz': 1000.0}
    simulation = Simulation(parameters)
    simulation.step()
    world = simulation.world
    scans = simulation.agents.scans
    pool = ScanPool(threads) if threads > 1 else None
    scans.pool = lambda: pool
    assert len(lidar.agent_runs(len(parameters['agents']), samples, threads)) == threads
    names = list(parameters['agents'])
    indices = np.array([int(name[5:]) for name in names])
    yaws = np.linspace(-3.0, 3.0, len(names))
    frames = [f'{name}/base_link' for name in names]
    for step in (7, 2**32 + 3):
        table = scans.take(world, names, indices, yaws, frames, step, step * 10**6, 10**6,
                           encode=False)
        encoded = scans.take(world, names, indices, yaws, frames, step, step * 10**6, 10**6)
        assert len(table) == len(encoded) == len(names)
        for kept, sent, index, yaw in zip(table, encoded, indices, yaws):
            scanner = scans.scanner(kept.name, float(world.radii[index]))
            alone = scanner.scan(world.positions, world.radii, world.walls,
                                 world.positions[index], float(yaw), int(index), step,
                                 world.static.scan_grid)
            assert kept.ranges.tobytes() == sent.ranges.tobytes() == alone.tobytes()
            assert np.isfinite(alone).any()
            fan = scanner.fan  # (range_min follows each radius)
            assert sent.cdr == encode_laser_scan(
                step * 10**6, sent.frame_id, fan.angle_min, fan.angle_max,
                fan.angle_increment, 0.0, scans.period_ns * 1e-9, fan.range_min,
                fan.range_max, alone)


@pytest.mark.parametrize('name', ['depot', 'tb3_sandbox'])
def test_long_scans_in_a_crowd_on_a_real_map_are_one_scan_per_agent_in_any_thread(
        name, monkeypatch):
    """The default lidar (360 beams, 12 m) of many robots among many balls in a shipped
    nav2 map, as scan_many gathers each scan's balls within reach and tests their windows
    (lidar_kernel._near_balls), split into runs over two threads or not: equal bit for bit
    to the numpy reference and to one Scanner each; with a scanner inside another ball
    (every range 0) and a fan of one direction (every beam against every ball) among them."""
    cells = load_map_file(str(MAPS / f'{name}.yaml')).solid_cells().checked()
    grid = ScanGrid(cells)
    rng = np.random.default_rng(len(name))
    free = np.argwhere(~cells.solid)
    count = int(min(max(len(free) * cells.resolution ** 2 / 2.0, 40), 400))  # 2 m^2 each
    picked = free[rng.integers(len(free), size=count)]
    positions = np.column_stack((cells.origin_x + (picked[:, 1] + rng.random(count))
                                 * cells.resolution,
                                 cells.origin_y + (picked[:, 0] + rng.random(count))
                                 * cells.resolution))
    radii = rng.uniform(0.05, 0.15, count)
    positions[1] = positions[0] + 0.1  # ball 1's disk holds scanner 0
    radii[1] = 0.2
    walls = np.array([[positions[2, 0] - 1.0, positions[2, 1] + 0.7,
                       positions[2, 0] + 1.0, positions[2, 1] + 0.7]])
    agents = np.concatenate(([0], rng.choice(np.arange(2, count), count // 2, replace=False)))
    yaws = rng.uniform(-math.pi, math.pi, len(agents))
    range_mins = radii[agents] + 0.05
    monkeypatch.setattr(lidar, 'MIN_RUN_BEAMS', 500)  # many runs, so threads share them
    assert len(lidar.agent_runs(len(agents), 360, 2)) == 8
    pool = ScanPool(2)
    for fan in (Fan.full_turn(360), Fan(-0.5, 1e-13, 5, 0.0, 12.0)):
        compiled = scan_many(positions, radii, walls, agents, yaws, fan, range_mins, 'numba',
                             grid)
        threaded = scan_many(positions, radii, walls, agents, yaws, fan, range_mins, 'numba',
                             grid, pool)
        reference = scan_many(positions, radii, walls, agents, yaws, fan, range_mins, 'numpy',
                              grid)
        assert compiled.tobytes() == reference.tobytes() == threaded.tobytes()
        assert compiled[0].tolist() == [-math.inf] * fan.samples  # inside ball 1: 0 < min
        finite = np.isfinite(compiled[1:])
        assert finite.mean() > 0.2 and not finite.all()
    one = [lidar.Scanner(Fan.full_turn(360)._replace(range_min=low), 'numba').distances(
        positions, radii, walls, positions[ball], yaw, ball, grid)
        for ball, yaw, low in zip(agents.tolist(), yaws.tolist(), range_mins.tolist())]
    assert np.array(one).tobytes() == scan_many(
        positions, radii, walls, agents, yaws, Fan.full_turn(360), range_mins, 'numba', grid,
        pool).tobytes()


def test_a_scan_pool_runs_every_run_once_and_raises_a_failure():
    """ScanPool.run: every item once, on this thread and the pool's, and a run's failure
    raised to the caller once no thread works any more."""
    pool = ScanPool(2)
    seen = []
    pool.run(seen.append, [(k, k + 1) for k in range(200)])
    assert sorted(seen) == [(k, k + 1) for k in range(200)]

    def failing(run):
        if run[0] == 150:
            raise ValueError('run 150')

    with pytest.raises(ValueError, match='run 150'):
        pool.run(failing, [(k, k + 1) for k in range(200)])


def test_a_forked_child_scans_with_a_pool_of_its_own():
    """A process forked after its scan pool started has none of the pool's threads: the
    child must make its own (scans.ScanPool._forget at fork), or its runs wait forever."""
    import os
    import time
    import warnings
    parent = ScanPool.shared()
    if parent is None:
        pytest.skip('one core: no scan pool to fork with')
    parent.run(lambda run: None, [(k, k + 1) for k in range(8)])  # its threads started
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)  # (fork with threads running)
        child = os.fork()
    if child == 0:
        done = []
        ScanPool.shared().run(done.append, [(k, k + 1) for k in range(8)])
        os._exit(0 if len(done) == 8 and ScanPool.shared() is not parent else 1)
    deadline = time.monotonic() + 30.0
    while True:
        pid, status = os.waitpid(child, os.WNOHANG)
        if pid:
            break
        if time.monotonic() > deadline:
            os.kill(child, 9)
            os.waitpid(child, 0)
            pytest.fail('the forked child never finished its runs')
        time.sleep(0.01)
    assert os.waitstatus_to_exitcode(status) == 0
