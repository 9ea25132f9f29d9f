"""A user's tracks, read from any ROS 2 MCAP or rosbag2 directory for ball_world_score.

`--tracks PATH TOPIC`: PATH is an MCAP file or the directory `ros2 bag record -s mcap`
makes (its metadata.yaml lists the files); TOPIC carries visualization_msgs/MarkerArray
(each ADD marker one track; its id, with its namespace, the track's identity) or
geometry_msgs/PoseArray (positions without identities: scored as detections). Each
message is the complete set of tracks at its stamp, as the example tracker publishes it
(a DELETEALL marker, then one marker per track).

The file is untrusted: it is read with the project's bounded reader (recording.mcap_reader's
Scan: every record's length checked against the file, chunks inflated within a bound and
their CRC checked) and decoded by msgs.track_cdr, whose every read is checked. A file that
is not an MCAP, is empty, cut off or corrupt, lacks the topic or carries another type is a
TracksError with one line, never a traceback.
"""
import os
from typing import NamedTuple

from mcap.records import Channel, Message, Schema
import numpy as np

from ball_world.msgs import track_cdr
from ball_world.recording.bag import listed_files, METADATA_FILE
from ball_world.recording.files import open_regular
from ball_world.recording.mcap_reader import load_untrusted, RecordingError, Scan

TYPES = (track_cdr.MARKER_ARRAY, track_cdr.POSE_ARRAY)
#: Most topics named when the one asked for is missing.
TOPICS_SHOWN = 8


class TracksError(Exception):
    """Tracks that cannot be scored; the message says why, in one line."""


class TrackSet(NamedTuple):
    """The tracks of one message (or one stamp of a MarkerArray's markers)."""

    stamp_ns: int
    frame_id: str
    ids: tuple  # the tracks' ids; () for a PoseArray (it has none)
    xy: np.ndarray  # (N, 2) in frame_id


class Tracks(NamedTuple):
    kind: str  # 'tracks' (with ids) or 'detections' (a PoseArray: no ids)
    type: str
    sets: list  # [TrackSet] in file order
    messages: int


def _files(path):
    """The MCAP files of PATH: itself, or those its rosbag2 metadata.yaml lists."""
    if not os.path.isdir(path):
        return [path]
    metadata = os.path.join(path, METADATA_FILE)
    try:
        open_regular(metadata).close()  # a FIFO or device would block the reading below
        names = listed_files(path, lambda text, what, limit: load_untrusted(
            text, what, limit, json_text=False))
    except (OSError, ValueError, RecordingError) as error:
        raise TracksError(f'{path}: {getattr(error, "strerror", None) or error}') from None
    return [os.path.join(path, name) for name in names]


def _messages(path, topic):
    """(schema name, schema text, log time, bytes) of every message on `topic` in one MCAP
    file, read front to back by the bounded reader; the file's other topics, for a hint."""
    schemas, channels, wanted, found = {}, {}, set(), []
    try:
        with open_regular(path) as stream:
            size = os.fstat(stream.fileno()).st_size
            if size == 0:
                raise TracksError(f'{path} is empty, not an MCAP file')
            scan = Scan(stream, size)
            for record in scan.records():
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                    if record.topic == topic:
                        wanted.add(record.id)
                elif isinstance(record, Message) and record.channel_id in wanted:
                    found.append(record)
    except RecordingError as error:
        raise TracksError(f'{path}: {error}') from None
    except OSError as error:
        raise TracksError(f'{path}: {error.strerror or error}') from None
    if scan.corrupt or not scan.finished:
        raise TracksError(f'{path}: {scan.problem} (a recording cut off or damaged: '
                          'repair it first, e.g. with `mcap recover`)')
    out = []
    for record in found:
        channel = channels[record.channel_id]
        schema = schemas.get(channel.schema_id)
        if channel.message_encoding != 'cdr':
            raise TracksError(f'{path}: {topic} is encoded as {channel.message_encoding!r}, '
                              'not cdr (ROS 2)')
        out.append((schema.name if schema else '',
                    schema.data.decode('utf-8', 'replace') if schema else '',
                    record.log_time, record.data))
    return out, sorted({c.topic for c in channels.values()})


def read_tracks(path, topic):
    """The Tracks on `topic` in `path` (TracksError when they cannot be read)."""
    path = os.fspath(path)
    records, topics = [], set()
    for file_path in _files(path):
        found, names = _messages(file_path, topic)
        records += found
        topics.update(names)
    if not records:
        if topic in topics:
            raise TracksError(f'{path} has no messages on {topic}')
        shown = sorted(topics)[:TOPICS_SHOWN]
        more = f' and {len(topics) - len(shown)} more' if len(topics) > len(shown) else ''
        listing = f"its topics: {', '.join(shown)}{more}" if shown else 'it has no topics'
        raise TracksError(f'{path} has no topic {topic}; {listing}')
    types = {name for name, _, _, _ in records}
    if len(types) > 1 or not types <= set(TYPES):
        raise TracksError(f"{topic} is a {', '.join(sorted(types))}; expected a "
                          f'{track_cdr.MARKER_ARRAY} (tracks with ids) or a '
                          f'{track_cdr.POSE_ARRAY} (positions without ids)')
    kind = types.pop()
    sets = []
    for _, definition, log_time, data in records:
        try:
            if kind == track_cdr.POSE_ARRAY:
                stamp, frame_id, xy = track_cdr.decode_poses(data)
                sets.append(TrackSet(stamp, frame_id, (), xy))
            else:
                sets += _marker_sets(track_cdr.decode_marker_array(
                    data, track_cdr.is_textured(definition)))
        except ValueError as error:
            raise TracksError(f'{path}: the {kind} on {topic} at log time {log_time} ns does '
                              f'not decode: {error}') from None
    return Tracks('detections' if kind == track_cdr.POSE_ARRAY else 'tracks', kind, sets,
                  len(records))


def _marker_sets(markers):
    """A MarkerArray's tracks: its ADD markers, grouped by stamp and frame (one group in
    the usual message). A message without ADD markers says "no tracks" at its markers'
    stamp (the example tracker's DELETEALL), or at no stamp when it has no marker at all."""
    groups = {}
    for marker in markers:
        key = (marker.stamp_ns, marker.frame_id)
        group = groups.setdefault(key, ([], []))
        if marker.action == track_cdr.ADD:
            group[0].append(marker.ns + '/' + str(marker.id) if marker.ns else marker.id)
            group[1].append((marker.x, marker.y))
    adds = {key: group for key, group in groups.items() if group[0]}
    chosen = adds or dict(list(groups.items())[:1])
    return [TrackSet(stamp, frame_id, tuple(ids), np.array(xy, dtype=np.float64).reshape(-1, 2))
            for (stamp, frame_id), (ids, xy) in chosen.items()]
