"""What user code returns, checked: accepted as the scoring would read it, or refused in one
line naming who returned it, when, and the bad value.

A tracker's update returns rows (id, x, y, ...): a list of tuples, a (T, >=3) numpy array
(its ids then floats), a generator. An id is an int of any size (numpy's too), a name (str),
or a float that is a whole number (an id in a float array): 3.0 is the id 3. A position is a
finite real number of any type (float, int, numpy scalar). Refused: None or a bool as an id,
a nan, inf or fractional id, a string, None, nan, inf or an int too large for a float as a
coordinate, a row shorter than 3, more than MAX_TRACKS rows, and anything that is not rows
(None, a number, a mapping). The ids' uniqueness within a scan is the scoring's check
(scoring.frames.DuplicateTrack), as TrackEval's.

A controller's act returns commands: an (N, 3) array-like of finite numbers (vx, vy, wz of N
agents); `commands` checks its shape and values.
"""
import math
import numbers

import numpy as np

from ball_world.user_code.describe import shown, UserCodeError

#: Most tracks one update may return (each costs a row of the scoring's similarity matrix).
MAX_TRACKS = 10_000
ROWS = 'rows (id, x, y, ...)'


def track_id(value):
    """The id as the scoring keeps it, or None when it is no id."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, (int, str)):
        return value
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    return None


def coordinate(value):
    """The coordinate as a float, or None when it is no finite real number."""
    if isinstance(value, np.generic) and not isinstance(value, np.bool_):
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    try:
        value = float(value)
    except (OverflowError, TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _rows(value):
    """[(id, x, y)] of the first three fields of each row (user code may run: a generator,
    __iter__, __getitem__), or a UserCodeError's text on what is wrong."""
    if value is None or isinstance(value, (str, bytes, dict, numbers.Number, np.generic)):
        raise UserCodeError(f'returned {shown(value)}, not {ROWS}')
    if isinstance(value, np.ndarray) and value.ndim != 2 and value.size:
        raise UserCodeError(f'returned an array of shape {value.shape}, not {ROWS} (an '
                            'array of shape (tracks, 3 or more))')
    try:
        iterator = iter(value)
    except TypeError:
        raise UserCodeError(f'returned {shown(value)}, not {ROWS}') from None
    out = []
    for index, row in enumerate(iterator):
        if index >= MAX_TRACKS:
            raise UserCodeError(f'returned more than {MAX_TRACKS:,} tracks')
        if isinstance(row, (str, bytes, dict)) or not hasattr(row, '__getitem__') \
                or not hasattr(row, '__len__'):
            raise UserCodeError(f'returned row {index} = {shown(row)}, not {ROWS}')
        if len(row) < 3:
            raise UserCodeError(f'returned row {index} = {shown(row)} with {len(row)} '
                                f'fields, not {ROWS}')
        out.append((row[0], row[1], row[2]))
    return out


def track_rows(value, who, when):
    """(ids, [(x, y)]) of what a tracker returned; UserCodeError('{who} {problem} {when}')."""
    from ball_world.user_code.calls import call
    try:
        rows = call(f'{who}: iterating what it returned {when}', _rows, value)
    except UserCodeError as error:
        text = str(error)
        if text.startswith('returned '):
            text = f'{who} {text} {when}'
        raise UserCodeError(text) from None
    ids, xy = [], []
    for index, (raw_id, raw_x, raw_y) in enumerate(rows):
        kept = track_id(raw_id)
        if kept is None:
            raise UserCodeError(
                f'{who} returned a track {when} whose id is {shown(raw_id)} (row {index}): an '
                'id is an int, a name (str) or a whole number, not nan, inf, None or a bool')
        ids.append(kept)
        point = []
        for axis, raw in (('x', raw_x), ('y', raw_y)):
            number = coordinate(raw)
            if number is None:
                raise UserCodeError(
                    f'{who} returned a track {when} whose {axis} is {shown(raw)} (row '
                    f'{index}, id {shown(kept)}): a position is a finite number, m')
            point.append(number)
        xy.append(tuple(point))
    return ids, xy


def commands(value, count, who, when):
    """An (count, 3) float64 array of finite commands (vx, vy, wz per agent) from what a
    controller's act returned; UserCodeError naming who, when and the bad value."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise UserCodeError(f'{who} returned {shown(value)} {when}, not numbers '
                            f'(an array of shape ({count}, 3))') from None
    if array.shape != (count, 3):
        raise UserCodeError(f'{who} returned an array of shape {array.shape} {when}, not '
                            f'({count}, 3): vx, vy, wz per agent')
    bad = np.argwhere(~np.isfinite(array))
    if len(bad):
        row, column = bad[0]
        raise UserCodeError(f'{who} returned a command {when} that is not finite: row '
                            f'{row}, column {column} is {float(array[row, column])!r}')
    return array
