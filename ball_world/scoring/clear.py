"""CLEAR-MOT (Bernardin and Stiefelhagen 2008) as TrackEval computes it.

Per frame, balls and tracks are matched by the optimal assignment (Hungarian) among pairs of
similarity >= 0.5 (within the gate), preferring first the correspondences of the previous
frame (a bonus of 1000 that no similarity can outweigh) and then the larger total
similarity. Counted over the frames:

- TP: matches; FN: visible balls left unmatched (misses); FP: kept tracks left unmatched;
- IDSW: a ball matched to another track than the one it was last matched to (at any earlier
  frame, however long ago);
- Frag: each time a ball's matched stretch starts again after a break, less its first;
- MT / PT / ML: balls matched in more than 80%, 20-80%, less than 20% of their frames.

MOTA = (TP - FP - IDSW) / (TP + FN); MOTP = the mean similarity of the matches (TrackEval's
definition, 1 for a perfect position; the mean distance is 2 gate (1 - MOTP)); MODA leaves
out the switches; sMOTA weighs each match by its similarity. A TrackEval subtlety kept on
purpose: a frame without tracks (or without balls) does not end the previous frame's
correspondences for the next frame's preference, as it does not in TrackEval.
"""
import numpy as np
from scipy.optimize import linear_sum_assignment

from ball_world.scoring.similarity import EPS, THRESHOLD

#: Counts summed over sequences (TrackEval's summed_fields).
COUNTS = ('CLR_TP', 'CLR_FN', 'CLR_FP', 'IDSW', 'MT', 'PT', 'ML', 'Frag', 'CLR_Frames',
          'MOTP_sum')
#: Figures computed from the counts.
FIGURES = ('MOTA', 'MOTP', 'MODA', 'CLR_Re', 'CLR_Pr', 'MTR', 'PTR', 'MLR', 'sMOTA', 'CLR_F1',
           'FP_per_frame', 'MOTAL')
#: Weight of keeping last frame's correspondence, above any similarity.
CONTINUITY = 1000.0


def frame_matches(similarity, gt_ids, tracker_ids, previous):
    """Row and column indices of one frame's CLEAR matches.

    previous: per ball id, the track id it was matched to in the previous frame (nan: none).
    """
    keeps = tracker_ids[None, :] == previous[gt_ids[:, None]]
    scores = CONTINUITY * keeps + similarity
    scores[similarity < THRESHOLD - EPS] = 0.0
    rows, columns = linear_sum_assignment(-scores)
    matched = scores[rows, columns] > 0.0 + EPS
    return rows[matched], columns[matched]


def evaluate(sequence):
    """CLEAR counts and figures of a Sequence, and its matches per frame.

    Returns (result, matches): result a dict of TrackEval's field names; matches a list with,
    per frame, (ball ids, track ids, similarities) of the matched pairs.
    """
    matches = [_no_match() for _ in range(sequence.num_timesteps)]
    # An empty side: TrackEval answers at once, its figures left at 0 (and CLR_Frames too).
    if sequence.num_tracker_dets == 0:
        return _empty(CLR_FN=sequence.num_gt_dets, ML=sequence.num_gt_ids, MLR=1.0), matches
    if sequence.num_gt_dets == 0:
        return _empty(CLR_FP=sequence.num_tracker_dets, MLR=1.0), matches
    counts = dict.fromkeys(COUNTS, 0)
    counts['MOTP_sum'] = 0.0
    counts['CLR_Frames'] = sequence.num_timesteps
    balls = sequence.num_gt_ids
    frames_seen = np.zeros(balls)  # frames in which each ball was visible
    frames_matched = np.zeros(balls)
    fragments = np.zeros(balls)  # matched stretches begun
    last_track = np.full(balls, np.nan)  # for switches: the track matched last, ever
    previous = np.full(balls, np.nan)  # for the preference: the previous frame's match
    for t, (gt_ids, tracker_ids) in enumerate(zip(sequence.gt_ids, sequence.tracker_ids)):
        if len(gt_ids) == 0:
            counts['CLR_FP'] += len(tracker_ids)
            continue
        if len(tracker_ids) == 0:
            counts['CLR_FN'] += len(gt_ids)
            frames_seen[gt_ids] += 1
            continue
        similarity = sequence.similarity[t]
        rows, columns = frame_matches(similarity, gt_ids, tracker_ids, previous)
        balls_matched = gt_ids[rows]
        tracks_matched = tracker_ids[columns]
        before = last_track[balls_matched]
        counts['IDSW'] += int(np.sum(~np.isnan(before) & (tracks_matched != before)))
        frames_seen[gt_ids] += 1
        frames_matched[balls_matched] += 1
        was_unmatched = np.isnan(previous)
        last_track[balls_matched] = tracks_matched
        previous[:] = np.nan
        previous[balls_matched] = tracks_matched
        fragments += was_unmatched & ~np.isnan(previous)
        counts['CLR_TP'] += len(rows)
        counts['CLR_FN'] += len(gt_ids) - len(rows)
        counts['CLR_FP'] += len(tracker_ids) - len(rows)
        if len(rows):
            counts['MOTP_sum'] += sum(similarity[rows, columns])
        matches[t] = (balls_matched, tracks_matched, similarity[rows, columns])
    seen = frames_seen > 0
    ratio = frames_matched[seen] / frames_seen[seen]
    counts['MT'] = int(np.sum(ratio > 0.8))
    counts['PT'] = int(np.sum(ratio >= 0.2)) - counts['MT']
    counts['ML'] = balls - counts['MT'] - counts['PT']
    counts['Frag'] = int(np.sum(fragments[fragments > 0] - 1))
    return finish(counts), matches


def _empty(**values):
    result = dict.fromkeys(FIGURES, 0.0)
    result.update(dict.fromkeys(COUNTS, 0))
    result.update(values)
    return result


def _no_match():
    return (np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), np.empty(0))


def finish(counts):
    """The figures that follow from the counts (TrackEval's _compute_final_fields)."""
    result = dict(counts)
    tp, fn, fp, idsw = (counts[k] for k in ('CLR_TP', 'CLR_FN', 'CLR_FP', 'IDSW'))
    truth = max(1.0, tp + fn)
    balls = max(1.0, counts['MT'] + counts['PT'] + counts['ML'])
    result['MTR'] = counts['MT'] / balls
    result['PTR'] = counts['PT'] / balls
    result['MLR'] = counts['ML'] / balls
    result['CLR_Re'] = tp / truth
    result['CLR_Pr'] = tp / max(1.0, tp + fp)
    result['MODA'] = (tp - fp) / truth
    result['MOTA'] = (tp - fp - idsw) / truth
    result['MOTP'] = counts['MOTP_sum'] / max(1.0, tp)
    result['sMOTA'] = (counts['MOTP_sum'] - fp - idsw) / truth
    result['CLR_F1'] = tp / max(1.0, tp + 0.5 * fn + 0.5 * fp)
    result['FP_per_frame'] = fp / max(1.0, counts['CLR_Frames'])
    result['MOTAL'] = (tp - fp - (np.log10(idsw) if idsw > 0 else 0)) / truth
    return result


def combine(results):
    """Sequences together, as TrackEval's combine_sequences: counts summed, figures again."""
    counts = {key: sum(result[key] for result in results) for key in COUNTS}
    return finish(counts)
