"""What exact mode carries from one step to the next, as plain arrays: taken from a World and
given to another, so that the other's steps are bit for bit the first's. No I/O.

Why it is needed: exact mode (core.exact, core.exact_kernel) keeps its predictions between
steps, and a prediction made at an earlier time, carried to the step's end by subtracting
each step's dt, differs in the last bits from one made afresh; which partner a ball skips
and which predictions are stale also depend on its past. A World rebuilt from positions and
velocities alone therefore steps differently. Everything the kernel's State holds is either
carried here or rebuilt from the world and what is carried, exactly as it was:

Carried (`CarriedState`):
- `unit`, the finest cell width, and `tori`, each radius class's bucket torus (column mask,
  row bits): chosen from the balls' spread when the state was built, long ago.
- per ball: its cell (`cells`; kept up to date by crossings, so not always the cell its
  rounded position falls in), the partner of its latest collision (`last`, never predicted
  against again until one of them changes course), its earliest impact (`hit_kind`,
  `hit_partner`, `hit_time`, and `hit_current`: whether the partner ball has not changed
  course since), where and when it leaves its cell (`exit_side`, `exit_time`), which of the
  two comes next (`next_kind`: rounding in the subtraction of dt can make the two times
  equal, so the choice is not always recomputable), and whether it was edited since the
  step (`edited`: the next step predicts it again).

Rebuilt: each ball's radius class (from the radii); the grids' shifts, bucket offsets and
reaches (from unit, tori and radii); the walls' buckets (from them and the walls); each
ball's event time (its hit time, its exit time or infinity, by next_kind: the kernel set it
equal to one of them and subtracted the same dt from both); the clocks (zero between
steps); the tournament tree (a function of the event times, rebuilt after every step); the
order of balls within a bucket (no outcome depends on it, see exact_kernel.restore); the
change counters (only their equality with a prediction's stamp matters, which hit_current
keeps). The event budget is per step and nothing of it carries over.

A carried state comes from untrusted files too (a split recording's start): `restore`
checks every value against the world before the compiled kernel, which trusts indices,
sees it, and raises ValueError naming the first that is wrong.
"""
from dataclasses import dataclass
import math

import numpy as np

#: Values of hit_kind, exit_side and next_kind: the kernel's own codes (exact_kernel's
#: PAIR ... NOTHING and NO_PARTNER; test_exact_carry checks), written here so that readers
#: of recordings use this module without importing numba, which the kernel needs.
PAIR, WALL, CROSSING, NOTHING = 0, 1, 2, 3
NO_SIDE = -1
NO_PARTNER = -1
#: Most cells a carried cell may be from the one its position falls in: crossings are taken
#: at the edge, so rounding can leave a ball's position just across it.
CELL_SLACK = 1


@dataclass(frozen=True, eq=False)
class CarriedState:
    """Exact mode's state between two steps (see the module docstring); N balls, C classes.

    With no tori, nothing is kept (a world never stepped, or whose state was dropped): the
    next step builds its predictions from the balls alone, as the World it came from would.
    """

    unit: float  # m
    tori: np.ndarray  # (C, 2) int64: column mask, row bits
    cells: np.ndarray  # (N, 2) int64
    last: np.ndarray  # (N,) int64: a ball, -2 - a wall, or NO_PARTNER
    hit_kind: np.ndarray  # (N,) int8: PAIR, WALL or NOTHING
    hit_partner: np.ndarray  # (N,) int64: a ball, a wall, or NO_PARTNER
    hit_current: np.ndarray  # (N,) bool: PAIR whose partner has not changed course since
    hit_time: np.ndarray  # (N,) s from the next step's start; inf for NOTHING
    exit_side: np.ndarray  # (N,) int8: 0 +x, 1 -x, 2 +y, 3 -y, or NO_SIDE
    exit_time: np.ndarray  # (N,) s from the next step's start; inf for NO_SIDE
    next_kind: np.ndarray  # (N,) int8: PAIR, WALL, CROSSING or NOTHING
    edited: np.ndarray  # (E,) int64: balls changed since the step, ascending

    @property
    def kept(self):
        """Whether there is a state at all (else the next step builds one)."""
        return len(self.tori) > 0

    def __len__(self):
        return len(self.cells)


def _nothing_kept():
    none = np.zeros(0, dtype=np.int64)
    small = np.zeros(0, dtype=np.int8)
    return CarriedState(unit=0.0, tori=np.zeros((0, 2), dtype=np.int64),
                        cells=np.zeros((0, 2), dtype=np.int64), last=none, hit_kind=small,
                        hit_partner=none, hit_current=np.zeros(0, dtype=bool),
                        hit_time=np.zeros(0), exit_side=small, exit_time=np.zeros(0),
                        next_kind=small, edited=none)


#: The state of a world that keeps none.
NOTHING_KEPT = _nothing_kept()


def export(state, world):
    """The CarriedState of the kernel State `state`, which is `world`'s (core.exact)."""
    from ball_world.core import exact_kernel as kernel

    n = len(world.positions)
    cells = np.empty((n, 2), dtype=np.int64)
    last = np.empty(n, dtype=np.int64)
    hit_kind = np.empty(n, dtype=np.int8)
    hit_partner = np.empty(n, dtype=np.int64)
    hit_current = np.empty(n, dtype=bool)
    exit_side = np.empty(n, dtype=np.int8)
    next_kind = np.empty(n, dtype=np.int8)
    edited = np.empty(n, dtype=np.int64)
    count = kernel.export(state, world.positions, world.velocities, cells, last, hit_kind,
                          hit_partner, hit_current, exit_side, next_kind, edited)
    grids = state.grids
    classes = len(grids) - 1
    return CarriedState(
        unit=float(state.unit),
        tori=grids[:classes, [kernel.COLUMN_MASK, kernel.ROW_BITS]].copy(), cells=cells,
        last=last, hit_kind=hit_kind, hit_partner=hit_partner, hit_current=hit_current,
        hit_time=state.hit_time.copy(), exit_side=exit_side, exit_time=state.exit_time.copy(),
        next_kind=next_kind, edited=edited[:count].copy())


def restore(world, carried):
    """The kernel State for `world` that `carried` describes; ValueError if it cannot be.

    Every index the compiled kernel would follow is checked here (a partner, a wall, a
    cell's bucket through the tori), so a crafted state is refused, never run.
    """
    from ball_world.core import exact_kernel as kernel

    n = len(world.positions)
    if n == 0:
        raise ValueError('exact state: kept for a world without balls, which keeps none')
    _check_shapes(carried, n)
    if not carried.kept:
        raise ValueError('exact state: tori lists no radius class, yet there are balls')
    classes, largest, members = kernel.class_sizes(world.radii)
    unit = carried.unit
    narrowest = 2.0 * float(largest[0]) * kernel.CELL_MARGIN
    if not (math.isfinite(unit) and unit >= narrowest):
        raise ValueError(f'exact state: cell width {unit!r} m is not finite, or narrower than '
                         f'the largest diameter of the smallest balls ({narrowest:.6g} m)')
    _check_tori(carried.tori, members, kernel.BUCKETS_PER_BALL)
    _check_cells(carried, world, classes, [kernel.cell_shift(unit, largest, c)
                                           for c in range(len(largest))])
    walls = len(world.static)  # the walls, then the map's runs
    _check_partners(carried, n, walls)
    _check_times(carried)
    balls = np.empty((n, kernel.COLUMNS), dtype=np.int64)
    balls[:, kernel.CELL_X] = carried.cells[:, 0]
    balls[:, kernel.CELL_Y] = carried.cells[:, 1]
    balls[:, kernel.COUNTER] = 0
    balls[:, kernel.LAST] = carried.last
    balls[:, kernel.HIT_KIND] = carried.hit_kind
    balls[:, kernel.HIT_PARTNER] = carried.hit_partner
    # A stale prediction's stamp is one no counter (0 from here on, rising) ever equals.
    balls[:, kernel.HIT_STAMP] = np.where(carried.hit_current, 0, -1)
    balls[:, kernel.EXIT] = carried.exit_side
    balls[:, kernel.KIND] = carried.next_kind
    balls[:, kernel.CLASS] = classes
    next_kind = carried.next_kind
    event_time = np.where(next_kind == CROSSING, carried.exit_time,
                          np.where(next_kind == NOTHING, math.inf, carried.hit_time))
    return kernel.restore(world.positions, world.velocities, world.radii,
                          *kernel.geometry(world.static), float(unit),
                          np.ascontiguousarray(carried.tori, dtype=np.int64),
                          np.ascontiguousarray(largest), balls,
                          np.array(carried.hit_time, dtype=np.float64),
                          np.array(carried.exit_time, dtype=np.float64), event_time,
                          np.ascontiguousarray(carried.edited, dtype=np.int64))


def _check_shapes(carried, n):
    for name, width in (('cells', 2), ('last', 0), ('hit_kind', 0), ('hit_partner', 0),
                        ('hit_current', 0), ('hit_time', 0), ('exit_side', 0),
                        ('exit_time', 0), ('next_kind', 0)):
        array = np.asarray(getattr(carried, name))
        shape = (n, width) if width else (n,)
        if array.shape != shape:
            raise ValueError(f'exact state: {name} has shape {array.shape}, not {shape} for '
                             f'{n} balls')
    edited = np.asarray(carried.edited)
    if edited.ndim != 1 or len(edited) > n or (len(edited) and not (
            edited.min() >= 0 and edited.max() < n and (np.diff(edited) > 0).all())):
        raise ValueError(f'exact state: edited is not a list of distinct balls of the {n} '
                         'in ascending order')


def _check_tori(tori, members, buckets_per_ball):
    tori = np.asarray(tori)
    count = len(members)
    if tori.shape != (count, 2):
        raise ValueError(f'exact state: tori has shape {tori.shape}, not ({count}, 2) for the '
                         f'{count} radius classes of these balls')
    for c in range(count):
        column_mask, row_bits = (int(value) for value in tori[c])
        limit = 64
        while limit < buckets_per_ball * int(members[c]):
            limit *= 2
        columns = column_mask + 1
        if not (0 < columns <= limit and columns & column_mask == 0
                and 0 <= row_bits <= limit.bit_length() and columns << row_bits <= limit):
            raise ValueError(f'exact state: the bucket torus of radius class {c} '
                             f'({column_mask}, {row_bits}) is not a power-of-two table of at '
                             f'most {limit} buckets')


def _check_cells(carried, world, classes, shifts):
    """Each carried cell is the one its ball's position falls in, give or take CELL_SLACK
    (edited balls aside: the next step places them again); shifts: each class's cells are
    the unit times 2 ** shift wide."""
    shifts = np.asarray(shifts, dtype=np.int64)
    widths = carried.unit * np.left_shift(1, shifts)[classes].astype(np.float64)
    with np.errstate(over='ignore', invalid='ignore'):
        falls = np.floor(world.positions / widths[:, None])
        off = np.abs(falls - carried.cells) > CELL_SLACK
    off[carried.edited] = False
    bad = np.flatnonzero(off.any(axis=1))
    if len(bad):
        i = bad[0]
        raise ValueError(f'exact state: ball {i} is in cell {carried.cells[i].tolist()}, '
                         f'but its position is in cell {falls[i].tolist()}')


def _check_partners(carried, n, walls):
    """Every ball and wall named is one of this world's, of the kind the codes say."""
    index = np.arange(n)
    hit, partner, last = carried.hit_kind, carried.hit_partner, carried.last
    side, following = carried.exit_side, carried.next_kind
    _first_wrong((
        (~np.isin(hit, (PAIR, WALL, NOTHING)), 'its impact is of no kind'),
        ((hit == PAIR) & ((partner < 0) | (partner >= n) | (partner == index)),
         'its impact names no other ball'),
        ((hit == WALL) & ((partner < 0) | (partner >= walls)), 'its impact names no wall'),
        ((hit == NOTHING) & (partner != NO_PARTNER), 'no impact, yet a partner'),
        ((hit != PAIR) & carried.hit_current, 'no ball to hit, yet a current stamp'),
        ((last != NO_PARTNER) & ((last >= n) | (last == index) | (last < -1 - walls)),
         'its latest collision names no other ball or wall'),
        (~np.isin(side, (0, 1, 2, 3, NO_SIDE)), 'it leaves its cell by no side'),
        (~np.isin(following, (PAIR, WALL, CROSSING, NOTHING)), 'its next event is of no kind'),
        (np.isin(following, (PAIR, WALL)) & (following != hit),
         'its next event is not its impact'),
        ((following == CROSSING) & (side == NO_SIDE), 'it crosses next, by no side'),
        ((following == NOTHING) & ((hit != NOTHING) | (side != NO_SIDE)),
         'no next event, yet an impact or a side to leave by'),
    ))


def _check_times(carried):
    """Times are never in the past (or NaN); a missing event is at infinity; the next event
    is the earlier of the two (as the kernel chose it, to rounding of the same dt)."""
    hit_time, exit_time = np.asarray(carried.hit_time), np.asarray(carried.exit_time)
    hit, side, following = carried.hit_kind, carried.exit_side, carried.next_kind
    with np.errstate(invalid='ignore'):
        problems = (
            (~(hit_time >= 0.0) | ~(exit_time >= 0.0), 'an event time is negative or NaN'),
            ((hit == NOTHING) & (hit_time != math.inf), 'no impact, yet a finite impact time'),
            ((side == NO_SIDE) & (exit_time != math.inf), 'no side, yet a finite exit time'),
            (np.isin(following, (PAIR, WALL)) & ~(hit_time <= exit_time),
             'its impact is next, yet later than its exit'),
            ((following == CROSSING) & ~(exit_time <= hit_time),
             'its exit is next, yet later than its impact'),
        )
    _first_wrong(problems)


def _first_wrong(problems):
    """Raise ValueError for the first (mask over the balls, what is wrong) with a ball in."""
    for wrong, what in problems:
        bad = np.flatnonzero(wrong)
        if len(bad):
            raise ValueError(f'exact state: ball {bad[0]}: {what}')
