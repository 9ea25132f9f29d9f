"""The agents as one part: what the Simulation calls before, around and after each step.

Why one part: the drive rule (core.agents), the odometry that drifts (core.odometry), the
bumpers, the scanners (ball_world.scans) and the frames every message names are one robot's
parts, and each needs the others' arrays at fixed points of a step. Made from the
parameters once (a reset makes a new one), the part keeps them; the Simulation only orders
the calls and hands over the World and the names' rows:

1. `command` (any number, between steps): a checked body-frame command, in force from the
   next step, kept for the step's record. A source of commands (a cmd_vel subscription,
   re-simulation, a controller) calls it, or `command_many` for many agents at once.
2. `drive` (before the step): the commands in force -> each agent's impulse for the step,
   which the Simulation applies through its impulse queue (its checks, its record).
3. `before_step` / `after_step` (around World.step): the agents as the step takes them,
   every impulse applied; then the headings turned, the collision impulses each agent took
   (the bumpers) and the noisy odometry advanced.
4. `frame` (after the step): the AgentFrame of the StepRecord, its bytes made once for the
   publishers and the recordings.

The part knows agents by name; their rows in the World's arrays (`rows`) are looked up
once and kept until the balls move in the arrays (`balls_moved`: a spawn, a deletion).
"""
import numpy as np

from ball_world.agents import control as controller_view
from ball_world.agents import frames as messages
from ball_world.core import odometry
from ball_world.core.agents import (agent_names, Agents, CommandRejected, frame_clash,
                                    Limits)
from ball_world.core.parameters import MAX_AGENTS, MAX_AGENTS_EACH, ParameterError
from ball_world.msgs.twist_cdr import encode_twist, encode_twist_stamped
from ball_world.scans import AgentScans, check as check_scans
from ball_world.step_record import AgentFrame, AppliedCommand, TakenCommands

#: AgentPart.drive's answer without agents: no ball, no impulse.
_NO_DRIVE = (np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), [])


def check(parameters, count):
    """The agents of a new world of `count` balls and their scanners' parameters, checked
    (ParameterError naming the parameter); returns the agents' names.

    Agents with topics of their own (agent.topics each) are at most MAX_AGENTS_EACH: their
    DDS entities are what bounds the node's start and stop."""
    names = agent_names(parameters, count)
    if parameters['agent.topics'] == 'each' and len(names) > MAX_AGENTS_EACH:
        raise ParameterError('agents', f'{len(names):,} agents with topics of their own '
                                       f'(agent.topics each): at most {MAX_AGENTS_EACH:,}; '
                                       f'agent.topics none takes up to {MAX_AGENTS:,}')
    check_scans(parameters)
    controller_view.check(parameters, names)
    return names


class _Contact:
    """What a step did to the agents (names in agent order): the collision impulses each
    took, (A, 2) world frame, and the noisy odometry's advance (core.odometry.Step) or None."""

    __slots__ = ('names', 'impulses', 'odometry')

    def __init__(self, names, impulses, advanced):
        self.names = names
        self.impulses = impulses
        self.odometry = advanced


class AgentPart:
    """The agents of one world (a segment of a run), made from its parameters.

    controlled: a controller drives some of them (the Simulation has one), so the part
    keeps what its observations need (control.Control); without one nothing is kept.
    """

    def __init__(self, parameters, names, controlled=False):
        self.state = Agents(names, Limits.from_parameters(parameters))
        self.prefix = str(parameters['frame_prefix'])
        self.stamped = bool(parameters['agent.cmd_vel_stamped'])
        self.tf_static = bool(parameters['agent.odom.tf_static'])
        self.alphas = parameters['agent.odom.noise']
        # agent.topics: 'each' agent has its own topics; 'none' (a swarm): no per-agent
        # message is made at all, and commands are recorded together (command_rows).
        self.each = parameters['agent.topics'] == 'each'
        rate = float(parameters['agent.odom.rate_hz'])
        self.odom_period_ns = max(1, round(1e9 / rate)) if rate > 0.0 else 0
        # The kinds of per-agent message (frames.KINDS) whose bytes are made: None for all;
        # the node narrows it to those someone subscribes to when nothing records them.
        self.encode = None
        self._noise = (odometry.OdometryNoise(parameters['random.seed'])
                       if odometry.enabled(self.alphas) else None)
        self.scans = AgentScans(parameters)
        self._names = messages.FrameNames(self.prefix)
        self._rows = None  # the agents' rows in the World's arrays, until the balls move
        self._before = None  # the agents as the step took them (before_step)
        self._contact = None  # what the last step did to them (_Contact), until its frame
        self._commands = []  # AppliedCommand taken since the last step
        self.control = controller_view.Control(parameters) if controlled else None

    # The agents as a collection ---------------------------------------------------------

    def __len__(self):
        return len(self.state)

    def __contains__(self, name):
        return name in self.state

    @property
    def names(self):
        """Agent names in the order they became agents (the order of odom and /tf)."""
        return self.state.names

    @property
    def noisy(self):
        """Whether the odometry drifts from the truth (agent.odom.noise)."""
        return self._noise is not None

    def yaws(self):
        return self.state.yaws()

    def yaw(self, name):
        return self.state.yaw(name)

    def rows(self, index_of):
        """The agents' rows in the World's arrays (int64, agent order), kept until
        balls_moved()."""
        if self._rows is None:
            rows = np.array([index_of[name] for name in self.state.names], dtype=np.int64)
            rows.flags.writeable = False  # shared by the records that carry it (indices)
            self._rows = rows
        return self._rows

    def balls_moved(self):
        """The balls moved in the World's arrays (a spawn, a deletion): rows are found again."""
        self._rows = None

    # Edits ------------------------------------------------------------------------------

    @property
    def limit(self):
        """The most agents this world may have (a spawn past it is refused)."""
        return MAX_AGENTS_EACH if self.each else MAX_AGENTS

    def frame_clash(self, frame_id, name):
        """Why an agent `name` cannot be under frame_id (core.agents.frame_clash), or None."""
        return frame_clash(frame_id, self.prefix, (name,))

    def add(self, name):
        self.state.add(name)
        self._rows = None

    def remove(self, name):
        self.state.remove(name)
        self._rows = None

    def set_yaw(self, name, yaw):
        self.state.set_yaw(name, yaw)

    def restore(self, name, yaw, command=None, odometry_pose=None, covariance=None):
        """An agent as it was at a step of a recorded run (core.agents.Agents.restore)."""
        self.state.restore(name, yaw, command, odometry_pose, covariance)
        self._rows = None

    # 1. Commands ------------------------------------------------------------------------

    def command(self, name, vx, vy, wz, since_ns, cdr=b''):
        """Take a body-frame command for agent `name`, in force from the step ending since_ns.

        Raises CommandRejected for an unknown agent or a bad command. Taken commands go into
        the step's record as `cdr` (the message as received), or encoded here when given in
        code (Twist, or TwistStamped with agent.cmd_vel_stamped); with agent.topics none not
        at all (the step's AgentFrame holds them as rows).
        """
        self.state.command(name, vx, vy, wz, since_ns)
        if not cdr and self.each:  # a swarm records its commands as rows (command_rows)
            cdr = (encode_twist_stamped(since_ns, '', vx, vy, wz) if self.stamped
                   else encode_twist(vx, vy, wz))
        self._commands.append(AppliedCommand(name, float(vx), float(vy), float(wz), cdr))

    def command_many(self, names, commands, since_ns):
        """Commands (N, 3) for the agents `names` (N), in order, as N calls of command().

        A controller's way in: every row is checked first, and one bad row refuses them all
        (CommandRejected naming it), so a controller's step is taken whole or not at all.
        A swarm (agent.topics none) keeps them as one batch (step_record.TakenCommands).
        """
        commands = np.array(commands, dtype=np.float64)  # a copy: the caller's may change
        if commands.shape != (len(names), 3):
            raise CommandRejected('shape', f'{len(names)} agents need commands of shape '
                                           f'({len(names)}, 3), got {commands.shape}')
        self.state.command_many(names, commands, since_ns)
        stamped, each = self.stamped, self.each
        taken = self._commands
        if not each:
            taken.append((tuple(names), commands))
            return
        for name, (vx, vy, wz) in zip(names, commands.tolist()):
            cdr = b''
            if each:
                cdr = (encode_twist_stamped(since_ns, '', vx, vy, wz) if stamped
                       else encode_twist(vx, vy, wz))
            taken.append(AppliedCommand(name, vx, vy, wz, cdr))

    def _command_rows(self, index_of):
        """(K, 4) rows (ball, vx, vy, wz) of the commands taken since the last step, in
        order, for the agents still there; ball is the row in the step's `balls`.

        A swarm's commands as one message a step (recording.agent_topics): a re-simulation
        takes them after the step's edits, as it takes cmd_vel, so the rows are those of
        the balls after every edit made before the step, and a command given to an agent
        deleted after it (which the deletion took away) is left out.
        """
        agents = self.state
        blocks = []
        for part in self._commands:
            if isinstance(part, AppliedCommand):
                if part.name in agents:
                    blocks.append(np.array([[index_of[part.name], part.vx, part.vy,
                                             part.wz]]))
                continue
            names, commands = part
            kept = [row for row, name in enumerate(names) if name in agents]
            block = np.empty((len(kept), 4))
            block[:, 0] = [index_of[names[row]] for row in kept]
            block[:, 1:] = commands[kept] if len(kept) < len(names) else commands
            blocks.append(block)
        return np.concatenate(blocks) if blocks else np.empty((0, 4))

    def headings(self, index_of):
        """(rows, yaws) of the agents in the World's arrays, or None without agents: what
        `balls` gives as each agent's orientation."""
        if not len(self.state):
            return None
        return self.rows(index_of), self.state.yaws()

    def _due(self, step_index, dt_ns):
        """Whether step `step_index` sends odometry, ground truth and /tf: every step at
        agent.odom.rate_hz 0, else step 0 and every step whose end crosses a multiple of
        the period (simulated time, as the scans' rate)."""
        period = self.odom_period_ns
        end = step_index * dt_ns
        return not period or step_index == 0 or end // period != (end - dt_ns) // period

    def _wanted(self, kind):
        return self.each and (self.encode is None or kind in self.encode)

    def controlled(self, name):
        """Whether agent `name` is driven by the controller (its cmd_vel is refused)."""
        return self.control is not None and self.control.drives(name)

    def observe(self, world, index_of, step_index, dt_ns):
        """The controller's Observation after step `step_index` when it is due then and
        drives any agent, else None (agents/control.py)."""
        control = self.control
        if control is None or not len(self.state) or not control.due(step_index, dt_ns):
            return None
        observation = control.observe(self, world, self.rows(index_of), step_index * dt_ns)
        return observation if observation.names else None

    def take_commands(self):
        """The commands taken since the last call, in order (for the step's record)."""
        taken, self._commands = self._commands, []
        if all(isinstance(part, AppliedCommand) for part in taken):
            return tuple(taken)
        return TakenCommands(taken)

    # 2. Before the step -----------------------------------------------------------------

    def drive(self, world, index_of, dt_ns, end_ns):
        """The drive's impulses for the step ending end_ns, agent order, from the World's
        velocities now (after the impulses that arrived before the step): (the balls that
        get one (int64 indices), jx, jy, their agents' names), arrays but the names (the
        Simulation applies a crowd's at once, so no tuple is made per agent)."""
        if not len(self.state):
            return _NO_DRIVE
        rows = self.rows(index_of)
        due, jx, jy = self.state.impulse_arrays(world.velocities, world.masses, rows, dt_ns,
                                                end_ns)
        names = self.state.names
        return rows[due], jx, jy, [names[agent] for agent in due.tolist()]

    # 3. Around the step -----------------------------------------------------------------

    def before_step(self, world, index_of):
        """Note the agents as the step takes them, every impulse applied: what the bumper
        measures the collisions against, and the true pose the odometry starts from."""
        if not len(self.state):
            self._before = None
            return
        rows = self.rows(index_of)
        self._before = (rows, world.velocities[rows], world.positions[rows],
                        self.state.yaws())

    def after_step(self, world, dt_ns, step_index):
        """The step ending at step_index * dt_ns is done: turn the headings, measure the
        contact and advance the noisy odometry.

        Within World.step velocities change only in collisions (no gravity, no friction;
        every impulse was applied before it), so m (v after - v before) is the impulse the
        agent received from balls, walls and map cells, in either backend and mode alike.
        """
        if self._before is None:
            return
        rows, velocities, positions, yaws = self._before
        self._before = None
        agents = self.state
        agents.turn(dt_ns, step_index * dt_ns)
        impulses = world.masses[rows][:, None] * (world.velocities[rows] - velocities)
        if self.control is not None:
            self.control.note_contact(agents.names, agents.yaws(), impulses)
        advanced = None
        if self._noise is not None:
            before = np.column_stack((positions, yaws))
            after = np.column_stack((world.positions[rows], agents.yaws()))
            agents.start_odometry(before)
            poses, covariances = agents.odometry()
            moved = np.flatnonzero((before != after).any(axis=1)).tolist()
            normals = self._noise.normals(agents.names, step_index, moved)
            advanced = odometry.advance(self.alphas, poses, covariances, before, after,
                                        normals, dt_ns * 1e-9)
            agents.set_odometry(advanced.poses, advanced.covariances)
        self._contact = _Contact(agents.names, impulses, advanced)

    # 4. After the step ------------------------------------------------------------------

    def frame(self, world, index_of, positions, velocities, step_index, dt_ns, frame_id):
        """The agents at the end of step `step_index` (rows, headings, odom, ground truth,
        bumper, scan and /tf bytes), or None without agents.

        positions and velocities: the record's copies of the World's arrays. Without
        odometry noise odom is the ground truth, bit for bit; with it, odom and /tf carry
        the odometry's pose (core.odometry).
        """
        contact, self._contact = self._contact, None
        agents = self.state
        if not len(agents):
            return None
        stamp_ns = step_index * dt_ns
        names = agents.names
        rows = self.rows(index_of)
        yaws = agents.yaws()
        twists = messages.body_twists(yaws, velocities[rows], agents.yaw_rates(stamp_ns))
        frame_names = self._names
        static = None
        if frame_names.update(names, frame_id) and self.tf_static and self.each:
            static = messages.tf_static(stamp_ns, frame_names)
        located = positions[rows]
        due = self._due(step_index, dt_ns)
        truth = (messages.ground_truth(stamp_ns, frame_names, located, yaws, twists)
                 if due and self._wanted(messages.GROUND_TRUTH) else ())
        poses = covariances = None
        if self._noise is None:  # odometry is the ground truth, as it always was
            at, heading, moving, spread, twist_spread = located, yaws, twists, None, None
        else:
            agents.start_odometry(np.column_stack((located, yaws)))
            poses, covariances = agents.odometry()
            current = contact is not None and contact.names == names
            moving, twist_spread = messages.noisy_twists(
                twists, contact.odometry if current else None)
            at, heading = poses[:, :2], poses[:, 2]
            spread = odometry.message_covariance(covariances)
        odom = (messages.odometry_messages(stamp_ns, frame_names, at, heading, moving, spread,
                                           twist_spread)
                if due and self._wanted(messages.ODOM) else ())
        tf = (messages.tf_message(stamp_ns, frame_names, at, heading)
              if due and self._wanted(messages.TF) else b'')
        hits = (() if contact is None or contact.names != names
                else messages.bumpers(names, frame_names.base, yaws, contact.impulses,
                                      stamp_ns, self._wanted(messages.BUMPER)))
        scans = self.scans.take(world, names, rows, yaws, frame_names.base, step_index,
                                stamp_ns, dt_ns, self._wanted(messages.SCAN))
        if self.control is not None:
            self.control.note_scans(scans, stamp_ns)
        return AgentFrame(
            names=names, indices=rows, yaws=yaws, twists=twists,
            odom_frames=frame_names.odom, base_frames=frame_names.base, odom_cdr=odom,
            tf_cdr=tf, tf_static_cdr=static, ground_truth_cdr=truth, bumpers=hits,
            scans=scans,
            odometry=poses, odometry_covariances=covariances, topics=self.each,
            command_rows=None if self.each else self._command_rows(index_of))
