"""ball_world_info for a recording of topics that is no world run: what `ball_world_cli record`
(or `ros2 bag record -s mcap`) writes. Without a 'ball_world' metadata record there are no
steps or segments to tell; what `ros2 bag info` tells is what is said: the files, the
duration, and each topic with its type and message count, read from each file's summary.

A file without a summary (its recorder was killed) is named with the repair that completes
it, as for any recording.
"""
import os

from ball_world.recording.bag import read_listing
from ball_world.recording.files import open_regular
from ball_world.recording.mcap_reader import RecordingError

#: The start of mcap_reader's refusal of a file without the node's metadata record.
NOT_A_RUN = "no 'ball_world' metadata record"


def _load(text, what, limit):
    import yaml
    if len(text) > limit:
        raise ValueError(f'{what} is larger than {limit:,} bytes')
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ValueError(f'{what} is not YAML: {" ".join(str(error).split())[:200]}') from None


def _files(path):
    if os.path.isdir(path):
        try:
            names = read_listing(path, _load).names
        except ValueError as error:
            raise RecordingError(str(error)) from None
        return [os.path.join(path, name) for name in names]
    return [path]


def _summary(path):
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    try:
        with open_regular(path) as stream:
            summary = make_reader(stream).get_summary()
    except (McapError, ValueError, EOFError) as error:
        raise RecordingError(f'{os.path.basename(path)}: not a readable MCAP file: '
                             f'{" ".join(str(error).split())[:200]}') from None
    if summary is None or summary.statistics is None:
        raise RecordingError(f'{os.path.basename(path)} has no summary (its recorder was '
                             f'stopped before it finished it); ball_world_repair {path} '
                             'completes it')
    return summary


def describe(path):
    """The lines ball_world_info prints for a recording of topics (RecordingError if none)."""
    counts = {}  # topic -> [type, messages]
    start = end = None
    files = _files(path)
    total = 0
    for file in files:
        summary = _summary(file)
        statistics = summary.statistics
        total += statistics.message_count
        if statistics.message_count:
            start = statistics.message_start_time if start is None else min(
                start, statistics.message_start_time)
            end = statistics.message_end_time if end is None else max(
                end, statistics.message_end_time)
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            entry = counts.setdefault(channel.topic, [schema.name if schema else '?', 0])
            entry[1] += statistics.channel_message_counts.get(channel_id, 0)
    lines = [f'recording:   {path} (topics recorded, not a ball_world run: no steps to '
             'tell)',
             f"files:       {len(files)} ({', '.join(os.path.basename(f) for f in files)})",
             f'duration:    {((end or 0) - (start or 0)) / 1e9:.3f} s',
             f'messages:    {total:,}']
    width = max((len(topic) for topic in counts), default=0)
    lines += [f'topic:       {topic.ljust(width)}  {type_name}  {count:,}'
              for topic, (type_name, count) in sorted(counts.items())]
    return [line if line.isprintable() else repr(line) for line in lines]
