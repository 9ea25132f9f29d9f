"""The batched scan noise (core.noise_kernel, core.noise_seed.EntropyRows) draws exactly what
`np.random.default_rng([seed, key, step]).normal(0.0, stddev, beams)` draws, row by row, bit
for bit: the numbers recordings hold and re-simulations check.

The reference is numpy itself, not the kernel's arithmetic: SeedSequence, PCG64 and the
ziggurat are numpy's, called the documented way."""
import numpy as np
import pytest

from ball_world.core import noise_kernel
from ball_world.core.lidar import add_noise, name_key
from ball_world.core.noise_seed import EntropyRows, int_words


def reference(ranges, pairs, steps, stddev):
    """Each row noised by core.lidar.add_noise with default_rng([seed, key, step])."""
    expected = ranges.copy()
    for row, ((seed, key), step) in enumerate(zip(pairs, steps)):
        add_noise(expected[row], stddev, np.random.default_rng([seed, key, int(step)]))
    return expected


def kernel(ranges, entropy, rows, steps, stddev):
    """The kernel on a copy: (noised ranges, (tail draws, wedge tests))."""
    got = ranges.copy()
    rare = noise_kernel.add_noise(got, entropy.words[rows], entropy.lengths[rows],
                                  np.asarray(steps, dtype=np.int64), stddev)
    return got, rare


def test_seed_words_are_seed_sequences_state():
    rng = np.random.default_rng(4)
    cases = [(0, 0, 0), (2**64 - 1, 2**64 - 1, 2**63 - 1), (2**100 + 3, 7, 2**32),
             (1, 2**130 - 1, 2**32 - 1), (5, 0, 2**40 + 1)]
    cases += [(int(rng.integers(2**63)), int(rng.integers(2**63)), int(rng.integers(2**62)))
              for _ in range(100)]
    for seed, key, step in cases:
        fixed = np.array(int_words(seed) + int_words(key), dtype=np.uint64)
        expected = np.random.SeedSequence([seed, key, step]).generate_state(4, np.uint64)
        assert noise_kernel.seed_words(fixed, step).tobytes() == expected.tobytes()


def test_many_scans_draw_default_rngs_numbers_bit_for_bit():
    # A sweep of seeds, keys and steps: one and two 32-bit words each, steps from 2**32 on
    # (two entropy words), seeds and keys of three and five words, 0s. Over 10**6 draws, so
    # the ziggurat's rare branches (about 0.03% of draws go to the tail and 1.5% to a
    # wedge test) certainly run: asserted below.
    rng = np.random.default_rng(21)
    pairs = [(0, 0), (2**64 - 1, 2**64 - 1), (2**70 + 9, 3), (4, 2**150 + 2**40), (7, 2**32)]
    pairs += [(int(rng.integers(2**63)), name_key(f'ball_{k}')) for k in range(1500)]
    pairs += [(int(rng.integers(2**31)), int(rng.integers(2**31))) for _ in range(1500)]
    steps = np.concatenate(([0, 2**63 - 1, 2**32, 2**32 - 1, 1],
                            rng.integers(0, 2**40, 1500), rng.integers(0, 10**6, 1500)))
    entropy = EntropyRows.of(pairs)
    assert entropy.words.shape[1] == 6  # widened for the 2**150 key (5 words)
    ranges = rng.uniform(0.1, 12.0, (len(pairs), 340))
    ranges[:, ::9] = np.inf  # nothing within range_max: no noise
    ranges[:, 4::13] = -np.inf  # closer than range_min
    ranges[:, 6::17] = np.nan
    rows = np.arange(len(pairs))
    got, (tail, wedge) = kernel(ranges, entropy, rows, steps, 0.01)
    assert got.tobytes() == reference(ranges, pairs, steps, 0.01).tobytes()
    assert ranges.size > 10**6 and tail > 50 and wedge > 5000
    finite = np.isfinite(ranges)
    assert np.all(got[finite] != ranges[finite])
    assert got[~finite].tobytes() == ranges[~finite].tobytes()  # NaN, inf left as they were


def test_rows_pick_their_entropy_and_scale_is_the_stddev():
    # Rows in any order, some twice; a stddev of 1 and one of 1e-3 (loc + scale * z as
    # numpy's normal computes it, not a rescaled draw).
    pairs = [(3, name_key('ball_0')), (3, name_key('ball_1')), (2**40, 11)]
    entropy = EntropyRows.of(pairs)
    rows = np.array([2, 0, 2, 1])
    steps = [5, 5, 6, 2**33]
    ranges = np.full((4, 1000), 2.5)
    for stddev in (1.0, 1e-3):
        got, _ = kernel(ranges, entropy, rows, steps, stddev)
        assert got.tobytes() == reference(ranges, [pairs[r] for r in rows], steps,
                                          stddev).tobytes()
    noised = entropy.add_noise(ranges.copy(), rows, steps, 1e-3)
    assert noised.tobytes() == got.tobytes()


def test_refusals_name_the_bad_value():
    entropy = EntropyRows(2)
    with pytest.raises(ValueError, match='non-negative integer, not -1'):
        entropy.set(0, -1, 3)
    with pytest.raises(ValueError, match='noise step must be a non-negative integer, not -2'):
        entropy.add_noise(np.ones((2, 3)), np.arange(2), [4, -2], 0.01)
    unchanged = np.ones((2, 3))
    assert entropy.add_noise(unchanged, np.arange(2), [1, 2], 0.0) is unchanged
    assert np.all(unchanged == 1.0)
