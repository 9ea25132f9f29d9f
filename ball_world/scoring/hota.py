"""HOTA (Luiten et al., "HOTA: A Higher Order Metric for Evaluating Multi-Object Tracking",
IJCV 2021) as TrackEval computes it: detection, association and localisation in one figure.

For each threshold alpha in 0.05, 0.10, ..., 0.95 a pair matches when its similarity is at
least alpha. Then DetA = TP / (TP + FN + FP) (how many detections are right) and
AssA = the mean over matches of TPA / (TPA + FNA + FPA), where for the matched pair's ball
and track TPA counts the frames they match together, FNA the ball's other frames and FPA
the track's (how well each match's identity holds over time). HOTA(alpha) =
sqrt(DetA x AssA); HOTA is its mean over alpha, and so are DetA, AssA and LocA (the mean
similarity of the matches). A tracker that finds every ball but changes ids often keeps a
high DetA and a low AssA; MOTA would hardly move.

Matching per frame maximises similarity weighted by how well the two ids align over the
whole sequence (TrackEval's global alignment score), once, and then each alpha keeps the
pairs at or above it. Accumulators are kept per pair that ever overlapped rather than as
dense (balls x tracks) arrays: the same sums in memory that follows the matches.
"""
import numpy as np
from scipy.optimize import linear_sum_assignment

from ball_world.scoring.similarity import ALPHAS, EPS

#: TrackEval's per-alpha fields, and the scalar ones.
ARRAYS = ('HOTA', 'DetA', 'AssA', 'DetRe', 'DetPr', 'AssRe', 'AssPr', 'LocA', 'OWTA')
COUNTS = ('HOTA_TP', 'HOTA_FN', 'HOTA_FP')
SCALARS = ('HOTA(0)', 'LocA(0)', 'HOTALocA(0)')


def _pair_keys(gt_ids, tracker_ids, width):
    return gt_ids[:, None] * width + tracker_ids[None, :]


def _overlaps(similarity):
    """Each pair's share of the similarity its ball and track spread over others (TrackEval's
    sim_iou): s / (row sum + column sum - s)."""
    denominator = similarity.sum(0)[None, :] + similarity.sum(1)[:, None] - similarity
    overlap = np.zeros_like(similarity)
    mask = denominator > 0.0 + EPS
    overlap[mask] = similarity[mask] / denominator[mask]
    return overlap


def _aligned(frame_keys, pair_keys, alignment):
    """The alignment of each of a frame's pairs; 0 for a pair that never overlapped (no pair
    overlaps anywhere when no track ever came near a ball: then every score is 0, and the
    assignment below matches pairs of similarity 0, as TrackEval's does)."""
    if len(pair_keys) == 0:
        return np.zeros(frame_keys.shape)
    where = np.searchsorted(pair_keys, frame_keys).clip(max=len(pair_keys) - 1)
    return np.where(pair_keys[where] == frame_keys, alignment[where], 0.0)


def evaluate(sequence):
    """HOTA and its parts for a Sequence: a dict of TrackEval's field names (arrays over
    ALPHAS for the per-alpha fields)."""
    n = len(ALPHAS)
    result = {name: np.zeros(n) for name in ARRAYS + COUNTS}
    result.update(dict.fromkeys(SCALARS, 0.0))
    if sequence.num_tracker_dets == 0 or sequence.num_gt_dets == 0:
        side = 'HOTA_FN' if sequence.num_tracker_dets == 0 else 'HOTA_FP'
        result[side] = (sequence.num_gt_dets if side == 'HOTA_FN'
                        else sequence.num_tracker_dets) * np.ones(n)
        result['LocA'] = np.ones(n)
        result['LocA(0)'] = 1.0
        return result
    width = max(1, sequence.num_tracker_ids)
    # First pass: how well each ball id and track id align over the whole sequence.
    keys, shares = [], []
    for similarity, gt_ids, tracker_ids in zip(sequence.similarity, sequence.gt_ids,
                                               sequence.tracker_ids):
        overlap = _overlaps(similarity)
        mask = overlap != 0.0
        keys.append(_pair_keys(gt_ids, tracker_ids, width)[mask])
        shares.append(overlap[mask])
    gt_count = np.bincount(np.concatenate(sequence.gt_ids), minlength=sequence.num_gt_ids)
    tracker_count = np.bincount(np.concatenate(sequence.tracker_ids),
                                minlength=sequence.num_tracker_ids)
    pair_keys, inverse = np.unique(np.concatenate(keys), return_inverse=True)
    potential = np.zeros(len(pair_keys))
    np.add.at(potential, inverse, np.concatenate(shares))
    alignment = potential / (gt_count[pair_keys // width] + tracker_count[pair_keys % width]
                             - potential)
    # Second pass: match each frame, count per alpha.
    tp, fn, fp, loc = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    matched_keys, matched_sims = [], []
    for similarity, gt_ids, tracker_ids in zip(sequence.similarity, sequence.gt_ids,
                                               sequence.tracker_ids):
        if len(gt_ids) == 0:
            fp += len(tracker_ids)
            continue
        if len(tracker_ids) == 0:
            fn += len(gt_ids)
            continue
        frame_keys = _pair_keys(gt_ids, tracker_ids, width)
        score = _aligned(frame_keys, pair_keys, alignment) * similarity
        rows, columns = linear_sum_assignment(-score)
        sims = similarity[rows, columns]
        passed = sims[None, :] >= ALPHAS[:, None] - EPS  # (alphas, matches)
        count = passed.sum(axis=1)
        tp += count
        fn += len(gt_ids) - count
        fp += len(tracker_ids) - count
        for a in np.flatnonzero(count):
            loc[a] += sum(sims[passed[a]])
        matched_keys.append(frame_keys[rows, columns])
        matched_sims.append(sims)
    result['HOTA_TP'], result['HOTA_FN'], result['HOTA_FP'] = tp, fn, fp
    matched_keys = np.concatenate(matched_keys) if matched_keys else np.empty(0, np.int64)
    matched_sims = np.concatenate(matched_sims) if matched_sims else np.empty(0)
    for a, alpha in enumerate(ALPHAS):
        pairs, together = np.unique(matched_keys[matched_sims >= alpha - EPS],
                                    return_counts=True)
        balls = gt_count[pairs // width]
        tracks = tracker_count[pairs % width]
        weight = max(1.0, tp[a])
        result['AssA'][a] = np.sum(together * (together / np.maximum(
            1, balls + tracks - together))) / weight
        result['AssRe'][a] = np.sum(together * (together / np.maximum(1, balls))) / weight
        result['AssPr'][a] = np.sum(together * (together / np.maximum(1, tracks))) / weight
    result['LocA'] = np.maximum(1e-10, loc) / np.maximum(1e-10, tp)
    return finish(result)


def finish(result):
    """The fields that follow from the others (TrackEval's _compute_final_fields)."""
    tp, fn, fp = result['HOTA_TP'], result['HOTA_FN'], result['HOTA_FP']
    result['DetRe'] = tp / np.maximum(1, tp + fn)
    result['DetPr'] = tp / np.maximum(1, tp + fp)
    result['DetA'] = tp / np.maximum(1, tp + fn + fp)
    result['HOTA'] = np.sqrt(result['DetA'] * result['AssA'])
    result['OWTA'] = np.sqrt(result['DetRe'] * result['AssA'])
    result['HOTA(0)'] = float(result['HOTA'][0])
    result['LocA(0)'] = float(result['LocA'][0])
    result['HOTALocA(0)'] = result['HOTA(0)'] * result['LocA(0)']
    return result


def combine(results):
    """Sequences together, as TrackEval's combine_sequences: counts summed, association
    figures weighted by each sequence's TP, LocA likewise."""
    combined = {name: sum(r[name] for r in results) for name in COUNTS}
    weight = np.maximum(1.0, combined['HOTA_TP'])
    for name in ('AssRe', 'AssPr', 'AssA'):
        combined[name] = sum(r[name] * r['HOTA_TP'] for r in results) / weight
    located = sum(r['LocA'] * r['HOTA_TP'] for r in results)
    combined['LocA'] = np.maximum(1e-10, located) / np.maximum(1e-10, combined['HOTA_TP'])
    return finish(combined)


def summary(result):
    """The figures as reported: each per-alpha field's mean over alpha (TrackEval's
    summary), plus HOTA(0) and LocA(0)."""
    figures = {name: float(np.mean(result[name])) for name in ARRAYS}
    figures.update({name: float(result[name]) for name in SCALARS})
    return figures
