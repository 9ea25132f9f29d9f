"""One recording scored: the example tracker's tracks, or a user's paired by stamp.

What `ball_world_score FILE` and `ball_world_score --scenes DIR` (each scene) compute: the
recording's scans and ground truth (tools.score_recording), the tracks (tools.score_frames,
tools.score_tracks), every metric (ball_world.scoring) and the report as a plain dict.
"""
import numpy as np


class ScoreError(Exception):
    """Something in the input that scoring cannot go on with; the message says what."""


def score_files(recording, agent, gate, tracks_source=None, tolerance=0.0):
    """Score one recording: with the example tracker, or with the tracks of
    tracks_source = (MCAP, TOPIC) paired by stamp within `tolerance` s. Returns
    (report dict, RecordedSegments, SequenceScores with their frame_list)."""
    from ball_world.scoring import figures as metrics
    from ball_world.tools import score_frames, score_recording as recorded, score_tracks
    from ball_world.tools import tracker as example

    segments = recorded.read_run(recording, agent)
    tracks = None
    if tracks_source:
        tracks = score_tracks.read_tracks(*tracks_source)
        if len(segments) > 1:
            raise ScoreError(f'{recording} holds {len(segments)} runs (the world was '
                             'reset): stamps start again at each, so recorded tracks cannot '
                             'be paired with one; record one run per file')
    scores, paired = [], None
    for segment in segments:
        if tracks is None:
            frames = score_frames.frames_with_tracker(segment.scans, example.ScanTracker(),
                                                      'the example tracker',
                                                      segment.occupancy_map)
        else:
            paired = score_frames.frames_with_tracks(segment, tracks.sets,
                                                     round(tolerance * 1e9))
            if paired.pairing.paired == 0:
                raise ScoreError(f'no track message pairs with a scan: {paired.note}')
            frames = paired.frames
        score = (metrics.score_detections if tracks is not None and
                 tracks.kind == 'detections' else metrics.score_tracks)(frames, gate)
        score.frame_list = frames
        scores.append(score)
    combined = metrics.combine(scores)
    visible = sum(int(f.visible.sum()) for s in scores for f in s.frame_list)
    sightings = sum(len(f.visible) for s in scores for f in s.frame_list)
    report = {
        'recording': str(recording), 'agent': agent, 'gate': gate,
        'tracks': {'source': 'the example tracker' if tracks is None else
                   f'{tracks_source[1]} in {tracks_source[0]}',
                   'type': 'example tracker' if tracks is None else tracks.type,
                   'kind': 'tracks' if tracks is None else tracks.kind},
        'scans': sum(len(s.scans) for s in segments), 'segments': len(segments),
        'truth': {'visible': visible, 'hidden': sightings - visible},
        'dont_care': combined.dont_care,
        'stamps': None if paired is None else _stamps_report(paired, tolerance),
        'figures': combined.figures(),
    }
    if len(scores) > 1:
        report['per_segment'] = [dict(segment=s.index, **score.figures())
                                 for s, score in zip(segments, scores)]
    return report, segments, scores


def _stamps_report(paired, tolerance):
    pairing = paired.pairing
    offsets = pairing.unpaired_offsets_ns()
    return {'messages': paired.messages, 'paired': pairing.paired,
            'unpaired': int(len(pairing.unpaired)), 'extra': int(len(pairing.extra)),
            'scans_without_tracks': pairing.scans_without, 'tolerance_s': tolerance,
            'unpaired_offset_ms': None if len(offsets) == 0 else {
                'median': float(np.median(offsets)) * 1e-6,
                'min': float(offsets.min()) * 1e-6, 'max': float(offsets.max()) * 1e-6},
            'note': paired.note}


def breakdown(scores):
    """(per ball, per track) rows of the scores' breakdown (None, None for detections)."""
    from ball_world.scoring import breakdown
    balls, tracks = [], []
    for score in scores:
        if score.kind != 'tracks':
            return None, None
        ball_lines, track_lines = breakdown.lines(score.sequence, score.matches)
        balls += [dict(ball=line.ball, frames=line.frames, matched=line.matched,
                       tracked=line.tracked, switches=line.switches,
                       fragmentations=line.fragmentations, tracks=list(line.tracks))
                  for line in ball_lines]
        tracks += [dict(track=line.track, first_s=line.first_ns * 1e-9,
                        lifetime_s=line.lifetime_s, frames=line.frames, matched=line.matched,
                        false_positives=line.false_positives, switches=line.switches,
                        fragmentations=line.fragmentations, balls=list(line.balls))
                   for line in track_lines]
    return balls, tracks
