"""How Rerun draws agents (core.agents): an arrow along each heading, labelled with its name.

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
AGENT_COLOR = (255, 200, 0)


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
                       vectors=vectors, labels=list(frame.names), show_labels=True,
                       colors=AGENT_COLOR, radii=rr.Radius.ui_points(2.5), draw_order=35.0)
