"""ball_world's metrics equal TrackEval's (the reference implementation of HOTA, used by
MOTChallenge and KITTI) on the same frames: random sequences with occlusions, misses,
clutter and id changes, and the example tracker on a simulated scene.

TrackEval (PyPI `trackeval`, pinned in requirements/base.txt) evaluates a sequence from its
per-frame ids and similarity matrices, the layout scoring.frames.prepare makes, after the
don't-care rule; its CLEAR, Identity and HOTA classes are called directly.
"""
import warnings

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest
from trackeval.metrics import CLEAR, HOTA, Identity

from ball_world.scoring import clear, hota, identity
from ball_world.scoring.frames import Frame, prepare
from ball_world.tools import score_bench
from ball_world.tools.score_frames import frames_with_tracker
from ball_world.tools.tracker import ScanTracker

GATE = 0.5


def trackeval_data(sequence):
    return dict(num_timesteps=sequence.num_timesteps, num_gt_ids=sequence.num_gt_ids,
                num_tracker_ids=sequence.num_tracker_ids,
                num_gt_dets=sequence.num_gt_dets, num_tracker_dets=sequence.num_tracker_dets,
                gt_ids=sequence.gt_ids, tracker_ids=sequence.tracker_ids,
                similarity_scores=sequence.similarity)


def assert_equal_to_trackeval(sequence):
    data = trackeval_data(sequence)
    theirs = {**CLEAR({'PRINT_CONFIG': False}).eval_sequence(data),
              **Identity({'PRINT_CONFIG': False}).eval_sequence(data),
              **HOTA().eval_sequence(data)}
    ours = {**clear.evaluate(sequence)[0], **identity.evaluate(sequence)[0],
            **hota.evaluate(sequence)}
    for name, value in theirs.items():
        assert np.allclose(np.asarray(ours[name], dtype=float), np.asarray(value, dtype=float),
                           rtol=0.0, atol=1e-9), name
    return ours


def random_frames(rng, count=80, balls=9):
    """Balls drifting in a box, some hidden at each frame; tracks that follow most of them
    with noise, lose some, change id now and then, and clutter."""
    positions = rng.uniform(0.0, 6.0, (balls, 2))
    velocities = rng.normal(0.0, 0.3, (balls, 2))
    ids, next_id, frames = {}, 100, []
    for t in range(count):
        positions = positions + 0.1 * velocities
        track_ids, track_xy = [], []
        for ball in range(balls):
            if rng.random() < 0.85:
                if ball not in ids or rng.random() < 0.05:
                    ids[ball], next_id = next_id, next_id + 1
                track_ids.append(ids[ball])
                track_xy.append(positions[ball] + rng.normal(0.0, 0.2, 2))
        for _ in range(rng.integers(0, 3)):
            track_ids.append(next_id)
            track_xy.append(rng.uniform(0.0, 6.0, 2))
            next_id += 1
        order = rng.permutation(len(track_ids))
        frames.append(Frame(t, tuple(f'ball_{b}' for b in range(balls)), positions.copy(),
                            rng.random(balls) > 0.2, tuple(track_ids[i] for i in order),
                            np.array(track_xy).reshape(-1, 2)[order]))
    return frames


@pytest.mark.parametrize('seed', range(8))
def test_random_sequences_score_as_trackeval_scores_them(seed):
    sequence = prepare(random_frames(np.random.default_rng(seed)), GATE)
    assert sequence.dont_care_count > 0  # the rule was exercised
    ours = assert_equal_to_trackeval(sequence)
    assert 0.0 < ours['IDF1'] < 1.0 and 0.0 < np.mean(ours['HOTA']) < 1.0


def test_the_example_tracker_scores_as_trackeval_scores_it():
    scene = score_bench.seed_scenes([5], 8.0)[0]
    frames = frames_with_tracker(score_bench.simulated_scans(scene), ScanTracker())
    sequence = prepare(frames, GATE)
    assert sequence.num_tracker_ids > 20  # tracks ended and began: association is tested
    ours = assert_equal_to_trackeval(sequence)
    assert ours['IDSW'] > 0 and ours['CLR_FN'] > 0


def test_empty_sides_answer_as_trackeval_does():
    no_tracks = [Frame(t, ('a',), np.zeros((1, 2)), np.ones(1, bool), (), np.zeros((0, 2)))
                 for t in range(3)]
    no_balls = [Frame(t, (), np.zeros((0, 2)), np.zeros(0, bool), (1,), np.zeros((1, 2)))
                for t in range(3)]
    for frames in (no_tracks, no_balls):
        assert_equal_to_trackeval(prepare(frames, GATE))


def frames_of(truth, tracks):
    """Frames from per-frame lists: truth [(x, y, visible)] by ball, tracks [(id, x, y)]."""
    return [Frame(t, tuple(f'ball_{b}' for b in range(len(balls))),
                  np.array([(x, y) for x, y, _ in balls], dtype=float).reshape(-1, 2),
                  np.array([seen for _, _, seen in balls], dtype=bool),
                  tuple(i for i, _, _ in shown),
                  np.array([(x, y) for _, x, y in shown], dtype=float).reshape(-1, 2))
            for t, (balls, shown) in enumerate(zip(truth, tracks))]


FAR = (9.0, 9.0)  # beyond twice the gate from every ball below: similarity 0
EDGE_CASES = {
    'no frames': ([], []),
    'one frame, one match': ([[(0, 0, True)]], [[(1, 0, 0)]]),
    'one frame, no match': ([[(0, 0, True)]], [[(1, *FAR)]]),
    'no match anywhere': ([[(0, 0, True), (1, 1, True)]] * 3, [[(1, *FAR), (2, 8, 8)]] * 3),
    'no truth': ([[]] * 3, [[(1, 0, 0)]] * 3),
    'no tracks': ([[(0, 0, True)]] * 3, [[]] * 3),
    'nothing at all': ([[]] * 3, [[]] * 3),
    'every ball hidden': ([[(0, 0, False)]] * 3, [[(1, *FAR)]] * 3),
    'near but beyond the gate': ([[(0, 0, True)]] * 3, [[(1, 1.5, 0)]] * 3),
    'a track at the largest floats': ([[(0, 0, True)]] * 2,
                                      [[(1, 1.7e308, -1.7e308)], [(1, -1.7e308, 1.7e308)]]),
    'truth, then tracks, then neither matching': (
        [[(0, 0, True)], [], [(0, 0, True)]], [[], [(1, 0, 0)], [(1, *FAR)]]),
}


@pytest.mark.parametrize('name', EDGE_CASES)
def test_edge_cases_score_as_trackeval_scores_them(name):
    truth, tracks = EDGE_CASES[name]
    with warnings.catch_warnings():
        warnings.simplefilter('error')  # no RuntimeWarning line beside the report
        ours = assert_equal_to_trackeval(prepare(frames_of(truth, tracks), 0.05))
        assert_equal_to_trackeval(prepare(frames_of(truth, tracks), GATE))
    if name in ('no match anywhere', 'one frame, no match', 'a track at the largest floats'):
        assert np.all(ours['HOTA'] == 0.0) and ours['MOTA'] <= 0.0  # scored, not refused


POINTS = [(0.0, 0.0), (0.3, 0.0), (0.6, 0.0), (1.0, 0.0), (9.0, 9.0)]
ball = st.tuples(st.sampled_from(POINTS), st.booleans())
frame_strategy = st.tuples(
    st.lists(ball, max_size=3),
    st.lists(st.tuples(st.integers(0, 4), st.sampled_from(POINTS)), max_size=3,
             unique_by=lambda track: track[0]))


def hypothesis_frames(drawn):
    truth = [[(*xy, seen) for xy, seen in balls] for balls, _ in drawn]
    tracks = [[(i, *xy) for i, xy in shown] for _, shown in drawn]
    return frames_of(truth, tracks)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(frame_strategy, max_size=5), min_size=1, max_size=3))
def test_small_random_sequences_and_their_combination_score_as_trackeval(sequences):
    """Any few frames (empty ones, one frame, no truth, no tracks, nothing near, ties on a
    grid of points) and several of them combined, as TrackEval's combine_sequences."""
    metrics = {'CLEAR': (CLEAR({'PRINT_CONFIG': False}), clear),
               'Identity': (Identity({'PRINT_CONFIG': False}), identity), 'HOTA': (HOTA(), hota)}
    ours_all = {name: [] for name in metrics}
    theirs_all = {name: {} for name in metrics}
    for position, drawn in enumerate(sequences):
        sequence = prepare(hypothesis_frames(drawn), GATE)
        data = trackeval_data(sequence)
        for name, (metric, module) in metrics.items():
            ours = module.evaluate(sequence)
            ours = ours[0] if isinstance(ours, tuple) else ours
            theirs = metric.eval_sequence(data)
            _assert_same(ours, theirs, name)
            ours_all[name].append(ours)
            theirs_all[name][position] = theirs
    for name, (metric, module) in metrics.items():
        _assert_same(module.combine(ours_all[name]),
                     metric.combine_sequences(theirs_all[name]), f'{name} combined')


def _assert_same(ours, theirs, what):
    for key, value in theirs.items():
        assert np.allclose(np.asarray(ours[key], dtype=float), np.asarray(value, dtype=float),
                           rtol=0.0, atol=1e-9), (what, key, ours[key], value)
