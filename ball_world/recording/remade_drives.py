"""The agents' drive impulses of a recorded segment, made again from what it recorded.

Why: recordings leave the drives out (recording.agent_topics: 1,000 robots at 100 Hz drive
up to 100,000 times a second), yet the sinks fed from a recording (ball_world_to_rrd) tell
a robot's drive from a push and split the energy plot into what the drives did and the
rest (rerun_energy), as the live view does from the node's records. A drive is a function
of what the recording holds: the commands in force (cmd_vel, or a swarm's agent_commands
rows, each in force from the step it is recorded with), the headings (0 at the start, or a
split file's resume state; turned every step by the commanded yaw rates; set by set_state
edits), and the velocities the step's drive met: the previous step's recorded `state`,
then the step's edits and the impulses they applied, replayed in the order applied.
core.agents makes them from these with the Simulation's own arithmetic, so they are the
node's bit for bit (test_rerun_recorded_agents compares them with a live run's).

What it cannot know it does not guess: after a step it could not follow (a gap a repair
left, a step cut off by a crash) a segment gets no drives until a split file's resume
state picks it up again. A drive the node refused (over the world's speed limit, which
re-simulation reports as a difference) is made here as if it had been taken.
"""
import numpy as np

from ball_world.core.agents import agent_names, Agents, CommandRejected, Limits
from ball_world.msgs.cdr import encode_vector3_stamped
from ball_world.step_record import AppliedImpulse, DriveBatch, impulses_of


class RemadeDrives:
    """Follows one segment's recorded steps in order and gives each its drives again.

    parameters: the segment's; snapshot: the WorldSnapshot it starts from (its balls at
    step 0, or at the step a split file resumes after: `resume`, its ResumeState, whose
    agents, headings and commands it starts from). Raises ParameterError for agents the
    parameters cannot have.
    """

    def __init__(self, parameters, snapshot, dt_ns, resume=None):
        limits = Limits.from_parameters(parameters)
        if resume is None:
            self.agents = Agents(agent_names(parameters, len(snapshot.names)), limits)
        else:  # as Simulation.resume: the state's agents, not those the segment began with
            self.agents = Agents((), limits)
            commands = dict(resume.commands)
            for name, yaw in zip(resume.agents, resume.yaws):
                self.agents.restore(name, yaw, commands.get(name))
        self.dt_ns = dt_ns
        # The drives' bytes are made (when read) as the node made them: a swarm's have none.
        self.each = parameters['agent.topics'] == 'each'
        self._step = -1 if resume is None else resume.step  # the last step followed
        self._lost = False  # a step could not be followed: no drives from there on
        self._names = tuple(snapshot.names)
        self._masses = np.asarray(snapshot.masses, dtype=np.float64)
        self._velocities = np.asarray(snapshot.velocities, dtype=np.float64)
        self._index_of = (None, None)  # (names, {name: index}) of the last step's balls

    def follow(self, step, impulses, roster):
        """The impulses of a recorded step (what roster.follow(step) returned; the roster
        then holds the step's balls) with its drives among them where the node applied
        them: after the impulses its edits applied, before the rest. Steps must come in
        order; a closing record is not one (it has no drive)."""
        if step.step != self._step + 1 or self._velocities is None:
            self._lost = True  # the headings and velocities from here on are not known
        self._step = step.step
        if not self._lost and step.step > 0:
            self._follow_edits(step.edits)
        if not self._lost and step.step > 0 and len(self.agents):  # a world without: nothing
            velocities = self._before_drive(step)
            index_of = self._indices(roster.names)
            self._take_commands(step, roster.names)
            drive = self.agents.impulses(velocities, roster.masses, index_of, self.dt_ns,
                                         step.stamp_ns)
            self.agents.turn(self.dt_ns, step.stamp_ns)
            if drive:
                first = step.edits[-1].impulses_before if step.edits else 0
                impulses = impulses_of((*impulses[:first],
                                        *self._applied(drive, index_of, step.stamp_ns),
                                        *impulses[first:]))
        self._names, self._masses = roster.names, roster.masses
        self._velocities = None if step.state is None else step.state[:, 2:4]
        return impulses

    def _before_drive(self, step):
        """The velocities the step's drive met: the last step's, then the step's edits and
        the impulses each applied first, in order (World.apply_impulse's arithmetic)."""
        if not step.edits:
            return self._velocities
        rows = self._velocities.tolist()
        names, masses = list(self._names), self._masses.tolist()
        index_of = {name: index for index, name in enumerate(names)}
        pushes = step.impulses
        done = 0
        for edit in step.edits:
            for impulse in pushes[done:edit.impulses_before]:
                index = index_of[impulse.frame_id]
                mass = masses[index]
                rows[index][0] += impulse.x / mass
                rows[index][1] += impulse.y / mass
            done = max(done, edit.impulses_before)
            if edit.kind == 'spawn':
                index_of[edit.name] = len(names)
                names.append(edit.name)
                masses.append(edit.mass)
                rows.append([edit.vx, edit.vy])
            elif edit.kind == 'delete':
                index = index_of.pop(edit.name)
                del names[index], masses[index], rows[index]
                index_of = {name: index for index, name in enumerate(names)}
            else:
                rows[index_of[edit.name]] = [edit.vx, edit.vy]
        return np.array(rows, dtype=np.float64).reshape(-1, 2)

    def _follow_edits(self, edits):
        """Agents spawned and deleted, headings set, as the Simulation's edits did."""
        agents = self.agents
        for edit in edits:
            if edit.kind == 'spawn' and edit.agent:
                agents.add(edit.name)
            elif edit.kind == 'delete':
                agents.remove(edit.name)
            elif edit.kind == 'set_state' and edit.yaw is not None and edit.name in agents:
                agents.set_yaw(edit.name, edit.yaw)

    def _take_commands(self, step, names):
        """The step's commands, after its edits (as re-simulation takes them): in force from
        its stamp; one for an agent no longer there (deleted after it) goes with it."""
        agents = self.agents
        for name, vx, vy, wz, _ in step.commands:
            if name in agents:
                try:
                    agents.command(name, vx, vy, wz, step.stamp_ns)
                except CommandRejected:
                    pass  # the node took none such: it is not among the recorded ones
        rows = step.command_rows
        if rows is None or not len(rows):
            return
        balls = rows[:, 0].tolist()
        if all(0 <= ball < len(names) and ball.is_integer() for ball in balls):
            chosen = [names[int(ball)] for ball in balls]
            try:
                agents.command_many(chosen, rows[:, 1:], step.stamp_ns)
                return
            except CommandRejected:
                pass  # one by one below, leaving out the ones no agent takes
        for ball, (vx, vy, wz) in zip(balls, rows[:, 1:].tolist()):
            if 0 <= ball < len(names) and ball.is_integer() and names[int(ball)] in agents:
                try:
                    agents.command(names[int(ball)], vx, vy, wz, step.stamp_ns)
                except CommandRejected:
                    pass

    def _indices(self, names):
        """{name: index} of the step's balls, kept while the roster hands the same names."""
        kept, index_of = self._index_of
        if kept is not names:
            index_of = {name: index for index, name in enumerate(names)}
            self._index_of = (names, index_of)
        return index_of

    def _applied(self, drive, index_of, stamp_ns):
        """The drive's impulses as the Simulation records them: one as an AppliedImpulse
        (Simulation._apply), more as one DriveBatch (Simulation._apply_at_once)."""
        if len(drive) == 1:
            [(name, jx, jy)] = drive
            return (AppliedImpulse(ball=index_of[name], jx=jx, jy=jy, frame_id=name,
                                   cdr=encode_vector3_stamped(stamp_ns, name, jx, jy, 0.0),
                                   drive=True),)
        names = [name for name, _, _ in drive]
        return (DriveBatch([index_of[name] for name in names], [item[1] for item in drive],
                           [item[2] for item in drive], names,
                           stamp_ns if self.each else None),)
