"""The pieces around the metrics: pairing stamps (and saying what did not pair), planar
transforms from /tf, means with confidence intervals over scenes."""
import math

import numpy as np
import pytest

from ball_world.scoring import scenes, stamps
from ball_world.scoring.planar_tf import PlanarTransforms, to_frame, TransformError

SCANS = [0, 100_000_000, 200_000_000, 300_000_000]


def test_equal_stamps_pair_and_a_late_one_is_reported_with_its_offset():
    pairing = stamps.pair(SCANS, [0, 100_000_000, 201_000_000])
    assert pairing.scan_of.tolist() == [0, 1, -1]
    assert pairing.unpaired.tolist() == [2] and pairing.scans_without == 2
    note = stamps.describe(pairing, 3, 0)
    assert '1 of 3 track messages match no scan stamp exactly' in note
    assert '1.000 ms after the nearest scan' in note and '--stamp-tolerance 0.002' in note


def test_stamps_one_millisecond_early_are_said_to_be_before():
    pairing = stamps.pair(SCANS, [s - 1_000_000 for s in SCANS[1:]])
    assert pairing.paired == 0
    assert '1.000 ms before the nearest scan' in stamps.describe(pairing, 3, 0)


def test_a_tolerance_pairs_with_the_nearest_scan_and_one_message_per_scan():
    pairing = stamps.pair(SCANS, [1_000_000, 99_000_000, 101_500_000, 260_000_000],
                          tolerance_ns=2_000_000)
    # 99 ms and 101.5 ms both want scan 1: the nearer (99 ms) keeps it.
    assert pairing.scan_of.tolist() == [0, 1, -1, -1]
    assert pairing.extra.tolist() == [2] and pairing.unpaired.tolist() == [3]
    assert 'taken by a nearer one' in stamps.describe(pairing, 4, 2_000_000)


def test_no_message_unpaired_says_nothing():
    assert stamps.describe(stamps.pair(SCANS, SCANS), 4, 0) is None


def test_transforms_compose_up_to_the_world_and_interpolate_between_stamps():
    transforms = PlanarTransforms()
    transforms.add('world', 'odom', 0, 1.0, 2.0, math.pi / 2, static=True)
    transforms.add('odom', 'base_link', 0, 1.0, 0.0, 0.0)
    transforms.add('odom', 'base_link', 100, 3.0, 0.0, math.pi)
    x, y, yaw = transforms.lookup('world', 'base_link', 0)
    assert (x, y, yaw) == pytest.approx((1.0, 3.0, math.pi / 2))
    # Half way: 2 m along odom's x, heading pi/2 (the shorter way from 0 to pi is ambiguous
    # only at pi; the remainder takes +pi), so x world = 1 - 0, y = 2 + 2.
    x, y, yaw = transforms.lookup('world', 'base_link', 50)
    assert (x, y) == pytest.approx((1.0, 4.0)) and yaw == pytest.approx(math.pi)
    points = to_frame([(1.0, 0.0)], *transforms.lookup('world', 'base_link', 0))
    assert points[0].tolist() == pytest.approx([1.0, 4.0])


def test_a_missing_link_or_a_stamp_outside_tf_is_an_error_naming_it():
    transforms = PlanarTransforms()
    transforms.add('odom', 'base_link', 100, 0.0, 0.0, 0.0)
    with pytest.raises(TransformError, match="'odom' is in neither /tf nor /tf_static"):
        transforms.lookup('world', 'base_link', 100)
    transforms.add('world', 'odom', 0, 0.0, 0.0, 0.0, static=True)
    with pytest.raises(TransformError, match='from 0.000000100 to 0.000000100 s'):
        transforms.lookup('world', 'base_link', 200)


def test_interval_is_students_t_of_the_mean():
    values = [0.5, 0.7, 0.6, 0.9]
    interval = scenes.interval(values)
    # t(0.975, 3) = 3.182446305284263; s = 0.1707825127659933
    assert interval.mean == pytest.approx(0.675)
    assert interval.half_width == pytest.approx(3.182446305284263 * 0.1707825127659933 / 2)
    assert (interval.low, interval.high, interval.count) == (0.5, 0.9, 4)


def test_undefined_values_are_left_out_and_one_value_has_no_interval():
    interval = scenes.interval([0.4, math.nan])
    assert interval.mean == 0.4 and interval.count == 1 and math.isnan(interval.half_width)
    assert interval.as_dict()['ci95'] is None


def test_worst_scenes_are_the_lowest_undefined_first():
    rows = [{'HOTA': 0.8}, {'HOTA': math.nan}, {'HOTA': 0.3}, {'HOTA': 0.5}]
    assert scenes.worst(rows, ['a', 'b', 'c', 'd'], 'HOTA', 3)[0][0] == 'b'
    assert [label for label, _ in scenes.worst(rows, list('abcd'), 'HOTA', 3)] == \
        ['b', 'c', 'd']


def test_stamps_pair_whatever_the_count_of_scans():
    assert stamps.pair([5], [5, 6]).scan_of.tolist() == [0, -1]
    assert stamps.pair([], [5]).unpaired.tolist() == [0]
    assert np.array_equal(stamps.pair(SCANS, []).scan_of, np.empty(0))
