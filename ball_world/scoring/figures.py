"""Every metric of one sequence of frames, or of several together, and the headline figures.

`score_tracks` is what ball_world_score computes for tracks with ids (MarkerArray, the
example tracker, a tracker class); `score_detections` for positions without ids
(PoseArray). Both apply the don't-care rule first (frames.prepare). Sequences (segments of
a recording, scenes of a benchmark) combine as TrackEval combines sequences.
"""
from dataclasses import dataclass
import math

import numpy as np

from ball_world.scoring import clear, detection, hota, identity
from ball_world.scoring.frames import prepare
from ball_world.scoring.similarity import distance_of

#: The headline figures of tracks, in the order a report gives them (TrackEval's names).
TRACK_FIGURES = ('HOTA', 'DetA', 'AssA', 'LocA', 'IDF1', 'IDP', 'IDR', 'MOTA', 'MOTP',
                 'IDSW', 'CLR_FN', 'CLR_FP', 'CLR_TP', 'Frag', 'MT', 'PT', 'ML', 'MODA',
                 'sMOTA')
#: The headline figures of detections without ids.
DETECTION_FIGURES = ('DetA', 'DetRe', 'DetPr', 'LocA', 'MODA', 'MODP', 'Recall', 'Precision',
                     'F1', 'DET_TP', 'DET_FN', 'DET_FP')
#: Figures where a lower value is better (a report's worst scene is the highest).
LOWER_IS_BETTER = ('IDSW', 'CLR_FN', 'CLR_FP', 'Frag', 'ML', 'DET_FN', 'DET_FP',
                   'mean_distance_m')


@dataclass
class SequenceScore:
    """The metrics of one sequence (or of sequences combined: then sequence is None)."""

    kind: str  # 'tracks' or 'detections'
    gate: float
    frames: int
    dont_care: int  # tracks removed by the don't-care rule
    clear: dict = None
    identity: dict = None
    hota: dict = None
    detection: dict = None
    sequence: object = None
    matches: list = None

    def figures(self):
        """{name: value} of the headline figures (plain floats and ints)."""
        if self.kind == 'detections':
            figures = {name: self.detection[name] for name in DETECTION_FIGURES}
            figures['mean_distance_m'] = _distance(figures['MODP'], figures['DET_TP'],
                                                   self.gate)
        else:
            values = {**self.clear, **self.identity, **hota.summary(self.hota)}
            figures = {name: values[name] for name in TRACK_FIGURES}
            figures['mean_distance_m'] = _distance(figures['MOTP'], figures['CLR_TP'],
                                                   self.gate)
        figures['frames'] = self.frames
        figures['dont_care'] = self.dont_care
        return {name: _number(value) for name, value in figures.items()}


def _distance(similarity, matches, gate):
    return distance_of(similarity, gate) if matches else math.nan


def _number(value):
    """numpy scalars as Python numbers (for JSON)."""
    return value.item() if isinstance(value, np.generic) else value


def score_tracks(frames, gate):
    """All metrics of tracks with ids over `frames` (a list of frames.Frame)."""
    sequence = prepare(frames, gate)
    clear_result, matches = clear.evaluate(sequence)
    identity_result, _ = identity.evaluate(sequence)
    return SequenceScore(kind='tracks', gate=gate, frames=sequence.num_timesteps,
                         dont_care=sequence.dont_care_count, clear=clear_result,
                         identity=identity_result, hota=hota.evaluate(sequence),
                         sequence=sequence, matches=matches)


def score_detections(frames, gate):
    """Per-frame detection metrics of positions without ids over `frames`."""
    sequence = prepare(frames, gate)
    return SequenceScore(kind='detections', gate=gate, frames=sequence.num_timesteps,
                         dont_care=sequence.dont_care_count,
                         detection=detection.evaluate(sequence), sequence=sequence)


def combine(scores):
    """Sequences scored apart, together (as TrackEval's combined sequences)."""
    scores = list(scores)
    if len(scores) == 1:
        return scores[0]
    first = scores[0]
    combined = SequenceScore(kind=first.kind, gate=first.gate,
                             frames=sum(s.frames for s in scores),
                             dont_care=sum(s.dont_care for s in scores))
    if first.kind == 'detections':
        combined.detection = detection.combine([s.detection for s in scores])
    else:
        combined.clear = clear.combine([s.clear for s in scores])
        combined.identity = identity.combine([s.identity for s in scores])
        combined.hota = hota.combine([s.hota for s in scores])
    return combined
