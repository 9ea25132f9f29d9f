"""Frames to score: a recording's scans with the tracks of the example tracker, of any
tracker class, or of a user's recorded messages paired with the scans by stamp.

Kept apart from the command line so that the benchmark (tools.score_bench) builds its frames
with the very same code from scans it simulates.
"""
from dataclasses import dataclass

import numpy as np

from ball_world.scoring import stamps as stamp_pairing
from ball_world.scoring.frames import Frame
from ball_world.scoring.planar_tf import to_frame, TransformError
from ball_world.tools import tracker as example


class FramesError(ValueError):
    """Tracks that cannot be put into frames; the message says why."""


def scan_of(message):
    """The tracker's Scan of a decoded LaserScan (agent_cdr.DecodedScan)."""
    return example.Scan(message.stamp_ns, message.frame_id, message.angle_min,
                        message.angle_increment, message.range_min, message.range_max,
                        message.ranges)


def frame(recorded, track_ids, track_xy):
    """The Frame of a RecordedScan (or a simulated one) with these tracks."""
    return Frame(stamp_ns=recorded.stamp_ns, truth_ids=recorded.names,
                 truth_xy=recorded.positions, visible=recorded.visible,
                 track_ids=tuple(track_ids),
                 track_xy=np.asarray(track_xy, dtype=np.float64).reshape(-1, 2))


def tracker_rows(rows, who, when=''):
    """(ids, xy) of what a tracker's update returned: rows (id, x, y, ...), checked
    (user_code.checks: refused in one line naming who, when and the bad value)."""
    from ball_world.user_code.checks import track_rows
    return track_rows(rows, who, when or 'at a scan')


def map_grid(occupancy_map):
    """The tracker's MapGrid (what /map carries) of a core.occupancy_map.OccupancyMap."""
    return example.MapGrid(occupancy_map.resolution, *occupancy_map.origin,
                           occupancy_map.data)


def frames_with_tracker(scans, tracker, who='the tracker', occupancy_map=None, where=''):
    """Frames of scans (RecordedScan) with `tracker` (update(scan, pose)) run on them; a
    tracker with a `use_map(grid)` method is first given the world's map, if it has one.
    What it raises or returns wrong is one line naming `who` and the scan (of `where`)."""
    from ball_world.user_code.calls import call
    if occupancy_map is not None and callable(getattr(tracker, 'use_map', None)):
        call(f"{who}{f' on {where}' if where else ''}: use_map", tracker.use_map,
             map_grid(occupancy_map))
    out = []
    for index, recorded in enumerate(scans):
        when = (f"{f'on {where} ' if where else ''}at scan {index} (stamp "
                f'{recorded.stamp_ns * 1e-9:.3f} s)')
        rows = call(f'{who} {when}', tracker.update, scan_of(recorded.message), recorded.pose)
        ids, xy = tracker_rows(rows, who, when)
        out.append(frame(recorded, ids, xy))
    return out


@dataclass
class Paired:
    """Frames of user tracks, and how their messages paired with the scans."""

    frames: list
    pairing: object  # scoring.stamps.Pairing
    messages: int
    note: str  # the one line on unpaired messages, or None


def frames_with_tracks(segment, sets, tolerance_ns=0):
    """Frames of a RecordedSegment's scans with the TrackSets paired to them by stamp.

    Tracks given in another frame than the world's are put in it through the segment's
    recorded transforms at the tracks' stamp. A scan no set paired with has no tracks.
    """
    scans = segment.scans
    scan_stamps = np.array([s.stamp_ns for s in scans], dtype=np.int64)
    pairing = stamp_pairing.pair(scan_stamps, [s.stamp_ns for s in sets], tolerance_ns)
    given = {}
    for index, scan in enumerate(pairing.scan_of.tolist()):
        if scan >= 0:
            given[scan] = sets[index]
    out = []
    for position, recorded in enumerate(scans):
        track_set = given.get(position)
        if track_set is None or len(track_set.xy) == 0:
            out.append(frame(recorded, (), np.empty((0, 2))))
            continue
        xy = track_set.xy
        if not np.isfinite(xy).all():
            raise FramesError(f'tracks at stamp {track_set.stamp_ns} ns have a position '
                              'that is not finite')
        if track_set.frame_id != segment.world_frame:
            xy = _in_world(segment, track_set)
        ids = track_set.ids or tuple(range(len(xy)))
        out.append(frame(recorded, ids, xy))
    note = stamp_pairing.describe(pairing, len(sets), tolerance_ns)
    return Paired(out, pairing, len(sets), note)


def _in_world(segment, track_set):
    if not track_set.frame_id:
        raise FramesError(f'tracks at stamp {track_set.stamp_ns} ns have an empty frame_id '
                          f'(give the frame they are in, e.g. {segment.world_frame!r})')
    try:
        pose = segment.transforms.lookup(segment.world_frame, track_set.frame_id,
                                         track_set.stamp_ns)
    except TransformError as error:
        raise FramesError(f'tracks in frame {track_set.frame_id!r} cannot be put in '
                          f'{segment.world_frame!r} through the recorded /tf: {error}') \
            from None
    return to_frame(track_set.xy, *pose)
