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

import numpy as np


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


# The command line: a recording's scans, ground truth and tracks to frames ------------------

PROG = 'ball_world_score'


class ScoreError(Exception):
    """Something in the input that scoring cannot go on with; the message says what."""


def recorded_frames(path, agent, tracks_path=None, tracks_topic=None, options=None):
    """CLEAR-MOT frames (truth, tracks) of each recorded scan of `agent` in a recording.

    Ground truth: the balls of that step (`balls`, with the radii and walls of its segment
    as edits left them) that the agent's scanner could see. Tracks: the example tracker run
    on the recorded scans (with `options`), or the tracks of `tracks_topic` (MarkerArray or
    PoseArray) in `tracks_path` whose header stamp equals the scan's.
    """
    from ball_world.core import lidar
    from ball_world.msgs.agent_cdr import decode_laser_scan, decode_tf_message
    from ball_world.recording.mcap_reader import BallRoster, snapshot_and_info
    from ball_world.recording.recording_set import open_recording
    from ball_world.scans import fan_from
    from ball_world.tools import tracker as example

    recording = open_recording(path)
    scan_topic = next((topic for topic in _topics(recording) if topic.endswith(f'/{agent}/scan')),
                      None)
    if scan_topic is None:
        raise ScoreError(f'{path} has no {agent}/scan topic (is {agent} an agent, and '
                         'agent.scan.samples > 0?)')
    scans = {m.log_time_ns: m.data for m in recording.messages([scan_topic])}
    yaws = {}
    for message in recording.messages(['/tf']):
        transforms = decode_tf_message(message.data)
        for child, row in zip(transforms.child_frame_ids, transforms.transforms):
            if child.endswith(f'{agent}/base_link'):
                yaws[message.log_time_ns] = 2.0 * math.atan2(row[5], row[6])
    supplied = _supplied_tracks(tracks_path, tracks_topic) if tracks_path else None
    tracker = example.Tracker(options or example.Options())
    frames = []
    roster = None
    segment = None
    for step in recording.steps():
        if roster is None or step.segment != segment:
            segment = step.segment
            snapshot, _ = snapshot_and_info(recording.segments[segment], step)
            roster = BallRoster(snapshot, segment)
            walls = snapshot.walls
            parameters = recording.segments[segment].parameters
            tracker = example.Tracker(options or example.Options())
        roster.follow(step)
        data = scans.get(step.log_time_ns)
        if data is None or step.positions is None:
            continue
        if step.log_time_ns not in yaws:
            raise ScoreError(f'{path}: no /tf for {agent} at the scan of step {step.step}')
        index = roster.names.index(agent)
        origin = step.positions[index]
        yaw = yaws[step.log_time_ns]
        fan = fan_from(parameters, float(roster.radii[index]))
        seen = lidar.seen_balls(step.positions, roster.radii, walls, origin, yaw, fan, index)
        truth = {roster.names[i]: tuple(step.positions[i]) for i in seen}
        message = decode_laser_scan(data)
        if supplied is not None:
            hypotheses = supplied.get(message.stamp_ns, {})
        else:
            geometry = example.ScanGeometry(message.angle_min, message.angle_increment,
                                            message.range_min, message.range_max)
            found = example.to_world(example.detect(message.ranges.astype(np.float64),
                                                    geometry, tracker.options), *origin, yaw)
            hypotheses = {row[0]: (row[1], row[2])
                          for row in tracker.update(message.stamp_ns * 1e-9, found)}
        frames.append((truth, hypotheses))
    if not frames:
        raise ScoreError(f'{path}: no scan of {agent} with its step recorded')
    return frames


def _topics(recording):
    return sorted(recording.topics)


def _supplied_tracks(path, topic):
    """{stamp_ns: {id: (x, y)}} of a tracks topic (MarkerArray: marker ids; PoseArray: pose
    order, so id switches mean nothing then) in any ROS 2 MCAP."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    tracks = {}
    try:
        with open(path, 'rb') as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for schema, _, _, message in reader.iter_decoded_messages(topics=[topic]):
                if schema.name == 'visualization_msgs/msg/MarkerArray':
                    for marker in message.markers:
                        if marker.action == 0:  # ADD (DELETEALL and DELETE carry no track)
                            stamp = _stamp_ns(marker.header.stamp)
                            tracks.setdefault(stamp, {})[marker.id] = (
                                marker.pose.position.x, marker.pose.position.y)
                elif schema.name == 'geometry_msgs/msg/PoseArray':
                    tracks[_stamp_ns(message.header.stamp)] = {
                        k: (pose.position.x, pose.position.y)
                        for k, pose in enumerate(message.poses)}
                else:
                    raise ScoreError(f'{topic} is a {schema.name}; expected a '
                                     'visualization_msgs/msg/MarkerArray or a '
                                     'geometry_msgs/msg/PoseArray')
    except (OSError, ValueError) as error:
        raise ScoreError(f'cannot read tracks from {path}: {error}')
    if not tracks:
        raise ScoreError(f'{path} has no messages on {topic}')
    return tracks


def _stamp_ns(stamp):
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def main(argv=None):
    import argparse
    import sys

    from ball_world.recording.mcap_reader import RecordingError
    from ball_world.tools import tracker as example

    parser = argparse.ArgumentParser(
        prog=PROG, description='CLEAR-MOT (MOTA, MOTP, id switches, misses, false '
        "positives) of tracks against the balls an agent's scanner could see, per recorded "
        'scan. Without --tracks it runs the example tracker (ball_world_tracker) on the '
        'recorded scans itself.')
    parser.add_argument('recording', help='a ball_world MCAP recorded with an agent that scans')
    parser.add_argument('--agent', default='ball_0', help='the scanning agent (default ball_0)')
    parser.add_argument('--gate', type=float, default=0.5,
                        help='largest distance of a match, m (default 0.5)')
    parser.add_argument('--tracks', nargs=2, metavar=('MCAP', 'TOPIC'),
                        help='score these tracks instead (MarkerArray or PoseArray, stamped '
                             "with the scans' stamps, e.g. recorded with ros2 bag record)")
    args = parser.parse_args(argv)
    if not (args.gate > 0.0 and math.isfinite(args.gate)):
        parser.error('--gate must be a number > 0')
    tracks_path, tracks_topic = args.tracks if args.tracks else (None, None)
    try:
        frames = recorded_frames(args.recording, args.agent, tracks_path, tracks_topic,
                                 example.Options())
    except (ScoreError, RecordingError, OSError, ValueError) as error:
        print(f'{PROG}: {error}', file=sys.stderr)
        return 1
    what = f'{tracks_topic} of {tracks_path}' if tracks_path else 'the example tracker'
    print(f'{args.recording}: {args.agent}/scan, tracks of {what}, gate {args.gate:g} m')
    for line in clear_mot(frames, args.gate).lines():
        print(line)
    return 0
