"""Per ball and per track: where a sequence's figures come from.

From CLEAR-MOT's matches of each frame (clear.evaluate):

- each ball: frames it was visible, frames it was matched (tracked share: MT above 80%,
  ML below 20%), its id switches and fragmentations (CLEAR's, so they add up to IDSW and
  Frag), and the tracks that followed it;
- each track: its lifetime (first to last stamp it was given, after the don't-care rule),
  frames, frames matched, frames it was a false positive, the balls it followed, its
  switches (the ball it matched changed) and fragmentations (a matched stretch that began
  again after a break, less its first).

Frames without balls or without tracks leave the "previous frame" as it was, as CLEAR's
counting does, so the per-ball numbers sum to the sequence's.
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BallLine:
    ball: object  # the ball's name
    frames: int
    matched: int
    switches: int
    fragmentations: int
    tracks: tuple  # the tracks that followed it, in order of first match

    @property
    def tracked(self):
        return self.matched / self.frames if self.frames else 0.0


@dataclass(frozen=True)
class TrackLine:
    track: object  # the tracker's id
    first_ns: int
    last_ns: int
    frames: int
    matched: int
    false_positives: int
    switches: int
    fragmentations: int
    balls: tuple  # the balls it followed, in order of first match

    @property
    def lifetime_s(self):
        return (self.last_ns - self.first_ns) * 1e-9


def _follow(owner_ids, partner_ids, active, state):
    """Advance one side's bookkeeping by one frame: switches, stretches begun, partners."""
    switches, stretches, partners, last, previous = state
    for owner, partner in zip(owner_ids.tolist(), partner_ids.tolist()):
        if owner in last and last[owner] != partner:
            switches[owner] = switches.get(owner, 0) + 1
        last[owner] = partner
        if owner not in previous:
            stretches[owner] = stretches.get(owner, 0) + 1
        if partner not in partners.setdefault(owner, []):
            partners[owner].append(partner)
    if active:
        state[4] = set(owner_ids.tolist())


def lines(sequence, matches):
    """(ball lines, track lines) of a Sequence and its CLEAR matches."""
    ball_state = [{}, {}, {}, {}, set()]
    track_state = [{}, {}, {}, {}, set()]
    ball_frames = np.bincount(np.concatenate(sequence.gt_ids + [np.empty(0, np.int64)]),
                              minlength=sequence.num_gt_ids)
    ball_matched = np.zeros(sequence.num_gt_ids, dtype=np.int64)
    track_frames = np.zeros(sequence.num_tracker_ids, dtype=np.int64)
    track_matched = np.zeros(sequence.num_tracker_ids, dtype=np.int64)
    first = {}
    last = {}
    for stamp, gt_ids, tracker_ids, (balls, tracks, _) in zip(
            sequence.stamps, sequence.gt_ids, sequence.tracker_ids, matches):
        active = len(gt_ids) > 0 and len(tracker_ids) > 0
        _follow(balls, tracks, active, ball_state)
        _follow(tracks, balls, active, track_state)
        ball_matched[balls] += 1
        track_frames[tracker_ids] += 1
        track_matched[tracks] += 1
        for track in tracker_ids.tolist():
            first.setdefault(track, stamp)
            last[track] = stamp
    ball_lines = tuple(
        BallLine(ball=name, frames=int(ball_frames[i]), matched=int(ball_matched[i]),
                 switches=ball_state[0].get(i, 0),
                 fragmentations=max(0, ball_state[1].get(i, 0) - 1),
                 tracks=tuple(sequence.tracker_labels[t] for t in ball_state[2].get(i, ())))
        for i, name in enumerate(sequence.gt_labels))
    track_lines = tuple(
        TrackLine(track=name, first_ns=first[i], last_ns=last[i], frames=int(track_frames[i]),
                  matched=int(track_matched[i]),
                  false_positives=int(track_frames[i] - track_matched[i]),
                  switches=track_state[0].get(i, 0),
                  fragmentations=max(0, track_state[1].get(i, 0) - 1),
                  balls=tuple(sequence.gt_labels[b] for b in track_state[2].get(i, ())))
        for i, name in enumerate(sequence.tracker_labels))
    return ball_lines, track_lines
