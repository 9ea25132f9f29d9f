"""A ruler for the Rerun arena: Rerun's 2D view draws no axes, so without it a picture of the
world has no scale. Ticks at round distances (1, 2 or 5 x 10^k m) along the bottom and the
left of the scene, labelled in metres, just outside it; the view's bounds are widened so the
labels stay on screen. Pure geometry: rerun_log logs it once per segment, as it does the
walls.
"""
import math

import numpy as np

#: Intervals at least along the longer side of the scene (the step is 1, 2 or 5 x 10^k).
TICKS = 5
#: Tick length, and the distance from the scene's edge to a tick's label, as fractions of the
#: scene's larger side.
TICK_FRACTION = 0.012
LABEL_FRACTION = 0.035
#: Room added at the bottom and the left of the view for the labels, same unit: their tags
#: (rerun_text) hang below their points, a label box high in a view fitted into 600 pixels.
PAD_FRACTION = 0.09


def tick_step(span):
    """The round distance between ticks for a side of `span` m: the largest 1, 2 or 5 x 10^k
    that gives at least TICKS intervals."""
    raw = max(span, 1e-9) / TICKS
    power = 10.0 ** math.floor(math.log10(raw))
    return max(m * power for m in (1.0, 2.0, 5.0) if m * power <= raw * (1.0 + 1e-9))


def _ticks(low, high, step):
    first = math.ceil(low / step - 1e-9)
    last = math.floor(high / step + 1e-9)
    return [k * step for k in range(first, last + 1)]


def _text(value, step):
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    return f'{value:.{decimals}f}'


def ruler(bounds):
    """(tick segments as an (n, 2, 2) array, label positions (m, 2), label texts) for a
    scene of bounds (xmin, ymin, xmax, ymax) in world coordinates (+y up)."""
    xmin, ymin, xmax, ymax = bounds
    size = max(xmax - xmin, ymax - ymin)
    step = tick_step(size)
    tick, gap = TICK_FRACTION * size, LABEL_FRACTION * size
    xs, ys = _ticks(xmin, xmax, step), _ticks(ymin, ymax, step)
    segments = [((x, ymin), (x, ymin - tick)) for x in xs]
    segments += [((xmin, y), (xmin - tick, y)) for y in ys]
    positions = [(x, ymin - gap) for x in xs] + [(xmin - gap, y) for y in ys]
    texts = [_text(x, step) for x in xs] + [_text(y, step) for y in ys]
    if xs:
        texts[len(xs) - 1] += ' m'  # the unit once, at the end of the x axis
    return (np.array(segments, dtype=np.float64).reshape(-1, 2, 2),
            np.array(positions, dtype=np.float64).reshape(-1, 2), texts)


def padded(bounds):
    """The bounds with room for the ruler's labels at the bottom and the left."""
    xmin, ymin, xmax, ymax = bounds
    pad = PAD_FRACTION * max(xmax - xmin, ymax - ymin)
    return (xmin - pad, ymin - pad, xmax, ymax)
