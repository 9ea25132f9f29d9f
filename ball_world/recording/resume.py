"""Where a split file picks up a segment: the state it starts from, written and read back.

A split recording (recording.split_writer) starts each new file between two steps of a
segment. So that the file alone can be inspected and re-simulated, its first 'ball_world'
metadata record is the segment's own (same index, log offset and parameters) plus two
values: `resume_step`, the step k the file continues from, and `resume_state`, the world at
the end of step k: the balls' entity names in pose order, the names deleted earlier in the
segment (never given again), and positions, velocities, radii and masses as little-endian
float64 in base64, so they come back bit for bit. The file's first step is then k + 1.

The state is untrusted when read back: parse_resume checks every count, name and number
and raises ValueError saying which one is wrong.
"""
import base64
import binascii
from dataclasses import dataclass
import json
import math

import numpy as np

from ball_world.core import limits
from ball_world.core.edits import NAME_PATTERN

RESUME_STEP = 'resume_step'
RESUME_STATE = 'resume_state'
_ARRAYS = {'positions': 2, 'velocities': 2, 'radii': 1, 'masses': 1}
_FIELDS = frozenset(('names', 'retired', *_ARRAYS))
_BOUNDS = {'positions': (-limits.COORDINATE_LIMIT, limits.COORDINATE_LIMIT),
           'radii': (limits.MIN_RADIUS, limits.MAX_RADIUS),
           'masses': (limits.MIN_MASS, limits.MAX_MASS)}


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


def _encode(array):
    return base64.b64encode(np.ascontiguousarray(array, dtype='<f8').tobytes()).decode()


def resume_metadata(record, retired):
    """The two metadata values for a file that continues after StepRecord `record`.

    retired: the names deleted earlier in the segment.
    """
    state = {'names': list(record.names), 'retired': sorted(retired),
             'positions': _encode(record.positions), 'velocities': _encode(record.velocities),
             'radii': _encode(record.radii), 'masses': _encode(record.masses)}
    return {RESUME_STEP: str(record.step), RESUME_STATE: json.dumps(state)}


def _names(value, what):
    if not isinstance(value, list) or len(value) > limits.MAX_BALLS * 100:
        raise ValueError(f'{what} is not a list of names')
    for name in value:
        if not (isinstance(name, str) and len(name) <= limits.MAX_NAME_LENGTH
                and NAME_PATTERN.fullmatch(name)):
            shown = repr(name)[:60]
            raise ValueError(f'{what} holds {shown}, which is no entity name')
    return tuple(value)


def _array(state, key, count):
    text = state[key]
    try:
        data = base64.b64decode(text.encode('ascii'), validate=True)
    except (AttributeError, UnicodeEncodeError, binascii.Error):
        raise ValueError(f'{key} is not base64 text') from None
    width = _ARRAYS[key]
    if len(data) != 8 * width * count:
        raise ValueError(f'{key} holds {len(data)} bytes, not {width} float64 for each of '
                         f'the {count} balls')
    array = np.frombuffer(data, dtype='<f8').astype(np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f'{key} holds a value that is not finite')
    low, high = _BOUNDS.get(key, (-math.inf, math.inf))
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
    if not isinstance(state, dict) or set(state) != _FIELDS:
        raise ValueError(f"'{RESUME_STATE}' does not hold exactly "
                         f"{', '.join(sorted(_FIELDS))}")
    names = _names(state['names'], 'names')
    if len(names) > limits.MAX_BALLS or len(set(names)) != len(names):
        raise ValueError(f'names lists {len(names):,} balls, or one twice')
    retired = _names(state['retired'], 'retired')
    count = len(names)
    arrays = {key: _array(state, key, count) for key in _ARRAYS}
    return ResumeState(step=int(step_text), names=names, retired=retired, **arrays)
