"""A user's controller, run at arm's length: the object the Simulation asks for commands.

`ControllerProcess(spec)` makes the class `spec` names ('package.module:Class' or
'path/to/file.py:Class', made with no arguments) in a supervised worker of its own
(workers.Remote); `act(observation)` sends it the agents.control.Observation, calls its
`act` there and returns what it gave back as checked commands: an (N, 3) float64 array of
finite vx, vy, wz, one row per observed agent (checks.commands). Whatever goes wrong (the
import, the class, an exception, a wrong shape, a NaN, os._exit, a crash, a call past the
deadline) is one UserCodeError line naming the controller and the simulated time, and the
worker is gone; the node and ball_world_sim print it and exit non-zero.

Why a process, not a call in the node's own: a controller that segfaults, leaks or hangs
would take the node (and its recording) with it; here the recording is closed whole and the
line says where the controller was. An observation of 10,000 agents with 16-beam scans is
about 2 MB, pickled both ways in a few milliseconds (docs/agents.md).
"""
from ball_world.user_code import checks
from ball_world.user_code.describe import UserCodeError
from ball_world.user_code.workers import JobFailed, Remote

#: Seconds a controller's start (import and construction) or one call may take.
DEADLINE_S = 10.0
OPTION = 'controller'


class ControllerProcess:
    """A controller living in its worker; act(observation) -> (N, 3) commands."""

    def __init__(self, spec, deadline_s=DEADLINE_S, option=OPTION):
        self.spec = spec
        self.who = f'{option} {spec}'
        text = f'the controller deadline of {deadline_s:g} s'
        try:
            self._remote = Remote(spec, option, deadline_s=deadline_s, deadline_text=text)
        except JobFailed as failure:
            raise UserCodeError(str(failure)) from None

    def act(self, observation):
        """The checked commands for `observation` (UserCodeError in one line)."""
        when = f'at t = {observation.time:.9g} s'
        try:
            raw = self._remote.call('act', observation)
        except JobFailed as failure:
            text = str(failure)
            if self.spec not in text:
                text = f'{self.who}: {text}'
            raise UserCodeError(f'{text} ({when})') from None
        return checks.commands(raw, len(observation.names), self.who, when)

    def close(self):
        self._remote.close()

    def __enter__(self):
        return self

    def __exit__(self, kind, error, trace):
        self.close()
