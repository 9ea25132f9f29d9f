"""ball_world_info: what a recording holds, at a glance, and whether it needs repair.

Reads a finished file through its summary (only the first and last chunks of the stats
topic are decoded), and a file without summary front to back. Any file that is not a
readable ball_world recording gets one line on stderr and exit status 2.
"""
import argparse
import os
import sys

from ball_world.msgs.cdr import decode_pose_array, decode_vector3_stamped
from ball_world.recording import agent_topics
from ball_world.recording.bag import what_stopped
from ball_world.recording.mcap_reader import decode_stats, EDIT_KINDS, RecordingError
from ball_world.recording.recording_set import open_recording
from ball_world.step_record import STATS_FIELDS
from ball_world.tools import print_report


def _shown(text):
    """A string from the recording as it may be printed: escaped unless plainly printable.

    Topic and type names come from the file; control characters in them must not reach the
    terminal (escape sequences can rewrite what it shows).
    """
    text = str(text)
    return text if text.isprintable() else repr(text)


def _seconds(ns):
    return f'{ns / 1e9:.9g} s'


def _duration(ns):
    """A span of log time to the millisecond: dt is kept in whole nanoseconds, so 1,800 steps
    of 1/60 s last 30.0000006 s, which is 30 s to anyone reading a summary."""
    return f"{f'{ns / 1e9:.3f}'.rstrip('0').rstrip('.')} s"


def _plural(count, word):
    return f"{count:,} {word}{'' if count == 1 else 's'}"


def _energy(message):
    if message is None:
        return None
    return float(decode_stats(message.data)[STATS_FIELDS.index('kinetic_energy')])


def _first(recording, topic):
    return next(iter(recording.messages([topic])), None) if topic else None


def _segment_lines(recording):
    """A line per segment, and the steps taken in all of them: a segment starts at step 0,
    its initial state, which is published and recorded but is not a step.

    A segment's last log time is its last step, unless it holds a closing record (impulses
    and edits made after that step, with no balls: mcap_reader.RecordedStep.closing); then
    the step before it is the last, and the closing record is said as what it is.
    """
    lines = []
    taken = 0
    segments = recording.segments
    last_logs = []
    for position, segment in enumerate(segments):
        if hasattr(recording, 'segment_end_ns'):  # a bag directory: gaps taken into account
            last_logs.append(recording.segment_end_ns(position) or 0)
        elif position + 1 < len(segments):
            last_logs.append(segments[position + 1].log_offset_ns - segment.dt_ns)
        else:
            last_logs.append(recording.end_ns if recording.end_ns is not None else 0)
    closing = _closing_records(recording, last_logs)
    for segment, last_log in zip(segments, last_logs):
        last_step = max(0, (last_log - segment.log_offset_ns) // segment.dt_ns)
        after = closing.get(last_log)
        if after and last_step > 0:
            last_step -= 1
        resumed_from = 0 if segment.resume is None else segment.resume.step
        taken += last_step - resumed_from
        first_step = 0 if segment.resume is None else resumed_from + 1
        lines.append(f'  {segment.index}: from log time {_duration(segment.log_offset_ns)}, '
                     f'steps {first_step}-{last_step}'
                     f"{f' (+ {after} after the last step)' if after else ''}, dt "
                     f'{segment.dt_ns / 1e6:.6g} ms, frame '
                     f"'{segment.frame_id}', written by ball_world {segment.package_version}")
    return lines, taken


def _closing_records(recording, last_logs):
    """{log time: 'N edits and M impulses'} of the segments' last log times that hold a
    closing record: impulse or edit messages, and no balls, state or stats."""
    roles = ('balls', 'state', 'stats', 'impulse', 'edits')
    topics = {recording.topic_of(role): role for role in roles if recording.topic_of(role)}
    found = {}
    for time, messages in recording.messages_at(last_logs, topics).items():
        held = [topics[message.topic] for message in messages]
        if any(role in held for role in roles[:3]):
            continue
        counts = [_plural(held.count(role), word) for role, word in (
            ('edits', 'edit'), ('impulse', 'impulse')) if role in held]
        if counts:
            found[time] = ' and '.join(counts)
    return found


def _file_lines(recording):
    """A bag directory's files (recording_set.RecordingSet): each with its steps and time."""
    files = getattr(recording, 'files', None)
    if not files:
        return []
    lines = [f'split into:  {len(files)} files (metadata.yaml)'
             + (f', {len(recording.missing)} missing' if recording.missing else '')]
    for member in files:
        topic = member.topic_of('balls')
        steps = member.topics[topic].message_count if topic in member.topics else 0
        span = (f', log time {_seconds(member.start_ns)} to {_seconds(member.end_ns)}'
                if member.start_ns is not None else '')
        state = '' if member.has_summary else ' (NO summary: its writer did not finish it)'
        lines.append(f'  {os.path.basename(member.path)}: {member.size} bytes, {steps} steps'
                     f'{span}{state}')
    repair = f'ball_world_repair {recording.path}'
    for name in recording.missing:
        lines.append(f'  MISSING: {name}, listed in metadata.yaml: the steps it held are lost')
    for gap in recording.gaps:
        lines.append(f'  GAP: {gap.describe()}')
    if recording.stopped:
        lines.append(f'  STOPPED: the recorder stopped on an error: {recording.stopped}'
                     f'{what_stopped(recording.stopped)}')
    unlisted = recording.unlisted
    if unlisted:
        lines.append(f"  NOT LISTED: {', '.join(unlisted)} (a file being written when the "
                     f'recorder stopped); {repair} adds it')
    for name, why in recording.strays:
        lines.append(f'  left out: {name}: {why}')
    return lines


def describe(recording):
    """The report as lines of text."""
    header = recording.header
    lines = [f'file:        {recording.path} ({recording.size} bytes)',
             f'written by:  {_shown(header.library)} (profile {header.profile!r})']
    lines.extend(_file_lines(recording))
    if getattr(recording, 'files', None) and not recording.has_summary:
        lines.append(f'summary:     NOT ALL ({recording.problem})')
        lines.append(f'             Repair it: ball_world_repair {recording.path}')
    elif recording.has_summary:
        lines.append('summary:     yes (the writer finished the file)')
    else:
        lines.append(f'summary:     NO ({recording.problem}); '
                     f'{recording.complete_bytes} of {recording.size} bytes are complete '
                     'records.')
        lines.append(f'             Repair it: ball_world_repair {recording.path}')
    compressions = ', '.join(sorted(_shown(c or 'none') for c in recording.compressions)) \
        or 'none'
    lines.append(f'compression: {compressions} ({recording.chunk_count} chunks)')
    if recording.start_ns is not None:
        lines.append(f'duration:    {_duration(recording.end_ns - recording.start_ns)} (log '
                     f'time {_duration(recording.start_ns)} to {_duration(recording.end_ns)})')
    balls_topic = recording.topic_of('balls')
    poses = recording.topics[balls_topic].message_count if balls_topic in recording.topics \
        else 0
    segment_lines, taken = _segment_lines(recording)
    count = len({segment.index for segment in recording.segments})
    lines.append(f"steps:       {taken:,} after the initial state{'' if count == 1 else 's'} "
                 f'({_plural(poses, "message")} on {_shown(balls_topic)}), in '
                 f'{_plural(count, "segment")}')
    lines.extend(segment_lines)
    first_balls = _first(recording, balls_topic)
    if first_balls is not None:
        count = len(decode_pose_array(first_balls.data)[2])
        # the world the parameters describe must be the recorded one (not built: counted)
        recording.segments[recording.segment_at(first_balls.log_time_ns)].check_ball_count(
            count)
        lines.append(f'balls:       {count}')
    lines.extend(_map_lines(recording))
    lines.append(f'messages:    {recording.message_count}')
    for info in recording.topics.values():
        lines.append(f'  {_shown(info.topic)}  {_shown(info.type)}  {info.message_count}')
    lines.extend(_impulse_lines(recording))
    lines.extend(_edit_lines(recording))
    lines.extend(_agent_lines(recording))
    lines.extend(_energy_lines(recording))
    return lines


def _map_lines(recording):
    """The map each segment was built with (its files are attached to the recording)."""
    lines = []
    seen = set()
    for segment in recording.segments:
        occupancy_map = segment.occupancy_map
        if occupancy_map is None:
            continue
        unknown_solid = segment.parameters['map.unknown_solid']
        key = (occupancy_map.files, unknown_solid)
        if key in seen:
            continue
        seen.add(key)
        occupied, free, unknown = occupancy_map.counts
        solid = occupied + (unknown if unknown_solid else 0)
        files = occupancy_map.files
        lines.append(f'map:         {_shown(files.yaml_name)} and {_shown(files.image_name)} '
                     f'(attached): {occupancy_map.width:,} x {occupancy_map.height:,} cells of '
                     f'{occupancy_map.yaml.resolution:g} m at ({occupancy_map.origin[0]:g}, '
                     f'{occupancy_map.origin[1]:g}) m, {occupancy_map.yaml.mode}')
        lines.append(f'             {occupied:,} occupied, {free:,} free, {unknown:,} unknown; '
                     f"{solid:,} solid cells (unknown {'solid' if unknown_solid else 'free'})"
                     + ('' if len(recording.segments) == 1 else
                        f' from segment {segment.index}'))
    return lines


def _energy_lines(recording):
    """Kinetic energy of the first and last recorded steps (and of which segments)."""
    topic = recording.topic_of('stats')
    first = _first(recording, topic)
    if first is None:
        return []
    last = recording.last_message(topic)
    segments = recording.segments
    first_segment = segments[recording.segment_at(first.log_time_ns)].index
    last_segment = segments[recording.segment_at(last.log_time_ns)].index
    start, end = _energy(first), _energy(last)
    line = (f'energy:      {start:.9g} J at start (segment {first_segment}), {end:.9g} J at '
            f'end (segment {last_segment})')
    if first_segment == last_segment and start:
        line += f', relative change {(end - start) / start:.3g}'
    return [line]


def _impulse_lines(recording, shown=10):
    """How many impulses were recorded and the first few pushes: in a file from before the
    agents' drives were left out (agent_topics), how many were drives (recorded again on
    <name>/drive); since, that its drives are not among them."""
    topic = recording.topic_of('impulse')
    count = recording.topics[topic].message_count if topic in recording.topics else 0
    drive_topics = [name for name, (kind, _, _) in recording.agent_roles.items()
                    if kind == agent_topics.DRIVE]
    drives = sum(recording.topics[name].message_count for name in drive_topics)
    split = f" ({count - drives} pushes, {drives} by the agents' drives)" if drives else ''
    if not drives and _drives_left_out(recording):
        split = (" (pushes; the agents' drives are not recorded: resim makes them again "
                 'from the commands)')
    lines = [f'impulses:    {count}{split}']
    listed = 0
    for message in _pushes(recording, topic, drive_topics) if count > drives else ():
        if listed == shown:
            lines.append(f'  ... and {count - drives - shown} more')
            break
        stamp_ns, frame_id, x, y, _ = decode_vector3_stamped(message.data)
        segment = recording.segments[recording.segment_at(message.log_time_ns)]
        lines.append(f'  segment {segment.index} step {stamp_ns // segment.dt_ns} '
                     f'({_seconds(stamp_ns)}): {_shown(frame_id)} J = ({x:.6g}, {y:.6g}) '
                     'N s')
        listed += 1
    return lines


def _drives_left_out(recording):
    """Whether a segment with agents (named at its start, or recorded) left its drives out."""
    segments = [segment for segment in recording.segments if not segment.drives_recorded]
    return bool(segments) and (bool(recording.agent_roles) or any(
        segment.parameters['agents'] for segment in segments))


def _pushes(recording, topic, drive_topics):
    """The impulse messages that are not an agent's drive, in order: at each log time, the
    impulses whose bytes a drive message of that log time does not claim."""
    group, time = [], None

    def pushes_of(messages):
        claimed = [m.data for m in messages if m.topic != topic]
        for message in messages:
            if message.topic != topic:
                continue
            if message.data in claimed:
                claimed.remove(message.data)
            else:
                yield message

    for message in recording.messages([topic, *drive_topics]):
        if message.log_time_ns != time:
            yield from pushes_of(group)
            group, time = [], message.log_time_ns
        group.append(message)
    yield from pushes_of(group)


def _edit_lines(recording, shown=10):
    """How many world edits of each kind, and the first few: where, what, which ball.

    Every edit is read and checked (as resim and to_rrd check it), so a crafted edit is
    refused here too.
    """
    counts = dict.fromkeys(EDIT_KINDS, 0)
    listed = []
    topic = recording.topic_of('edits')
    recorded = recording.topics[topic].message_count if topic in recording.topics else 0
    for position, step, edit in recording.edits() if recorded else ():
        counts[edit.kind] += 1
        if len(listed) < shown:
            what = {'spawn': f'at ({edit.x:.6g}, {edit.y:.6g}), v ({edit.vx:.6g}, '
                             f'{edit.vy:.6g}), radius {edit.radius:.6g} m, mass '
                             f'{edit.mass:.6g} kg',
                    'set_state': f'to ({edit.x:.6g}, {edit.y:.6g}), v ({edit.vx:.6g}, '
                                 f'{edit.vy:.6g})',
                    'delete': ''}[edit.kind]
            listed.append(f'  segment {recording.segments[position].index} step {step}: '
                          f'{edit.kind} {edit.name} {what}'.rstrip())
    total = sum(counts.values())
    lines = [f'edits:       {total}' + (' (' + ', '.join(
        f'{count} {kind}' for kind, count in counts.items() if count) + ')' if total else '')]
    lines.extend(listed)
    if total > len(listed):
        lines.append(f'  ... and {total - len(listed)} more')
    return lines


def _agent_lines(recording):
    """The agents (each with an odom topic) and how many commands they took, if any."""
    names, commands = [], 0
    for topic, (kind, name, _) in recording.agent_roles.items():
        if kind == agent_topics.ODOM:
            names.append(name)
        elif kind == agent_topics.COMMAND:
            commands += recording.topics[topic].message_count
    if not names:
        return []
    return [f'agents:      {len(names)} ({", ".join(_shown(n) for n in sorted(names))}), '
            f'{commands} commands']


def info_topics_refused(error):
    """Whether _topics_or_none has said why it could not read the recording either."""
    from ball_world.tools import info_topics
    return info_topics.NOT_A_RUN in str(error)


def _topics_or_none(path, error):
    """What a recording of topics holds (ball_world_cli record, ros2 bag record), when the
    error says it is no world run; None when it is something else (the error stands)."""
    from ball_world.tools import info_topics
    if info_topics.NOT_A_RUN not in str(error):
        return None
    try:
        return info_topics.describe(path)
    except RecordingError as refusal:
        print(f'ball_world_info: {path}: {refusal}', file=sys.stderr)
        return None
    except OSError as refusal:
        print(f'ball_world_info: {path}: {refusal.strerror or refusal}', file=sys.stderr)
        return None


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog='ball_world_info', description='Summarise a ball_world recording: MCAP, a bag '
                                            'directory of split files, or Rerun .rrd (a '
                                            'file, or the name of split parts NAME_<i>.rrd).')
    parser.add_argument('file', help='the .mcap recording, a bag directory of split files, an '
                                     '.rrd, or the .rrd name of split parts')
    args = parser.parse_args(argv)
    try:
        if args.file.endswith('.rrd'):
            from ball_world.tools.info_rrd import describe as describe_rrd
            lines = describe_rrd(args.file)
        else:
            lines = describe(open_recording(args.file))
    except RecordingError as error:
        lines = _topics_or_none(args.file, error)
        if lines is None:
            if info_topics_refused(error):
                return 2
            print(f'ball_world_info: {args.file}: {error}', file=sys.stderr)
            return 2
    except ValueError as error:  # an undecodable message
        print(f'ball_world_info: {args.file}: {error}', file=sys.stderr)
        return 2
    except OSError as error:  # an .rrd that is not there, or not a file
        print(f'ball_world_info: {args.file}: {error.strerror or error}', file=sys.stderr)
        return 2
    print_report('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
