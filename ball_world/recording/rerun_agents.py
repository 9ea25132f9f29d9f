"""How Rerun draws agents (core.agents): an arrow along each heading.

A module of its own so rerun_log.py only calls it: an agent is a ball (drawn with the
balls) plus this arrow, from its centre, HEADING_RADII of its radius long, so the heading
reads at any zoom that shows the ball.
"""
import numpy as np
import rerun as rr

#: Entity path of the arrows, under the arena's +y-up transform.
AGENTS = 'arena/agents'
#: Arrow length in radii of the agent.
HEADING_RADII = 2.0
#: Arrow length where a record carries no radii, m.
DEFAULT_LENGTH = 0.5
#: Burnt orange: no ball has it, and it keeps a contrast of at least 4:1 on the viewer's
#: light theme and on its dark one (yellow was 1.3:1 on the light one). The agent's name is
#: drawn with the balls' names (rerun_labels places it where it collides with nothing).
AGENT_COLOR = (200, 80, 0)


def heading_arrows(record):
    """rr.Arrows2D of the record's agents, or None in a world without agents."""
    frame = getattr(record, 'agents', None)
    if frame is None:
        return None
    indices = frame.indices
    radii = getattr(record, 'radii', None)
    lengths = (np.asarray(radii, dtype=np.float64)[indices] * HEADING_RADII
               if radii is not None else np.full(len(indices), DEFAULT_LENGTH))
    vectors = np.stack((np.cos(frame.yaws), np.sin(frame.yaws)), axis=1) * lengths[:, None]
    return rr.Arrows2D(origins=np.asarray(record.positions, dtype=np.float64)[indices],
                       vectors=vectors, colors=AGENT_COLOR, radii=rr.Radius.ui_points(2.5),
                       draw_order=35.0)
