"""From distance to similarity: what a match is, and the thresholds of the metrics.

TrackEval scores boxes by their IoU, a similarity in [0, 1]. For points on a plane the
field uses a similarity that falls linearly with distance: max(0, 1 - d / (2 gate)), which
is 1 at the ball's centre, 0.5 at the gate and 0 at twice the gate. CLEAR-MOT and IDF1 count
a match at similarity >= 0.5 (within the gate, as TrackEval's threshold of 0.5 IoU); HOTA
integrates over the thresholds alpha = 0.05, 0.10, ..., 0.95, so it also rewards how close
a match is.
"""
import numpy as np

#: Similarity a CLEAR-MOT or identity match needs (TrackEval's THRESHOLD).
THRESHOLD = 0.5
#: HOTA's localisation thresholds, made as TrackEval makes them (the same floats).
ALPHAS = np.arange(0.05, 0.99, 0.05)
#: The margin TrackEval allows its comparisons of similarities (np.finfo(float).eps).
EPS = float(np.finfo('float').eps)


def similarity(truth_xy, track_xy, gate):
    """(G, T) similarities of G ball centres and T track positions, both (N, 2), at `gate` m."""
    truth_xy = np.asarray(truth_xy, dtype=np.float64).reshape(-1, 2)
    track_xy = np.asarray(track_xy, dtype=np.float64).reshape(-1, 2)
    # A track near the largest float is infinitely far: similarity 0, not a warning.
    with np.errstate(over='ignore'):
        distance = np.hypot(truth_xy[:, None, 0] - track_xy[None, :, 0],
                            truth_xy[:, None, 1] - track_xy[None, :, 1])
        return np.maximum(0.0, 1.0 - distance / (2.0 * gate))


def distance_of(similarity_value, gate):
    """The distance (m) a similarity below 1 and above 0 stands for: 2 gate (1 - s)."""
    return 2.0 * gate * (1.0 - similarity_value)
