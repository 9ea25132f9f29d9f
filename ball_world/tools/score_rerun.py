"""A scored run in Rerun: balls, tracks, misses and false positives over time.

`ball_world_score run.mcap --rerun scored.rrd` logs, at each scan (timelines `sim_time` and
`scan`):

- `arena/balls/visible` and `arena/balls/hidden`: the balls the scan could see (green, their
  names under them in `arena/balls/names`) and those it could not (grey: don't-care);
- `arena/agent`: the scanning agent (orange) and its true heading, `arena/scan` the end
  points of its beams from where it truly was; `arena/agent/odom` (grey) its pose as /tf had
  it, what a tracker was given, when it drifted from the truth (agent.odom.noise);
- `arena/map`: the recorded map's cells, when the world had a map (they hide balls too);
- `arena/tracks`: the tracks with their ids, blue when matched, magenta when a false
  positive, grey when don't-care (on a hidden ball); `arena/matches` a line from each
  matched ball to its track;
- `arena/misses` a red ring around each visible ball no track matched, `arena/switches` a
  yellow ring where a ball's track changed, `arena/false_positives` a magenta cross;
- `plots/per_scan` (misses, false positives, id switches at each scan) and
  `plots/cumulative` (the same summed, with MOTA so far on its own axis in `plots/mota`).

The arena is flipped as in the node's own .rrd (rerun_log): +y points up, as in RViz. The
file is written under a temporary name and moved into place when complete (PartialOutput).
"""
import math

import numpy as np

from ball_world.recording.files import PartialOutput

ARENA = 'arena'
GREEN, GREY, BLUE, MAGENTA, RED, YELLOW = ((90, 190, 110), (150, 150, 150, 110),
                                           (60, 120, 230), (220, 60, 200), (230, 50, 50),
                                           (240, 200, 40))
ORANGE = (250, 150, 30)
RING_STEPS = 32
TRACK_RADIUS = 0.07


def _ring(x, y, r):
    angles = np.linspace(0.0, 2.0 * math.pi, RING_STEPS + 1)
    return np.column_stack((x + r * np.cos(angles), y + r * np.sin(angles)))


def _cross(x, y, size=0.12):
    return [[(x - size, y - size), (x + size, y + size)],
            [(x - size, y + size), (x + size, y - size)]]


def _blueprint(segments):
    import rerun.blueprint as rrb
    walls = np.concatenate([s.walls.reshape(-1, 4) for s in segments if s.walls is not None]
                           or [np.zeros((0, 4))])
    points = np.concatenate([walls[:, :2], walls[:, 2:]] + [
        scan.positions for s in segments for scan in s.scans[:1]])
    (xmin, ymin), (xmax, ymax) = points.min(axis=0) - 0.5, points.max(axis=0) + 0.5
    arena = rrb.Spatial2DView(
        origin='/', contents=f'/{ARENA}/**', name='scored scans (+y up)',
        visual_bounds=rrb.VisualBounds2D(x_range=[xmin, xmax], y_range=[-ymax, -ymin]))
    plots = rrb.Vertical(
        rrb.TimeSeriesView(origin='/plots/per_scan', name='at each scan',
                           plot_legend=rrb.PlotLegend(corner='LeftTop')),
        rrb.TimeSeriesView(origin='/plots/cumulative', name='summed since the start',
                           plot_legend=rrb.PlotLegend(corner='LeftTop')),
        rrb.TimeSeriesView(origin='/plots/mota', name='MOTA so far'))
    return rrb.Blueprint(rrb.Horizontal(arena, plots, column_shares=[2, 1]),
                         rrb.TimePanel(timeline='sim_time', state='collapsed',
                                       play_state='following'),
                         collapse_panels=True)


def _series(stream, rr):
    counts = dict(colors=[RED, MAGENTA, YELLOW],
                  names=['misses', 'false positives', 'id switches'])
    stream.log('plots/per_scan', rr.SeriesLines(**counts), static=True)
    stream.log('plots/cumulative', rr.SeriesLines(**counts), static=True)
    stream.log('plots/mota', rr.SeriesLines(colors=BLUE, names='MOTA'), static=True)
    stream.log(ARENA, rr.Transform3D(
        rotation=rr.RotationAxisAngle(axis=(1.0, 0.0, 0.0), degrees=180.0)), static=True)


def log_run(stream, segments, scores):
    """Log scored segments into a Rerun RecordingStream."""
    import rerun as rr
    _series(stream, rr)
    base_ns = 0
    scan_index = 0
    totals = np.zeros(3)
    truth_total = 0
    for segment, score in zip(segments, scores):
        sequence = score.sequence
        last_track = {}
        stamp = 0
        for k, (recorded, frame) in enumerate(zip(segment.scans, score.frame_list)):
            stamp = frame.stamp_ns
            stream.set_time('sim_time', duration=np.timedelta64(base_ns + stamp, 'ns'))
            stream.set_time('scan', sequence=scan_index)
            scan_index += 1
            if k == 0 and segment.walls is not None:
                stream.log(f'{ARENA}/walls', rr.LineStrips2D(
                    segment.walls.reshape(-1, 2, 2), colors=(120, 120, 120)))
            if k == 0 and segment.occupancy_map is not None:
                from ball_world.recording.rerun_map import map_entities
                for path, archetype in map_entities(segment.occupancy_map, (120, 120, 120)):
                    stream.log(path, archetype)
            counts = _log_scan(stream, rr, recorded, frame, score, k, sequence, last_track)
            totals += counts
            truth_total += int(np.sum(frame.visible))
            stream.log('plots/per_scan', rr.Scalars(counts[:3]))
            stream.log('plots/cumulative', rr.Scalars(totals[:3]))
            if truth_total:
                stream.log('plots/mota', rr.Scalars(1.0 - totals[:3].sum() / truth_total))
        base_ns += stamp + 1


def _log_scan(stream, rr, recorded, frame, score, k, sequence, last_track):
    """Log one scan; returns (misses, false positives, id switches) there."""
    positions, radii, visible = frame.truth_xy, recorded.radii, frame.visible
    names = np.array(frame.truth_ids, dtype=object)
    x, y, yaw = recorded.truth_pose
    agent = np.all(positions == (x, y), axis=1)  # the scanner's own ball
    hidden = ~visible & ~agent
    stream.log(f'{ARENA}/balls/visible', rr.Points2D(
        positions[visible], radii=radii[visible], colors=GREEN))
    # Names under the balls (Rerun draws a label below its point): not over the tracks'.
    below = positions[visible] - np.column_stack((np.zeros(int(visible.sum())),
                                                  radii[visible] + 0.04))
    stream.log(f'{ARENA}/balls/names', rr.Points2D(
        below, radii=0.001, colors=GREEN, labels=[str(n) for n in names[visible]],
        show_labels=True))
    stream.log(f'{ARENA}/balls/hidden', rr.Points2D(
        positions[hidden], radii=radii[hidden], colors=GREY))
    stream.log(f'{ARENA}/agent', rr.Points2D(positions[agent], radii=radii[agent],
                                             colors=ORANGE))
    stream.log(f'{ARENA}/agent/heading', rr.Arrows2D(origins=[(x, y)], vectors=[
        (0.6 * math.cos(yaw), 0.6 * math.sin(yaw))], colors=ORANGE))
    # Where /tf put the scanner (what a tracker was given): drawn only where it drifted.
    ox, oy, oyaw = recorded.pose
    drifted = (ox, oy, oyaw) != (x, y, yaw)
    stream.log(f'{ARENA}/agent/odom', rr.Arrows2D(
        origins=np.array([(ox, oy)] if drifted else [], dtype=np.float64).reshape(-1, 2),
        vectors=np.array([(0.6 * math.cos(oyaw), 0.6 * math.sin(oyaw))] if drifted else [],
                         dtype=np.float64).reshape(-1, 2), colors=GREY))
    message = recorded.message
    ranges = np.asarray(message.ranges, dtype=np.float64)
    angles = yaw + message.angle_min + np.arange(len(ranges)) * message.angle_increment
    hit = np.isfinite(ranges)
    stream.log(f'{ARENA}/scan', rr.Points2D(np.column_stack(
        (x + ranges[hit] * np.cos(angles[hit]), y + ranges[hit] * np.sin(angles[hit]))),
        radii=0.02, colors=ORANGE))
    removed = set(sequence.dont_care[k].tolist())
    matched_ball, matched_track, switched = {}, {}, []
    if score.matches is not None:
        balls, tracks, _ = score.matches[k]
        for ball, track in zip(balls.tolist(), tracks.tolist()):
            ball_name = sequence.gt_labels[ball]
            track_name = sequence.tracker_labels[track]
            matched_ball[ball_name] = track_name
            matched_track[track_name] = ball_name
            if last_track.get(ball_name, track_name) != track_name:
                switched.append(ball_name)
            last_track[ball_name] = track_name
    colours, strips, crosses = [], [], []
    where = {name: i for i, name in enumerate(frame.truth_ids)}
    for index, (track, (tx, ty)) in enumerate(zip(frame.track_ids, frame.track_xy)):
        if index in removed:
            colours.append(GREY)
        elif track in matched_track:
            colours.append(BLUE)
            bx, by = positions[where[matched_track[track]]]
            strips.append([(bx, by), (tx, ty)])
        else:
            colours.append(MAGENTA)
            crosses += _cross(tx, ty)
    stream.log(f'{ARENA}/tracks', rr.Points2D(
        frame.track_xy, radii=TRACK_RADIUS, colors=colours or None,
        labels=[str(t) for t in frame.track_ids], show_labels=True))
    stream.log(f'{ARENA}/matches', rr.LineStrips2D(strips, colors=BLUE, radii=0.015))
    missed = [i for i in np.flatnonzero(visible) if frame.truth_ids[i] not in matched_ball]
    stream.log(f'{ARENA}/misses', rr.LineStrips2D(
        [_ring(*positions[i], radii[i] + 0.08) for i in missed], colors=RED, radii=0.03))
    stream.log(f'{ARENA}/false_positives', rr.LineStrips2D(crosses, colors=MAGENTA,
                                                           radii=0.03))
    stream.log(f'{ARENA}/switches', rr.LineStrips2D(
        [_ring(*positions[where[name]], radii[where[name]] + 0.16) for name in switched],
        colors=YELLOW, radii=0.03))
    false_positives = len(frame.track_ids) - len(removed) - len(matched_track)
    return np.array([len(missed), false_positives, len(switched)], dtype=np.float64)


def write_rrd(path, segments, scores, force=False):
    """Write the scored run to a Rerun file at `path` (OSError when it may not be).

    The claim on the temporary file (created, locked) is held while the SDK writes to it
    by path, as the node's recorder does (recording.files.ClaimedSink)."""
    import rerun as rr
    output = PartialOutput(path, force, 'pass --force')
    stream = None
    try:
        stream = rr.RecordingStream('ball_world_score', recording_id='ball_world_score',
                                    send_properties=False)
        stream.set_log_time_enabled(False)
        stream.set_log_tick_enabled(False)
        stream.save(output.path, default_blueprint=_blueprint(segments))
        log_run(stream, segments, scores)
        stream.flush()
        stream.disconnect()
        output.commit()
    except BaseException:
        if stream is not None:
            stream.disconnect()
        output.discard()
        raise
