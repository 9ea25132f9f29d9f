"""ball_world_resim: re-run a recording from its parameters, impulses and edits; compare bits.

This is the determinism contract checked end to end: each segment's world is rebuilt from
the parameters in its metadata record; before each step, its recorded impulses and world
edits (spawn, delete, set_state) are applied in the order the node applied them (an edit's
impulses_before says how many of the step's impulses came before it), through the same
Simulation calls the node makes; and every recorded pose, state row and stats entry (except
the real-time factor, which depends on the wall clock), every impulse and every edit
message (the agents' drive impulses are not recorded: they are made again from the
recorded commands, as the node made them, and checked through everything they move; a file
from before, which recorded them, has them compared too), and every agent's recorded scan
(<name>/scan, its seeded noise included), ground truth and bumper, must be bit-identical to
the re-simulated one; odom and /tf too (with agent.odom.noise the drifting odometry, its
seeded noise included). A segment's closing
record (edits, and the impulses they applied, made after its last step:
mcap_reader.RecordedStep.closing) is made the same way, without a step, and checked the same
way. An edit the re-simulation refuses,
or a spawn that gets another name, is a difference too. Exit status: 0 all identical, 1 a
difference, 2 an unreadable recording or parameters that no longer build a world (one line
on stderr), 3 identical where checked but some steps could not be checked: a gap in a split
set (a file missing or cut short) is reported with the steps it lacks, and the run is picked
up again from the state the next file resumes from; nothing is ever simulated through a
gap.

A split file (a bag directory's later file, or one given alone) that starts inside a
segment is picked up from the state it resumes from (recording.resume): the balls, agents
and names at the step before its first, and in exact mode the collision predictions that
step handed the next (core.exact_carry), so each file alone re-simulates bit for bit too.

The recording is untrusted: its parameters were checked by the reader as the node checks
them, and a segment whose first recorded step has another ball count than its parameters
make is refused before its world is built.
"""
import argparse
from dataclasses import dataclass
import math
import sys
from typing import Optional

import numpy as np

from ball_world.core.agents import CommandRejected
from ball_world.core.edits import Ball, EditRefused
from ball_world.core.scenario import ScenarioError
from ball_world.msgs.agent_cdr import decode_laser_scan, decode_odometry
from ball_world.msgs.cdr import decode_state_layout, decode_vector3_stamped
from ball_world.recording import agent_topics
from ball_world.recording.mcap_reader import RecordingError
from ball_world.recording.recording_set import open_recording
from ball_world.simulation import Simulation, SpawnRequest
from ball_world.step_record import STATS_FIELDS
from ball_world.tools import print_report
from ball_world.tools.progress import Progress

PROG = 'ball_world_resim'
#: Exit status when every step checked is identical but some steps could not be checked.
UNCHECKED = 3

_POSITION_NAMES = ('x', 'y')
_STATE_NAMES = ('x', 'y', 'vx', 'vy')
#: Stats entries that follow from the trajectory (the real-time factor does not).
_COMPARED_STATS = STATS_FIELDS[:-1]


@dataclass(frozen=True)
class Difference:
    """One recorded value that the re-simulation does not reproduce bit for bit."""

    segment: int
    step: int
    what: str  # 'balls x', 'state vy', 'stats kinetic_energy', 'edit refused', ...
    ball: Optional[int]
    recorded: object
    resimulated: object
    size: float  # |recorded - resimulated|, inf when not comparable as numbers

    def describe(self):
        where = f'segment {self.segment} step {self.step}'
        if self.ball is not None:
            where += f' ball {self.ball}'
        return (f'{where} {self.what}: recorded {self.recorded!r}, re-simulated '
                f'{self.resimulated!r} (difference {self.size:.3g})')


@dataclass
class SegmentResult:
    index: int
    position: int  # in Recording.segments
    steps: int = 0
    impulses: int = 0
    edits: int = 0
    last_step: int = 0
    differing_steps: int = 0
    closing: Optional[tuple] = None  # (impulses, edits) made after the last step, if any
    first_step: Optional[int] = None
    resumed: bool = False  # picked up from the state a split file resumes from
    skipping: Optional['Unchecked'] = None  # the steps being passed over, if so


@dataclass
class Unchecked:
    """Steps of a segment that could not be re-simulated, and why: `first` to `last` (None:
    not known, the recording holds none of them, or up to the end of what it holds)."""

    segment: int
    first: Optional[int]
    last: Optional[int]
    why: str

    def describe(self):
        if self.first is None:
            steps = f'the steps before step {self.last + 1}'
        elif self.last is None or self.last == self.first:
            steps = f'step {self.first}'
        else:
            steps = f'steps {self.first}-{self.last}'
        return f'segment {self.segment}: {steps} NOT CHECKED: {self.why}'


class Comparison:
    """Collects differences: the first one met, the largest one, and counts per segment;
    and the steps that could not be checked (a gap in the recording)."""

    def __init__(self):
        self.first = None
        self.largest = None
        self.count = 0
        self.segments = []
        self.unchecked = []

    @property
    def identical(self):
        return self.count == 0

    def add(self, difference, largest=None):
        """Count one difference; `largest` is its biggest element when it spans an array."""
        largest = largest or difference
        self.count += 1
        if self.first is None:
            self.first = difference
        if self.largest is None or largest.size > self.largest.size:
            self.largest = largest

    def arrays(self, segment, step, what, names, recorded, resimulated):
        """Compare two float arrays bit for bit; report the first and largest mismatch."""
        recorded = np.ascontiguousarray(recorded, dtype=np.float64)
        resimulated = np.ascontiguousarray(resimulated, dtype=np.float64)
        if recorded.shape != resimulated.shape:
            self.add(Difference(segment, step, f'{what} shape', None, recorded.shape,
                                resimulated.shape, math.inf))
            return False
        same = recorded.view(np.uint64) == resimulated.view(np.uint64)
        if same.all():
            return True
        with np.errstate(invalid='ignore'):
            size = np.abs(recorded - resimulated)
        size[~np.isfinite(size)] = math.inf
        size[same] = 0.0
        found = []
        for index in (np.argwhere(~same)[0], np.unravel_index(np.argmax(size), size.shape)):
            index = tuple(int(i) for i in index)
            ball = index[0] if recorded.ndim == 2 else None
            found.append(Difference(segment, step, f'{what} {names[index[-1]]}', ball,
                                    float(recorded[index]), float(resimulated[index]),
                                    float(size[index])))
        self.add(*found)
        return False


def _rebuild(segment, first_step):
    """The segment's Simulation at step 0 (the reader checked that its dt is the recorded one)."""
    if first_step.ball_count is not None:
        segment.check_ball_count(first_step.ball_count)
    return Simulation(segment.parameters, sinks=(), occupancy_map=segment.occupancy_map)


def _resume(segment):
    """The segment's Simulation at the step a split file continues from (its resume state).

    Exact mode keeps its collision predictions from step to step (core.exact): the file's
    resume state carries them (recording.resume's resume_exact, core.exact_carry), and the
    world takes them over, so its steps are the recorded ones bit for bit. A file in exact
    mode without them (written before they were) is refused: from positions and velocities
    alone its steps would differ in the last bits.
    """
    if segment.parameters['physics.mode'] == 'exact' and segment.resume.exact is None:
        raise RecordingError(f'segment {segment.index} is picked up at step '
                             f'{segment.resume.step + 1} (a split file) in exact mode, but the '
                             'file does not carry the collision predictions of the step before '
                             '(resume_exact; an older ball_world wrote it without them): it '
                             're-simulates bit for bit only from its first step (give the bag '
                             'directory with the file where it starts)')
    simulation = Simulation(segment.parameters, sinks=(), occupancy_map=segment.occupancy_map)
    try:
        simulation.resume(segment.parameters, segment.resume, segment.index,
                          segment.log_offset_ns)
    except ValueError as error:  # balls the World refuses (core.limits)
        raise RecordingError(f'segment {segment.index}: the state it resumes from: '
                             f'{error}') from None
    return simulation


def _advance(simulation, step, comparison, segment_index, drives_recorded=True):
    """Step the simulation once to `step` (the next one), its impulses and edits applied first.

    Impulses are queued up to each edit's impulses_before, then the edit is made (which
    applies them first, as in the node); the rest are applied by the step.
    drives_recorded: the segment's drive impulses are among the recorded ones
    (mcap_reader.Segment.drives_recorded); either way the simulation makes them again.
    """
    if step.step == 0:
        _compare_events(simulation.last_record, step, comparison, segment_index)
        return simulation.last_record
    _make_edits(simulation, step, comparison, segment_index, drives_recorded)
    result, rejected = simulation.step()
    _report_rejected(rejected, step.step, comparison, segment_index)
    _compare_events(result, step, comparison, segment_index, drives_recorded)
    return result


def _make_edits(simulation, step, comparison, segment_index, drives_recorded=True):
    """Queue the step's impulses and make its edits, in the order the node applied them."""
    impulses = step.impulses
    queued = 0
    for edit in step.edits:
        for impulse in impulses[queued:edit.impulses_before]:
            simulation.queue_impulse(impulse.frame_id, impulse.x, impulse.y)
        queued = max(queued, edit.impulses_before)
        _edit(simulation, edit, step.step, comparison, segment_index)
    for name, vx, vy, wz, cdr in step.commands:
        try:
            simulation.command(name, vx, vy, wz, cdr)
        except CommandRejected:
            pass  # an agent deleted after its command, as the node dropped it with the agent
    _swarm_commands(simulation, step, comparison, segment_index)
    # The agents' drive comes right after the impulses the edits applied (see Simulation).
    driven, rejected = simulation.apply_drive()
    _report_rejected(rejected, step.step, comparison, segment_index)
    if not drives_recorded:
        driven = 0  # not among the recorded impulses (recording.agent_topics)
    for impulse in impulses[queued + driven:]:
        simulation.queue_impulse(impulse.frame_id, impulse.x, impulse.y)


def _swarm_commands(simulation, step, comparison, segment_index):
    """A swarm's recorded commands (agent_commands rows), taken after the step's edits as
    the node's were: each names a ball of the step that is an agent, or is a difference."""
    if step.command_rows is None:
        return
    names = simulation.names
    for ball, vx, vy, wz in step.command_rows.tolist():
        ball = int(ball)
        name = names[ball] if ball < len(names) else f'ball row {ball}'
        try:
            simulation.command(name, vx, vy, wz)
        except CommandRejected as refusal:
            comparison.add(Difference(segment_index, step.step, 'command refused', None,
                                      'taken', str(refusal), math.inf))


def _close(simulation, step, comparison, segment_index, drives_recorded=True):
    """A closing record: the edits and impulses applied after the segment's last step.

    They are made as the node made them, and applied without a step; each must be accepted
    as recorded, and the impulse and edit messages the re-simulation makes must be the
    recorded ones (stamped with the step they would have preceded).
    """
    _make_edits(simulation, step, comparison, segment_index, drives_recorded)
    _report_rejected(simulation.apply_queued(), step.step, comparison, segment_index)
    _compare_events(simulation.pending_events(), step, comparison, segment_index)


def _edit(simulation, edit, k, comparison, segment_index):
    """Make one recorded edit through the Simulation as the node did; differences noted."""
    try:
        if edit.kind == 'spawn':
            ball = Ball(x=edit.x, y=edit.y, vx=edit.vx, vy=edit.vy, radius=edit.radius,
                        mass=edit.mass)
            # Renaming allowed: a name taken in the re-simulation shows as another name.
            [got], rejected = simulation.spawn([SpawnRequest(edit.name, True, ball,
                                                             agent=edit.agent)])
            if isinstance(got, EditRefused):
                raise got
            if got != edit.name:
                comparison.add(Difference(segment_index, k, 'spawned name', None, edit.name,
                                          got, math.inf))
        elif edit.kind == 'delete':
            rejected = simulation.delete(edit.name)
        else:
            rejected = simulation.set_state(edit.name, edit.x, edit.y, edit.vx, edit.vy,
                                            yaw=edit.yaw)
    except EditRefused as refusal:
        comparison.add(Difference(segment_index, k, f'{edit.kind} refused', None, edit.name,
                                  str(refusal), math.inf))
        return
    _report_rejected(rejected, k, comparison, segment_index)


def _report_rejected(rejected, k, comparison, segment_index):
    for rejection in rejected:
        comparison.add(Difference(segment_index, k, 'impulse rejected', None, 'applied',
                                  str(rejection), math.inf))


def _compare_events(record, step, comparison, segment_index, drives_recorded=True):
    """The impulse and edit messages the re-simulation made must be the recorded ones (the
    drives' among them only where they were recorded: an older file)."""
    impulses = record.impulses
    if not drives_recorded:
        impulses = impulses.pushes() if hasattr(impulses, 'pushes') else impulses
    for what, recorded, resimulated, shown in (
            ('impulse message', [i.cdr for i in step.impulses],
             [i.cdr for i in impulses if drives_recorded or not i.drive],
             decode_vector3_stamped),
            ('edit message', [e.text for e in step.edits], [e.text for e in record.edits],
             str)):
        if recorded == resimulated:
            continue
        position = next((i for i, (a, b) in enumerate(zip(recorded, resimulated)) if a != b),
                        min(len(recorded), len(resimulated)))
        values = [shown(items[position]) if position < len(items) else f'none of {len(items)}'
                  for items in (recorded, resimulated)]
        comparison.add(Difference(segment_index, step.step, f'{what} {position}', None,
                                  *values, math.inf))


def _compare_step(step, record, comparison, segment_index):
    """Compare one recorded step with the re-simulated record; True when identical."""
    before = comparison.count
    k = step.step
    if step.balls_stamp_ns is not None and step.balls_stamp_ns != record.stamp_ns:
        comparison.add(Difference(segment_index, k, 'balls stamp_ns', None,
                                  step.balls_stamp_ns, record.stamp_ns, math.inf))
    if step.positions is not None:
        comparison.arrays(segment_index, k, 'balls', _POSITION_NAMES, step.positions,
                          record.positions)
    if step.state is not None:
        comparison.arrays(segment_index, k, 'state', _STATE_NAMES, step.state,
                          np.concatenate((record.positions, record.velocities), axis=1))
    if step.stats is not None:
        resimulated = decode_state_layout(record.stats_cdr)[2]
        count = len(_COMPARED_STATS)
        comparison.arrays(segment_index, k, 'stats', _COMPARED_STATS, step.stats[:count],
                          resimulated[:count])
    _compare_agents(step, record, comparison, segment_index)
    return comparison.count == before


def _compare_agents(step, record, comparison, segment_index):
    """Each agent's odom (pose, heading, twist) and /tf must be the recorded bytes; a
    swarm's headings, which only `balls` carries, its bytes."""
    frame = record.agents
    if (frame is not None and not frame.topics and step.balls_cdr is not None
            and step.balls_cdr != record.balls_cdr):
        comparison.add(Difference(segment_index, step.step, 'balls message (headings)', None,
                                  len(step.balls_cdr), len(record.balls_cdr), math.inf))
    resimulated = {} if frame is None else dict(zip(frame.names, frame.odom_cdr))
    recorded = step.odom or {}
    for name in sorted(set(recorded) | set(resimulated)):
        if recorded.get(name) != resimulated.get(name):
            shown = [_odom_text(odom.get(name)) for odom in (recorded, resimulated)]
            comparison.add(Difference(segment_index, step.step, f'odom of {name}', None,
                                      *shown, math.inf))
    if step.tf_cdr is not None and (frame is None or step.tf_cdr != frame.tf_cdr):
        comparison.add(Difference(segment_index, step.step, '/tf message', None,
                                  len(step.tf_cdr), None if frame is None else
                                  len(frame.tf_cdr), math.inf))


def _odom_text(data):
    """An odom message as a difference shows it: pose and twist numbers, or 'none'."""
    if data is None:
        return 'none'
    try:
        odom = decode_odometry(data)
    except ValueError as error:
        return f'undecodable ({error})'
    return f'pose {odom.pose.tolist()} twist {odom.twist.tolist()}'


def resimulate(recording, progress=None):
    """Re-simulate every segment of a Recording; returns a Comparison.

    What cannot be re-simulated is passed over and said in Comparison.unchecked, never
    simulated through: the steps a gap in a split set lacks (recording_set.Gap; the run is
    picked up again from the state the next file resumes from), and the steps of a segment
    after a jump inside it (a damaged chunk dropped by ball_world_repair, a crafted log time)
    up to the next state to resume from.

    Raises ScenarioError when a segment's parameters do not build a world, RecordingError
    when the recording cannot be read. progress (tools.progress.Progress) counts steps.
    """
    comparison = Comparison()
    simulation = result = None
    scans = RecordedAgentMessages(recording)
    gaps = {(gap.segment, gap.resumes): gap for gap in getattr(recording, 'gaps', ())}
    for step in recording.steps():
        if progress is not None and not step.closing:
            progress.advance()
        segment = recording.segments[step.segment]
        if result is None or result.position != step.segment:
            result = _begin(recording, segment, step, comparison, gaps)
            if result.skipping is None:
                simulation = (_rebuild(segment, step) if step.step == 0
                              else _resume(segment))
                result.resumed = step.step != 0
        elif result.skipping is not None:
            point = _resume_point(recording, segment, step)
            if point is None:
                if not step.closing:
                    result.skipping.last = step.step
                continue
            # a later file of the set picks the segment up here: on from its state
            result = SegmentResult(segment.index, step.segment, resumed=True)
            comparison.segments.append(result)
            simulation = _resume(point)
        elif result.closing is not None:
            raise RecordingError(f'segment {segment.index} has step {step.step} after the '
                                 'closing record of its last step')
        elif step.step <= result.last_step:
            comparison.add(Difference(segment.index, step.step, 'step order', None,
                                      result.last_step, step.step, math.inf))
            continue
        elif step.step != result.last_step + 1:
            # Never re-simulate a gap: a crafted log time could ask for years of steps.
            comparison.unchecked.append(Unchecked(
                segment.index, result.last_step + 1, step.step - 1,
                f'segment {segment.index} jumps from step {result.last_step} to step '
                f'{step.step}: the steps between are not recorded'))
            result.skipping = Unchecked(
                segment.index, step.step, step.step,
                'no state to go on from after the steps missing before them')
            comparison.unchecked.append(result.skipping)
            continue
        if step.closing:
            before = comparison.count
            _close(simulation, step, comparison, segment.index, segment.drives_recorded)
            result.closing = (len(step.impulses), len(step.edits))
            if comparison.count != before:
                result.differing_steps += 1
            continue
        record = _advance(simulation, step, comparison, segment.index,
                          segment.drives_recorded)
        result.steps += 1
        result.impulses += len(step.impulses)
        result.edits += len(step.edits)
        result.last_step = step.step
        if result.first_step is None:
            result.first_step = step.step
        same = _compare_step(step, record, comparison, segment.index)
        same = scans.compare(step, record, comparison, segment.index) and same
        if not same:
            result.differing_steps += 1
    return comparison


def _resume_point(recording, segment, step):
    """The copy of `segment` a file of a set resumes from just before `step`, if any."""
    points = getattr(recording, 'resume_points', {})
    return points.get((segment.index, segment.log_offset_ns, step.step - 1))


def _begin(recording, segment, step, comparison, gaps):
    """The SegmentResult of a segment (or of the part of it a split file resumes) whose
    first step is `step`; the steps before it that are missing noted as unchecked."""
    result = SegmentResult(segment.index, step.segment)
    comparison.segments.append(result)
    if segment.resume is not None:
        gap = gaps.get((segment.index, segment.resume.step))
        if gap is not None:
            comparison.unchecked.append(Unchecked(
                segment.index, None if gap.last is None else gap.last + 1,
                segment.resume.step, gap.why))
    if step.step == 0 or (segment.resume is not None and step.step == segment.resume.step + 1):
        return result
    resumes = ('' if segment.resume is None
               else f' (its state is that of step {segment.resume.step})')
    result.skipping = Unchecked(segment.index, step.step, step.step,
                                f'the recording of segment {segment.index} begins at step '
                                f'{step.step}{resumes}: no state to start from')
    comparison.unchecked.append(result.skipping)
    return result


class RecordedAgentMessages:
    """The agents' recorded scans, ground truth and bumpers (<name>/scan, <name>/ground_truth,
    <name>/bumper), read alongside the steps in log-time order.

    Each must equal, byte for byte, the re-simulated agent's message of the same step (a
    scan's ranges with their seeded noise, the true pose and twist, the collision impulse in
    base_link; stamp and frame too); one recorded but not re-simulated, or the reverse, is a
    difference too. A recording made before a kind existed has none of it, and is compared
    without it.
    """

    def __init__(self, recording):
        self._kinds = {}  # topic -> (kind, agent name)
        for topic in recording.topics:
            found = agent_topics.agent_message(topic)
            if found is not None:
                self._kinds[topic] = found
        self.recorded_kinds = {kind for kind, _ in self._kinds.values()}
        self._messages = (recording.messages(set(self._kinds)) if self._kinds else iter(()))
        self._next = next(self._messages, None)

    def take(self, log_time_ns):
        """{(kind, agent name): bytes} recorded at this log time."""
        found = {}
        while self._next is not None and self._next.log_time_ns <= log_time_ns:
            if self._next.log_time_ns == log_time_ns:
                found[self._kinds[self._next.topic]] = self._next.data
            self._next = next(self._messages, None)
        return found

    def compare(self, step, record, comparison, segment_index):
        recorded = self.take(step.log_time_ns)
        resimulated = {key: data for key, data in _agent_messages(record).items()
                       if key[0] in self.recorded_kinds or key[0] == agent_topics.SCAN}
        if recorded == resimulated:
            return True
        for key in sorted(set(recorded) | set(resimulated)):
            ours, theirs = recorded.get(key), resimulated.get(key)
            if ours != theirs:
                kind, name = key
                shown = _SHOWN[kind]
                comparison.add(Difference(segment_index, step.step, f'{kind} {name}', None,
                                          shown(ours), shown(theirs), math.inf))
        return False


def _agent_messages(record):
    """{(kind, agent name): bytes} of a re-simulated record's scans, ground truth, bumpers."""
    agents = getattr(record, 'agents', None)
    if agents is None or not agents.topics:  # a swarm's agents have no messages
        return {}
    found = {(agent_topics.SCAN, scan.name): scan.cdr for scan in agents.scans}
    found.update(((agent_topics.GROUND_TRUTH, name), data)
                 for name, data in zip(agents.names, agents.ground_truth_cdr))
    found.update(((agent_topics.BUMPER, bumper.name), bumper.cdr)
                 for bumper in agents.bumpers)
    return found


def _bumper_text(data):
    """A bumper message as a difference shows it (or 'none')."""
    if data is None:
        return 'none'
    try:
        stamp_ns, frame_id, x, y, z = decode_vector3_stamped(data)
    except ValueError as error:
        return f'undecodable ({error})'
    return f'{frame_id} at {stamp_ns} ns: ({x!r}, {y!r}, {z!r})'


def _scan_text(data):
    """A LaserScan's bytes as a short description (or 'none')."""
    if data is None:
        return 'none'
    try:
        scan = decode_laser_scan(data)
    except ValueError as error:
        return f'undecodable ({error})'
    return (f'{scan.frame_id} at {scan.stamp_ns} ns, {len(scan.ranges)} ranges, first '
            f'{scan.ranges[:3].tolist()}')


#: How a difference shows each kind of agent message.
_SHOWN = {agent_topics.SCAN: _scan_text, agent_topics.GROUND_TRUTH: _odom_text,
          agent_topics.BUMPER: _bumper_text}


def describe(comparison):
    entries = []  # (segment, step, order, line): what was compared and what was not, in order
    for order, unchecked in enumerate(comparison.unchecked):
        step = unchecked.first if unchecked.first is not None else unchecked.last
        entries.append((unchecked.segment, step, order, unchecked.describe()))
    for order, result in enumerate(comparison.segments):
        if result.skipping is not None and not result.steps:
            continue  # said with the steps not checked
        verdict = ('identical' if not result.differing_steps
                   else f'{result.differing_steps} steps differ')
        edits = f', {result.edits} edits' if result.edits else ''
        if result.closing is not None:
            edits += (f'; after the last step {result.closing[0]} impulses and '
                      f'{result.closing[1]} edits')
        picked = ''
        if result.resumed:
            picked = (f' (picked up at step {result.first_step} from the state a split file '
                      'resumes from)')
        entries.append((result.index, result.first_step or 0, order,
                        f'segment {result.index}: {result.steps} steps compared (last step '
                        f'{result.last_step}), {result.impulses} impulses{edits}: '
                        f'{verdict}{picked}'))
    lines = [line for _, _, _, line in sorted(entries, key=lambda entry: entry[:3])]
    total = sum(result.steps for result in comparison.segments)
    if comparison.identical and not comparison.unchecked:
        lines.append(f'all {total} recorded steps re-simulate bit-identically (largest '
                     'difference 0)')
    elif comparison.identical:
        lines.append(f'the {total} steps checked re-simulate bit-identically (largest '
                     'difference 0), but NOT ALL STEPS COULD BE CHECKED (see above)')
    else:
        lines.append(f'first difference: {comparison.first.describe()}')
        lines.append(f'largest difference: {comparison.largest.size:.3g} at '
                     f'{comparison.largest.describe()}')
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog=PROG,
        description='Re-simulate a recording from its parameters, impulses and world edits '
                    'and check that every recorded pose and state row is bit-identical. Exit '
                    '0 if so, 1 if not, 2 if the recording cannot be read or rebuilt, 3 if '
                    'every step checked is identical but some could not be checked (a gap: '
                    'a split file missing or cut short; the report says which steps).')
    parser.add_argument('file', help='the .mcap recording, or a bag directory of split files')
    args = parser.parse_args(argv)
    progress = None
    try:
        recording = open_recording(args.file)
        balls = recording.topics.get(recording.topic_of('balls'))
        progress = Progress(balls.message_count if balls else 0, 'steps', PROG)
        comparison = resimulate(recording, progress)
        if not any(result.steps for result in comparison.segments):
            raise RecordingError('no recorded steps to compare'
                                 + ''.join(f'; {unchecked.describe()}'
                                           for unchecked in comparison.unchecked))
    except RecordingError as error:
        _abandon(progress)
        print(f'{PROG}: {args.file}: {error}', file=sys.stderr)
        return 2
    except ScenarioError as error:
        _abandon(progress)
        print(f'{PROG}: {args.file}: cannot rebuild the world: {error}', file=sys.stderr)
        return 2
    progress.finish()
    print_report('\n'.join(describe(comparison)))
    if not comparison.identical:
        return 1
    return UNCHECKED if comparison.unchecked else 0


def _abandon(progress):
    if progress is not None:
        progress.abandon()


if __name__ == '__main__':
    sys.exit(main())
