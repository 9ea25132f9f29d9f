"""Every parameter of a ball world in one table: name, type, default, range, meaning, when.

Why one table: the node's ROS descriptors, the scenario's defaults, the checks a value must
pass (at start, on `ros2 param set`, and when a recording is read back), the shipped
config/ball_world.yaml and the parameter table of docs/reference.md must never disagree. They
are all derived from, or tested against, PARAMETERS. No ROS here: the offline tools use the
same checks.

A parameter's range is the range the node really runs: `check` refuses anything outside it
with a ParameterError naming the parameter, and every value inside it gives a world that
steps in bounded time and memory (see core.limits), or a refusal at world-building time
that names the parameter (for combinations, such as balls that overlap).
"""
from dataclasses import dataclass
import math
import re
from typing import Any, Callable, Optional

import numpy as np

from ball_world.core import limits

#: How a value is typed in a parameters file or on the command line.
DOUBLE = 'double'
INTEGER = 'integer'
BOOL = 'bool'
STRING = 'string'
DOUBLE_ARRAY = 'double[]'
STRING_ARRAY = 'string[]'

#: When a change takes effect: on the next ~/reset, at once, or never (read-only, set at start).
ON_RESET = 'reset'
AT_ONCE = 'now'
AT_START = 'start'

_INT64_MAX = 2**63 - 1
#: Longest accepted file path.
MAX_PATH_LENGTH = 4096
#: Largest |v| of an explicit ball or of random.speed, m/s (the world's own speed limit, which
#: depends on dt and the radii, is checked when it is built).
MAX_SPEED = 1e6
#: An entity name (core.edits.NAME_PATTERN: the same rule, without importing the edits).
_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*')
#: Most agents a world may have: a swarm's (agent.topics none), which has no topics of its
#: own; 10,000 start, step and stop in seconds (docs/agents.md).
MAX_AGENTS = 10_000
#: Most agents with topics of their own (agent.topics each), the declared limit: each costs
#: a subscription and three publishers, which DDS announces one by one: at 1,000 the node
#: starts in 5-11 s and stops in 3-6 s on a loaded 2-core machine (docs/agents.md); at
#: 3,000 it took 14 s to start and (before the budgeted stop) 72 s to stop.
MAX_AGENTS_EACH = 1_000
#: Largest alpha of agent.odom.noise: a variance of 10 times the motion squared already
#: makes odometry useless; beyond it a value is a mistake.
MAX_ODOMETRY_ALPHA = 10.0


class ParameterError(ValueError):
    """A value that cannot make a valid world; `parameter` names the culprit."""

    def __init__(self, parameter, reason):
        super().__init__(f"parameter '{parameter}': {reason}")
        self.parameter = parameter
        self.reason = reason


def number_text(value):
    """A number as users write it: 0.5, 10, 1e-06; never np.float64(0.5)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return f'{value:,}'
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)


def list_text(values, limit=6):
    """[0.5, 0.1] (shortened past `limit` entries), for refusal messages."""
    shown = ', '.join(number_text(v) for v in list(values)[:limit])
    more = len(values) - limit
    return f'[{shown}{", ..." if more > 0 else ""}]' + (f' ({len(values)} entries)'
                                                        if more > 0 else '')


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) or (
        hasattr(value, 'dtype') and getattr(value, 'shape', None) == ()
        and value.dtype.kind in 'iuf')


@dataclass(frozen=True)
class Parameter:
    """One parameter: its type, default, range, meaning and when it takes effect."""

    name: str
    kind: str
    default: Any
    description: str
    applies: str = ON_RESET
    low: Optional[float] = None  # inclusive bound of the value, or of every array entry
    high: Optional[float] = None
    choices: tuple = ()  # allowed strings
    sizes: Optional[tuple] = None  # allowed array lengths
    multiple_of: int = 1  # array length must be a multiple of this
    max_size: Optional[int] = None  # most array entries
    max_length: Optional[int] = None  # longest string
    rule: Optional[Callable] = None  # more checks of the one value: returns a reason or None
    # The least value but 0 (which turns the feature off): values between are refused.
    least: Optional[float] = None

    @property
    def read_only(self):
        return self.applies == AT_START

    def range_text(self):
        """The range as docs/reference.md and the descriptors state it."""
        if self.choices:
            return ', '.join(self.choices)
        parts = []
        if self.least is not None:
            parts.append(f'0, or {number_text(self.least)} to {number_text(self.high)}')
        elif self.low is not None:
            parts.append(f'{number_text(self.low)} to {number_text(self.high)}')
        if self.sizes is not None:
            parts.append(' or '.join(str(s) for s in self.sizes) + ' entries')
        elif self.max_size is not None:
            parts.append(f'at most {self.max_size:,} entries'
                         + (f', a multiple of {self.multiple_of}' if self.multiple_of > 1
                            else ''))
        if self.max_length is not None:
            parts.append(f'at most {self.max_length} characters')
        return '; '.join(parts)

    def check(self, value):
        """The value in its canonical Python form, or ParameterError saying what is wrong.

        Integers are accepted for doubles (`-p rate_hz:=60`, `arena:=[0, 0, 10, 10]`) and
        converted; anything else of the wrong type is refused.
        """
        if self.kind == DOUBLE:
            if not _is_number(value):
                raise ParameterError(self.name, f'expected a number, got {value!r}')
            return self._check_range(float(value))
        if self.kind == INTEGER:
            if isinstance(value, bool) or not isinstance(value, int):
                if isinstance(value, float) and abs(value) >= 2.0 ** 63:
                    # ROS reads an integer that does not fit in 64 bits as a double: the
                    # digits given are lost, so they are not echoed as if they were read.
                    raise ParameterError(self.name, f'does not fit in a 64-bit integer (got '
                                                    f'about {value:.3g})' + (
                                                        f'; the range is {self.range_text()}'
                                                        if self.low is not None else ''))
                if isinstance(value, float) and value.is_integer():
                    value = int(value)
                else:
                    raise ParameterError(self.name, f'expected a whole number, got {value!r}')
            return self._check_range(int(value))
        if self.kind == BOOL:
            if not isinstance(value, bool):
                raise ParameterError(self.name, f'expected true or false, got {value!r}')
            return value
        if self.kind == STRING:
            value = self._check_string(value)
        elif self.kind == STRING_ARRAY:
            value = self._check_strings(value)
        else:
            value = self._check_array(value)
        reason = self.rule(value) if self.rule is not None else None
        if reason:
            raise ParameterError(self.name, reason)
        return value

    def _check_range(self, value):
        if not math.isfinite(value):
            raise ParameterError(self.name, f'must be finite, got {value}')
        if self.least is not None and value != 0 and not self.least <= value <= self.high:
            raise ParameterError(self.name, f'must be 0 (off), or between '
                                            f'{number_text(self.least)} and '
                                            f'{number_text(self.high)}, got '
                                            f'{number_text(value)}')
        if self.low is not None and not self.low <= value <= self.high:
            raise ParameterError(self.name, f'must be between {number_text(self.low)} and '
                                            f'{number_text(self.high)}, got '
                                            f'{number_text(value)}')
        return value

    def _check_string(self, value):
        if not isinstance(value, str):
            raise ParameterError(self.name, f'expected a string, got {value!r}')
        if self.max_length is not None and len(value) > self.max_length:
            raise ParameterError(self.name, f'is {len(value):,} characters long; at most '
                                            f'{self.max_length} are accepted')
        if any(not character.isprintable() for character in value):
            raise ParameterError(self.name, 'contains control characters')
        if self.choices and value not in self.choices:
            raise ParameterError(self.name, f'expected one of {", ".join(self.choices)}, got '
                                            f'{value[:64]!r}')
        return value

    def _check_strings(self, value):
        if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
            raise ParameterError(self.name, f'expected a list of names, got {value!r:.64}')
        if self.max_size is not None and len(value) > self.max_size:
            raise ParameterError(self.name, f'has {len(value):,} entries; at most '
                                            f'{self.max_size:,} are accepted')
        for index, entry in enumerate(value):
            if not isinstance(entry, str):
                raise ParameterError(self.name, f'entry {index} is not a name: {entry!r:.64}')
            if not _NAME.fullmatch(entry) or len(entry) > limits.MAX_NAME_LENGTH:
                raise ParameterError(self.name, f'entry {index} {entry[:64]!r} is not an entity '
                                                'name (a letter, then letters, digits or '
                                                'underscores)')
        return list(value)

    def _check_array(self, value):
        if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
            raise ParameterError(self.name, f'expected a list of numbers, got {value!r}')
        count = len(value)
        if self.max_size is not None and count > self.max_size:
            raise ParameterError(self.name, f'has {count:,} entries; at most '
                                            f'{self.max_size:,} are accepted')
        if self.sizes is not None and count not in self.sizes:
            expected = ' or '.join(str(s) for s in self.sizes)
            raise ParameterError(self.name, f'expected {expected} numbers, got {count}')
        if count % self.multiple_of:
            raise ParameterError(self.name, f'{count} numbers is not a multiple of '
                                            f'{self.multiple_of}')
        # Vectorised: arrays of 100,000 entries are checked several times per world build.
        if isinstance(value, (list, tuple)) and any(type(entry) is bool for entry in value):
            index = next(i for i, entry in enumerate(value) if type(entry) is bool)
            raise ParameterError(self.name, f'entry {index} is not a number: {value[index]!r}')
        try:
            numbers = np.asarray(value)
        except (TypeError, ValueError):
            numbers = np.asarray(value, dtype=object)
        if numbers.ndim != 1 and count:
            raise ParameterError(self.name, 'expected a flat list of numbers')
        if count and numbers.dtype.kind not in 'iuf':
            index = next((i for i, entry in enumerate(value) if not _is_number(entry)), 0)
            raise ParameterError(self.name, f'entry {index} is not a number: {value[index]!r}')
        numbers = numbers.astype(np.float64).reshape(-1)
        bad = np.flatnonzero(~np.isfinite(numbers))
        if len(bad):
            raise ParameterError(self.name, f'entry {bad[0]} is not finite ({numbers[bad[0]]})')
        if self.low is not None:
            bad = np.flatnonzero(~((self.low <= numbers) & (numbers <= self.high)))
            if len(bad):
                raise ParameterError(self.name, f'entry {bad[0]} is '
                                                f'{number_text(numbers[bad[0]])}; entries must '
                                                f'be between {number_text(self.low)} and '
                                                f'{number_text(self.high)}')
        return numbers.tolist()


def _box(arena):
    if arena and not (arena[0] < arena[2] and arena[1] < arena[3]):
        return f'needs xmin < xmax and ymin < ymax, got {list_text(arena)}'
    return None


def _frame(frame_id):
    if not frame_id.strip():
        return 'must name a frame (tf2 has no empty frame id)'
    if frame_id.endswith('/'):
        return f"{frame_id[:64]!r} ends with '/': a tf2 frame id names a frame, not a prefix"
    return _frame_text(frame_id)


def _prefix(prefix):
    return _frame_text(prefix) if prefix else None


def _frame_text(text):
    """Why `text` cannot begin or be part of a tf2 frame id, or None: tf2 refuses a leading
    '/' (ROS 1's global names), and whitespace or an empty segment ('a//b') would make
    frames that look alike and are not."""
    if text.startswith('/'):
        return (f"{text[:64]!r} starts with '/', which tf2 refuses in a frame id (frames "
                "are not ROS names: write it without the '/')")
    if any(character.isspace() for character in text):
        return f'{text[:64]!r} contains whitespace, which no frame id should'
    if '//' in text:
        return f"{text[:64]!r} has an empty segment ('//')"
    return None


def _controller_spec(spec):
    """Why a controller spec is malformed (MODULE:CLASS or FILE.py:CLASS), or None."""
    if not spec:
        return None
    module, _, name = spec.rpartition(':')
    if not module or not name.isidentifier():
        return "expected 'package.module:Class' or 'path/to/file.py:Class'"
    return None


def _min_max(pair):
    if pair[0] > pair[1]:
        return f'expected [min, max] with min <= max, got {list_text(pair)}'
    return None


_XY = dict(low=-limits.COORDINATE_LIMIT, high=limits.COORDINATE_LIMIT)
_BALLS = dict(max_size=limits.MAX_BALLS)

#: The smallest split a recording takes (record.max_bytes, record.max_seconds) besides 0:
#: each file costs its start (the parameters, the state it resumes from: about 60 bytes a
#: ball), its summary and a new metadata.yaml, and its .rrd part a footer; files of one step
#: each (record.max_bytes 1) made the node fall a third behind its rate. docs/reliability.md
#: has what the node does at these edges.
MIN_SPLIT_BYTES = 1 << 20
MIN_SPLIT_SECONDS = 1.0

PARAMETERS = (
    Parameter('rate_hz', DOUBLE, 60.0, 'Steps per second of wall time; 0 runs as fast as '
              'possible (then dt must be > 0).', AT_ONCE, 0.0, 1e6),
    Parameter('dt', DOUBLE, 0.0, 'Simulated seconds per step, kept in whole nanoseconds (at '
              'least 1 ns); 0 means 1 / rate_hz.', ON_RESET, 0.0, limits.MAX_DT),
    Parameter('max_steps', INTEGER, 0, 'Stop after this many steps, close the recordings and '
              'exit 0; 0 runs until shutdown.', AT_ONCE, 0, _INT64_MAX),
    Parameter('frame_id', STRING, 'world', 'Frame of balls, markers and entity states.', AT_ONCE,
              max_length=limits.MAX_NAME_LENGTH, rule=_frame),
    Parameter('start_paused', BOOL, False, 'Start paused at step 0 (resume with ~/pause '
              'false), so clients can connect before anything moves.', AT_START),
    Parameter('arena', DOUBLE_ARRAY, [0.0, 0.0, 10.0, 10.0], 'xmin, ymin, xmax, ymax of a box '
              'of four walls, m; empty: no box.', sizes=(0, 4), rule=_box, **_XY),
    Parameter('walls', DOUBLE_ARRAY, [], 'More wall segments, flat x1, y1, x2, y2, ... in m.',
              multiple_of=4, max_size=4 * limits.MAX_WALLS, **_XY),
    Parameter('map', STRING, '', "A map in nav2_map_server's format: the YAML's path "
              '(relative to the working directory; its image relative to the YAML). Occupied '
              'cells, and everything outside the image, are solid walls; /map publishes it. '
              "'': no map.", AT_START, max_length=MAX_PATH_LENGTH),
    Parameter('map.unknown_solid', BOOL, True, 'Unknown cells (-1) of the map are solid too (a '
              'map is closed where nobody looked).'),
    Parameter('balls.x', DOUBLE_ARRAY, [], 'Explicit balls: x of each centre, m.', **_BALLS,
              **_XY),
    Parameter('balls.y', DOUBLE_ARRAY, [], 'Explicit balls: y of each centre, m.', **_BALLS,
              **_XY),
    Parameter('balls.vx', DOUBLE_ARRAY, [], 'Explicit balls: x velocity, m/s.', **_BALLS,
              low=-MAX_SPEED, high=MAX_SPEED),
    Parameter('balls.vy', DOUBLE_ARRAY, [], 'Explicit balls: y velocity, m/s.', **_BALLS,
              low=-MAX_SPEED, high=MAX_SPEED),
    Parameter('balls.radius', DOUBLE_ARRAY, [], 'Explicit balls: radius, m.', **_BALLS,
              low=limits.MIN_RADIUS, high=limits.MAX_RADIUS),
    Parameter('balls.mass', DOUBLE_ARRAY, [], 'Explicit balls: mass, kg.', **_BALLS,
              low=limits.MIN_MASS, high=limits.MAX_MASS),
    Parameter('random.count', INTEGER, 20, 'Balls added at random after the explicit ones, '
              'never overlapping anything.', ON_RESET, 0, limits.MAX_BALLS),
    Parameter('random.seed', INTEGER, 0, 'Seed of the random balls (numpy PCG64).', ON_RESET,
              0, _INT64_MAX),
    Parameter('random.radius', DOUBLE_ARRAY, [0.1, 0.3], 'min, max radius of random balls, m.',
              sizes=(2,), low=limits.MIN_RADIUS, high=limits.MAX_RADIUS, rule=_min_max),
    Parameter('random.speed', DOUBLE, 2.0, 'Max initial speed of random balls, m/s.',
              ON_RESET, 0.0, MAX_SPEED),
    Parameter('random.density', DOUBLE, 1.0, 'Mass of a random ball = density x area, kg/m^2.',
              ON_RESET, 1e-6, 1e6),
    Parameter('physics.backend', STRING, 'auto', "How the world steps: 'numpy' (the "
              "reference), 'numba' (compiled, bit-identical) or 'auto' (numba when "
              'installed).', choices=('auto', 'numpy', 'numba')),
    Parameter('physics.mode', STRING, 'seed', "How collisions are found: 'seed' (the rule of "
              'the note the project started from, not random.seed: after the balls moved, '
              "touching and approaching) or 'exact' (every collision at its true time of "
              'impact; needs numba).', choices=('seed', 'exact')),
    Parameter('agents', STRING_ARRAY, [], 'Entity names of the balls that are agents (robots '
              'driven by <name>/cmd_vel), e.g. [ball_0]; at most 1,000 with agent.topics '
              'each.', max_size=MAX_AGENTS),
    Parameter('frame_prefix', STRING, '', "Prefix of the agents' frames (<p><name>/odom, "
              '<p><name>/base_link), so two worlds on one graph do not clash.', AT_START,
              max_length=limits.MAX_NAME_LENGTH, rule=_prefix),
    Parameter('agent.max_speed', DOUBLE, 2.0, 'Agents: the largest commanded speed followed, '
              'm/s.', ON_RESET, 0.0, 1000.0),
    Parameter('agent.max_accel', DOUBLE, 4.0, 'Agents: how fast the velocity follows the '
              'command, m/s^2.', ON_RESET, 0.0, 1e6),
    Parameter('agent.max_yaw_rate', DOUBLE, 3.0, 'Agents: the largest yaw rate followed, '
              'rad/s.', ON_RESET, 0.0, 1000.0),
    Parameter('agent.cmd_timeout', DOUBLE, 0.5, 'Agents: simulated s without a command before '
              'an agent brakes to rest; 0 holds the last command.', ON_RESET, 0.0, 3600.0),
    Parameter('agent.drive', STRING, 'omni', "Agents: 'omni' follows linear.x and linear.y "
              "(holonomic); 'diff' is a differential drive (unicycle): linear.y ignored, the "
              'velocity kept along the heading.', choices=('omni', 'diff')),
    Parameter('agent.odom.noise', DOUBLE_ARRAY, [0.0, 0.0, 0.0, 0.0], 'Agents: alpha1..alpha4 '
              'of the odometry motion model (Probabilistic Robotics 5.4; variances per step): '
              'rotation noise from rotation and from translation, translation noise from '
              'translation and from rotation; seeded by random.seed, the agent and the step. '
              'All 0: odometry is the ground truth.', sizes=(4,), low=0.0,
              high=MAX_ODOMETRY_ALPHA),
    Parameter('agent.odom.rate_hz', DOUBLE, 0.0, 'Agents: odometry, ground truth and their '
              '/tf per second of simulated time; 0: every step.', ON_RESET, 0.0, 1e6,
              least=1e-3),
    Parameter('agent.topics', STRING, 'each', "Agents: 'each' gives every agent its own "
              "topics (cmd_vel, odom, ground_truth, bumper, scan, /tf); 'none' gives them none "
              '(a swarm: balls, state and recordings carry it).', AT_START,
              choices=('each', 'none')),
    Parameter('controller', STRING, '', 'A controller class driving agents beside the '
              "physics, 'package.module:Class' or 'path/to/file.py:Class' (docs/agents.md); "
              "'': none. Read at start only: a set at run time would run code named by anyone "
              'on the graph.', AT_START, max_length=MAX_PATH_LENGTH, rule=_controller_spec),
    Parameter('controller.rate_hz', DOUBLE, 10.0, 'Controller: calls per second of simulated '
              'time.', ON_RESET, 1e-3, 1e6),
    Parameter('controller.agents', STRING_ARRAY, [], 'Controller: the agents it drives ([]: '
              'every agent); those refuse their cmd_vel.', ON_RESET, max_size=MAX_AGENTS),
    Parameter('agent.odom.tf_static', BOOL, True, 'Agents: publish frame_id -> <p><name>/odom '
              '(identity) on /tf_static; false when a localization node (AMCL, slam_toolbox) '
              'publishes map -> odom.'),
    Parameter('agent.cmd_vel_stamped', BOOL, False, 'Agents: take geometry_msgs/msg/'
              'TwistStamped on cmd_vel instead of Twist.', AT_START),
    Parameter('agent.scan.samples', INTEGER, 360, "Agents' lidar: beams per scan; 0: no "
              'scanner.', ON_RESET, 0, 100_000),
    Parameter('agent.scan.angle_min', DOUBLE, -math.pi, "Agents' lidar: first beam, rad, body "
              'frame.', ON_RESET, -2.0 * math.pi, 2.0 * math.pi),
    Parameter('agent.scan.angle_max', DOUBLE, math.pi - 2.0 * math.pi / 360, "Agents' lidar: "
              'last beam, rad, body frame (default pi - 2 pi / 360: one beam per degree).',
              ON_RESET, -2.0 * math.pi, 2.0 * math.pi),
    Parameter('agent.scan.range_min', DOUBLE, 0.0, "Agents' lidar: nearest range, m from the "
              "agent's centre; 0: 0.05 m beyond the agent's radius.", ON_RESET, 0.0,
              limits.COORDINATE_LIMIT),
    Parameter('agent.scan.range_max', DOUBLE, 12.0, "Agents' lidar: farthest range, m from the "
              "agent's centre.", ON_RESET, 0.0, limits.COORDINATE_LIMIT),
    Parameter('agent.scan.rate_hz', DOUBLE, 10.0, "Agents' lidar: scans per second of "
              'simulated time.', ON_RESET, 1e-3, 1e6),
    Parameter('agent.scan.noise_stddev', DOUBLE, 0.01, "Agents' lidar: Gaussian range noise, "
              'm, seeded by random.seed, the agent and the step.', ON_RESET, 0.0, 1000.0),
    Parameter('publish_clock', BOOL, True, 'Publish /clock (simulation time) with each step, '
              'before its /tf, as Gazebo and Stage do: clients with use_sim_time follow it.',
              AT_ONCE),
    Parameter('markers.rate_hz', DOUBLE, 10.0, 'Wall-clock rate of the RViz markers; 0 turns '
              'them off. The node lowers it when markers would take over 5% of its time.',
              AT_ONCE, 0.0, 1000.0),
    Parameter('record.overwrite', BOOL, False, 'Allow recording over an existing file '
              '(otherwise it is refused at start).', AT_START),
    Parameter('record.mcap', STRING, '', 'MCAP file to record to; empty records nothing.',
              AT_START, max_length=MAX_PATH_LENGTH),
    Parameter('record.max_bytes', INTEGER, 0, 'Start a new MCAP file past this size, in '
              'bytes: record.mcap is then a rosbag2 bag directory, and record.rerun is split '
              'at the same steps; 0: one file.', AT_START, 0, _INT64_MAX,
              least=MIN_SPLIT_BYTES),
    Parameter('record.max_seconds', DOUBLE, 0.0, 'Start a new MCAP file past this much '
              'simulated time, s: record.mcap is then a rosbag2 bag directory, and '
              'record.rerun is split at the same steps; 0: one file.', AT_START, 0.0, 1e9,
              least=MIN_SPLIT_SECONDS),
    Parameter('record.max_files', INTEGER, 0, 'Keep at most this many split files (MCAP and '
              '.rrd parts alike; the oldest removed, logged); 0: all.', AT_START, 0,
              1_000_000),
    Parameter('record.rerun', STRING, '', 'Rerun .rrd file to log to; empty logs nothing. '
              'With a split, the parts NAME_0.rrd, NAME_1.rrd, ... beside it.',
              AT_START, max_length=MAX_PATH_LENGTH),
    Parameter('record.rerun_every', INTEGER, 1, 'Log every k-th step to the .rrd (steps with '
              'impulses are always logged).', AT_START, 1, 1_000_000),
    Parameter('view.rerun', STRING, '', "Live Rerun view: '' off, 'spawn' starts the native "
              'viewer, or a rerun+http://HOST:PORT/proxy URL of a running viewer or rerun '
              '--serve-web.', AT_START, max_length=MAX_PATH_LENGTH),
    Parameter('view.recording_id', STRING, '', 'Rerun recording id of the live view, so that '
              'other programs (ball_world_view_tracks) draw into the same recording; empty: '
              "derived from the parameters, as the .rrd's.", AT_START, max_length=256),
    Parameter('rerun.velocities', BOOL, False, 'Rerun: draw velocity arrows (costly for large '
              'worlds).', AT_START),
    Parameter('rerun.trail_seconds', DOUBLE, 0.0, 'Rerun: draw each path over this many '
              'simulated seconds; 0: none (costly for large worlds).', AT_START, 0.0, 10.0),
)

BY_NAME = {parameter.name: parameter for parameter in PARAMETERS}

#: The defaults, as plain Python values.
DEFAULTS = {parameter.name: parameter.default for parameter in PARAMETERS}

#: The six lists that describe explicit balls, one entry per ball in each.
BALL_FIELDS = ('balls.x', 'balls.y', 'balls.vx', 'balls.vy', 'balls.radius', 'balls.mass')


_WHEN_TEXT = {ON_RESET: 'on reset', AT_ONCE: 'at once', AT_START: 'read-only'}


def _default_text(parameter):
    value = parameter.default
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'`{value}`' if value else '""'
    if isinstance(value, list):
        return '[' + ', '.join(str(v) for v in value) + ']'
    return str(value)


def markdown_table():
    """docs/reference.md's parameter table, made from PARAMETERS (a test keeps them equal)."""
    lines = ['| name | type | default | range | takes effect | meaning |',
             '|---|---|---|---|---|---|']
    for parameter in PARAMETERS:
        lines.append(f'| `{parameter.name}` | {parameter.kind} | {_default_text(parameter)} | '
                     f'{parameter.range_text() or "any"} | {_WHEN_TEXT[parameter.applies]} | '
                     f'{parameter.description} |')
    return '\n'.join(lines)


def check(name, value):
    """The canonical value of one parameter, or ParameterError (unknown names included)."""
    parameter = BY_NAME.get(name)
    if parameter is None:
        raise ParameterError(name, 'no such parameter')
    return parameter.check(value)


def checked(values):
    """Every parameter of `values` over the defaults, each checked; unknown names ignored.

    Ignoring unknown names lets a recording made by a newer version with extra parameters be
    read by this one; the node warns about unknown names itself.
    """
    merged = dict(DEFAULTS)
    for name, value in values.items():
        if name in BY_NAME:
            merged[name] = BY_NAME[name].check(value)
    return merged
