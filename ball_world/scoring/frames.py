"""A scan's ground truth and tracks, and the sequence the metrics read.

Ground truth at a scan is every ball with a flag: whether that scan could see it (at least
one beam, without noise, meets it first within range). A tracker cannot be blamed for a
ball nothing showed it, nor for keeping a track on it while it is hidden: a good tracker
does exactly that through an occlusion. So, as MOTChallenge does with distractors and
TrackEval's preprocessing with them, before any metric:

1. every track is matched to every ball, hidden or not, by the optimal assignment
   (Hungarian, scipy.optimize.linear_sum_assignment) on similarity, pairs below the
   threshold (0.5: beyond the gate) excluded;
2. tracks matched to a hidden ball are removed (don't-care: neither hit nor false positive);
3. hidden balls are removed (not misses).

What is left (visible balls, kept tracks, their similarities) is TrackEval's sequence
layout: per frame the ids of the balls and of the tracks (numbered 0.. over the sequence,
in sorted order of the names, as TrackEval relabels them) and their similarity matrix.
"""
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from ball_world.scoring.similarity import EPS, similarity, THRESHOLD


@dataclass(frozen=True)
class Frame:
    """One scan: every ball (visible or not) and the tracks given for it."""

    stamp_ns: int
    truth_ids: tuple  # the balls' names, the scanning agent's own included
    truth_xy: np.ndarray  # (G, 2) their centres at the scan, m, world frame
    visible: np.ndarray  # (G,) bool: the scan could see the ball
    track_ids: tuple  # the tracker's ids (ints or names; unique within the frame)
    track_xy: np.ndarray  # (T, 2) the tracks' positions, m, world frame


@dataclass
class Sequence:
    """Frames prepared for the metrics (TrackEval's `data` of one sequence)."""

    gt_ids: list  # per frame: int array of the visible balls' ids
    tracker_ids: list  # per frame: int array of the kept tracks' ids
    similarity: list  # per frame: (visible balls, kept tracks) similarities
    gt_labels: tuple  # id -> ball name
    tracker_labels: tuple  # id -> the tracker's own id
    stamps: list  # per frame: stamp_ns
    kept_truth: list  # per frame: indices of the frame's balls that are visible
    kept_tracks: list  # per frame: indices of the frame's tracks that were kept
    dont_care: list = field(default_factory=list)  # per frame: indices of removed tracks

    @property
    def num_timesteps(self):
        return len(self.gt_ids)

    @property
    def num_gt_ids(self):
        return len(self.gt_labels)

    @property
    def num_tracker_ids(self):
        return len(self.tracker_labels)

    @property
    def num_gt_dets(self):
        return int(sum(len(ids) for ids in self.gt_ids))

    @property
    def num_tracker_dets(self):
        return int(sum(len(ids) for ids in self.tracker_ids))

    @property
    def dont_care_count(self):
        return int(sum(len(removed) for removed in self.dont_care))


class DuplicateTrack(ValueError):
    """A frame names one track twice; the message says which and when."""


def hidden_matches(frame, gate):
    """Indices of the frame's tracks that the optimal assignment on similarity pairs with a
    hidden ball (similarity >= 0.5): the tracks the don't-care rule removes."""
    if not len(frame.truth_ids) or not len(frame.track_ids) or bool(np.all(frame.visible)):
        return np.empty(0, dtype=np.int64)
    scores = similarity(frame.truth_xy, frame.track_xy, gate)
    scores[scores < THRESHOLD - EPS] = 0.0
    rows, columns = linear_sum_assignment(-scores)
    matched = scores[rows, columns] > 0.0 + EPS
    rows, columns = rows[matched], columns[matched]
    return np.sort(columns[~np.asarray(frame.visible, dtype=bool)[rows]])


def prepare(frames, gate):
    """The Sequence of `frames` (a list of Frame) at `gate` m, the don't-care rule applied.

    Raises DuplicateTrack for a frame whose tracks repeat an id (TrackEval refuses such
    input too: a track is one object at a time).
    """
    truth_keep, track_keep, removed, sims = [], [], [], []
    gt_names, track_names = set(), set()
    for frame in frames:
        if len(set(frame.track_ids)) != len(frame.track_ids):
            seen = set()
            twice = next(i for i in frame.track_ids if i in seen or seen.add(i))
            raise DuplicateTrack(f'track id {_shown(twice)} appears twice at stamp '
                                 f'{frame.stamp_ns} ns')
        gone = hidden_matches(frame, gate)
        kept = np.setdiff1d(np.arange(len(frame.track_ids)), gone)
        visible = np.flatnonzero(np.asarray(frame.visible, dtype=bool))
        truth_keep.append(visible)
        track_keep.append(kept)
        removed.append(gone)
        sims.append(similarity(np.asarray(frame.truth_xy).reshape(-1, 2)[visible],
                               np.asarray(frame.track_xy).reshape(-1, 2)[kept], gate))
        gt_names.update(frame.truth_ids[i] for i in visible)
        track_names.update(frame.track_ids[i] for i in kept)
    gt_labels = tuple(sorted(gt_names, key=_order))
    tracker_labels = tuple(sorted(track_names, key=_order))
    gt_index = {name: i for i, name in enumerate(gt_labels)}
    tracker_index = {name: i for i, name in enumerate(tracker_labels)}
    gt_ids = [np.array([gt_index[frame.truth_ids[i]] for i in keep], dtype=np.int64)
              for frame, keep in zip(frames, truth_keep)]
    tracker_ids = [np.array([tracker_index[frame.track_ids[i]] for i in keep], dtype=np.int64)
                   for frame, keep in zip(frames, track_keep)]
    return Sequence(gt_ids=gt_ids, tracker_ids=tracker_ids, similarity=sims,
                    gt_labels=gt_labels, tracker_labels=tracker_labels,
                    stamps=[frame.stamp_ns for frame in frames], kept_truth=truth_keep,
                    kept_tracks=track_keep, dont_care=removed)


def _order(key):
    """A sort key for ids of mixed kinds: numbers first in numeric order, then names
    (ball_10 after ball_9), then anything else by its text."""
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        return (0, int(key), ())
    text = str(key)
    head = text.rstrip('0123456789')
    digits = text[len(head):].lstrip('0')
    # Digits compared as numbers without making one (a name may end in 5,000 digits).
    return (1, 0, (head, (len(digits), digits) if text[len(head):] else (-1, ''), text))


def _shown(key):
    """An id in a message: its repr, cut short (a huge int's repr is no line to read)."""
    text = str(key) if isinstance(key, int) and key.bit_length() < 1000 else (
        'a huge int' if isinstance(key, int) else repr(key))
    return text if len(text) <= 60 else text[:57] + '...'
