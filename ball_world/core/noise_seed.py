"""A scan's noise generator, numpy's `default_rng([seed, key, step])` at a fraction of its cost.

Why: a scan's noise is seeded by (random.seed, the scanner's name key, the step) so that a
re-simulation draws it again (core.lidar). Making that generator the documented way costs
about 11 us (SeedSequence's entropy coercion and hashing, then a new PCG64 and Generator),
a third of a whole scan at 1,000 balls. The numbers must stay the ones recordings hold, so
this does numpy's own arithmetic, only cheaper: SeedSequence's pool mixing and state
generation (uint32 multiply-xorshift hashing, as numpy documents it for SeedSequence) in a
compiled function, then PCG64's seeding (two steps of its 128-bit LCG) in Python integers,
set into one PCG64 the scanner keeps and reuses. `test/test_lidar.py` checks the draws
against `default_rng` bit for bit over many seeds, keys and steps. Without numba it is
`default_rng` itself.
"""
import numpy as np

try:
    from numba import njit
except ImportError:  # the documented, slower construction is used instead
    njit = None

MASK32 = 0xFFFFFFFF
MASK128 = (1 << 128) - 1
#: SeedSequence's constants (pool of 4 words; hash multipliers A and B; mix multipliers).
POOL_SIZE = 4
INIT_A = 0x43b0d7e5
MULT_A = 0x931e8875
INIT_B = 0x8b51f9dd
MULT_B = 0x58f38ded
MIX_MULT_L = 0xca01f9dd
MIX_MULT_R = 0x4973f715
#: PCG64's 128-bit LCG multiplier.
PCG_MULTIPLIER = (2549297995355413924 << 64) | 4865540595714422341


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


def _seed_words(fixed, step):
    """SeedSequence(entropy).generate_state(4, uint64) for the entropy words `fixed` (uint64
    array of 32-bit words) followed by the words of `step` (int_words): the pool mixed from
    the entropy, then hashed out into 8 words, read as 4 little-endian uint64."""
    mask = np.uint64(MASK32)
    shift = np.uint64(16)
    high = np.uint64(step) >> np.uint64(32)
    entropy = np.empty(len(fixed) + (2 if high else 1), dtype=np.uint64)
    entropy[:len(fixed)] = fixed
    entropy[len(fixed)] = np.uint64(step) & mask
    if high:
        entropy[len(fixed) + 1] = high
    pool = np.zeros(POOL_SIZE, dtype=np.uint64)
    hash_a = np.uint64(INIT_A)
    mult_a = np.uint64(MULT_A)
    left = np.uint64(MIX_MULT_L)
    right = np.uint64(MIX_MULT_R)

    def hashmix(value, hash_const):
        value = (value ^ hash_const) & mask
        hash_const = (hash_const * mult_a) & mask
        value = (value * hash_const) & mask
        return value ^ (value >> shift), hash_const

    def mix(x, y):
        result = (left * x - right * y) & mask
        return result ^ (result >> shift)

    for i in range(POOL_SIZE):
        word = entropy[i] if i < len(entropy) else np.uint64(0)
        pool[i], hash_a = hashmix(word, hash_a)
    for i_src in range(POOL_SIZE):
        for i_dst in range(POOL_SIZE):
            if i_src != i_dst:
                hashed, hash_a = hashmix(pool[i_src], hash_a)
                pool[i_dst] = mix(pool[i_dst], hashed)
    for i_src in range(POOL_SIZE, len(entropy)):
        for i_dst in range(POOL_SIZE):
            hashed, hash_a = hashmix(entropy[i_src], hash_a)
            pool[i_dst] = mix(pool[i_dst], hashed)
    out = np.zeros(4, dtype=np.uint64)
    hash_b = np.uint64(INIT_B)
    mult_b = np.uint64(MULT_B)
    for i in range(8):
        value = (pool[i % POOL_SIZE] ^ hash_b) & mask
        hash_b = (hash_b * mult_b) & mask
        value = (value * hash_b) & mask
        out[i // 2] |= (value ^ (value >> shift)) << np.uint64(32 * (i % 2))
    return out


if njit is not None:
    _seed_words = njit(cache=True, nogil=True)(_seed_words)


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
        if njit is None or not 0 <= step < 2**63:  # (a negative step is refused there)
            return np.random.default_rng([self.seed, self.key, step])
        self._bits.state = pcg64_state(_seed_words(self._fixed, step).tolist())
        return self._generator


def warm():
    """Compile (or load from numba's cache) the seeding, so a first noisy scan does not."""
    return NoiseSeeds(0, 0).generator(0)
