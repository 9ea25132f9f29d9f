"""Detection metrics, for positions without identities (a geometry_msgs/PoseArray).

A PoseArray carries no track ids: the order of its poses is no identity, so identity
metrics (IDSW, IDF1, AssA, HOTA) cannot be computed from it, and counting pose order as ids
would charge a perfect tracker with switches whenever its list is ordered differently. What
can be scored is each frame on its own:

- at the threshold (similarity >= 0.5, within the gate), matched by the optimal assignment
  of largest total similarity (CLEAR-MOT's matching without its preference for the
  previous frame): TP, FN, FP, recall, precision, F1, MODA = (TP - FP) / (TP + FN) and
  MODP = the mean similarity of the matches;
- over HOTA's thresholds alpha = 0.05 .. 0.95, from one assignment of largest total
  similarity per frame: DetA = TP / (TP + FN + FP), DetRe, DetPr and LocA, each the mean
  over alpha (HOTA's detection part, which needs no identities).
"""
import numpy as np
from scipy.optimize import linear_sum_assignment

from ball_world.scoring.similarity import ALPHAS, EPS, THRESHOLD

COUNTS = ('DET_TP', 'DET_FN', 'DET_FP', 'MODP_sum', 'DET_Frames')


def evaluate(sequence):
    """Detection counts and figures of a Sequence (its ids are ignored)."""
    n = len(ALPHAS)
    counts = dict.fromkeys(COUNTS, 0)
    counts['MODP_sum'] = 0.0
    counts['DET_Frames'] = sequence.num_timesteps
    tp, fn, fp, loc = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for similarity, gt_ids, tracker_ids in zip(sequence.similarity, sequence.gt_ids,
                                               sequence.tracker_ids):
        balls, tracks = len(gt_ids), len(tracker_ids)
        if balls == 0 or tracks == 0:
            counts['DET_FN'] += balls
            counts['DET_FP'] += tracks
            fn += balls
            fp += tracks
            continue
        scores = np.where(similarity < THRESHOLD - EPS, 0.0, similarity)
        rows, columns = linear_sum_assignment(-scores)
        kept = scores[rows, columns] > 0.0 + EPS
        matched = int(kept.sum())
        counts['DET_TP'] += matched
        counts['DET_FN'] += balls - matched
        counts['DET_FP'] += tracks - matched
        counts['MODP_sum'] += float(sum(similarity[rows[kept], columns[kept]]))
        rows, columns = linear_sum_assignment(-similarity)
        sims = similarity[rows, columns]
        passed = sims[None, :] >= ALPHAS[:, None] - EPS
        count = passed.sum(axis=1)
        tp += count
        fn += balls - count
        fp += tracks - count
        loc += np.where(passed, sims[None, :], 0.0).sum(axis=1)
    counts.update(DetA_TP=tp, DetA_FN=fn, DetA_FP=fp, LocA_sum=loc)
    return finish(counts)


def finish(counts):
    """The figures that follow from the counts."""
    result = dict(counts)
    tp, fn, fp = counts['DET_TP'], counts['DET_FN'], counts['DET_FP']
    result['Recall'] = tp / max(1.0, tp + fn)
    result['Precision'] = tp / max(1.0, tp + fp)
    result['F1'] = tp / max(1.0, tp + 0.5 * fn + 0.5 * fp)
    result['MODA'] = (tp - fp) / max(1.0, tp + fn)
    result['MODP'] = counts['MODP_sum'] / max(1.0, tp)
    a_tp, a_fn, a_fp = counts['DetA_TP'], counts['DetA_FN'], counts['DetA_FP']
    result['DetA'] = float(np.mean(a_tp / np.maximum(1.0, a_tp + a_fn + a_fp)))
    result['DetRe'] = float(np.mean(a_tp / np.maximum(1.0, a_tp + a_fn)))
    result['DetPr'] = float(np.mean(a_tp / np.maximum(1.0, a_tp + a_fp)))
    result['LocA'] = float(np.mean(np.where(a_tp > 0, counts['LocA_sum'] / np.maximum(
        1.0, a_tp), 1.0)))
    return result


def combine(results):
    """Sequences together: every count summed, the figures again."""
    keys = COUNTS + ('DetA_TP', 'DetA_FN', 'DetA_FP', 'LocA_sum')
    return finish({key: sum(result[key] for result in results) for key in keys})
