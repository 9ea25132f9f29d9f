"""How Rerun draws agents (core.agents): an arrow along each heading (the name is drawn with
the balls' names, rerun_labels), and each bumper hit (<name>/bumper) as an arrow from the
agent's centre along the impulse.

A module of its own so rerun_log.py only calls it: an agent is a ball (drawn with the
balls) plus its heading arrow, from the edge of its disc outwards, HEADING_RADII of its
radius long, so the heading reads at any zoom that shows the ball. Off the disc it still lies
on the robot's rays, on map cells, on other balls: it is cased (rerun_casing), a light orange
over a dark slate arrow, so it reads on any of them (1.19:1 on a pink robot before).
A hit's arrow (BUMPERS) points along the impulse the agent took, in the world (the message
holds it in base_link; turned back by the heading), its length the velocity change times
BUMPER_SECONDS but at least BUMPER_MIN_RADII radii, labelled with the agent and the impulse
in N s; BumperView keeps it on screen for BUMPER_SHOWN seconds of simulated time, since one
step is too short to see.
"""
import numpy as np

from ball_world.msgs.bumper_markers import BUMPER_MIN_RADII, BUMPER_SECONDS, BUMPER_SHOWN
from ball_world.recording.rerun_casing import cased_arrows

#: Entity path of the arrows, under the arena's +y-up transform.
AGENTS = 'arena/agents'
#: Arrow length in radii of the agent.
HEADING_RADII = 2.0
#: Arrow length where a record carries no radii, m.
DEFAULT_LENGTH = 0.5
#: Light orange, over its casing (rerun_casing: 7.3:1 on it): no ball is as light and as
#: orange. Alone it had no colour with 3:1 on every robot disc, ray and theme.
AGENT_COLOR = (255, 150, 40)
#: The heading's radius, UI points (its casing is CASING_POINTS wider).
AGENT_RADIUS = 2.0
#: Entity path of the bumper hits, under the arena's +y-up transform.
BUMPERS = 'arena/bumpers'
#: Light violet over its casing (rerun_casing: 7.5:1 on it): no ball has it. Alone, the violet
#: (160, 80, 235) had 1.55:1 on a robot's rays (screenshot of the dark theme).
BUMPER_VIEW_COLOR = (200, 160, 255)
#: The text of a hit's tag (rerun_text): a light violet.
BUMPER_TEXT_COLOR = (226, 208, 255)


def heading_arrows(record):
    """rr.Arrows2D of the record's agents, or None in a world without agents."""
    frame = getattr(record, 'agents', None)
    if frame is None:
        return None
    indices = frame.indices
    radii = getattr(record, 'radii', None)
    if radii is None:  # no disc to start from: from the centre, a fixed length
        own = np.zeros(len(indices))
        lengths = np.full(len(indices), DEFAULT_LENGTH)
    else:
        own = np.asarray(radii, dtype=np.float64)[indices]
        lengths = own * HEADING_RADII
    headings = np.stack((np.cos(frame.yaws), np.sin(frame.yaws)), axis=1)
    origins = np.asarray(record.positions, dtype=np.float64)[indices] + headings * own[:, None]
    return cased_arrows(origins, headings * lengths[:, None], AGENT_COLOR, AGENT_RADIUS, 35.0)


def heading_discs(record, radii):
    """(centres (k, 2), radii (k,)) of discs over the agents' heading arrows (radii: every
    ball's, in pose order), which no name may cover (rerun_labels keep_clear), or None:
    two per arrow, each a radius wide, at one and two radii beyond the disc's edge (the
    arrow runs from the edge to HEADING_RADII radii beyond it)."""
    frame = getattr(record, 'agents', None)
    if frame is None or not len(frame.indices):
        return None
    own = np.asarray(radii, dtype=np.float64)[frame.indices]
    headings = np.stack((np.cos(frame.yaws), np.sin(frame.yaws)), axis=1)
    centres = np.asarray(record.positions, dtype=np.float64)[frame.indices]
    along = [centres + headings * (own * (1.0 + k * HEADING_RADII / 2.0))[:, None]
             for k in (1, 2)]
    return np.concatenate(along), np.concatenate((0.5 * own, 0.5 * own))


def bumper_arrows(record):
    """rr.Arrows2D of the record's bumper hits (world frame, from each agent's centre), or
    None when no agent was hit in its step. Their labels are kept, not shown: rerun_log
    draws them as tags under each arrow's middle, where Rerun would draw them."""
    frame = getattr(record, 'agents', None)
    if frame is None or not frame.bumpers:
        return None
    row_of = {name: row for row, name in enumerate(frame.names)}
    rows = [row_of[bumper.name] for bumper in frame.bumpers]
    indices = frame.indices[rows]
    yaws = frame.yaws[rows]
    body = np.array([(bumper.x, bumper.y) for bumper in frame.bumpers], dtype=np.float64)
    cos, sin = np.cos(yaws), np.sin(yaws)
    world = np.stack((cos * body[:, 0] - sin * body[:, 1], sin * body[:, 0] + cos * body[:, 1]),
                     axis=1)
    size = np.hypot(world[:, 0], world[:, 1])
    radii = getattr(record, 'radii', None)
    masses = getattr(record, 'masses', None)
    radius = (np.asarray(radii, dtype=np.float64)[indices] if radii is not None
              else np.full(len(rows), DEFAULT_LENGTH / HEADING_RADII))
    change = (size / np.asarray(masses, dtype=np.float64)[indices] if masses is not None
              else size)
    length = np.maximum(change * BUMPER_SECONDS, BUMPER_MIN_RADII * radius)
    vectors = world / np.where(size > 0.0, size, 1.0)[:, None] * length[:, None]
    return cased_arrows(
        np.asarray(record.positions, dtype=np.float64)[indices], vectors, BUMPER_VIEW_COLOR,
        2.5, 36.0, labels=[f'{bumper.name} hit {value:.3g} N s'
                           for bumper, value in zip(frame.bumpers, size)],
        show_labels=[False] * len(rows))


class BumperView:
    """When to draw and clear the bumper arrows: a hit stays BUMPER_SHOWN simulated seconds,
    and, given a wall clock, `hold` seconds of its time too (a live view's page draws only the
    last frame of each chunk it is sent)."""

    def __init__(self, clock=None, hold=0.0):
        self.shown_until_ns = None
        self.clock = clock
        self.hold = hold
        self.wall_until = None

    def update(self, record):
        """('log', Arrows2D), ('clear', None) or None: what BUMPERS needs at this record."""
        arrows = bumper_arrows(record)
        if arrows is not None:
            self.shown_until_ns = record.stamp_ns + round(BUMPER_SHOWN * 1e9)
            self.wall_until = None if self.clock is None else self.clock() + self.hold
            return 'log', arrows
        if self.shown_until_ns is None:
            return None
        if record.step == 0:  # a reset: the hit's time is over, whatever the stamps say now
            self.shown_until_ns = min(self.shown_until_ns, record.stamp_ns)
        if record.stamp_ns < self.shown_until_ns or (
                self.wall_until is not None and self.clock() < self.wall_until):
            return None
        self.shown_until_ns = self.wall_until = None
        return 'clear', None
