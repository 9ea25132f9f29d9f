"""CLEAR-MOT (ball_world_score's clear_mot) on hand-made frames whose figures are counted by
hand from the definitions (Bernardin and Stiefelhagen 2008)."""
import math

import pytest

from ball_world.tools.score import clear_mot


def test_perfect_tracking_scores_one_and_the_offset():
    frames = [({0: (0.0, 0.0), 1: (5.0, 5.0)}, {7: (0.01, 0.0), 8: (5.0, 5.01)})
              for _ in range(3)]
    score = clear_mot(frames, gate=0.5)
    assert (score.truth, score.matches, score.misses, score.false_positives,
            score.id_switches) == (6, 6, 0, 0, 0)
    assert score.mota == 1.0
    assert score.motp == pytest.approx(0.01)


def test_swapped_ids_count_two_switches():
    # Frame 2: the two tracks trade places (each now 0.1 from the other ball).
    frames = [({0: (0.0, 0.0), 1: (1.0, 0.0)}, {7: (0.0, 0.0), 8: (1.0, 0.0)}),
              ({0: (0.0, 0.0), 1: (1.0, 0.0)}, {7: (0.9, 0.0), 8: (0.1, 0.0)})]
    score = clear_mot(frames, gate=0.3)
    assert score.id_switches == 2
    assert score.mota == pytest.approx(1.0 - 2 / 4)
    assert score.motp == pytest.approx(0.2 / 4)


def test_misses_and_false_positives():
    # Frame 1: ball 0 tracked, ball 1 missed, a track far from everything (false positive).
    # Frame 2: nothing tracked: two misses.
    frames = [({0: (0.0, 0.0), 1: (3.0, 0.0)}, {5: (0.2, 0.0), 6: (9.0, 9.0)}),
              ({0: (0.0, 0.0), 1: (3.0, 0.0)}, {})]
    score = clear_mot(frames, gate=0.5)
    assert (score.matches, score.misses, score.false_positives) == (1, 3, 1)
    assert score.mota == pytest.approx(1.0 - (3 + 1) / 4)
    assert score.motp == pytest.approx(0.2)


def test_a_correspondence_stands_while_within_the_gate():
    # Frame 2: track 8 is nearer to ball 0 than its track 7, but 7 is still within the
    # gate: the match stands (no switch), 8 is a false positive.
    frames = [({0: (0.0, 0.0)}, {7: (0.0, 0.0)}),
              ({0: (0.0, 0.0)}, {7: (0.3, 0.0), 8: (0.05, 0.0)})]
    score = clear_mot(frames, gate=0.5)
    assert (score.id_switches, score.false_positives) == (0, 1)
    assert score.motp == pytest.approx(0.3 / 2)


def test_a_switch_is_counted_against_the_last_match_even_after_a_gap():
    # Ball 0 matched to 7, then unseen by the tracker (a miss), then matched to 9: a switch.
    frames = [({0: (0.0, 0.0)}, {7: (0.0, 0.0)}), ({0: (0.0, 0.0)}, {}),
              ({0: (0.0, 0.0)}, {9: (0.0, 0.0)})]
    score = clear_mot(frames, gate=0.5)
    assert (score.matches, score.misses, score.id_switches) == (2, 1, 1)
    assert score.mota == pytest.approx(1.0 - 2 / 3)


def test_greedy_pairs_nearest_first():
    # Ball 0 at 0, ball 1 at 1; tracks at 0.45 and 1.4 (gate 0.5). Nearest first pairs
    # (ball 1, track at 1.4? 0.4) and (ball 0, track at 0.45: 0.45): both matched.
    frames = [({0: (0.0, 0.0), 1: (1.0, 0.0)}, {7: (0.45, 0.0), 8: (1.4, 0.0)})]
    score = clear_mot(frames, gate=0.5)
    assert score.matches == 2
    assert score.motp == pytest.approx((0.45 + 0.4) / 2)


def test_no_ground_truth_gives_nan_not_a_crash():
    score = clear_mot([({}, {1: (0.0, 0.0)})], gate=0.5)
    assert math.isnan(score.mota) and math.isnan(score.motp)
    assert score.false_positives == 1
