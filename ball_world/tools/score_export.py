"""The scored frames as CSV, for TrackEval, motmetrics or a spreadsheet.

One row per ball and per track at each scan (docs/scoring.md, "The CSV"):

    segment,scan,stamp_ns,source,id,x,y,radius,visible,dont_care,matched

- source: `truth` (a ball) or `track`;
- visible (truth): 1 if the scan could see the ball, 0 if it was hidden (a don't-care
  region: MOTChallenge's distractor);
- dont_care (track): 1 if the track matched a hidden ball and was removed before scoring;
- matched: the id CLEAR-MOT matched it to at that scan (a track's ball, a ball's track),
  empty when unmatched (a miss, a false positive) or not scored.

x, y in metres in the world frame; radius the ball's (empty for tracks). The file is
written beside its target under a temporary name and moved into place when complete
(recording.files.PartialOutput): never through a symlink, never over an existing file
without --force.
"""
import csv
import io

from ball_world.recording.files import PartialOutput

COLUMNS = ('segment', 'scan', 'stamp_ns', 'source', 'id', 'x', 'y', 'radius', 'visible',
           'dont_care', 'matched')


def rows(segments, scores):
    """The CSV's rows (tuples in COLUMNS order) of scored segments."""
    for segment, score in zip(segments, scores):
        sequence = score.sequence
        for k, (recorded, frame) in enumerate(zip(segment.scans, score.frame_list)):
            partner = {}
            if score.matches is not None:
                balls, tracks, _ = score.matches[k]
                for ball, track in zip(balls.tolist(), tracks.tolist()):
                    partner[('truth', sequence.gt_labels[ball])] = sequence.tracker_labels[track]
                    partner[('track', sequence.tracker_labels[track])] = sequence.gt_labels[ball]
            for name, (x, y), radius, visible in zip(frame.truth_ids, frame.truth_xy,
                                                     recorded.radii, frame.visible):
                yield (segment.index, k, frame.stamp_ns, 'truth', name, repr(float(x)),
                       repr(float(y)), repr(float(radius)), int(bool(visible)), '',
                       partner.get(('truth', name), ''))
            removed = set(sequence.dont_care[k].tolist())
            for index, (track, (x, y)) in enumerate(zip(frame.track_ids, frame.track_xy)):
                yield (segment.index, k, frame.stamp_ns, 'track', track, repr(float(x)),
                       repr(float(y)), '', '', int(index in removed),
                       partner.get(('track', track), ''))


def write_csv(path, segments, scores, force=False):
    """Write the CSV to `path` (OSError, e.g. FileRefused, when it may not be written)."""
    output = PartialOutput(path, force, 'pass --force')
    try:
        with io.TextIOWrapper(output.claim.writer(), encoding='utf-8', newline='') as text:
            writer = csv.writer(text)
            writer.writerow(COLUMNS)
            writer.writerows(rows(segments, scores))
        output.commit()
    except BaseException:
        output.discard()
        raise
