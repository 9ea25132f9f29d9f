"""Many scenes: each figure's mean with a 95% confidence interval, and the worst scenes.

One run is one sample of a tracker's behaviour: a seed that happens to keep the balls apart
flatters it. Over n scenes a figure's mean is given with the two-sided 95% interval of
Student's t (mean +- t(0.975, n - 1) s / sqrt(n), s the sample standard deviation): the
range the mean over many more such scenes would lie in, if scenes vary as these do. Scenes
where a figure is undefined (nan: no ground truth) are left out of its mean and counted.
"""
from dataclasses import dataclass
import math

import numpy as np
from scipy import stats

#: Confidence of the intervals.
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Interval:
    """A figure over scenes: mean, half-width of its confidence interval, and spread."""

    mean: float
    half_width: float  # nan for fewer than two scenes
    std: float
    low: float  # smallest value of one scene
    high: float
    count: int  # scenes with a defined value

    def as_dict(self):
        return {'mean': _plain(self.mean), 'ci95': _plain(self.half_width),
                'std': _plain(self.std), 'min': _plain(self.low), 'max': _plain(self.high),
                'scenes': self.count}


def _plain(value):
    """A float for JSON: nan and infinities become None (JSON has neither)."""
    return float(value) if math.isfinite(value) else None


def interval(values):
    """The mean of `values` (nan ones left out) with its 95% confidence half-width."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    n = len(values)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, math.nan, math.nan, 0)
    mean = float(np.mean(values))
    if n == 1:
        return Interval(mean, math.nan, math.nan, mean, mean, 1)
    std = float(np.std(values, ddof=1))
    half = float(stats.t.ppf(0.5 + CONFIDENCE / 2.0, n - 1)) * std / math.sqrt(n)
    return Interval(mean, half, std, float(values.min()), float(values.max()), n)


def summarize(rows, names):
    """{name: Interval} over scenes; rows: one dict of figures per scene."""
    return {name: interval([row.get(name, math.nan) for row in rows]) for name in names}


def worst(rows, labels, name, count):
    """The `count` scenes with the lowest `name` (ties in the order given), as
    (label, value) pairs; scenes where it is undefined come first (nothing was scored)."""
    values = np.array([row.get(name, math.nan) for row in rows], dtype=np.float64)
    keys = np.where(np.isfinite(values), values, -np.inf)
    order = np.argsort(keys, kind='stable')[:count]
    return [(labels[i], float(values[i])) for i in order]
