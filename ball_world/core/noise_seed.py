"""A scan's noise generator, numpy's `default_rng([seed, key, step])` at a fraction of its cost.

Why: a scan's noise is seeded by (random.seed, the scanner's name key, the step) so that a
re-simulation draws it again (core.lidar). Making that generator the documented way costs
about 11 us (SeedSequence's entropy coercion and hashing, then a new PCG64 and Generator),
a third of a whole scan at 1,000 balls. The numbers must stay the ones recordings hold, so
this does numpy's own arithmetic, only cheaper: SeedSequence's pool mixing and state
generation compiled (core.noise_kernel.seed_words), then PCG64's seeding (two steps of its
128-bit LCG) in Python integers, set into one PCG64 the scanner keeps and reuses.
`test/test_lidar.py` checks the draws against `default_rng` bit for bit over many seeds,
keys and steps. Without numba it is `default_rng` itself.

Many scans at once (a swarm's, a vector env's) skip the Generator altogether: EntropyRows
holds each scanner's seed words and noises all their ranges in one compiled call
(core.noise_kernel.add_noise, the same bits).
"""
import numpy as np

from ball_world.core import noise_kernel
from ball_world.core.noise_kernel import PCG_MULTIPLIER

MASK32 = 0xFFFFFFFF
MASK128 = (1 << 128) - 1
#: Entropy words an EntropyRows row holds at first: a seed and a key below 2**64 need 4.
WORDS = 4


def int_words(value):
    """A non-negative int as SeedSequence takes it: its 32-bit words, least significant
    first, at least one (ValueError for a negative one, as SeedSequence refuses it)."""
    value = int(value)
    if value < 0:
        raise ValueError(f'a noise seed must be a non-negative integer, not {value}')
    words = [value & MASK32]
    value >>= 32
    while value:
        words.append(value & MASK32)
        value >>= 32
    return words


def pcg64_state(words):
    """PCG64's state dict for SeedSequence's 4 uint64 state words s1, s0, i1, i0 (Python
    ints): inc = (i << 1) | 1, then state = step(step(0) + s), step(x) = x * mult + inc."""
    seed = (words[0] << 64) | words[1]
    inc = ((((words[2] << 64) | words[3]) << 1) | 1) & MASK128
    state = (inc + seed) & MASK128  # step(0) is inc
    state = (state * PCG_MULTIPLIER + inc) & MASK128
    return {'bit_generator': 'PCG64', 'state': {'state': state, 'inc': inc},
            'has_uint32': 0, 'uinteger': 0}


class NoiseSeeds:
    """The generators of one scanner's noise: `generator(step)` draws exactly as
    `np.random.default_rng([seed, key, step])` does. It reseeds and returns the same
    Generator each time, so draw from it before asking for the next step's."""

    def __init__(self, seed, key):
        self.seed = int(seed)
        self.key = int(key)
        self._fixed = np.array(int_words(self.seed) + int_words(self.key), dtype=np.uint64)
        self._bits = np.random.PCG64()
        self._generator = np.random.Generator(self._bits)

    def generator(self, step):
        """The Generator of this step's noise."""
        step = int(step)
        if not noise_kernel.available() or not 0 <= step < 2**63:  # (default_rng refuses
            return np.random.default_rng([self.seed, self.key, step])  # a negative step)
        self._bits.state = pcg64_state(noise_kernel.seed_words(self._fixed, step).tolist())
        return self._generator


class EntropyRows:
    """The noise seeds of many scanners, one row each, for noising many scans in one
    compiled call (`add_noise`): row k draws as `default_rng([seed_k, key_k, step])`."""

    def __init__(self, rows):
        self.words = np.zeros((rows, WORDS), dtype=np.uint64)  # seed's words, then key's
        self.lengths = np.zeros(rows, dtype=np.int64)

    @classmethod
    def of(cls, pairs):
        """Rows of the (seed, key) pairs, in order."""
        pairs = list(pairs)
        table = cls(len(pairs))
        for row, (seed, key) in enumerate(pairs):
            table.set(row, seed, key)
        return table

    def set(self, row, seed, key):
        """Row `row` draws as default_rng([seed, key, step]) (ValueError for a negative seed
        or key, as SeedSequence refuses them)."""
        words = int_words(seed) + int_words(key)
        if len(words) > self.words.shape[1]:  # a seed or key beyond 2**64: rare, so grown
            wider = np.zeros((len(self.words), len(words)), dtype=np.uint64)
            wider[:, :self.words.shape[1]] = self.words
            self.words = wider
        self.words[row, :len(words)] = words
        self.lengths[row] = len(words)

    def add_noise(self, ranges, rows, steps, stddev):
        """Noise of `stddev` m on ranges (N, beams) float64 C-contiguous, in place: row k as
        core.lidar.add_noise noises the scan of entropy row rows[k] at step steps[k] (the
        same bits). Needs numba (noise_kernel.available()); returns ranges."""
        if stddev > 0.0 and len(ranges):
            steps = np.asarray(steps, dtype=np.int64)
            if steps.min() < 0:
                raise ValueError(f'a noise step must be a non-negative integer, not '
                                 f'{steps.min()}')
            noise_kernel.add_noise(ranges, self.words[rows], self.lengths[rows], steps,
                                   float(stddev))
        return ranges

    def standard_normals(self, rows, step, count):
        """(len(rows), count) standard normals, row k default_rng([seed, key, step])
        .standard_normal(count) of entropy row rows[k] (the same bits). Needs numba; a
        step from 0 to 2**63 - 1."""
        out = np.empty((len(rows), count))
        if len(rows):
            noise_kernel.standard_normals(out, self.words[rows], self.lengths[rows],
                                          np.full(len(rows), step, dtype=np.int64))
        return out


def warm():
    """Compile (or load from numba's cache) the seeding and the batched draws, so a first
    noisy scan does not."""
    noise_kernel.warm()
