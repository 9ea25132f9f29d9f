"""numpy's noise arithmetic compiled: SeedSequence, PCG64 and the normal ziggurat, for many
scans in one call.

Why: a scan's noise is `np.random.default_rng([seed, key, step]).normal(0.0, stddev, beams)`
(core.lidar), and recordings and re-simulations hold those very numbers. Even seeded cheaply
(core.noise_seed) that generator costs several microseconds of Python per scan, paid per
robot per scan: more than the scans themselves for a swarm of 10,000 robots or a vector env
of 64 worlds. `add_noise` noises each row of a (N, beams) table of ranges as its own scan
would be, all rows in one compiled loop, by numpy's own arithmetic done over again:

1. SeedSequence's state words from the row's entropy words (seed, key, then the step's one or
   two 32-bit words): its pool mixing and output hashing, uint32 multiply-xorshifts (the
   same function seeds core.noise_seed's per-scan generator);
2. PCG64 seeded from them (inc = (i << 1) | 1, two steps of its 128-bit LCG with the seed
   added between), then `next_uint64`: a step of the LCG (state * multiplier + inc mod
   2**128, in two uint64 halves), output XSL-RR (the halves xor-ed, rotated right by the
   state's top 6 bits);
3. numpy's `random_standard_normal`: the 256-level ziggurat with numpy's tables (which numba
   ships), its rare branches too: the tail beyond r (idx 0) and the wedges, which draw
   doubles as (next_uint64 >> 11) * 2**-53 and take libm's log1p and exp, as numpy's C does;
4. `loc + scale * z` as numpy's `random_normal`, added to the row's finite ranges, one draw
   per beam whether or not it is finite (core.lidar.add_noise).

No fastmath (no fused multiply-adds, no re-association). Everything compiled lives in this
one file, so numba's cache (which watches only the file of a cached function) is rebuilt
whenever any of it changes. `test/test_noise_kernel.py` checks the draws against
`default_rng` bit for bit over many seeds, keys and steps, with enough of them that the tail
and the wedges certainly ran. Without numba `add_noise` is None and callers noise scan by
scan through core.lidar (the same numbers).
"""
import math

import numpy as np

try:
    from numba import njit
    from numba.np.random._constants import (fi_double, ki_double, wi_double,
                                            ziggurat_nor_inv_r, ziggurat_nor_r)
except ImportError:  # callers draw through numpy (core.noise_seed, core.lidar.add_noise)
    njit = None

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

_U0 = np.uint64(0)
_U1 = np.uint64(1)
_LOW32 = np.uint64(0xFFFFFFFF)
_BYTE = np.uint64(0xFF)
_BITS52 = np.uint64(0x000FFFFFFFFFFFFF)
_S8 = np.uint64(8)
_S11 = np.uint64(11)
_S16 = np.uint64(16)
_S32 = np.uint64(32)
_S58 = np.uint64(58)
_S63 = np.uint64(63)
_S64 = np.uint64(64)
_MULT_HIGH = np.uint64(PCG_MULTIPLIER >> 64)
_MULT_LOW = np.uint64(PCG_MULTIPLIER & 0xFFFFFFFFFFFFFFFF)
#: 2**-53: a uint64's top 53 bits as a double in [0, 1).
_DOUBLE_UNIT = 1.0 / 9007199254740992.0


# SeedSequence -------------------------------------------------------------------------

def _hashmix(value, hash_const):
    """SeedSequence's hashmix: (hashed value, next hash constant), uint32 in uint64."""
    value = (value ^ hash_const) & _LOW32
    hash_const = (hash_const * np.uint64(MULT_A)) & _LOW32
    value = (value * hash_const) & _LOW32
    return value ^ (value >> _S16), hash_const


def _mix(x, y):
    """SeedSequence's mix of two uint32 (in uint64)."""
    result = (np.uint64(MIX_MULT_L) * x - np.uint64(MIX_MULT_R) * y) & _LOW32
    return result ^ (result >> _S16)


def _state_words(entropy, count, pool, out):
    """out (4 uint64) = SeedSequence(entropy[:count]).generate_state(4, uint64): the pool
    (scratch of POOL_SIZE) mixed from the entropy's 32-bit words, then hashed out into 8
    words, read as 4 little-endian uint64."""
    hash_a = np.uint64(INIT_A)
    for i in range(POOL_SIZE):
        pool[i], hash_a = _hashmix(entropy[i] if i < count else _U0, hash_a)
    for i_src in range(POOL_SIZE):
        for i_dst in range(POOL_SIZE):
            if i_src != i_dst:
                hashed, hash_a = _hashmix(pool[i_src], hash_a)
                pool[i_dst] = _mix(pool[i_dst], hashed)
    for i_src in range(POOL_SIZE, count):
        for i_dst in range(POOL_SIZE):
            hashed, hash_a = _hashmix(entropy[i_src], hash_a)
            pool[i_dst] = _mix(pool[i_dst], hashed)
    hash_b = np.uint64(INIT_B)
    for i in range(4):
        out[i] = _U0
    for i in range(8):
        value = (pool[i % POOL_SIZE] ^ hash_b) & _LOW32
        hash_b = (hash_b * np.uint64(MULT_B)) & _LOW32
        value = (value * hash_b) & _LOW32
        out[i // 2] |= (value ^ (value >> _S16)) << np.uint64(32 * (i % 2))


def _with_step(entropy, fixed, length, step):
    """entropy[:count] = fixed[:length] then the 32-bit words of `step` (one, or two from
    2**32 on, as SeedSequence takes an int); returns count."""
    for i in range(length):
        entropy[i] = fixed[i]
    word = np.uint64(step)
    entropy[length] = word & _LOW32
    if word >> _S32:
        entropy[length + 1] = word >> _S32
        return length + 2
    return length + 1


def seed_words(fixed, step):
    """SeedSequence(entropy).generate_state(4, uint64) for the entropy words `fixed` (uint64
    array of 32-bit words) followed by the words of `step` (0 <= step < 2**64)."""
    entropy = np.empty(len(fixed) + 2, dtype=np.uint64)
    pool = np.empty(POOL_SIZE, dtype=np.uint64)
    out = np.empty(4, dtype=np.uint64)
    _state_words(entropy, _with_step(entropy, fixed, len(fixed), step), pool, out)
    return out


# PCG64 --------------------------------------------------------------------------------

def _high_product(a, b):
    """The high 64 bits of the 128-bit product of the uint64 a and b (32-bit halves)."""
    a_low = a & _LOW32
    a_high = a >> _S32
    b_low = b & _LOW32
    b_high = b >> _S32
    low_low = a_low * b_low
    high_low = a_high * b_low
    middle = (low_low >> _S32) + (high_low & _LOW32) + a_low * b_high
    return a_high * b_high + (high_low >> _S32) + (middle >> _S32)


def _pcg_next(high, low, inc_high, inc_low):
    """PCG64's next 64 bits from the state (high, low) and increment (inc_high, inc_low):
    (the bits, the new state's high, low). A step of the 128-bit LCG (state = state *
    multiplier + inc, modulo 2**128), then XSL-RR of the new state.

    Why the state goes in and out as plain values, not in an array: the draws of a scan
    then keep it in registers; read and written through an array (which the scan's row
    might alias, for all the compiler knows) every draw cost about twice as much
    (docs/performance.md)."""
    product_low = low * _MULT_LOW
    product_high = _high_product(low, _MULT_LOW) + low * _MULT_HIGH + high * _MULT_LOW
    new_low = product_low + inc_low
    new_high = product_high + inc_high + (_U1 if new_low < product_low else _U0)
    folded = new_high ^ new_low
    turn = new_high >> _S58
    return (folded >> turn) | (folded << ((_S64 - turn) & _S63)), new_high, new_low


def _seeded(words):
    """PCG64 seeded by SeedSequence's state words (s1, s0, i1, i0): (state high, low, inc
    high, low), as numpy makes it: inc = (i << 1) | 1; state = 0; step; state += s;
    step."""
    inc_high = (words[2] << _U1) | (words[3] >> _S63)
    inc_low = (words[3] << _U1) | _U1
    low = inc_low + words[1]  # step(0) is inc
    high = inc_high + words[0] + (_U1 if low < words[1] else _U0)
    _, high, low = _pcg_next(high, low, inc_high, inc_low)
    return high, low, inc_high, inc_low


def _to_double(bits):
    """numpy's next_double: the top 53 bits of 64 as a double in [0, 1)."""
    return np.float64(bits >> _S11) * _DOUBLE_UNIT


# The normal ziggurat ------------------------------------------------------------------

def _standard_normal(high, low, inc_high, inc_low, rare):
    """numpy's random_standard_normal from PCG64's state: (the draw, the new state's high,
    low). Counts the rare branches: rare[0] the draws that went to the tail, rare[1] the
    wedge tests (the tests assert both ran)."""
    while True:
        r, high, low = _pcg_next(high, low, inc_high, inc_low)
        idx = r & _BYTE
        r >>= _S8
        rabs = (r >> _U1) & _BITS52
        x = np.float64(rabs) * wi_double[idx]
        if r & _U1:
            x = -x
        if rabs < ki_double[idx]:
            return x, high, low  # 99.3% of draws
        if idx == _U0:
            rare[0] += 1
            while True:
                first, high, low = _pcg_next(high, low, inc_high, inc_low)
                second, high, low = _pcg_next(high, low, inc_high, inc_low)
                xx = -ziggurat_nor_inv_r * math.log1p(-_to_double(first))
                yy = -math.log1p(-_to_double(second))
                if yy + yy > xx * xx:
                    if (rabs >> _S8) & _U1:
                        return -(ziggurat_nor_r + xx), high, low
                    return ziggurat_nor_r + xx, high, low
        else:
            rare[1] += 1
            uniform, high, low = _pcg_next(high, low, inc_high, inc_low)
            if ((fi_double[idx - _U1] - fi_double[idx]) * _to_double(uniform)
                    + fi_double[idx]) < math.exp(-0.5 * x * x):
                return x, high, low


# Many scans ---------------------------------------------------------------------------

def _add_noise(ranges, words, lengths, steps, scale):
    """Row k of `ranges` (N, beams) plus default_rng([*words[k, :lengths[k]], steps[k]])
    .normal(0.0, scale, beams) on its finite entries, in place; returns (tail draws, wedge
    tests) over all rows."""
    entropy = np.empty(words.shape[1] + 2, dtype=np.uint64)
    pool = np.empty(POOL_SIZE, dtype=np.uint64)
    state = np.empty(4, dtype=np.uint64)
    rare = np.zeros(2, dtype=np.int64)
    loc = 0.0
    for row in range(ranges.shape[0]):
        count = _with_step(entropy, words[row], lengths[row], steps[row])
        _state_words(entropy, count, pool, state)
        high, low, inc_high, inc_low = _seeded(state)
        out = ranges[row]
        for beam in range(out.shape[0]):
            draw, high, low = _standard_normal(high, low, inc_high, inc_low, rare)
            noise = loc + scale * draw
            if math.isfinite(out[beam]):
                out[beam] += noise
    return rare[0], rare[1]


def _standard_normals(out, words, lengths, steps):
    """Row k of `out` (N, count) gets default_rng([*words[k, :lengths[k]], steps[k]])
    .standard_normal(count): each agent's odometry noise of a step (core.odometry), all rows
    in one call."""
    entropy = np.empty(words.shape[1] + 2, dtype=np.uint64)
    pool = np.empty(POOL_SIZE, dtype=np.uint64)
    state = np.empty(4, dtype=np.uint64)
    rare = np.zeros(2, dtype=np.int64)
    for row in range(out.shape[0]):
        count = _with_step(entropy, words[row], lengths[row], steps[row])
        _state_words(entropy, count, pool, state)
        high, low, inc_high, inc_low = _seeded(state)
        for column in range(out.shape[1]):
            out[row, column], high, low = _standard_normal(high, low, inc_high, inc_low, rare)


if njit is not None:
    # The helpers compile where the two kernels call them (numba inlines what LLVM likes).
    _hashmix = njit(nogil=True)(_hashmix)
    _mix = njit(nogil=True)(_mix)
    _state_words = njit(nogil=True)(_state_words)
    _with_step = njit(nogil=True)(_with_step)
    _high_product = njit(nogil=True)(_high_product)
    _pcg_next = njit(nogil=True)(_pcg_next)
    _seeded = njit(nogil=True)(_seeded)
    _to_double = njit(nogil=True)(_to_double)
    _standard_normal = njit(nogil=True)(_standard_normal)
    seed_words = njit(cache=True, nogil=True)(seed_words)
    add_noise = njit(cache=True, nogil=True)(_add_noise)
    standard_normals = njit(cache=True, nogil=True)(_standard_normals)
else:
    add_noise = standard_normals = None


def available():
    """True when numba is installed, so the compiled draws can run."""
    return njit is not None


def warm():
    """Compile (or load from numba's cache) the kernels, so a first noisy scan does not."""
    if available():
        seed_words(np.zeros(1, dtype=np.uint64), 2**32)
        add_noise(np.zeros((1, 2)), np.zeros((1, 2), dtype=np.uint64),
                  np.ones(1, dtype=np.int64), np.ones(1, dtype=np.int64), 0.01)
        standard_normals(np.zeros((1, 3)), np.zeros((1, 2), dtype=np.uint64),
                         np.ones(1, dtype=np.int64), np.ones(1, dtype=np.int64))
