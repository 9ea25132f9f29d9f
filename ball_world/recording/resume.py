"""Where a split file picks up a segment: the state it starts from, written and read back.

A split recording (recording.split_writer) starts each new file between two steps of a
segment. So that the file alone can be inspected and re-simulated, its first 'ball_world'
metadata record is the segment's own (same index, log offset and parameters) plus two
values: `resume_step`, the step k the file continues from, and `resume_state`, the world at
the end of step k: the balls' entity names in pose order, the names deleted earlier in the
segment (never given again), and positions, velocities, radii and masses as little-endian
float64 in base64, so they come back bit for bit. The file's first step is then k + 1.

A world with agents (core.agents) adds what drives them on: `agents`, their names in agent
order, `yaws`, their headings (float64, base64), and of those that were given one the last
command, which may still be in force: `commanded` (names), `commands` (vx, vy, wz each,
float64, base64) and `since_ns` (the simulation time it took effect). A state without agents
has none of these keys, as before agents existed. With noisy odometry (agent.odom.noise,
core.odometry) two more keys hold its state, which drifts from the truth and so cannot be
made again from the balls: `odometry`, each agent's odometry pose (x, y, yaw; float64,
base64), and `odometry_covariance`, its six covariance entries (core.odometry
COVARIANCE_ENTRIES; float64, base64). CommandsInForce follows the records of a
segment to know the commands, which a StepRecord carries only at the step they were given.

In exact mode a third value, `resume_exact`, holds what exact mode carries from step k to
step k + 1 (core.exact_carry: its cells, predictions and partners), without which the
file's steps would differ from the recorded ones in the last bits: a JSON object of
base64 little-endian arrays, `unit` (float64), `tori` (int64, two per radius class),
`cells` (int64, two per ball), `last` and `hit_partner` (int32 per ball), `hit_time` and
`exit_time` (float64 per ball), `codes` (four bytes per ball: hit kind, exit side + 1, next
event kind, whether the hit's partner is unchanged since) and `edited` (int64 ball indices);
or `{}` when the world kept no predictions then (the next step makes them from the balls).
It costs 44 bytes per ball before base64 (59 after). A reader that does not know the key
reads the file as before.

The state is untrusted when read back: parse_resume checks every count, name and number
and raises ValueError saying which one is wrong (exact mode's values are checked against
the world once it is built, by core.exact_carry).
"""
import base64
import binascii
from dataclasses import dataclass
import json
import math
from typing import Optional

import numpy as np

from ball_world.core import limits
from ball_world.core.agents import Command, MAX_COMMAND
from ball_world.core.edits import NAME_PATTERN
from ball_world.core.exact_carry import CarriedState, NOTHING_KEPT

RESUME_STEP = 'resume_step'
RESUME_STATE = 'resume_state'
RESUME_EXACT = 'resume_exact'
_ARRAYS = {'positions': 2, 'velocities': 2, 'radii': 1, 'masses': 1}
_FIELDS = frozenset(('names', 'retired', *_ARRAYS))
_AGENT_FIELDS = frozenset(('agents', 'yaws', 'commanded', 'commands', 'since_ns'))
_ODOMETRY_FIELDS = frozenset(('odometry', 'odometry_covariance'))
_BOUNDS = {'positions': (-limits.COORDINATE_LIMIT, limits.COORDINATE_LIMIT),
           'radii': (limits.MIN_RADIUS, limits.MAX_RADIUS),
           'masses': (limits.MIN_MASS, limits.MAX_MASS)}
#: resume_exact's arrays of one row per ball: stored type and row width.
_EXACT_ROWS = {'cells': ('<i8', 2), 'last': ('<i4', 1), 'hit_partner': ('<i4', 1),
               'hit_time': ('<f8', 1), 'exit_time': ('<f8', 1), 'codes': ('u1', 4)}
_EXACT_FIELDS = frozenset(('unit', 'tori', 'edited', *_EXACT_ROWS))
#: Most radius classes a carried state may list (radii within MAX_RADIUS_RATIO make 5).
_MOST_CLASSES = 64
#: Largest value of each byte of codes: hit kind, exit side + 1, next kind, current.
_CODE_LIMITS = np.array([3, 4, 3, 1], dtype=np.uint8)


@dataclass(frozen=True, eq=False)
class ResumeState:
    """The world at the end of step `step` of a segment, as a split file starts from it.

    Compared by identity: its arrays have no single truth value.
    """

    step: int
    names: tuple
    retired: tuple
    positions: np.ndarray  # (N, 2)
    velocities: np.ndarray  # (N, 2)
    radii: np.ndarray  # (N,)
    masses: np.ndarray  # (N,)
    agents: tuple = ()  # agent names, in agent order (core.agents.Agents.names)
    yaws: tuple = ()  # their headings, rad, in the same order
    commands: tuple = ()  # ((name, core.agents.Command), ...): the last command of each
    # Noisy odometry: each agent's pose (x, y, yaw) and covariance entries, agent order.
    odometry: tuple = ()
    odometry_covariances: tuple = ()
    # Exact mode: what step `step` hands the next (core.exact_carry.CarriedState; maybe
    # NOTHING_KEPT). None when the file does not say (seed mode, or an older writer).
    exact: Optional[CarriedState] = None


class CommandsInForce:
    """The last command of every agent in a segment, from its StepRecords in order.

    A command recorded with step k took effect at k's stamp (Simulation.command), the last
    one given wins (core.agents.Agents.command), and a deleted agent's goes with it.
    """

    def __init__(self):
        self.commands = {}

    def restart(self):
        """A new segment: no agent has a command."""
        self.commands = {}

    def follow(self, record):
        """Take the commands and deletions recorded with `record` (a StepRecord, or the
        PendingEvents of a closing record, which holds no commands)."""
        stamp_ns = record.stamp_ns
        for command in getattr(record, 'commands', ()):
            self.commands[command.name] = Command(command.vx, command.vy, command.wz,
                                                  stamp_ns)
        for edit in record.edits:
            if edit.kind == 'delete':
                self.commands.pop(edit.name, None)


def _encode(array):
    return base64.b64encode(np.ascontiguousarray(array, dtype='<f8').tobytes()).decode()


def resume_metadata(record, retired, commands=None):
    """The metadata values for a file that continues after StepRecord `record`: its step
    and state, and in exact mode (record.exact set) what the step hands the next.

    retired: the names deleted earlier in the segment. commands: agent name -> its last
    Command (CommandsInForce.commands), for a world with agents.
    """
    state = {'names': list(record.names), 'retired': sorted(retired),
             'positions': _encode(record.positions), 'velocities': _encode(record.velocities),
             'radii': _encode(record.radii), 'masses': _encode(record.masses)}
    if record.agents is not None:
        names = list(record.agents.names)
        given = [name for name in names if name in (commands or {})]
        state.update(
            agents=names, yaws=_encode(record.agents.yaws), commanded=given,
            commands=_encode([(commands[n].vx, commands[n].vy, commands[n].wz)
                              for n in given]),
            since_ns=[commands[name].since_ns for name in given])
        if record.agents.odometry is not None:
            state.update(odometry=_encode(record.agents.odometry),
                         odometry_covariance=_encode(record.agents.odometry_covariances))
    values = {RESUME_STEP: str(record.step), RESUME_STATE: json.dumps(state)}
    if getattr(record, 'exact', None) is not None:
        values[RESUME_EXACT] = exact_metadata(record.exact)
    return values


def _encode_as(array, dtype):
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode()


def exact_metadata(carried):
    """resume_exact's text for a core.exact_carry.CarriedState."""
    if not carried.kept:
        return '{}'
    codes = np.stack((carried.hit_kind, carried.exit_side + 1, carried.next_kind,
                      carried.hit_current), axis=1)
    rows = {'cells': carried.cells, 'last': carried.last, 'hit_partner': carried.hit_partner,
            'hit_time': carried.hit_time, 'exit_time': carried.exit_time, 'codes': codes}
    document = {key: _encode_as(rows[key], dtype) for key, (dtype, _) in _EXACT_ROWS.items()}
    document.update(unit=_encode_as([carried.unit], '<f8'), tori=_encode_as(carried.tori, '<i8'),
                    edited=_encode_as(carried.edited, '<i8'))
    return json.dumps(document)


def _names(value, what):
    if not isinstance(value, list) or len(value) > limits.MAX_BALLS * 100:
        raise ValueError(f'{what} is not a list of names')
    for name in value:
        if not (isinstance(name, str) and len(name) <= limits.MAX_NAME_LENGTH
                and NAME_PATTERN.fullmatch(name)):
            shown = repr(name)[:60]
            raise ValueError(f'{what} holds {shown}, which is no entity name')
    return tuple(value)


def _array(state, key, count, width=None, bounds=None, what='balls'):
    text = state[key]
    try:
        data = base64.b64decode(text.encode('ascii'), validate=True)
    except (AttributeError, UnicodeEncodeError, binascii.Error):
        raise ValueError(f'{key} is not base64 text') from None
    width = width or _ARRAYS[key]
    if len(data) != 8 * width * count:
        raise ValueError(f'{key} holds {len(data)} bytes, not {width} float64 for each of '
                         f'the {count} {what}')
    array = np.frombuffer(data, dtype='<f8').astype(np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f'{key} holds a value that is not finite')
    low, high = bounds or _BOUNDS.get(key, (-math.inf, math.inf))
    if len(array) and not (array.min() >= low and array.max() <= high):
        raise ValueError(f'{key} holds a value outside {low:g} to {high:g}')
    return array.reshape(count, width) if width > 1 else array


def parse_resume(values, parse_json):
    """The ResumeState of a metadata record's values, or None when it starts its segment.

    parse_json(text, what): the caller's bounded JSON parser for untrusted text.
    Raises ValueError naming what is wrong.
    """
    if RESUME_STEP not in values and RESUME_STATE not in values:
        return None
    step_text = values.get(RESUME_STEP)
    if not isinstance(step_text, str) or not step_text.isdigit() or len(step_text) > 19:
        raise ValueError(f"'{RESUME_STEP}' is {repr(step_text)[:40]}, not a step number")
    state = parse_json(values.get(RESUME_STATE), f"'{RESUME_STATE}'")
    if not isinstance(state, dict) or set(state) not in (
            _FIELDS, _FIELDS | _AGENT_FIELDS, _FIELDS | _AGENT_FIELDS | _ODOMETRY_FIELDS):
        raise ValueError(f"'{RESUME_STATE}' does not hold exactly "
                         f"{', '.join(sorted(_FIELDS))} (and with agents "
                         f"{', '.join(sorted(_AGENT_FIELDS))}, and with noisy odometry "
                         f"{', '.join(sorted(_ODOMETRY_FIELDS))})")
    names = _names(state['names'], 'names')
    if len(names) > limits.MAX_BALLS or len(set(names)) != len(names):
        raise ValueError(f'names lists {len(names):,} balls, or one twice')
    retired = _names(state['retired'], 'retired')
    count = len(names)
    arrays = {key: _array(state, key, count) for key in _ARRAYS}
    if 'agents' in state:
        arrays.update(_agents(state, names))
    if RESUME_EXACT in values:
        arrays['exact'] = _exact(values[RESUME_EXACT], count, parse_json)
    return ResumeState(step=int(step_text), names=names, retired=retired, **arrays)


def _bytes(document, key, dtype, width, count=None, most=None):
    """document[key] decoded: `count` rows of `width` values (or at most `most` rows)."""
    what = f'{RESUME_EXACT} {key}'
    try:
        data = base64.b64decode(document[key].encode('ascii'), validate=True)
    except (AttributeError, UnicodeEncodeError, binascii.Error):
        raise ValueError(f'{what} is not base64 text') from None
    row = np.dtype(dtype).itemsize * width
    rows = len(data) // row
    if (count is not None and len(data) != row * count) or (
            count is None and (len(data) % row or rows > most)):
        expected = f'{count}' if count is not None else f'at most {most}'
        raise ValueError(f'{what} holds {len(data)} bytes, not {expected} rows of {row}')
    array = np.frombuffer(data, dtype=dtype)
    return array.reshape(rows, width) if width > 1 else array


def _exact(text, count, parse_json):
    """resume_exact's CarriedState for `count` balls (its values are checked against the
    world by core.exact_carry when it is taken over; here only their sizes and codes)."""
    document = parse_json(text, f"'{RESUME_EXACT}'")
    if document == {}:
        return NOTHING_KEPT
    if not isinstance(document, dict) or set(document) != _EXACT_FIELDS:
        raise ValueError(f"'{RESUME_EXACT}' is neither {{}} nor exactly "
                         f"{', '.join(sorted(_EXACT_FIELDS))}")
    rows = {key: _bytes(document, key, dtype, width, count)
            for key, (dtype, width) in _EXACT_ROWS.items()}
    codes = rows['codes']
    if len(codes) and (codes > _CODE_LIMITS).any():
        raise ValueError(f'{RESUME_EXACT} codes holds a value that is no code')
    codes = codes.astype(np.int8)
    return CarriedState(
        unit=float(_bytes(document, 'unit', '<f8', 1, 1)[0]),
        tori=_bytes(document, 'tori', '<i8', 2, most=_MOST_CLASSES).astype(np.int64),
        cells=rows['cells'].astype(np.int64), last=rows['last'].astype(np.int64),
        hit_kind=codes[:, 0], hit_partner=rows['hit_partner'].astype(np.int64),
        hit_current=codes[:, 3] == 1, hit_time=rows['hit_time'].astype(np.float64),
        exit_side=codes[:, 1] - 1, exit_time=rows['exit_time'].astype(np.float64),
        next_kind=codes[:, 2],
        edited=_bytes(document, 'edited', '<i8', 1, most=count).astype(np.int64))


def _subset(state, key, of, what):
    """state[key]: names, each once, each one of `of`."""
    names = _names(state[key], key)
    if len(set(names)) != len(names) or not set(names) <= set(of):
        raise ValueError(f'{key} names an agent twice, or one that is not {what}')
    return names


def _agents(state, names):
    """The agents' fields of a resume state, checked: agents, yaws, commands."""
    agents = _subset(state, 'agents', names, 'a ball of the state')
    yaws = _array(state, 'yaws', len(agents), 1, (-math.pi, math.pi), 'agents')
    given = _subset(state, 'commanded', agents, 'an agent')
    values = _array(state, 'commands', len(given), 3, (-MAX_COMMAND, MAX_COMMAND),
                    'agents commanded')
    since = state['since_ns']
    if not (isinstance(since, list) and len(since) == len(given) and all(
            type(t) is int and 0 <= t <= limits.MAX_SIM_TIME_NS for t in since)):
        raise ValueError(f'since_ns is not a simulation time in ns for each of the '
                         f'{len(given)} agents commanded')
    commands = tuple((name, Command(*(float(v) for v in row), since[i]))
                     for i, (name, row) in enumerate(zip(given, values.reshape(-1, 3))))
    found = {'agents': agents, 'yaws': tuple(float(yaw) for yaw in yaws),
             'commands': commands}
    if 'odometry' in state:
        poses = _array(state, 'odometry', len(agents), 3, None, 'agents')
        if len(poses) and not np.abs(poses[:, 2]).max() <= math.pi:
            raise ValueError('odometry holds a yaw outside [-pi, pi]')
        covariances = _array(state, 'odometry_covariance', len(agents), 6, None, 'agents')
        found.update(odometry=tuple(poses), odometry_covariances=tuple(covariances))
    return found
