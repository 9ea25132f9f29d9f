"""Agents: balls that are robots, driven by body-frame velocity commands (cmd_vel).

Why a module of its own, without ROS: the rule that turns a command into an impulse must be
one piece of code for the live node and for re-simulation, so a recording with agents
re-simulates bit for bit. An agent stays a ball of the seed physics (it collides elastically
and can be pushed); what it adds is a heading and a drive:

- The heading (yaw, rad) is kinematic: collisions do not turn it. Each step it turns by the
  commanded yaw rate (clamped to max_yaw_rate) times dt, kept in [-pi, pi].
- Before each step the drive moves the agent's velocity toward the commanded one: the body
  command (forward, left) is clamped to max_speed, rotated into the world by the heading the
  step ends with (so odometry, taken at the end, sees the commanded body velocity), and the
  change dv is limited to max_accel * dt. It reaches the world
  as an impulse J = m dv through the Simulation's impulse queue, with the same checks as any
  impulse and recorded as one.
- Two drives (agent.drive). `omni` (holonomic, the default) follows forward and left as
  above. `diff` is a differential drive, the unicycle of every wheeled base: `left` is
  ignored, and the velocity is kept along the heading. Its change along the heading (the
  motors) is limited to max_accel * dt; any sideways velocity (a collision of the last step,
  or the old velocity seen from a heading that turned) is removed whole by the same impulse,
  because what stops a wheeled base from sliding sideways is the grip of its wheels, not its
  motors. So after the drive's impulse the velocity is along the heading (to rounding), a
  collision during the step may push it sideways for that step only, and a diff-drive agent
  commanded sideways stays where it is.
- A command is in force for cmd_timeout seconds of simulated time from the step it took
  effect; after that (and before any command) the agent brakes to rest at max_accel and stops
  turning, as turtlesim's turtles do. cmd_timeout 0 holds the last command.

Agents are known by entity name, never by index: spawns and deletions move balls in the
arrays, names stay.
"""
from dataclasses import dataclass
import math
import re

import numpy as np

from ball_world.core.orientation import wrap_yaw
from ball_world.core.parameters import ParameterError

#: Largest |component| of a command taken at all, m/s or rad/s: beyond it a command is a
#: mistake (1e308), not a wish to go fast; refused and counted like a bad impulse.
MAX_COMMAND = 1e6
#: A velocity within this fraction of the target's speed has reached it: v + (m dv) / m may
#: miss the target by an ulp, and chasing that ulp would add an impulse to every step.
_SETTLED = 1e-12
#: The names of the balls a world starts with.
_START_NAME = re.compile(r'ball_(0|[1-9][0-9]{0,8})')
#: since_ns of an agent that has had no command yet.
_NO_COMMAND = -1
#: agent.drive's values: holonomic (today's drive) and differential (a unicycle).
OMNI = 'omni'
DIFF = 'diff'
DRIVES = (OMNI, DIFF)


class CommandRejected(ValueError):
    """A command that must not reach an agent; `reason` is a short key for counting."""

    def __init__(self, reason, detail):
        super().__init__(detail)
        self.reason = reason


@dataclass(frozen=True)
class Limits:
    """How an agent follows its commands: the agent.* parameters."""

    max_speed: float  # m/s
    max_accel: float  # m/s^2
    max_yaw_rate: float  # rad/s
    cmd_timeout: float  # s of simulated time; 0: hold the last command
    drive: str = OMNI  # OMNI or DIFF

    @classmethod
    def from_parameters(cls, parameters):
        return cls(max_speed=parameters['agent.max_speed'],
                   max_accel=parameters['agent.max_accel'],
                   max_yaw_rate=parameters['agent.max_yaw_rate'],
                   cmd_timeout=parameters['agent.cmd_timeout'],
                   drive=parameters.get('agent.drive', OMNI))


@dataclass(frozen=True)
class Command:
    """The last command of an agent: body-frame velocity, yaw rate, and when it took effect."""

    vx: float  # m/s forward
    vy: float  # m/s left
    wz: float  # rad/s counter-clockwise
    since_ns: int  # simulation time of the first step it acted on


def check_command(name, vx, vy, wz):
    """(vx, vy, wz) as floats, or CommandRejected: not finite, or an absurd magnitude."""
    # Written out, not as all() / max() over a generator: a node with 1,000 robots at
    # 10 Hz checks 10,000 commands a second.
    if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(wz)):
        raise CommandRejected('non_finite', f'cmd_vel for {name} is not finite: '
                                            f'({vx}, {vy}, {wz})')
    if abs(vx) > MAX_COMMAND or abs(vy) > MAX_COMMAND or abs(wz) > MAX_COMMAND:
        raise CommandRejected('too_large', f'cmd_vel for {name} ({vx:.3g}, {vy:.3g}, '
                                           f'{wz:.3g}) exceeds {MAX_COMMAND:g} in magnitude')
    return float(vx), float(vy), float(wz)


def body_to_world(yaw, x, y):
    """A body-frame vector (forward, left) in world axes, for heading yaw."""
    c = math.cos(yaw)
    s = math.sin(yaw)
    return c * x - s * y, s * x + c * y


def world_to_body(yaw, x, y):
    """A world-frame vector in body axes (forward, left), for heading yaw."""
    c = math.cos(yaw)
    s = math.sin(yaw)
    return c * x + s * y, -s * x + c * y


def wrapped(yaw):
    """yaw in [-pi, pi] (a number or an array): the same direction, exactly (IEEE remainder,
    core.orientation), a representable range for ever."""
    return wrap_yaw(yaw)


def frames(prefix, name):
    """An agent's (odom frame, body frame): <prefix><name>/odom, <prefix><name>/base_link."""
    return f'{prefix}{name}/odom', f'{prefix}{name}/base_link'


def frame_clash(frame_id, prefix, names):
    """Why frame_id cannot be the frame of the agents `names` under `prefix`, or None.

    frame_id is the parent of every agent's odom frame (/tf_static); were it one of the
    agents' own frames, tf2 would get a transform from a frame to itself, or a loop.
    `names` is any collection of names (a set is fastest).
    """
    if not frame_id.startswith(prefix):
        return None
    name, _, kind = frame_id[len(prefix):].rpartition('/')
    if kind in ('odom', 'base_link') and name in names:
        return (f"'{frame_id[:64]}' is agent {name}'s own frame; frame_id must be a frame "
                'above the agents (world, map)')
    return None


def agent_names(parameters, count):
    """The agents of a new world of `count` balls, checked (ParameterError naming `agents`).

    parameters['agents'] names balls; a world starts with ball_0 to ball_<count - 1>, and
    each name must be one of them, once.
    """
    requested = list(parameters.get('agents', []))
    seen = set()
    for name in requested:
        match = _START_NAME.fullmatch(name)
        if match is None or int(match.group(1)) >= count:
            what = (f'the world starts with ball_0 to ball_{count - 1}' if count
                    else 'the world starts with no balls')
            raise ParameterError('agents', f"no ball named '{name[:64]}' to make an agent; "
                                           f'{what}')
        if name in seen:
            raise ParameterError('agents', f"'{name}' is listed twice")
        seen.add(name)
    clash = frame_clash(parameters.get('frame_id', 'world'),
                        parameters.get('frame_prefix', ''), seen)
    if clash:
        raise ParameterError('frame_id', clash)
    return requested


class Agents:
    """The agents of a world: headings, last commands, and the drive rule.

    Kept as arrays, one row per agent in the order they became agents (the order of odom
    and /tf), so a step of 100 agents costs a few numpy operations, not 100 Python loops.
    Rows move only when an agent is added or removed; names map to rows.
    """

    def __init__(self, names, limits):
        self.limits = limits
        self._names = list(names)
        self._row = {name: row for row, name in enumerate(self._names)}
        count = len(self._names)
        self._yaws = np.zeros(count)
        self._commands = np.zeros((count, 3))  # vx, vy, wz of the last command
        self._since = np.full(count, _NO_COMMAND, dtype=np.int64)
        # Noisy odometry (core.odometry): each agent's odometry pose (x, y, yaw), NaN until it
        # starts at the agent's true pose, and its covariance (odometry.COVARIANCE_ENTRIES).
        self._odometry = np.full((count, 3), np.nan)
        self._covariance = np.zeros((count, 6))
        self.commands_taken = 0

    def __len__(self):
        return len(self._names)

    def __contains__(self, name):
        return name in self._row

    @property
    def names(self):
        """Agent names in the order they became agents (the order of odom and /tf)."""
        return tuple(self._names)

    def yaws(self):
        """Headings in the order of `names`, rad (a copy)."""
        return self._yaws.copy()

    def yaw(self, name):
        return float(self._yaws[self._row[name]])

    def add(self, name, yaw=0.0):
        """Make the ball `name` an agent (a spawn with agent: true)."""
        self._row[name] = len(self._names)
        self._names.append(name)
        self._yaws = np.append(self._yaws, wrapped(float(yaw)))
        self._commands = np.vstack((self._commands, np.zeros((1, 3))))
        self._since = np.append(self._since, np.int64(_NO_COMMAND))
        self._odometry = np.vstack((self._odometry, np.full((1, 3), np.nan)))
        self._covariance = np.vstack((self._covariance, np.zeros((1, 6))))

    def remove(self, name):
        """Forget an agent (its ball was deleted); a name that is no agent is ignored."""
        row = self._row.pop(name, None)
        if row is None:
            return
        del self._names[row]
        self._row = {other: index for index, other in enumerate(self._names)}
        self._yaws = np.delete(self._yaws, row)
        self._commands = np.delete(self._commands, row, axis=0)
        self._since = np.delete(self._since, row)
        self._odometry = np.delete(self._odometry, row, axis=0)
        self._covariance = np.delete(self._covariance, row, axis=0)

    def restore(self, name, yaw, command=None, odometry=None, covariance=None):
        """Make `name` an agent with heading yaw and its last Command, as they were at a
        step of a recorded run (a split file resumes there): both kept bit for bit, and so
        are its noisy odometry's pose (x, y, yaw) and covariance when given."""
        if name not in self._row:
            self.add(name)
        row = self._row[name]
        self._yaws[row] = float(yaw)  # as recorded: wrapping it again could change a bit
        if command is not None:
            self._commands[row] = (command.vx, command.vy, command.wz)
            self._since[row] = int(command.since_ns)
        if odometry is not None:
            self._odometry[row] = odometry
            self._covariance[row] = covariance

    def odometry(self):
        """(poses (A, 3), covariances (A, 6)) of the noisy odometry, copies, agent order."""
        return self._odometry.copy(), self._covariance.copy()

    def start_odometry(self, true_poses):
        """Agents whose odometry has not started (new ones) start at their true pose
        (A, 3), with covariance 0: the odom frame is where the agent was then."""
        fresh = np.isnan(self._odometry[:, 0])
        if fresh.any():
            self._odometry[fresh] = true_poses[fresh]
            self._covariance[fresh] = 0.0

    def set_odometry(self, poses, covariances):
        """The odometry after a step (core.odometry.advance), agent order."""
        self._odometry = poses
        self._covariance = covariances

    def set_yaw(self, name, yaw):
        self._yaws[self._row[name]] = wrapped(float(yaw))

    def command(self, name, vx, vy, wz, since_ns):
        """Take a checked command for agent `name`, in force from the step ending since_ns."""
        row = self._row.get(name)
        if row is None:
            raise CommandRejected('unknown_agent', f"no agent named '{name[:64]}'")
        self._commands[row] = check_command(name, vx, vy, wz)
        self._since[row] = int(since_ns)
        self.commands_taken += 1

    def command_many(self, names, commands, since_ns):
        """Take commands (N, 3) for the agents `names`, in force from the step ending
        since_ns, as N calls of command() would (a name given twice: its last row), but
        checked first and all refused for one bad row (CommandRejected naming it)."""
        rows = [self._row.get(name) for name in names]
        if None in rows:
            name = names[rows.index(None)]
            raise CommandRejected('unknown_agent', f"no agent named '{name[:64]}'")
        self.command_rows(np.array(rows, dtype=np.int64), commands, since_ns)

    def command_rows(self, rows, commands, since_ns):
        """command_many for agents given by their indices in agent order (int64 array), for
        callers that hold every agent's row already (envs.arenas: no name looked up)."""
        commands = np.asarray(commands, dtype=np.float64)
        bad = ~(np.isfinite(commands) & (np.abs(commands) <= MAX_COMMAND)).all(axis=1)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            check_command(self._names[rows[row]], *commands[row].tolist())  # raises, saying why
        self._commands[rows] = commands
        self._since[rows] = int(since_ns)
        self.commands_taken += len(rows)

    def last_command(self, name):
        """The last Command of `name`, or None."""
        row = self._row[name]
        if self._since[row] == _NO_COMMAND:
            return None
        vx, vy, wz = self._commands[row].tolist()
        return Command(vx, vy, wz, int(self._since[row]))

    def _in_force(self, end_ns):
        """Which agents' last command acts in the step ending end_ns (the others brake)."""
        since = self._since
        active = (since != _NO_COMMAND) & (since <= end_ns)
        timeout = self.limits.cmd_timeout
        if timeout > 0.0:
            active &= (end_ns - since) * 1e-9 < timeout
        return active

    def yaw_rates(self, end_ns):
        """The yaw rate (clamped) each agent turns at in the step ending end_ns, rad/s."""
        limit = self.limits.max_yaw_rate
        return np.where(self._in_force(end_ns),
                        np.clip(self._commands[:, 2], -limit, limit), 0.0)

    def headings_after(self, dt_ns, end_ns):
        """The headings at the end of the step ending end_ns (their yaw rates applied)."""
        return wrapped(self._yaws + self.yaw_rates(end_ns) * (dt_ns * 1e-9))

    def impulses(self, velocities, masses, index_of, dt_ns, end_ns):
        """The drive's impulses for the step ending end_ns: [(name, jx, jy)], agent order.

        velocities and masses are the world's arrays (after the impulses that arrived before
        the step), index_of maps names to indices. An agent already at its target gets none.
        """
        if not self._names:
            return []
        rows = np.array([index_of.get(name, -1) for name in self._names], dtype=np.int64)
        due, jx, jy = self.impulse_arrays(velocities, masses, rows, dt_ns, end_ns)
        names = self._names
        due, jx, jy = due.tolist(), jx.tolist(), jy.tolist()
        return [(names[agent], x, y) for agent, x, y in zip(due, jx, jy)]

    def impulse_arrays(self, velocities, masses, rows, dt_ns, end_ns):
        """impulses() as arrays, for callers that step many agents (envs.arenas,
        AgentPart.drive): (the agents due, in agent order, jx, jy); `rows` are the agents'
        indices into velocities and masses (-1: not in the world)."""
        limits = self.limits
        present = rows >= 0
        active = self._in_force(end_ns)
        forward = np.where(active, self._commands[:, 0], 0.0)
        yaws = self.headings_after(dt_ns, end_ns)
        cos, sin = np.cos(yaws), np.sin(yaws)
        moving = velocities[np.where(present, rows, 0)]
        reach = limits.max_accel * (dt_ns * 1e-9)
        if limits.drive == DIFF:
            dvx, dvy, change, target = _unicycle(forward, cos, sin, moving, limits.max_speed,
                                                 reach)
        else:
            left = np.where(active, self._commands[:, 1], 0.0)
            dvx, dvy, change, target = _holonomic(forward, left, cos, sin, moving,
                                                  limits.max_speed, reach)
        mass = masses[np.where(present, rows, 0)]
        due = np.flatnonzero(present & ~(change <= _SETTLED * target))
        return due, mass[due] * dvx[due], mass[due] * dvy[due]

    def turn(self, dt_ns, end_ns):
        """Advance every heading over the step ending end_ns by its clamped yaw rate."""
        self._yaws = self.headings_after(dt_ns, end_ns)


def _holonomic(forward, left, cos, sin, moving, max_speed, reach):
    """omni: (dvx, dvy, |dv| before the limit, target speed) toward the body command.

    The command is clamped to max_speed along its direction, turned into the world by the
    end heading (cos, sin), and the change of velocity limited to `reach` (max_accel dt).
    """
    speed = np.hypot(forward, left)
    fast = speed > max_speed
    scale = np.divide(max_speed, speed, out=np.ones_like(speed), where=fast)
    forward, left = forward * scale, left * scale
    target_x = cos * forward - sin * left
    target_y = sin * forward + cos * left
    dvx = target_x - moving[:, 0]
    dvy = target_y - moving[:, 1]
    change = np.hypot(dvx, dvy)
    over = change > reach
    shrink = np.divide(reach, change, out=np.ones_like(change), where=over)
    return dvx * shrink, dvy * shrink, change, np.hypot(target_x, target_y)


def _unicycle(forward, cos, sin, moving, max_speed, reach):
    """diff: (dvx, dvy, |dv| before the limit, target speed) of a wheeled base.

    Along the heading the speed moves toward `forward` (clamped to max_speed) by at most
    `reach`; across it the velocity is removed whole (the wheels' grip, not the motors).
    """
    forward = np.clip(forward, -max_speed, max_speed)
    along = cos * moving[:, 0] + sin * moving[:, 1]
    across = cos * moving[:, 1] - sin * moving[:, 0]
    gain = np.clip(forward - along, -reach, reach)
    change = np.hypot(forward - along, across)
    dvx = cos * gain + sin * across
    dvy = sin * gain - cos * across
    return dvx, dvy, change, np.abs(forward)
