"""Stage's wander, for every robot at once: the swarm's first controller.

Each robot cruises forward; when its scan sees something within AVOID_DISTANCE in the
front quarter it stops and turns towards the freer side (the side whose nearest range is
farther) until the way is clear; after a bump it backs off for a moment; otherwise it turns
at a random rate now and then (a new draw every WANDER_CALLS calls), as Stage's
examples/ctrl/wander does. The draws come from one generator seeded with SEED, so the same
observations give the same commands in the node and in ball_world_sim, bit for bit.

Without a scanner (agent.scan.samples 0) a robot only wanders and backs off from bumps.
"""
import numpy as np

#: Forward speed when the way is clear, m/s.
CRUISE_SPEED = 0.4
#: Turn rate when avoiding, rad/s.
AVOID_TURN = 1.5
#: A range closer than this within +-45 degrees of the heading is in the way, m.
AVOID_DISTANCE = 0.5
#: Largest random turn rate, rad/s, and how many calls one draw lasts.
WANDER_TURN = 0.6
WANDER_CALLS = 20
#: Backing off after a bump: speed, m/s, and for how many calls.
BACK_SPEED = -0.2
BACK_CALLS = 5
SEED = 1


class Wander:
    """Cruise, avoid, back off, wander (module docstring)."""

    def __init__(self):
        self.random = np.random.default_rng(SEED)
        self.turns = {}  # name -> (random turn rate, calls left)
        self.backing = {}  # name -> calls left backing off

    def act(self, obs):
        count = len(obs.names)
        commands = np.zeros((count, 3))
        commands[:, 0] = CRUISE_SPEED
        commands[:, 2] = self._wander(obs.names)
        blocked, turn = self._obstacles(obs)
        commands[blocked, 0] = 0.0
        commands[blocked, 2] = turn[blocked]
        bumped = np.hypot(obs.bumper[:, 0], obs.bumper[:, 1]) > 0.0
        for row, name in enumerate(obs.names):
            if bumped[row]:
                self.backing[name] = BACK_CALLS
            left = self.backing.get(name, 0)
            if left:
                commands[row, 0] = BACK_SPEED
                self.backing[name] = left - 1
        return commands

    def _wander(self, names):
        """Each robot's random turn rate, drawn again every WANDER_CALLS calls."""
        draws = self.random.uniform(-WANDER_TURN, WANDER_TURN, len(names))
        rates = np.empty(len(names))
        for row, name in enumerate(names):
            rate, left = self.turns.get(name, (0.0, 0))
            if left == 0:
                rate, left = float(draws[row]), WANDER_CALLS
            self.turns[name] = (rate, left - 1)
            rates[row] = rate
        return rates

    @staticmethod
    def _obstacles(obs):
        """(blocked (N,), the avoiding turn rate (N,)) from the scans."""
        count, beams = obs.scan.shape
        blocked = np.zeros(count, dtype=bool)
        turn = np.zeros(count)
        if beams == 0:
            return blocked, turn
        angle_min, increment = obs.fan[0], obs.fan[1]
        angles = np.arctan2(np.sin(angle_min + increment * np.arange(beams)),
                            np.cos(angle_min + increment * np.arange(beams)))
        ranges = np.where(np.isnan(obs.scan), np.inf, obs.scan)
        ranges = np.where(ranges < 0.0, 0.0, ranges)  # -inf: closer than range_min
        front = np.abs(angles) <= np.pi / 4
        if front.any():
            blocked = ranges[:, front].min(axis=1) < AVOID_DISTANCE
        left, right = (angles > 0) & (angles <= np.pi / 2), (angles < 0) & (angles >= -np.pi / 2)
        nearest_left = ranges[:, left].min(axis=1) if left.any() else np.full(count, np.inf)
        nearest_right = ranges[:, right].min(axis=1) if right.any() else np.full(count, np.inf)
        turn = np.where(nearest_left >= nearest_right, AVOID_TURN, -AVOID_TURN)
        return blocked, turn
