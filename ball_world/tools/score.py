"""ball_world_score: how well tracks follow the balls a scanner could see (CLEAR-MOT).

The figures are the CLEAR-MOT metrics of Bernardin and Stiefelhagen ("Evaluating Multiple
Object Tracking Performance: The CLEAR MOT Metrics", EURASIP JIVP 2008), which tracking
papers report, computed per scan:

- ground truth of a scan: the balls the scanner could see at that step (at least one beam,
  without noise, meets the ball first within [range_min, range_max]: core.lidar.seen_balls);
  a tracker cannot be blamed for a ball nothing showed it;
- matching: a correspondence of the previous scan is kept while its track is still within
  `gate` of its ball; the remaining balls and tracks are paired nearest first (greedy on
  distance, not Hungarian: scipy is not a dependency; the two differ only when two pairings
  compete within the gate);
- misses: balls left unmatched; false positives: tracks left unmatched; an id switch: a
  ball matched to another track than the one it was last matched to;
- MOTA = 1 - (misses + false positives + id switches) / ground truth objects;
- MOTP = mean distance (m) between matched balls and tracks.

Offline and deterministic: the same frames give the same figures. `clear_mot` is the pure
function; the command line feeds it from a recording.
"""
import math
from typing import NamedTuple


class Score(NamedTuple):
    """CLEAR-MOT figures over a sequence of frames."""

    frames: int
    truth: int
    matches: int
    misses: int
    false_positives: int
    id_switches: int
    distance: float

    @property
    def mota(self):
        """1 - (misses + false positives + id switches) / truth; nan without ground truth."""
        if self.truth == 0:
            return math.nan
        return 1.0 - (self.misses + self.false_positives + self.id_switches) / self.truth

    @property
    def motp(self):
        """Mean distance of a matched pair, m; nan without matches."""
        return self.distance / self.matches if self.matches else math.nan

    def lines(self):
        """The figures as the report prints them."""
        return [f'frames {self.frames}, ground truth objects {self.truth}',
                f'MOTA {self.mota:.4f}',
                f'MOTP {self.motp:.4f} m',
                f'matches {self.matches}, misses {self.misses}, false positives '
                f'{self.false_positives}, id switches {self.id_switches}']


def clear_mot(frames, gate):
    """CLEAR-MOT of `frames`, each a pair (truth, tracks) of dicts id -> (x, y).

    Ids of truth are the balls' (entity names or indices), ids of tracks the tracker's; a
    pair counts as a match only within `gate` metres.
    """
    previous = {}  # truth id -> track id, matched in the previous frame
    last = {}  # truth id -> the track it was last matched to, in any frame
    counts = dict(frames=0, truth=0, matches=0, misses=0, false_positives=0, id_switches=0)
    distance = 0.0
    for truth, tracks in frames:
        matches = {}
        used = set()
        # Correspondences of the previous frame stand while still within the gate.
        for ball, track in previous.items():
            if ball in truth and track in tracks and track not in used \
                    and math.dist(truth[ball], tracks[track]) <= gate:
                matches[ball] = track
                used.add(track)
        # The rest nearest first (ties in the order of the ids, so the result is fixed).
        candidates = sorted(
            (math.dist(position, tracks[track]), _order(ball), _order(track), ball, track)
            for ball, position in truth.items() if ball not in matches
            for track in tracks if track not in used)
        for gap, _, _, ball, track in candidates:
            if gap > gate:
                break
            if ball in matches or track in used:
                continue
            matches[ball] = track
            used.add(track)
        for ball, track in matches.items():
            if ball in last and last[ball] != track:
                counts['id_switches'] += 1
            last[ball] = track
            distance += math.dist(truth[ball], tracks[track])
        counts['frames'] += 1
        counts['truth'] += len(truth)
        counts['matches'] += len(matches)
        counts['misses'] += len(truth) - len(matches)
        counts['false_positives'] += len(tracks) - len(matches)
        previous = matches
    return Score(distance=distance, **counts)


def _order(key):
    """A sort key for ids of mixed kinds (ints and names)."""
    return (0, key, '') if isinstance(key, int) else (1, 0, str(key))
