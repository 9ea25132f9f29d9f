"""The reference backend: the seed-mode step (`core.stepping`) as vectorized numpy.

Each stage works on whole columns of contacts at once and takes its formulas from
`core.rules`, which the numba backend compiles too; the stages have the same names there.
Candidates come from Verlet lists (`broadphase.NeighbourLists`) rebuilt only when balls may
have closed the skin: a rebuild costs a few hundred numpy calls, a substep about a hundred.
"""
from typing import NamedTuple

import numpy as np

from ball_world.core import rules
from ball_world.core.broadphase import NeighbourLists, take_rows
from ball_world.core.stepping import (BALL_BALL, BALL_WALL, MAX_ROUNDS, over_budget,
                                      plan_substeps, refusal_possible, replan, ROUNDS, STEP_DONE,
                                      STEP_REFUSED, SUBSTEPS, UNRESOLVED)

#: Skin of the Verlet lists in smallest radii: a rebuild every two to four substeps.
SKIN_RADII = 2.0


class Contacts(NamedTuple):
    """The touching contacts of one substep, in canonical order, with their geometry."""

    pair_a: np.ndarray
    pair_b: np.ndarray
    pair_rx: np.ndarray  # r_a - r_b, x
    pair_ry: np.ndarray
    wall_ball: np.ndarray
    wall_sx: np.ndarray  # offset s from the wall, x
    wall_sy: np.ndarray
    wall_wx: np.ndarray  # the wall's unit direction w, x
    wall_wy: np.ndarray
    wall_interior: np.ndarray  # inside the segment (else beyond an end point)


def max_speed(v):
    """Speed of the fastest ball, m/s."""
    if len(v) == 0:
        return 0.0
    return float(np.sqrt(rules.speed_squared(v[:, 0], v[:, 1]).max()))


def move(x, v, h):
    """Stage 1: every ball moves for h seconds."""
    x[:] = rules.advance(x, v, h)


def find_contacts(x, lists):
    """Stage 2: the touching candidates, in the lists' (canonical) order."""
    a = lists.ball_a
    b = lists.ball_b
    rel = take_rows(x, a) - take_rows(x, b)
    touching = np.flatnonzero(rules.pair_touching(rel[:, 0], rel[:, 1], lists.reach2))
    rel = take_rows(rel, touching)

    balls = lists.wall_ball
    points = take_rows(x, balls)
    sx, sy, interior = rules.wall_offset(
        points[:, 0], points[:, 1], lists.wall_start[:, 0], lists.wall_start[:, 1],
        lists.wall_direction[:, 0], lists.wall_direction[:, 1], lists.wall_length)
    near = np.flatnonzero(rules.wall_touching(sx, sy, lists.wall_radius))
    direction = take_rows(lists.wall_direction, near)
    return Contacts(np.take(a, touching), np.take(b, touching), rel[:, 0], rel[:, 1],
                    np.take(balls, near), np.take(sx, near), np.take(sy, near),
                    direction[:, 0], direction[:, 1], np.take(interior, near))


def approaching(v, c):
    """Which contacts are approaching now: (pair indices, wall indices), each ascending."""
    va = take_rows(v, c.pair_a)
    vb = take_rows(v, c.pair_b)
    pairs = np.flatnonzero(rules.pair_approaching(c.pair_rx, c.pair_ry, va[:, 0], va[:, 1],
                                                  vb[:, 0], vb[:, 1]))
    vw = take_rows(v, c.wall_ball)
    walls = np.flatnonzero(rules.wall_approaching(c.wall_sx, c.wall_sy, vw[:, 0], vw[:, 1]))
    return pairs, walls


def conflict_free(c, pairs, walls, best):
    """Keep the approaching contacts whose balls are in no lower-numbered approaching one.

    Contacts are numbered pairs first, then walls, in canonical order; `best` is a scratch
    array with one entry per ball.
    """
    n_pairs = len(pairs)
    ids_pairs = np.arange(n_pairs)
    ids_walls = np.arange(n_pairs, n_pairs + len(walls))
    a = np.take(c.pair_a, pairs)
    b = np.take(c.pair_b, pairs)
    w = np.take(c.wall_ball, walls)
    best[np.concatenate((a, b, w))] = np.iinfo(np.intp).max
    np.minimum.at(best, a, ids_pairs)
    np.minimum.at(best, b, ids_pairs)
    np.minimum.at(best, w, ids_walls)
    keep_pairs = (np.take(best, a) == ids_pairs) & (np.take(best, b) == ids_pairs)
    keep_walls = np.take(best, w) == ids_walls
    return pairs[keep_pairs], walls[keep_walls]


def respond_pairs(v, masses, c, pairs):
    """Stage 4 for ball-ball contacts that share no ball: the seed's response."""
    a = np.take(c.pair_a, pairs)
    b = np.take(c.pair_b, pairs)
    va = take_rows(v, a)
    vb = take_rows(v, b)
    vax, vay, vbx, vby = rules.pair_response(
        va[:, 0], va[:, 1], vb[:, 0], vb[:, 1], np.take(c.pair_rx, pairs),
        np.take(c.pair_ry, pairs), np.take(masses, a), np.take(masses, b))
    v[a] = np.stack((vax, vay), axis=1)
    v[b] = np.stack((vbx, vby), axis=1)
    return np.concatenate((a, b))


def respond_walls(v, c, walls):
    """Stage 4 for ball-wall contacts on distinct balls: reflect off the wall or its end."""
    balls = np.take(c.wall_ball, walls)
    vb = take_rows(v, balls)
    vx = vb[:, 0].copy()
    vy = vb[:, 1].copy()
    inside = np.take(c.wall_interior, walls)
    ends = ~inside
    vx[inside], vy[inside] = rules.reflect_off_wall(
        vx[inside], vy[inside], np.take(c.wall_wx, walls)[inside],
        np.take(c.wall_wy, walls)[inside])
    if ends.any():
        vx[ends], vy[ends] = rules.reflect_off_end(
            vx[ends], vy[ends], np.take(c.wall_sx, walls)[ends],
            np.take(c.wall_sy, walls)[ends])
    v[balls] = np.stack((vx, vy), axis=1)
    return balls


def resolve(v, masses, c, best, totals):
    """Stage 3: rounds of conflict-free approaching contacts until none is approaching.

    Returns the largest speed a ball had right after a response (0 when none collided).
    """
    fastest2 = 0.0
    if len(c.pair_a) == 0 and len(c.wall_ball) == 0:
        return 0.0
    for round_index in range(MAX_ROUNDS + 1):
        pairs, walls = approaching(v, c)
        if len(pairs) == 0 and len(walls) == 0:
            break
        if round_index == MAX_ROUNDS:
            totals[UNRESOLVED] += len(pairs) + len(walls)
            break
        totals[ROUNDS] += 1
        pairs, walls = conflict_free(c, pairs, walls, best)
        moved = np.concatenate((respond_pairs(v, masses, c, pairs), respond_walls(v, c, walls)))
        totals[BALL_BALL] += len(pairs)
        totals[BALL_WALL] += len(walls)
        vm = take_rows(v, moved)
        fastest2 = max(fastest2, float(rules.speed_squared(vm[:, 0], vm[:, 1]).max()))
    return float(np.sqrt(fastest2))


class NumpyStepper:
    """Steps a World with the numpy stages; holds the Verlet lists and a scratch array."""

    def __init__(self):
        self.invalidate()

    def invalidate(self):
        """Forget everything derived from the balls (after the World was edited)."""
        self.lists = None
        self.best = None

    def prepare(self, world):
        """Nothing to build ahead: the lists need the balls' first positions, and the index
        they ask is the World's static one, built with it."""

    def step(self, world, dt, travel, totals):
        """One seed-mode step; counts into `totals` (zeroed first); STEP_DONE or STEP_REFUSED.

        A step refused part-way puts positions and velocities back as they were.
        """
        x = world.positions
        v = world.velocities
        totals[:] = 0
        if self.lists is None:
            self.lists = NeighbourLists(SKIN_RADII * world.min_radius)
            self.best = np.empty(len(x), dtype=np.intp)
        speed = max_speed(v)
        count = plan_substeps(speed, dt, travel)
        if over_budget(0, count, 0):
            return STEP_REFUSED
        keep = refusal_possible(world.kinetic_energy(), float(world.masses.min()), travel, dt)
        saved = (x.copy(), v.copy()) if keep else None
        h = dt / count
        done = 0
        while done < count:
            move(x, v, h)
            self.lists.update(x, world.radii, world.static, speed * h)
            contacts = find_contacts(x, self.lists)
            fastest = resolve(v, world.masses, contacts, self.best, totals)
            done += 1
            totals[SUBSTEPS] += 1
            count, done, h, speed = replan(count, done, h, speed, fastest, travel)
            if over_budget(totals[SUBSTEPS], count, done):
                x[:], v[:] = saved  # kept: this is reachable only when refusal_possible
                self.invalidate()  # the lists followed the balls part-way
                return STEP_REFUSED
        return STEP_DONE
