"""What a controller sees of its agents, and when it is asked: the agents' side of a
controller (the user's class runs elsewhere: user_code.controller).

A controller is one more source of commands (ARCHITECTURE.md): at step 0 and at every step
whose end crosses a multiple of 1 / controller.rate_hz of simulated time (the rule of the
scans and of agent.odom.rate_hz, so the rate never depends on the wall clock), the
Simulation builds an Observation of the agents the controller drives, as the step left
them, hands it to the controller, and gives the commands it returns to the agents as
cmd_vel would (AgentPart.command_many), in force from the next step and recorded with it.
A re-simulation takes them from the recording: the controller's code is not needed again.

`Control` keeps what the observation needs between calls and the Simulation would
otherwise drop: every agent's latest scan (a scan is taken at its own rate) and the
collision impulses each took since the last call (its bumper, summed in base_link, each
step's impulse turned by that step's heading). It exists only in a Simulation that has a
controller: a world without one pays nothing for it.
"""
from typing import NamedTuple

import numpy as np

from ball_world.agents.frames import body_twists
from ball_world.core.parameters import ParameterError
from ball_world.scans import fan_from, ScanTable


def check(parameters, agents):
    """Refuse controller.agents naming a ball that is not one of `agents` (the agents the
    world starts with), or one twice (ParameterError naming controller.agents)."""
    known = set(agents)
    seen = set()
    for name in parameters['controller.agents']:
        if name not in known:
            raise ParameterError('controller.agents', f"'{name[:64]}' is not one of the "
                                                      'agents (parameter agents)')
        if name in seen:
            raise ParameterError('controller.agents', f"'{name[:64]}' is listed twice")
        seen.add(name)


def _frozen(array):
    array.flags.writeable = False
    return array


def _observation(time, names, truth, odom, twist, scan, scan_time, bumper, fan):
    """An Observation with read-only arrays: how one is rebuilt after pickling (a pickled
    array comes back writeable; a controller in its worker sees them as the caller did)."""
    return Observation(float(time), tuple(names), *(_frozen(np.array(a)) for a in (
        truth, odom, twist, scan, scan_time, bumper)), tuple(float(f) for f in fan))


class Observation(NamedTuple):
    """Every agent a controller drives, at once (row i is names[i]); read-only arrays.

    time: s of simulated time; truth: (N, 3) x, y, yaw in frame_id; odom: (N, 3) the
    odometry's pose (drifting with agent.odom.noise; the truth without it); twist: (N, 3)
    vx, vy, wz in base_link; scan: (N, beams) float32, the latest scan's ranges (REP 117
    infinities; NaN for an agent not scanned yet); scan_time: (N,) s, when each was taken
    (NaN: none yet); bumper: (N, 2) the collision impulse taken since the last call, N s,
    base_link; fan: (angle_min, angle_increment, range_min, range_max) of the scans.
    """

    time: float
    names: tuple
    truth: np.ndarray
    odom: np.ndarray
    twist: np.ndarray
    scan: np.ndarray
    scan_time: np.ndarray
    bumper: np.ndarray
    fan: tuple

    def __reduce__(self):
        return _observation, tuple(self)


class Control:
    """The controller's view of one AgentPart: when it is due, and what it sees."""

    def __init__(self, parameters):
        self.period_ns = max(1, round(1e9 / float(parameters['controller.rate_hz'])))
        self.chosen = frozenset(parameters['controller.agents'])  # empty: every agent
        self.samples = int(parameters['agent.scan.samples'])
        self.parameters = parameters
        self.calls = 0
        self._bumper = {}  # name -> [forward, left] summed since the last call
        self._scan_rows = {}  # name -> row of _scans
        self._scans = np.empty((0, self.samples), dtype=np.float32)
        self._scan_time = np.empty(0)

    def due(self, step_index, dt_ns):
        """Whether the controller is asked after step `step_index` (before the next)."""
        end = step_index * dt_ns
        return step_index == 0 or end // self.period_ns != (end - dt_ns) // self.period_ns

    def driven(self, names):
        """The agents the controller drives now, in agent order (controller.agents, or
        every agent; one deleted since the start is left out)."""
        if not self.chosen:
            return tuple(names)
        chosen = self.chosen
        return tuple(name for name in names if name in chosen)

    def drives(self, name):
        return not self.chosen or name in self.chosen

    # What the part tells it after each step ----------------------------------------------

    def note_contact(self, names, yaws, impulses):
        """The collision impulses (A, 2, world frame) the agents took in a step, turned into
        base_link at the step's end heading (as the bumper topic gives them) and summed."""
        hit = np.flatnonzero((impulses != 0.0).any(axis=1))
        if not len(hit):
            return
        cos, sin = np.cos(yaws[hit]), np.sin(yaws[hit])
        jx, jy = impulses[hit, 0], impulses[hit, 1]
        forward, left = (cos * jx + sin * jy).tolist(), (cos * jy - sin * jx).tolist()
        summed = self._bumper
        for row, x, y in zip(hit.tolist(), forward, left):
            total = summed.get(names[row])
            if total is None:
                summed[names[row]] = [x, y]
            else:
                total[0] += x
                total[1] += y

    def note_scans(self, scans, stamp_ns):
        """The scans of a step (scans.AgentScan, agent order): each agent's latest."""
        if not scans:
            return
        if isinstance(scans, ScanTable):  # a swarm's: one table already
            names, table = scans.names, scans.table
        else:
            names = [scan.name for scan in scans]
            table = [scan.ranges for scan in scans]
        if tuple(self._scan_rows) != tuple(names):
            self._scan_rows = {name: row for row, name in enumerate(names)}
        self._scans = np.array(table, dtype=np.float32).reshape(len(names), self.samples)
        self._scan_time = np.full(len(scans), stamp_ns * 1e-9)

    # The observation ---------------------------------------------------------------------

    def observe(self, part, world, rows, stamp_ns):
        """The Observation of the agents the controller drives (part: the AgentPart; rows:
        its agents' rows in the World's arrays), and their names; the bumper sums restart."""
        names = part.names
        driven = self.driven(names)
        if len(driven) == len(names):
            pick = slice(None)
        else:
            position = {name: row for row, name in enumerate(names)}
            pick = np.array([position[name] for name in driven], dtype=np.int64)
        at = rows[pick]
        yaws = part.yaws()[pick]
        truth = np.column_stack((world.positions[at], yaws))
        odom = truth.copy()
        if part.noisy:  # an agent whose odometry has not started (new) is at its truth
            poses = part.state.odometry()[0][pick]
            started = ~np.isnan(poses[:, 0])
            odom[started] = poses[started]
        twist = body_twists(yaws, world.velocities[at], part.state.yaw_rates(stamp_ns)[pick])
        scan, scan_time = self._latest(driven)
        bumper = np.zeros((len(driven), 2))
        summed, self._bumper = self._bumper, {}
        for row, name in enumerate(driven):
            total = summed.get(name)
            if total is not None:
                bumper[row] = total
        self.calls += 1
        return _observation(stamp_ns * 1e-9, driven, truth, odom, twist, scan, scan_time,
                            bumper, self._fan(world, at))

    def _latest(self, names):
        rows = self._scan_rows
        if tuple(rows) == names:
            return self._scans, self._scan_time
        scan = np.full((len(names), self.samples), np.nan, dtype=np.float32)
        when = np.full(len(names), np.nan)
        for row, name in enumerate(names):
            kept = rows.get(name)
            if kept is not None:
                scan[row] = self._scans[kept]
                when[row] = self._scan_time[kept]
        return scan, when

    def _fan(self, world, rows):
        """(angle_min, angle_increment, range_min, range_max) of the agents' scans (range_min
        0 means beyond each agent's radius: the smallest agent's is given)."""
        if self.samples == 0:
            return (0.0, 0.0, 0.0, 0.0)
        radius = float(world.radii[rows].min()) if len(rows) else 0.0
        fan = fan_from(self.parameters, radius)
        return (fan.angle_min, fan.angle_increment, fan.range_min, fan.range_max)
