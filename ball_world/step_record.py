"""What the node hands to its sinks (MCAP recording, Rerun logging) after each step.

The flow is one-directional: the node steps the World, packs one StepRecord, and every sink
writes it. Sinks never touch the World or ROS, so the offline converter can feed them from a
recording exactly as the live node does.
"""
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple, Optional, Protocol

import numpy as np

PACKAGE_NAME = 'ball_world'

#: The entries of the per-step `stats` topic, in order; its layout has one dim per entry,
#: labelled with these names. real_time_factor is NaN where unknown (offline runs, the
#: first step).
STATS_FIELDS = ('kinetic_energy', 'momentum_x', 'momentum_y', 'ball_ball', 'ball_wall',
                'real_time_factor')


@dataclass(frozen=True)
class AppliedImpulse:
    """An impulse the node accepted and applied before a step."""

    ball: int
    jx: float  # N*s along world x
    jy: float  # N*s along world y
    frame_id: str  # 'ball_<i>', as it arrived
    # the Vector3Stamped as recorded on `impulse`: CDR, header.stamp = sim time of the step
    # (a drive's is never recorded, recording.agent_topics; b'' for a swarm's drive)
    cdr: bytes
    # An agent's own drive (core.agents: its cmd_vel turned into an impulse), not a push from
    # outside; views draw and count the two apart.
    drive: bool = False


@dataclass(frozen=True)
class AppliedEdit:
    """A world edit (spawn, delete, set_state) the node applied between two steps.

    It is recorded, and published on `edits`, as `text`: one JSON object with every field
    below, so a recording re-simulates exactly and any tool can read it. impulses_before
    is how many of the step's impulses were applied before this edit (edits are applied
    when their service is called; impulses when the step comes or an edit forces them).
    """

    kind: str  # 'spawn', 'delete' or 'set_state'
    name: str  # the entity's name
    x: float = 0.0  # spawn, set_state: centre, m
    y: float = 0.0
    vx: float = 0.0  # spawn, set_state: velocity, m/s
    vy: float = 0.0
    radius: float = 0.0  # spawn: m
    mass: float = 0.0  # spawn: kg
    impulses_before: int = 0
    text: str = ''  # the JSON document as recorded and published
    agent: bool = False  # spawn: the ball is an agent (the JSON has 'agent': true)
    yaw: Optional[float] = None  # set_state of an agent: its heading, rad (JSON 'yaw')


@dataclass(frozen=True)
class AppliedCommand:
    """A velocity command an agent took (core.agents), in force from the step it is recorded
    with: body frame, as received on <name>/cmd_vel (cdr: the message's bytes, or b'')."""

    name: str  # the agent's entity name
    vx: float  # m/s forward
    vy: float  # m/s left
    wz: float  # rad/s
    cdr: bytes = b''


class DriveBatch(NamedTuple):
    """The agents' drives of a step, applied together (Simulation._apply_at_once): the
    balls' rows, the impulses (N s, world frame) and the agents' names; stamp_ns, the step's
    stamp, for their Vector3Stamped bytes (agent.topics each: made only when read, `cdrs`;
    no recording holds them, recording.agent_topics), None for a swarm's (no bytes)."""

    balls: list
    jx: list
    jy: list
    names: list
    stamp_ns: Optional[int] = None

    def cdrs(self):
        """The drives' Vector3Stamped bytes, as <name>/drive held them in recordings made
        before drives were left out (b'' for a swarm)."""
        if self.stamp_ns is None:
            return [b''] * len(self.names)
        from ball_world.msgs.impulse_batch import encode_impulses
        return encode_impulses(self.stamp_ns, self.names, self.jx, self.jy)


class _Batched(Sequence):
    """A step's items in order, kept as single items (`single`, a class) and batches whose
    items are made only when someone iterates (AppliedImpulses, TakenCommands)."""

    __slots__ = ('_parts', '_length')
    single = None

    def __init__(self, parts):
        self._parts = tuple(parts)
        self._length = sum(1 if isinstance(part, self.single) else self._batch_length(part)
                           for part in self._parts)

    @property
    def parts(self):
        return self._parts

    def __len__(self):
        return self._length

    def __getitem__(self, index):
        return tuple(self)[index]

    def __eq__(self, other):
        return isinstance(other, (tuple, type(self))) and tuple(self) == tuple(other)

    __hash__ = None


class AppliedImpulses(_Batched):
    """The impulses applied before a step, in order, as AppliedImpulses: single ones and the
    agents' drives (DriveBatch), whose AppliedImpulses (drive=True) and bytes are made only
    when someone reads them. Why: as TakenCommands (a node of 1,000 robots at 100 Hz spent
    a quarter of its step making 1,000 objects a step that nobody but a recording reads);
    `pushes()` gives the others without making them, `parts` the batches as they are.
    """

    __slots__ = ()
    single = AppliedImpulse

    @staticmethod
    def _batch_length(part):
        return len(part.balls)

    def pushes(self):
        """The impulses that are not batched drives (of either agent.topics), in order."""
        return tuple(part for part in self._parts if isinstance(part, AppliedImpulse))

    def __iter__(self):
        for part in self._parts:
            if isinstance(part, AppliedImpulse):
                yield part
                continue
            for ball, jx, jy, name, cdr in zip(part.balls, part.jx, part.jy, part.names,
                                               part.cdrs()):
                yield AppliedImpulse(ball=ball, jx=jx, jy=jy, frame_id=name, cdr=cdr,
                                     drive=True)


def impulses_of(parts):
    """parts (AppliedImpulse and DriveBatch) as a record holds them: a tuple when every
    part is one impulse (as always before swarms), else AppliedImpulses."""
    if all(isinstance(part, AppliedImpulse) for part in parts):
        return tuple(parts)
    return AppliedImpulses(parts)


class TakenCommands(_Batched):
    """The commands taken before a step, in order, as AppliedCommands: single ones (a
    cmd_vel message) and batches (a swarm's controller: names and an (N, 3) array), each
    batch's AppliedCommands made only when someone reads them.

    Why: a 10,000-robot swarm's controller gives 10,000 commands a call; its recording
    holds them as one message of rows (AgentFrame.command_rows, made from the batches
    directly), so most steps nobody reads them one by one, and making 10,000 objects a step
    for nobody cost more than the step itself.
    """

    __slots__ = ()
    single = AppliedCommand  # or a batch: (names, (N, 3) float64 array)

    @staticmethod
    def _batch_length(part):
        return len(part[0])

    def __iter__(self):
        for part in self._parts:
            if isinstance(part, AppliedCommand):
                yield part
                continue
            names, commands = part
            for name, (vx, vy, wz) in zip(names, commands.tolist()):
                yield AppliedCommand(name, vx, vy, wz)


@dataclass(frozen=True)
class Bumper:
    """The collision impulse an agent took in a step (balls, walls, map cells; its drive and
    pushes excluded), N s, in its base_link frame at the step's end heading."""

    name: str  # the agent's entity name
    frame_id: str  # <p><name>/base_link
    x: float  # forward
    y: float  # left
    cdr: bytes  # geometry_msgs/msg/Vector3Stamped, as published on <name>/bumper


@dataclass(frozen=True)
class AgentFrame:
    """The agents at the end of a step: names, rows in the arrays, headings (rad)."""

    names: tuple  # entity names, in the order of odom and /tf
    indices: np.ndarray  # (A,) rows of positions and velocities
    yaws: np.ndarray  # (A,) headings, rad, in [-pi, pi]
    twists: np.ndarray  # (A, 3) vx, vy in the body frame (m/s), yaw rate (rad/s)
    odom_frames: tuple  # <p><name>/odom of each agent
    base_frames: tuple  # <p><name>/base_link of each agent
    # nav_msgs/Odometry of each agent, CDR, as published on <name>/odom: the ground truth
    # without agent.odom.noise, the drifting odometry with it (core.odometry). Empty (and
    # so are tf_cdr and ground_truth_cdr) at a step agent.odom.rate_hz skips, with
    # agent.topics none, and for a kind nobody takes (AgentPart.encode).
    odom_cdr: tuple
    tf_cdr: bytes  # tf2_msgs/TFMessage: every odom -> base_link (odom's poses), on /tf
    # /tf_static (frame_id -> each odom frame, identity) when the set of agents changed with
    # this record (a segment's first record included), else None.
    tf_static_cdr: Optional[bytes] = None
    # The agents' lidar scans (ball_world.scans.AgentScan) when this step is a scan step.
    scans: tuple = ()
    # nav_msgs/Odometry of each agent's true pose and twist (header frame_id, child
    # base_link), as published on <name>/ground_truth; () where not known (read back from
    # an older recording).
    ground_truth_cdr: tuple = ()
    # Bumper of each agent hit in the step that ended here, agent order (none at step 0): a
    # sequence (agents.frames.Bumpers, made at its first read) or a tuple.
    bumpers: tuple = ()
    # With agent.odom.noise: the odometry's state after this step, agent order: poses (A, 3)
    # x, y, yaw and covariances (A, 6) (core.odometry), which a split file resumes from.
    odometry: Optional[np.ndarray] = None
    odometry_covariances: Optional[np.ndarray] = None
    # agent.topics: True ('each') when the agents have topics of their own; False for a
    # swarm ('none'), whose frame carries no per-agent bytes at all.
    topics: bool = True
    # A swarm's commands taken before this step, (K, 4) rows (ball, vx, vy, wz), ball the
    # row in `balls`: recorded as one message (recording.agent_topics); None with topics.
    command_rows: Optional[np.ndarray] = None


@dataclass(frozen=True)
class WorldSnapshot:
    """The static part of a world: what sinks need once per segment (start or reset)."""

    radii: np.ndarray  # (N,)
    masses: np.ndarray  # (N,)
    walls: np.ndarray  # (M, 4) x1, y1, x2, y2
    positions: np.ndarray  # (N, 2) at step 0
    velocities: np.ndarray  # (N, 2) at step 0
    dt_ns: int
    frame_id: str
    names: Optional[tuple] = None  # entity names in pose order (ball_<i> when None)
    # The map (core.occupancy_map.OccupancyMap: its files' bytes and its grid) and its
    # nav_msgs/OccupancyGrid bytes as published on `map` at the segment start; None without.
    occupancy_map: Optional[object] = None
    map_cdr: Optional[bytes] = None


@dataclass(frozen=True)
class RunInfo:
    """Everything a sink needs to label a segment of a run.

    parameters: the node's effective parameters (name -> plain Python value), enough to
    rebuild the same world. topics: logical name ('balls', 'state', 'impulse') -> resolved
    ROS topic name ('/balls', '/sim2/balls', ...). segment: 0 at start, +1 on every reset.
    log_offset_ns: added to the simulation stamp to get a log time that never decreases
    across resets.
    """

    parameters: dict
    topics: dict
    segment: int
    log_offset_ns: int
    package_version: str
    backend: str = ''  # the backend physics.backend resolved to (auto: numba or numpy)
    # A split file that continues the segment: the metadata values saying from where
    # (recording.resume.resume_metadata); None where the segment starts.
    resume: Optional[dict] = None


@dataclass(frozen=True)
class StepRecord:
    """One step's output. Arrays are owned by the record (copies), never the live World."""

    step: int  # k: this record is the state at the end of step k (k = 0: initial state)
    stamp_ns: int  # simulation time k * dt, integer nanoseconds
    log_time_ns: int  # stamp_ns + segment log offset: never decreases within a recording
    positions: np.ndarray  # (N, 2)
    velocities: np.ndarray  # (N, 2)
    ball_ball: int  # ball-ball collisions resolved in this step
    ball_wall: int  # ball-wall collisions resolved in this step
    kinetic_energy: float  # J
    momentum: np.ndarray  # (2,) kg*m/s
    balls_cdr: bytes  # geometry_msgs/PoseArray, CDR, as published
    state_cdr: bytes  # std_msgs/Float64MultiArray, CDR, as published
    stats_cdr: bytes  # std_msgs/Float64MultiArray, CDR: STATS_FIELDS in order, as published
    impulses: tuple = field(default_factory=tuple)  # AppliedImpulse applied before this step
    real_time_factor: Optional[float] = None  # simulated / wall time, when known
    edits: tuple = field(default_factory=tuple)  # AppliedEdit applied before this step
    # The balls in pose order: entity names, radii and masses. They change only with edits
    # (world_changed is then True for the first step after them); unchanged, the same
    # objects are handed on, so a record costs nothing more.
    names: Optional[tuple] = None
    radii: Optional[np.ndarray] = None
    masses: Optional[np.ndarray] = None
    world_changed: bool = False
    # Agents (core.agents): None in a world without agents, so its records are as before.
    agents: Optional[AgentFrame] = None
    # Exact mode, for a sink that asks (wants_carried_state, a split recording): what this
    # step hands the next (core.exact_carry.CarriedState), so a file may resume after it.
    exact: Optional[object] = None
    commands: tuple = field(default_factory=tuple)  # AppliedCommand taken before this step


@dataclass(frozen=True)
class PendingEvents:
    """Impulses and edits applied after a segment's last step, handed over when it ends.

    A world edited (or pushed by an impulse that an edit applied) after its last step has
    no step record to carry the change: pause, step, spawn, then quit or reset. So that a
    recording still holds every change the world made, Simulation.close() and reset() hand
    these to the sinks that take them (write_pending), stamped like the step they would
    have preceded. In an MCAP they are that step's impulse and edit messages without its
    balls, state and stats (a closing record); the tools read them as such.
    """

    step: int  # the step they would have preceded
    stamp_ns: int  # its simulation time
    log_time_ns: int  # its log time (simulation time plus the segment's offset)
    impulses: tuple = field(default_factory=tuple)  # AppliedImpulse, in the order applied
    edits: tuple = field(default_factory=tuple)  # AppliedEdit, in order (impulses_before)


class Sink(Protocol):
    """A destination for a run: the MCAP recorder and the Rerun logger implement this."""

    def start_segment(self, world: WorldSnapshot, info: RunInfo) -> None:
        """Begin a segment: called once at start and again after every reset."""

    def write_step(self, record: StepRecord) -> None:
        """Write one step; must not block for long (the node calls it on its stepping path)."""

    def flush(self) -> None:
        """Make everything written so far durable (called about once a second)."""

    # Optional: def write_pending(self, events: PendingEvents) -> None, for sinks that record
    # edits made after a segment's last step (the MCAP recorder); the others never see them.

    def close(self) -> None:
        """Finish the file so every reader opens it (summary, index, footer)."""
