"""The scoring mathematics (ball_world.scoring) on hand-made frames whose figures follow
from the definitions by hand: CLEAR-MOT (Bernardin and Stiefelhagen 2008), IDF1 (Ristani et
al. 2016), HOTA (Luiten et al. 2021), the don't-care rule, and the detection metrics of
tracks without ids."""
import math

import numpy as np
import pytest

from ball_world.scoring import breakdown, figures
from ball_world.scoring.frames import DuplicateTrack, Frame, prepare
from ball_world.scoring.similarity import ALPHAS, similarity

GATE = 0.5


def frame(stamp, balls, tracks, hidden=()):
    """A Frame from {name: (x, y)} of balls and {id: (x, y)} of tracks."""
    names = tuple(balls)
    return Frame(stamp, names, np.array([balls[n] for n in names], dtype=float).reshape(-1, 2),
                 np.array([n not in hidden for n in names], dtype=bool), tuple(tracks),
                 np.array([tracks[t] for t in tracks], dtype=float).reshape(-1, 2))


def test_similarity_is_one_at_the_centre_half_at_the_gate_zero_at_twice_it():
    values = similarity([(0.0, 0.0)], [(0.0, 0.0), (0.5, 0.0), (0.0, 1.0), (3.0, 0.0)], GATE)
    assert values.tolist() == [[1.0, 0.5, 0.0, 0.0]]


def test_an_oracle_scores_one_on_every_metric():
    frames = [frame(t, {'a': (t, 0.0), 'b': (5.0, t), 'c': (2.0, 2.0)},
                    {'A': (t, 0.0), 'B': (5.0, t), 'C': (2.0, 2.0)}, hidden=('c',) if t % 2
                    else ()) for t in range(6)]
    result = figures.score_tracks(frames, GATE).figures()
    for name in ('HOTA', 'DetA', 'AssA', 'LocA', 'IDF1', 'IDP', 'IDR', 'MOTA', 'MOTP',
                 'MODA', 'sMOTA'):
        assert result[name] == 1.0, name
    assert (result['IDSW'], result['CLR_FN'], result['CLR_FP']) == (0, 0, 0)
    # c is hidden at odd stamps: its track there is don't-care, neither hit nor miss. Its
    # matched stretches start again after each (TrackEval's Frag counts those restarts).
    assert result['dont_care'] == 3 and result['CLR_TP'] == 15 and result['Frag'] == 2


def test_swapped_ids_count_two_switches_and_halve_idf1():
    frames = [frame(t, {'a': (0.0, 0.0), 'b': (1.0, 0.0)},
                    {7: (0.0, 0.0), 8: (1.0, 0.0)} if t < 2 else {7: (1.0, 0.0), 8: (0.0, 0.0)})
              for t in range(4)]
    result = figures.score_tracks(frames, 0.3).figures()
    assert result['IDSW'] == 2
    assert result['MOTA'] == pytest.approx(1.0 - 2 / 8)
    # Each ball keeps one track for 2 of its 4 frames: IDTP 4 of 8.
    assert (result['IDF1'], result['IDP'], result['IDR']) == (0.5, 0.5, 0.5)


def test_misses_and_false_positives_and_motp():
    frames = [frame(0, {'a': (0.0, 0.0), 'b': (3.0, 0.0)}, {5: (0.2, 0.0), 6: (9.0, 9.0)}),
              frame(1, {'a': (0.0, 0.0), 'b': (3.0, 0.0)}, {})]
    result = figures.score_tracks(frames, GATE).figures()
    assert (result['CLR_TP'], result['CLR_FN'], result['CLR_FP']) == (1, 3, 1)
    assert result['MOTA'] == pytest.approx(1.0 - (3 + 1) / 4)
    assert result['MOTP'] == pytest.approx(1.0 - 0.2 / (2 * GATE))
    assert result['mean_distance_m'] == pytest.approx(0.2)


def test_last_frames_correspondence_is_kept_within_the_gate():
    # Frame 2: track 8 is nearer ball a than its track 7, but 7 is still within the gate.
    frames = [frame(0, {'a': (0.0, 0.0)}, {7: (0.0, 0.0)}),
              frame(1, {'a': (0.0, 0.0)}, {7: (0.3, 0.0), 8: (0.05, 0.0)})]
    result = figures.score_tracks(frames, GATE).figures()
    assert (result['IDSW'], result['CLR_FP']) == (0, 1)


def test_a_switch_is_counted_against_the_last_match_even_after_a_gap():
    frames = [frame(0, {'a': (0.0, 0.0)}, {7: (0.0, 0.0)}),
              frame(1, {'a': (0.0, 0.0)}, {9: (5.0, 5.0)}),
              frame(2, {'a': (0.0, 0.0)}, {9: (0.0, 0.0)})]
    result = figures.score_tracks(frames, GATE).figures()
    assert (result['CLR_TP'], result['CLR_FN'], result['IDSW'], result['Frag']) == (2, 1, 1, 1)


def test_the_assignment_is_optimal_where_nearest_first_is_not():
    # Ball a at 0, b at 0.8; tracks at 0.45 and 1.2 (gate 0.5). Nearest first pairs b with
    # the track at 0.45 (0.35 apart) and leaves a and the track at 1.2 (0.4 from b) alone;
    # the optimal assignment matches both.
    frames = [frame(0, {'a': (0.0, 0.0), 'b': (0.8, 0.0)}, {1: (0.45, 0.0), 2: (1.2, 0.0)})]
    result = figures.score_tracks(frames, GATE).figures()
    assert result['CLR_TP'] == 2 and result['MOTA'] == 1.0


def test_idf1_counts_the_longest_identity():
    # One ball for ten frames: track 1 the first six, track 2 the last four.
    frames = [frame(t, {'a': (0.0, 0.0)}, {1 if t < 6 else 2: (0.0, 0.0)}) for t in range(10)]
    result = figures.score_tracks(frames, GATE).figures()
    assert (result['IDF1'], result['IDP'], result['IDR']) == (0.6, 0.6, 0.6)
    # HOTA: every match is exact (DetA 1); AssA = (6 * 6/10 + 4 * 4/10) / 10 = 0.52.
    assert result['DetA'] == 1.0
    assert result['AssA'] == pytest.approx(0.52)
    assert result['HOTA'] == pytest.approx(math.sqrt(0.52))


def test_hota_integrates_localisation_over_the_thresholds():
    # One ball followed by one track 0.3 m away (similarity 0.7): the pair matches at the
    # thresholds alpha <= 0.7, 14 of the 19, with AssA 1 at each.
    frames = [frame(t, {'a': (0.0, 0.0)}, {1: (0.3, 0.0)}) for t in range(5)]
    result = figures.score_tracks(frames, GATE).figures()
    passed = int(np.sum(ALPHAS <= 0.7 + 1e-12))
    assert passed == 14
    assert result['DetA'] == pytest.approx(passed / len(ALPHAS))
    assert result['AssA'] == pytest.approx(passed / len(ALPHAS))
    assert result['HOTA'] == pytest.approx(passed / len(ALPHAS))
    assert result['MOTA'] == 1.0 and result['MOTP'] == pytest.approx(0.7)


def test_a_track_on_a_hidden_ball_is_dont_care_and_one_on_nothing_is_a_false_positive():
    balls = {'seen': (0.0, 0.0), 'behind': (4.0, 0.0)}
    frames = [frame(0, balls, {1: (0.0, 0.0), 2: (4.1, 0.0), 3: (9.0, 9.0)},
                    hidden=('behind',))]
    sequence = prepare(frames, GATE)
    assert sequence.dont_care[0].tolist() == [1]
    result = figures.score_tracks(frames, GATE).figures()
    assert (result['CLR_TP'], result['CLR_FN'], result['CLR_FP']) == (1, 0, 1)


def test_a_track_between_a_hidden_and_a_visible_ball_goes_to_the_better_assignment():
    # Track 1 sits on the visible ball, track 2 on the hidden one, both within the gate of
    # either ball: the assignment of largest total similarity keeps 1, removes 2.
    balls = {'seen': (0.0, 0.0), 'behind': (0.6, 0.0)}
    frames = [frame(0, balls, {1: (0.05, 0.0), 2: (0.55, 0.0)}, hidden=('behind',))]
    result = figures.score_tracks(frames, GATE).figures()
    assert (result['CLR_TP'], result['CLR_FP'], result['dont_care']) == (1, 0, 1)


def test_a_frame_may_not_name_a_track_twice():
    frames = [Frame(0, ('a',), np.zeros((1, 2)), np.ones(1, bool), (4, 4), np.zeros((2, 2)))]
    with pytest.raises(DuplicateTrack, match='track id 4 appears twice at stamp 0'):
        prepare(frames, GATE)


def test_no_ground_truth_scores_false_positives_not_a_crash():
    result = figures.score_tracks([frame(0, {}, {1: (0.0, 0.0)})], GATE).figures()
    assert result['CLR_FP'] == 1 and result['CLR_TP'] == 0 and result['HOTA'] == 0.0


def test_detections_are_scored_frame_by_frame_whatever_their_order():
    # Positions without ids, listed in another order at every frame: a perfect detector.
    positions = {'a': (0.0, 0.0), 'b': (2.0, 0.0), 'c': (4.0, 1.0)}
    frames = []
    for t in range(6):
        order = list(positions)[t % 3:] + list(positions)[:t % 3]
        frames.append(frame(t, positions, {k: positions[n] for k, n in enumerate(order)}))
    result = figures.score_detections(frames, GATE).figures()
    for name in ('DetA', 'DetRe', 'DetPr', 'LocA', 'MODA', 'MODP', 'Recall', 'Precision', 'F1'):
        assert result[name] == 1.0, name
    assert 'IDSW' not in result and 'HOTA' not in result
    # The same positions taken as ids would switch at every frame.
    assert figures.score_tracks(frames, GATE).figures()['IDSW'] > 0


def test_breakdown_adds_up_to_the_sequence():
    rng = np.random.default_rng(4)
    frames = []
    for t in range(30):
        balls = {f'ball_{i}': (i * 1.0, 0.0) for i in range(4)}
        tracks = {(t // 7 + i) % 5: (i * 1.0 + rng.normal(0, 0.2), 0.0)
                  for i in range(4) if rng.random() < 0.8}
        frames.append(frame(t, balls, tracks, hidden=('ball_3',) if t % 5 == 0 else ()))
    score = figures.score_tracks(frames, GATE)
    balls, tracks = breakdown.lines(score.sequence, score.matches)
    assert sum(line.switches for line in balls) == score.clear['IDSW']
    assert sum(line.fragmentations for line in balls) == score.clear['Frag']
    assert sum(line.matched for line in balls) == score.clear['CLR_TP']
    assert sum(line.false_positives for line in tracks) == score.clear['CLR_FP']
    assert sum(line.frames for line in balls) == score.clear['CLR_TP'] + score.clear['CLR_FN']


def test_sequences_combine_as_one_when_their_ids_differ():
    first = [frame(t, {'a': (0.0, 0.0)}, {1: (0.1, 0.0)}) for t in range(3)]
    second = [frame(t, {'b': (0.0, 0.0)}, {2: (0.0, 0.0)} if t else {}) for t in range(3)]
    combined = figures.combine([figures.score_tracks(first, GATE),
                                figures.score_tracks(second, GATE)]).figures()
    whole = figures.score_tracks(first + [frame(3 + f.stamp_ns, {'b': (0.0, 0.0)},
                                                dict(zip(f.track_ids, map(tuple, f.track_xy))))
                                          for f in second], GATE).figures()
    for name in ('MOTA', 'MOTP', 'IDF1', 'CLR_FN', 'IDSW', 'HOTA', 'DetA', 'AssA', 'LocA'):
        assert combined[name] == pytest.approx(whole[name]), name


def test_the_scoring_mathematics_has_no_ros_no_files_and_no_tools():
    import ast
    from pathlib import Path
    folder = Path(figures.__file__).parent
    outside = ('rclpy', 'mcap', 'rerun', 'yaml', 'ball_world.ros', 'ball_world.recording',
               'ball_world.tools', 'ball_world.msgs', 'os', 'io', 'pathlib')
    for path in folder.glob('*.py'):
        tree = ast.parse(path.read_text())
        names = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                 for alias in node.names}
        names |= {node.module for node in ast.walk(tree)
                  if isinstance(node, ast.ImportFrom) and node.module}
        bad = sorted(n for n in names if any(n == o or n.startswith(o + '.') for o in outside))
        assert not bad, f'{path.name} imports {bad}'
        calls = {node.func.id for node in ast.walk(tree)
                 if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)}
        assert 'open' not in calls and 'print' not in calls, path.name
