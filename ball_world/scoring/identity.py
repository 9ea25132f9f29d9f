"""The identity metrics IDF1, IDP, IDR (Ristani et al. 2016), as TrackEval computes them.

Each ball is given at most one track for its whole life and each track at most one ball,
the pairing chosen to maximise the frames in which a ball and its track match (similarity
>= 0.5, within the gate). IDTP: those frames; IDFN: the balls' other visible frames; IDFP:
the tracks' other frames. IDF1 = IDTP / (IDTP + (IDFP + IDFN) / 2): the share of detections
carrying the right identity, where MOTA counts only the moments identities change.

TrackEval finds the pairing with one Hungarian assignment over a square matrix of side
(balls + track ids), with dummy rows and columns for "unpaired". Its cost is
sum(ball frames) + sum(track frames) - 2 x (frames the chosen pairs match), so the optimum
is the pairing of largest total matched frames, whatever the dummies. That pairing is
found here on the matched pairs alone, one small assignment per connected group of balls
and tracks that ever matched each other: the same optimum (so the same counts exactly) in
time and memory that follow the matches, not (balls + tracks)^2, which for a long run of a
tracker that starts thousands of tracks would not fit in memory.
"""
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ball_world.scoring.similarity import THRESHOLD

COUNTS = ('IDTP', 'IDFN', 'IDFP')


def matched_frames(sequence):
    """(ball ids, track ids, frames): every pair that matched (similarity >= 0.5) in at
    least one frame, with the number of frames it did."""
    keys = []
    tracks = max(1, sequence.num_tracker_ids)
    for similarity, gt_ids, tracker_ids in zip(sequence.similarity, sequence.gt_ids,
                                               sequence.tracker_ids):
        rows, columns = np.nonzero(similarity >= THRESHOLD)
        keys.append(gt_ids[rows] * tracks + tracker_ids[columns])
    keys, frames = np.unique(np.concatenate(keys) if keys else np.empty(0, dtype=np.int64),
                             return_counts=True)
    return keys // tracks, keys % tracks, frames


def best_pairing(balls, tracks, frames, num_balls, num_tracks):
    """The pairs (ball, track) of one-to-one pairing with the most matched frames; returns
    (ball ids, track ids, their frames)."""
    if len(frames) == 0:
        return balls, tracks, frames
    graph = coo_matrix((np.ones(len(frames)), (balls, num_balls + tracks)),
                       shape=(num_balls + num_tracks,) * 2)
    _, group = connected_components(graph, directed=False)
    chosen = []
    order = np.argsort(group[balls], kind='stable')
    starts = np.flatnonzero(np.diff(group[balls][order], prepend=-1))
    for part in np.split(order, starts[1:]):
        ball_ids, rows = np.unique(balls[part], return_inverse=True)
        track_ids, columns = np.unique(tracks[part], return_inverse=True)
        weights = np.zeros((len(ball_ids), len(track_ids)))
        weights[rows, columns] = frames[part]
        picked_rows, picked_columns = linear_sum_assignment(-weights)
        for r, c in zip(picked_rows, picked_columns):
            if weights[r, c] > 0:
                chosen.append((ball_ids[r], track_ids[c], weights[r, c]))
    chosen = np.array(chosen, dtype=np.float64).reshape(-1, 3)
    return chosen[:, 0].astype(np.int64), chosen[:, 1].astype(np.int64), chosen[:, 2]


def evaluate(sequence):
    """IDTP, IDFN, IDFP and IDF1, IDR, IDP of a Sequence (TrackEval's field names), and the
    pairing: {ball id: track id}."""
    if sequence.num_tracker_dets == 0:
        return finish(dict(IDTP=0, IDFN=sequence.num_gt_dets, IDFP=0), empty=True), {}
    if sequence.num_gt_dets == 0:
        return finish(dict(IDTP=0, IDFN=0, IDFP=sequence.num_tracker_dets), empty=True), {}
    balls, tracks, frames = best_pairing(*matched_frames(sequence), sequence.num_gt_ids,
                                         sequence.num_tracker_ids)
    idtp = int(round(frames.sum()))
    counts = dict(IDTP=idtp, IDFN=sequence.num_gt_dets - idtp,
                  IDFP=sequence.num_tracker_dets - idtp)
    return finish(counts), dict(zip(balls.tolist(), tracks.tolist()))


def finish(counts, empty=False):
    """The figures that follow from the counts (TrackEval's; an empty side leaves them 0)."""
    result = dict(counts)
    if empty:
        result.update(IDF1=0.0, IDR=0.0, IDP=0.0)
        return result
    tp, fn, fp = counts['IDTP'], counts['IDFN'], counts['IDFP']
    result['IDR'] = tp / max(1.0, tp + fn)
    result['IDP'] = tp / max(1.0, tp + fp)
    result['IDF1'] = tp / max(1.0, tp + 0.5 * fp + 0.5 * fn)
    return result


def combine(results):
    """Sequences together, as TrackEval's combine_sequences: counts summed."""
    return finish({key: sum(result[key] for result in results) for key in COUNTS})
