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
- A command is in force for cmd_timeout seconds of simulated time from the step it took
  effect; after that (and before any command) the agent brakes to rest at max_accel and stops
  turning, as turtlesim's turtles do. cmd_timeout 0 holds the last command.

Agents are known by entity name, never by index: spawns and deletions move balls in the
arrays, names stay.
"""
from dataclasses import dataclass
import math
import re

from ball_world.core.parameters import ParameterError

#: Largest |component| of a command taken at all, m/s or rad/s: beyond it a command is a
#: mistake (1e308), not a wish to go fast; refused and counted like a bad impulse.
MAX_COMMAND = 1e6
_TWO_PI = 2.0 * math.pi
#: A velocity within this fraction of the target's speed has reached it: v + (m dv) / m may
#: miss the target by an ulp, and chasing that ulp would add an impulse to every step.
_SETTLED = 1e-12
#: The names of the balls a world starts with.
_START_NAME = re.compile(r'ball_(0|[1-9][0-9]{0,8})')


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

    @classmethod
    def from_parameters(cls, parameters):
        return cls(max_speed=parameters['agent.max_speed'],
                   max_accel=parameters['agent.max_accel'],
                   max_yaw_rate=parameters['agent.max_yaw_rate'],
                   cmd_timeout=parameters['agent.cmd_timeout'])


@dataclass(frozen=True)
class Command:
    """The last command of an agent: body-frame velocity, yaw rate, and when it took effect."""

    vx: float  # m/s forward
    vy: float  # m/s left
    wz: float  # rad/s counter-clockwise
    since_ns: int  # simulation time of the first step it acted on


def check_command(name, vx, vy, wz):
    """(vx, vy, wz) as floats, or CommandRejected: not finite, or an absurd magnitude."""
    values = (vx, vy, wz)
    if not all(math.isfinite(value) for value in values):
        raise CommandRejected('non_finite', f'cmd_vel for {name} is not finite: '
                                            f'({vx}, {vy}, {wz})')
    if max(abs(value) for value in values) > MAX_COMMAND:
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
    """yaw in [-pi, pi]: the same direction, a representable range for ever."""
    return math.remainder(yaw, _TWO_PI)


def frames(prefix, name):
    """An agent's (odom frame, body frame): <prefix><name>/odom, <prefix><name>/base_link."""
    return f'{prefix}{name}/odom', f'{prefix}{name}/base_link'


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
    return requested


class Agents:
    """The agents of a world: headings, last commands, and the drive rule."""

    def __init__(self, names, limits):
        self.limits = limits
        self._yaw = {name: 0.0 for name in names}
        self._command = {}
        self.commands_taken = 0

    def __len__(self):
        return len(self._yaw)

    def __contains__(self, name):
        return name in self._yaw

    @property
    def names(self):
        """Agent names in the order they became agents (the order of odom and /tf)."""
        return tuple(self._yaw)

    def yaws(self):
        """Headings in the order of `names`, rad."""
        return tuple(self._yaw.values())

    def yaw(self, name):
        return self._yaw[name]

    def add(self, name, yaw=0.0):
        """Make the ball `name` an agent (a spawn with agent: true)."""
        self._yaw[name] = wrapped(float(yaw))

    def remove(self, name):
        """Forget an agent (its ball was deleted); a name that is no agent is ignored."""
        self._yaw.pop(name, None)
        self._command.pop(name, None)

    def restore(self, name, yaw, command=None):
        """Make `name` an agent with heading yaw and its last Command, as they were at a
        step of a recorded run (a split file resumes there): both kept bit for bit."""
        self._yaw[name] = float(yaw)
        if command is not None:
            self._command[name] = command

    def set_yaw(self, name, yaw):
        self._yaw[name] = wrapped(float(yaw))

    def command(self, name, vx, vy, wz, since_ns):
        """Take a checked command for agent `name`, in force from the step ending since_ns."""
        if name not in self._yaw:
            raise CommandRejected('unknown_agent', f"no agent named '{name[:64]}'")
        vx, vy, wz = check_command(name, vx, vy, wz)
        self._command[name] = Command(vx, vy, wz, int(since_ns))
        self.commands_taken += 1

    def last_command(self, name):
        """The last Command of `name`, or None."""
        return self._command.get(name)

    def in_force(self, name, end_ns):
        """The command acting on `name` in the step ending end_ns, or None (brake)."""
        command = self._command.get(name)
        if command is None or end_ns < command.since_ns:
            return None
        timeout = self.limits.cmd_timeout
        if timeout > 0.0 and (end_ns - command.since_ns) * 1e-9 >= timeout:
            return None
        return command

    def impulses(self, velocities, masses, index_of, dt_ns, end_ns):
        """The drive's impulses for the step ending end_ns: [(name, jx, jy)], agent order.

        velocities and masses are the world's arrays (after the impulses that arrived before
        the step), index_of maps names to indices. An agent already at its target gets none.
        """
        limits = self.limits
        reach = limits.max_accel * (dt_ns * 1e-9)
        result = []
        for name in self._yaw:
            index = index_of.get(name)
            if index is None:
                continue
            yaw = self.heading_after(name, dt_ns, end_ns)
            command = self.in_force(name, end_ns)
            if command is None:
                target_x = target_y = 0.0
            else:
                forward, left = command.vx, command.vy
                speed = math.hypot(forward, left)
                if speed > limits.max_speed:
                    scale = limits.max_speed / speed
                    forward, left = forward * scale, left * scale
                target_x, target_y = body_to_world(yaw, forward, left)
            dvx = target_x - float(velocities[index, 0])
            dvy = target_y - float(velocities[index, 1])
            change = math.hypot(dvx, dvy)
            if change <= _SETTLED * math.hypot(target_x, target_y):
                continue
            if change > reach:
                scale = reach / change
                dvx, dvy = dvx * scale, dvy * scale
            mass = float(masses[index])
            result.append((name, mass * dvx, mass * dvy))
        return result

    def yaw_rate(self, name, end_ns):
        """The yaw rate (clamped) agent `name` turns at in the step ending end_ns, rad/s."""
        command = self.in_force(name, end_ns)
        if command is None:
            return 0.0
        limit = self.limits.max_yaw_rate
        return min(max(command.wz, -limit), limit)

    def heading_after(self, name, dt_ns, end_ns):
        """The heading of `name` at the end of the step ending end_ns (its yaw rate applied)."""
        rate = self.yaw_rate(name, end_ns)
        yaw = self._yaw[name]
        return yaw if rate == 0.0 else wrapped(yaw + rate * (dt_ns * 1e-9))

    def turn(self, dt_ns, end_ns):
        """Advance every heading over the step ending end_ns by its clamped yaw rate."""
        for name in self._yaw:
            self._yaw[name] = self.heading_after(name, dt_ns, end_ns)
