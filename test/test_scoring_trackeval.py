"""ball_world's metrics equal TrackEval's (the reference implementation of HOTA, used by
MOTChallenge and KITTI) on the same frames: random sequences with occlusions, misses,
clutter and id changes, and the example tracker on a simulated scene.

TrackEval (PyPI `trackeval`, pinned in requirements/base.txt) evaluates a sequence from its
per-frame ids and similarity matrices, the layout scoring.frames.prepare makes, after the
don't-care rule; its CLEAR, Identity and HOTA classes are called directly.
"""
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
