"""What ball_world_score reads from a world's recording: each scan of an agent, the pose it
was taken from, and the ground truth at it.

For every recorded scan of `<ns>/<agent>/scan`: the balls of that step (`balls`, with the
names and radii of its segment as the recorded edits left them), which of them the scan
could see, and two poses of the scanner:

- `truth_pose`, where the scan was really taken: the agent's recorded
  `<ns>/<agent>/ground_truth` at the scan's step. What the scan could see is computed from
  it (core.lidar.seen_balls: at least one beam, without noise, meets the ball first within
  range, from the agent's centre along its true heading), with the walls and the map's
  cells (scans.scan_grid of the map the recording keeps), exactly as the live scan was.
  With `agent.odom.noise` the odometry, and so /tf, drifts from the truth: ground truth
  never comes from /tf. A recording made before ground truth was recorded had no noisy
  odometry, so its /tf pose is the true one.
- `pose`, what a tracker on the robot is given: the scanner's frame in the world frame,
  looked up in the recorded /tf and /tf_static for exactly the frame the scan names,
  `<frame_prefix><agent>/base_link` (never a frame that merely ends like it: an agent
  named `xball_0` has its own). With noisy odometry it drifts, as a real robot's does.

Each segment (a run between resets) is a sequence of its own, with its own transforms:
stamps start again at 0 after a reset.

The recording is read with the project's bounded reader (recording.mcap_reader): a file
that is not a ball_world recording, cut off or corrupt is a RecordingError with one line.
"""
from dataclasses import dataclass, field

import numpy as np

from ball_world.core import lidar
from ball_world.core.agents import frames as agent_frames
from ball_world.core.orientation import quaternion_to_yaw
from ball_world.msgs.agent_cdr import decode_laser_scan, decode_odometry, decode_tf_message
from ball_world.msgs.cdr import decode_pose_array, decode_vector3_stamped
from ball_world.recording import agent_topics
from ball_world.recording.mcap_reader import (BallRoster, parse_edits, RecordedImpulse,
                                              RecordedStep, RecordingError,
                                              snapshot_and_info)
from ball_world.recording.mcap_writer import EVENT_ROLES
from ball_world.recording.recording_set import open_recording
from ball_world.scans import fan_from, scan_grid
from ball_world.scoring.planar_tf import PlanarTransforms, TransformError, yaw_of


@dataclass(frozen=True)
class RecordedScan:
    """One scan of the agent, with its step's balls and what it could see."""

    step: int
    stamp_ns: int
    message: object  # agent_cdr.DecodedScan
    pose: tuple  # (x, y, yaw) of the scanner's frame in the world frame, as /tf has it
    names: tuple  # the balls of the step
    positions: np.ndarray  # (N, 2)
    radii: np.ndarray  # (N,)
    visible: np.ndarray  # (N,) bool
    # (x, y, yaw) where the scan was really taken (ground truth): `pose` drifts from it with
    # agent.odom.noise
    truth_pose: tuple = None


@dataclass
class RecordedSegment:
    """The scans of one segment and the transforms recorded in it."""

    index: int
    world_frame: str
    scan_frame: str  # <frame_prefix><agent>/base_link
    transforms: PlanarTransforms
    walls: np.ndarray = None  # (M, 4) wall segments, for drawing
    occupancy_map: object = None  # the recorded map (core.occupancy_map), for drawing
    scans: list = field(default_factory=list)


def add_transforms(transforms, data, static=False):
    """Every transform of a TFMessage's bytes into `transforms` (ValueError if malformed)."""
    decoded = decode_tf_message(data)
    for stamp, parent, child, row in zip(decoded.stamps_ns, decoded.frame_ids,
                                         decoded.child_frame_ids, decoded.transforms):
        transforms.add(parent, child, stamp, row[0], row[1], yaw_of(*row[3:7]), static)


def read_run(path, agent):
    """[RecordedSegment] of `agent`'s scans in the recording at `path` (a file or a bag
    directory); RecordingError with one line for anything that cannot be scored.

    One pass over the topics it needs (balls, impulses and edits, /tf, /tf_static, the
    scans), decoding the balls only at the scans: a 10-minute run is read in seconds.
    """
    recording = open_recording(path)
    scan_topics = set()
    for segment in recording.segments:
        namespace = agent_topics.namespace_of(segment.topics)
        scan_topics.add(f'{namespace}/{agent}/{agent_topics.SCAN}')
    if not scan_topics & set(recording.topics):
        agents = sorted({topic.rsplit('/', 2)[-2] for topic in recording.topics
                         if topic.endswith(f'/{agent_topics.SCAN}')})
        known = f"its scanning agents: {', '.join(agents)}" if agents else \
            'it has no scans (no agents, or agent.scan.samples 0)'
        raise RecordingError(f'no scan of {agent!r} ({agent}/scan); {known}')
    segments = [RecordedSegment(index=segment.index, world_frame=segment.frame_id,
                                scan_frame=agent_frames(segment.parameters['frame_prefix'],
                                                        agent)[1],
                                transforms=PlanarTransforms())
                for segment in recording.segments]
    roles = {topic: role for topic, role in recording.roles.items()
             if role == 'balls' or role in EVENT_ROLES}
    roles.update({topic: 'scan' for topic in scan_topics})
    roles.update({topic.rpartition('/')[0] + '/' + agent_topics.GROUND_TRUTH: 'truth'
                  for topic in scan_topics if topic.rpartition('/')[0] + '/'
                  + agent_topics.GROUND_TRUTH in recording.topics})
    roles.update({agent_topics.TF_TOPIC: 'tf', agent_topics.TF_STATIC_TOPIC: 'tf_static'})
    reader = _Reader(recording, segments, agent)
    for message in recording.messages(list(roles)):
        reader.add(roles[message.topic], message)
    reader.finish()
    found = [segment for segment in segments if segment.scans]
    if not found:
        raise RecordingError(f'no scan of {agent!r} was recorded with its step')
    return found


class _Reader:
    """The messages of one log time gathered, then turned into the roster's changes, the
    transforms and, at a scan, a RecordedScan."""

    def __init__(self, recording, segments, agent):
        self.recording = recording
        self.segments = segments
        self.agent = agent
        self.log_time_ns = None
        self.current = self.roster = self.walls = self.grid = None
        self.group = {}

    def add(self, role, message):
        if message.log_time_ns != self.log_time_ns:
            self.finish()
            self.log_time_ns = message.log_time_ns
        self.group.setdefault(role, []).append(message.data)

    def finish(self):
        if not self.group:
            return
        group, self.group = self.group, {}
        log_time = self.log_time_ns
        try:
            self._take(group, log_time)
        except ValueError as error:
            raise RecordingError(f'a message at log time {log_time} ns does not decode: '
                                 f'{error}') from None

    def _take(self, group, log_time):
        recording = self.recording
        position = recording.segment_at(log_time)
        described = recording.segments[position]
        segment = self.segments[position]
        if position != self.current:
            self.current = position
            snapshot, _ = snapshot_and_info(described)
            self.roster = BallRoster(snapshot, described.index)
            self.walls = segment.walls = snapshot.walls
            segment.occupancy_map = snapshot.occupancy_map
            self.grid = scan_grid(described.parameters, snapshot.occupancy_map)
        stamp = log_time - described.log_offset_ns
        step = stamp // described.dt_ns
        impulses = tuple(RecordedImpulse(*decode_vector3_stamped(data), cdr=data)
                         for data in group.get('impulse', ()))
        edits = group.get('edits', ())
        if impulses or edits:
            try:
                applied = parse_edits(edits, len(impulses))
            except RecordingError as error:
                raise RecordingError(f'segment {described.index} step {step}: recorded '
                                     f'{error}') from None
            self.roster.follow(RecordedStep(
                segment=position, step=step, stamp_ns=stamp, log_time_ns=log_time,
                positions=None, state=None, stats=None, impulses=impulses, balls_cdr=None,
                state_cdr=None, stats_cdr=None, balls_stamp_ns=None, edits=applied))
        for data in group.get('tf_static', ()):
            add_transforms(segment.transforms, data, static=True)
        for data in group.get('tf', ()):
            add_transforms(segment.transforms, data)
        if 'scan' in group and 'balls' in group:
            positions = decode_pose_array(group['balls'][-1])[2]
            truth = group.get('truth', (None,))[-1]
            segment.scans.append(_scan_of(step, positions, decode_laser_scan(group['scan'][-1]),
                                          truth, self.roster, (self.walls, self.grid), segment,
                                          self.agent, described.parameters))


def _scan_of(step, positions, message, truth, roster, geometry, segment, agent, parameters):
    if len(positions) != len(roster):
        raise RecordingError(f'step {step} has {len(positions)} balls, not {len(roster)}')
    if message.frame_id != segment.scan_frame:
        raise RecordingError(f'the scan of step {step} is in frame '
                             f'{message.frame_id!r}, not {segment.scan_frame!r}')
    try:
        index = roster.names.index(agent)
    except ValueError:
        raise RecordingError(f'{agent!r} is no ball at step {step}') from None
    try:
        pose = segment.transforms.lookup(segment.world_frame, segment.scan_frame,
                                         message.stamp_ns)
    except TransformError as error:
        raise RecordingError(f'no pose of the scan of step {step}: {error}') from None
    if truth is not None:
        truth_pose = true_pose(truth, segment.scan_frame, message.stamp_ns)
    elif any(parameters['agent.odom.noise']):
        raise RecordingError(f'no {agent}/{agent_topics.GROUND_TRUTH} at the scan of step '
                             f'{step}: with agent.odom.noise /tf is not the true pose')
    else:  # recorded before ground truth was: odometry then was the truth
        truth_pose = pose
    return scan_at(step, message, pose, truth_pose, roster.names, positions, roster.radii,
                   geometry, index, parameters)


def true_pose(data, base_frame, stamp_ns):
    """(x, y, yaw) of a recorded `<name>/ground_truth` (nav_msgs/Odometry bytes) of frame
    `base_frame` at `stamp_ns`; ValueError when it is not that."""
    truth = decode_odometry(data)
    if truth.child_frame_id != base_frame or truth.stamp_ns != stamp_ns:
        raise ValueError(f'the ground truth of {truth.child_frame_id!r} at {truth.stamp_ns} ns '
                         f'is not that of {base_frame!r} at {stamp_ns} ns')
    quaternion_to_yaw(truth.pose[3:7])  # ValueError unless a rotation about z
    # the yaw as /tf's is read (planar_tf), so that an odometry without noise gives /tf a
    # pose equal to this one, bit for bit
    return float(truth.pose[0]), float(truth.pose[1]), yaw_of(*truth.pose[3:7])


def scan_at(step, message, pose, truth_pose, names, positions, radii, geometry, index,
            parameters):
    """The RecordedScan of agent `index`'s scan `message`, taken from `truth_pose` (given to
    a tracker as `pose`) among these balls: which of them it could see past the walls and
    the map's cells, geometry = (walls, scans.scan_grid) (the same computation for a
    recording and for the benchmark's simulated scenes, so the two score alike)."""
    walls, grid = geometry
    fan = fan_from(parameters, float(radii[index]))
    seen = lidar.seen_balls(positions, radii, walls, positions[index], truth_pose[2], fan,
                            index, grid)
    visible = np.zeros(len(positions), dtype=bool)
    visible[seen] = True
    return RecordedScan(step=step, stamp_ns=message.stamp_ns, message=message, pose=pose,
                        names=tuple(names), positions=positions, radii=radii,
                        visible=visible, truth_pose=truth_pose)
