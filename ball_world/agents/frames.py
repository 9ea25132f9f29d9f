"""The agents' messages of a step, as bytes: odometry, ground truth, /tf, /tf_static, bumpers.

Why apart from the part that steps them (agents.part): what an agent *is* after a step
(arrays: poses, headings, twists, contact impulses, the odometry's state) and how it is
*said* on ROS topics (REP 105 frames, body-frame twists, CDR made once for publishers and
recordings alike, msgs.agent_cdr) change for different reasons. Everything here is a pure
function of arrays and names.
"""
import numpy as np

from ball_world.core import odometry
from ball_world.core.agents import frames
from ball_world.msgs.agent_cdr import encode_odometry, encode_tf_message
from ball_world.msgs.impulse_batch import encode_impulses
from ball_world.step_record import Bumper

#: The per-agent messages a step can make, each encoded only when someone takes it
#: (AgentPart.encode): odom, ground_truth, /tf, bumper, scan.
ODOM = 'odom'
GROUND_TRUTH = 'ground_truth'
TF = 'tf'
BUMPER = 'bumper'
SCAN = 'scan'
KINDS = frozenset((ODOM, GROUND_TRUTH, TF, BUMPER, SCAN))


class FrameNames:
    """Each agent's frames under a prefix: <p><name>/odom, <p><name>/base_link, and the world
    frame (frame_id) repeated, made again only when the agents or frame_id changed (the node
    may change frame_id between steps)."""

    def __init__(self, prefix):
        self.prefix = prefix
        self._key = None
        self.odom = self.base = self.world = ()

    def update(self, names, frame_id):
        """Make the names for `names` under frame_id; True when they changed (a new set of
        agents, or a new frame_id: /tf_static is then said again)."""
        key = (names, frame_id)
        if self._key == key:
            return False
        pairs = [frames(self.prefix, name) for name in names]
        self._key = key
        self.odom = tuple(pair[0] for pair in pairs)
        self.base = tuple(pair[1] for pair in pairs)
        self.world = (frame_id,) * len(names)
        return True


def body_twists(yaws, velocities, yaw_rates):
    """(A, 3) twists in the body frame (REP 105): the world velocity (A, 2) turned by -yaw,
    and the yaw rate of the step that just ended."""
    cos, sin = np.cos(yaws), np.sin(yaws)
    twists = np.empty((len(yaws), 3))
    twists[:, 0] = cos * velocities[:, 0] + sin * velocities[:, 1]
    twists[:, 1] = cos * velocities[:, 1] - sin * velocities[:, 0]
    twists[:, 2] = yaw_rates
    return twists


def tf_static(stamp_ns, names):
    """/tf_static: frame_id -> each agent's odom frame, identity (FrameNames)."""
    count = len(names.odom)
    return encode_tf_message(stamp_ns, names.world, names.odom, np.zeros((count, 2)),
                             np.zeros(count))


def ground_truth(stamp_ns, names, positions, yaws, twists):
    """nav_msgs/Odometry of each agent's true pose and twist, in frame_id."""
    return tuple(encode_odometry(stamp_ns, names.world, names.base, positions, yaws, twists))


def odometry_messages(stamp_ns, names, positions, yaws, twists, covariances=None,
                      twist_covariances=None):
    """nav_msgs/Odometry of each agent in its odom frame (covariances (A, 36) or zeros)."""
    return tuple(encode_odometry(stamp_ns, names.odom, names.base, positions, yaws, twists,
                                 covariances, twist_covariances))


def tf_message(stamp_ns, names, positions, yaws):
    """/tf: every agent's odom -> base_link in one TFMessage."""
    return encode_tf_message(stamp_ns, names.odom, names.base, positions, yaws)


def noisy_twists(twists, advanced):
    """(twists, their (A, 36) covariances) the noisy odometry reports: the true body twists
    plus the error of the step that ended here (advanced: its core.odometry.Step), or the
    true ones with covariance 0 when that step is not known for these agents (None: a new
    world, a spawn: agents that had just started at their true pose)."""
    if advanced is None:
        return twists, np.zeros((len(twists), 36))
    return (twists + advanced.twist_errors,
            odometry.message_covariance(advanced.twist_covariances))


def bumpers(names, base_frames, yaws, impulses, stamp_ns, encode=True):
    """The Bumpers of the agents that took a collision impulse (impulses (A, 2), world
    frame), in their base_link frames at the step's end headings (agent order); their bytes
    b'' unless `encode`."""
    hit = np.flatnonzero((impulses != 0.0).any(axis=1))
    if not len(hit):
        return ()
    cos, sin = np.cos(yaws[hit]), np.sin(yaws[hit])
    jx, jy = impulses[hit, 0], impulses[hit, 1]
    return Bumpers(names, base_frames, hit, cos * jx + sin * jy, cos * jy - sin * jx,
                   stamp_ns, encode)


class Bumpers:
    """A step's Bumper of each agent hit (agent order), a sequence whose Bumpers (and their
    bytes) are made the first time someone reads one.

    Why not at once: in a crowd of robots a third of them are hit every step, and making
    300 Bumpers (frozen dataclasses) and their bytes took 0.3-0.4 ms of a 1.4 ms step
    (1,000 lidar robots in the warehouse) that nobody reads when nobody listens to
    <name>/bumper, draws bumper_markers or records (a controller sees the impulses as
    arrays, agents.control). Two threads reading at once make the same tuple twice, one of
    which is kept: harmless. Plain data, so it pickles as a tuple would.
    """

    __slots__ = ('_names', '_base_frames', '_hit', '_forward', '_left', '_stamp_ns',
                 '_encode', '_made')

    def __init__(self, names, base_frames, hit, forward, left, stamp_ns, encode):
        self._names = names
        self._base_frames = base_frames
        self._hit = hit
        self._forward = forward
        self._left = left
        self._stamp_ns = stamp_ns
        self._encode = encode
        self._made = None

    def _all(self):
        made = self._made
        if made is None:
            rows = self._hit.tolist()
            forward = self._forward.tolist()
            left = self._left.tolist()
            frames_hit = [self._base_frames[row] for row in rows]
            messages = (encode_impulses(self._stamp_ns, frames_hit, forward, left)
                        if self._encode else [b''] * len(rows))
            made = self._made = tuple(
                Bumper(self._names[row], frame, x, y, cdr)
                for row, frame, x, y, cdr in zip(rows, frames_hit, forward, left, messages))
        return made

    def __len__(self):
        return len(self._hit)

    def __iter__(self):
        return iter(self._all())

    def __getitem__(self, index):
        return self._all()[index]

    def __eq__(self, other):
        if isinstance(other, (tuple, Bumpers)):
            return tuple(self) == tuple(other)
        return NotImplemented

    __hash__ = None  # (equal to a tuple, but made lazily: not a key)

    def __repr__(self):
        return f'Bumpers{self._all()!r}'
