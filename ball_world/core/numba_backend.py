"""The optional compiled backend: the same rules as physics.py, as numba kernels.

Why it exists: a numpy step pays about 1-2 us per numpy call and needs over a hundred calls
per substep, so below a few thousand balls the fixed cost dominates (about 250 us per
substep, measured here). Compiled loops have no such floor. The rules are the seed's, as in
the numpy path: a posteriori detection (touching AND approaching), the seed's responses,
substeps of at most MAX_TRAVEL of the smallest radius. What differs is the order in which
simultaneous contacts are resolved: here sequentially, in passes over the contact list until
none is approaching (each response still exactly the seed's pairwise one, so energy is
conserved). The two backends therefore give different, equally valid, trajectories; each is
deterministic, and the backend is part of the recorded parameters.

numba is in requirements/base.txt; without it the numpy backend still works, and
`available()` says whether this one can.
"""
import math

import numpy as np

try:
    from numba import njit
except ImportError:  # the numpy backend needs nothing more
    njit = None


def available():
    """True when numba is installed, so World(backend='numba') can run."""
    return njit is not None


def _compile(function):
    return njit(cache=True, nogil=True)(function) if njit is not None else function


@_compile
def _cells(x, cell, n):
    """Counting sort of balls into a grid: (order, starts, keys, rows).

    order lists the balls cell by cell; the balls of cell k are order[starts[k]:starts[k+1]];
    keys[i] is ball i's cell, rows the number of cells in a column (key = column * rows + row).
    """
    minx = x[0, 0]
    miny = x[0, 1]
    maxx = minx
    maxy = miny
    for i in range(n):
        minx = min(minx, x[i, 0])
        maxx = max(maxx, x[i, 0])
        miny = min(miny, x[i, 1])
        maxy = max(maxy, x[i, 1])
    # Balls that fly far apart (no arena) would need a huge grid: grow the cells instead.
    while ((maxx - minx) / cell + 1.0) * ((maxy - miny) / cell + 1.0) > 4.0 * n + 1024.0:
        cell *= 2.0
    inverse = 1.0 / cell
    columns = int((maxx - minx) * inverse) + 1
    rows = int((maxy - miny) * inverse) + 1
    keys = np.empty(n, dtype=np.int64)
    starts = np.zeros(columns * rows + 1, dtype=np.int64)
    for i in range(n):
        cx = min(int((x[i, 0] - minx) * inverse), columns - 1)
        cy = min(int((x[i, 1] - miny) * inverse), rows - 1)
        keys[i] = cx * rows + cy
        starts[keys[i] + 1] += 1
    for k in range(columns * rows):
        starts[k + 1] += starts[k]
    fill = starts[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return order, starts, keys, columns, rows


@_compile
def _add_pair(pairs, count, i, j):
    if count == pairs.shape[0]:
        grown = np.empty((2 * pairs.shape[0], 2), dtype=np.int64)
        grown[:count] = pairs[:count]
        pairs = grown
    pairs[count, 0] = min(i, j)
    pairs[count, 1] = max(i, j)
    return pairs


@_compile
def _pair_contacts(x, radii, n):
    """Touching ball pairs, through a grid of cells one diameter wide and a half stencil."""
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, radii[i])
    order, starts, keys, columns, rows = _cells(x, 2.0 * rmax, n)
    pairs = np.empty((4 * n + 16, 2), dtype=np.int64)
    count = 0
    for first in range(n):
        i = order[first]
        key = keys[i]
        cx = key // rows
        cy = key - cx * rows
        xi = x[i, 0]
        yi = x[i, 1]
        ri = radii[i]
        # The rest of the own cell, then the cells above, and right-below/right/right-above.
        for neighbour in range(5):
            if neighbour == 0:
                low = first + 1
                high = starts[key + 1]
            else:
                gx = cx + (0 if neighbour == 1 else 1)
                gy = cy + (1 if neighbour == 1 else neighbour - 3)
                if gx >= columns or gy < 0 or gy >= rows:
                    continue
                other = gx * rows + gy
                low = starts[other]
                high = starts[other + 1]
            for s in range(low, high):
                j = order[s]
                dx = xi - x[j, 0]
                dy = yi - x[j, 1]
                reach = ri + radii[j]
                if dx * dx + dy * dy < reach * reach:
                    pairs = _add_pair(pairs, count, i, j)
                    count += 1
    return pairs[:count]


@_compile
def _wall_contacts(x, radii, n, starts, ends, directions, lengths):
    """Touching ball-wall pairs with the offset s (the seed's, or from the end point)."""
    m = starts.shape[0]
    capacity = n + 16
    balls = np.empty(capacity, dtype=np.int64)
    walls = np.empty(capacity, dtype=np.int64)
    offsets = np.empty((capacity, 2))
    interior = np.empty(capacity, dtype=np.bool_)
    count = 0
    for i in range(n):
        for k in range(m):
            rx = x[i, 0] - starts[k, 0]
            ry = x[i, 1] - starts[k, 1]
            # Cheap reject first: further from the wall's line than the radius.
            across = rx * directions[k, 1] - ry * directions[k, 0]
            if across >= radii[i] or -across >= radii[i]:
                continue
            along = rx * directions[k, 0] + ry * directions[k, 1]
            inside = along > 0.0 and along < lengths[k]
            if along <= 0.0:
                sx, sy = rx, ry
            elif along >= lengths[k]:
                sx = x[i, 0] - ends[k, 0]
                sy = x[i, 1] - ends[k, 1]
            else:
                sx = rx - along * directions[k, 0]
                sy = ry - along * directions[k, 1]
            if sx * sx + sy * sy < radii[i] * radii[i]:
                if count == capacity:
                    capacity *= 2
                    balls = np.concatenate((balls, np.empty_like(balls)))
                    walls = np.concatenate((walls, np.empty_like(walls)))
                    offsets = np.concatenate((offsets, np.empty_like(offsets)))
                    interior = np.concatenate((interior, np.empty_like(interior)))
                balls[count] = i
                walls[count] = k
                offsets[count, 0] = sx
                offsets[count, 1] = sy
                interior[count] = inside
                count += 1
    return balls[:count], walls[:count], offsets[:count], interior[:count]


@_compile
def _substep(x, v, radii, masses, h, starts, ends, directions, lengths, max_rounds, totals):
    """Move, detect, resolve in passes. Returns the fastest speed of a ball that collided."""
    n = x.shape[0]
    for i in range(n):
        x[i, 0] += v[i, 0] * h
        x[i, 1] += v[i, 1] * h
    totals[2] += 1
    pairs = _pair_contacts(x, radii, n)
    balls, walls, offsets, interior = _wall_contacts(
        x, radii, n, starts, ends, directions, lengths)
    if pairs.shape[0] == 0 and balls.shape[0] == 0:
        return 0.0
    fastest2 = 0.0
    left = 0
    for _ in range(max_rounds):
        changed = 0
        for c in range(pairs.shape[0]):
            a = pairs[c, 0]
            b = pairs[c, 1]
            rx = x[a, 0] - x[b, 0]
            ry = x[a, 1] - x[b, 1]
            if rx * (v[a, 0] - v[b, 0]) + ry * (v[a, 1] - v[b, 1]) >= 0.0:
                continue
            # The seed's ball-ball response, written as in physics.World._collide_pairs.
            dist2 = rx * rx + ry * ry
            ma = masses[a]
            mb = masses[b]
            dvx = v[a, 0] - v[b, 0]
            dvy = v[a, 1] - v[b, 1]
            k_a = 2.0 * mb / (ma + mb) * (dvx * rx + dvy * ry) / dist2
            k_b = 2.0 * ma / (ma + mb) * ((-dvx) * (-rx) + (-dvy) * (-ry)) / dist2
            v[a, 0] = v[a, 0] - k_a * rx
            v[a, 1] = v[a, 1] - k_a * ry
            v[b, 0] = v[b, 0] - k_b * -rx
            v[b, 1] = v[b, 1] - k_b * -ry
            totals[0] += 1
            changed += 1
            fastest2 = max(fastest2, v[a, 0] * v[a, 0] + v[a, 1] * v[a, 1],
                           v[b, 0] * v[b, 0] + v[b, 1] * v[b, 1])
        for c in range(balls.shape[0]):
            i = balls[c]
            sx = offsets[c, 0]
            sy = offsets[c, 1]
            vx = v[i, 0]
            vy = v[i, 1]
            if sx * vx + sy * vy >= 0.0:
                continue
            if interior[c]:
                # v' = 2 (v.w) w - v
                wx = directions[walls[c], 0]
                wy = directions[walls[c], 1]
                along = vx * wx + vy * wy
                v[i, 0] = 2.0 * along * wx - vx
                v[i, 1] = 2.0 * along * wy - vy
            else:
                # Beyond an end point: reflect about n = s / |s|.
                norm = math.sqrt(sx * sx + sy * sy)
                nx = sx / norm
                ny = sy / norm
                vn = vx * nx + vy * ny
                v[i, 0] = vx - 2.0 * vn * nx
                v[i, 1] = vy - 2.0 * vn * ny
            totals[1] += 1
            changed += 1
            fastest2 = max(fastest2, v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1])
        if changed == 0:
            break
        totals[3] += 1
        left = changed
    else:
        totals[4] += left
    return math.sqrt(fastest2)


@_compile
def _plan(speed, duration, min_radius, max_travel):
    """Substeps so that no ball travels more than max_travel * min_radius (as World._plan)."""
    if speed == 0.0 or min_radius == 0.0:
        return 1
    return max(1, int(math.ceil(speed * duration / (max_travel * min_radius))))


@_compile
def _step(x, v, radii, masses, dt, min_radius, max_travel, starts, ends, directions, lengths,
          max_rounds, totals):
    """A whole step, planned and split into substeps exactly as World.step does."""
    n = x.shape[0]
    speed2 = 0.0
    for i in range(n):
        speed2 = max(speed2, v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1])
    speed = math.sqrt(speed2)
    count = _plan(speed, dt, min_radius, max_travel)
    h = dt / count
    done = 0
    while done < count:
        new_speed = _substep(x, v, radii, masses, h, starts, ends, directions, lengths,
                             max_rounds, totals)
        done += 1
        if new_speed > speed:
            speed = new_speed
            if done < count and _plan(speed, h, min_radius, max_travel) > 1:
                rest = (count - done) * h
                count = _plan(speed, rest, min_radius, max_travel)
                h = rest / count
                done = 0


def step(world, dt, max_travel):
    """One step of `world` by the compiled kernel; returns the five StepStats counters."""
    walls = world.walls
    from ball_world.core.world import MAX_ROUNDS
    counters = np.zeros(5, dtype=np.int64)
    _step(world.positions, world.velocities, world.radii, world.masses, dt, world.min_radius,
          max_travel, walls.starts, walls.ends, walls.directions, walls.lengths, MAX_ROUNDS,
          counters)
    return counters.tolist()
