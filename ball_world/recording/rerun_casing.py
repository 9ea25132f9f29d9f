"""Marks with a dark casing: a light line over a wider dark one, readable on anything.

A heading arrow or a track's ring lies on whatever is there: its robot's disc, the rays of
a scan, a map's grey cells, the white or the near-black of the viewer's two themes. No one
colour has 3:1 against all of them (the orange heading had 1.19:1 on a pink robot, the green
ring 1.13:1 on the map's cells). So such a mark is drawn twice in one batch: first wider in
CASING_COLOR (the tags' dark slate, rerun_text), then in its own light colour, which keeps
CORE_CONTRAST or more against the casing: the mark's edge is the casing whatever lies under
it, and the casing itself stands out from any light background (the dark theme's background
is as dark: there the light core does).

One batch, not two entities: a live view is sent one message per entity a flush, and a
page takes in few a second. Rerun draws a batch's instances in order, so the cores (logged
after their casings) lie on top (screenshots of both themes, docs/view.md).
"""
import numpy as np
import rerun as rr

from ball_world.recording.rerun_text import TAG_COLOR

#: The casing's colour: the tags' dark slate.
CASING_COLOR = TAG_COLOR
#: A cased mark's colour keeps at least this contrast against CASING_COLOR (WCAG 2).
CORE_CONTRAST = 7.0
#: How much wider than its core a casing is, UI points of radius.
CASING_POINTS = 1.5


def cased_arrows(origins, vectors, color, radius, draw_order, **fields):
    """rr.Arrows2D of each arrow twice: its casing (radius + CASING_POINTS, CASING_COLOR),
    then the arrow itself (radius in UI points, `color`). Extra fields are given per arrow
    and repeated for the casing; labels are the arrows' (the casings' are empty)."""
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 2)
    vectors = np.asarray(vectors, dtype=np.float64).reshape(-1, 2)
    count = len(origins)
    doubled = {name: list(value) * 2 for name, value in fields.items()}
    if 'labels' in fields:  # a label once, on the arrow itself
        doubled['labels'] = [''] * count + list(fields['labels'])
    return rr.Arrows2D(
        origins=np.concatenate((origins, origins)), vectors=np.concatenate((vectors, vectors)),
        colors=[CASING_COLOR] * count + [tuple(color)] * count,
        radii=[rr.Radius.ui_points(radius + CASING_POINTS)] * count
        + [rr.Radius.ui_points(radius)] * count,
        draw_order=draw_order, **doubled)


def cased_strips(strips, color, radius, draw_order):
    """rr.LineStrips2D of each strip twice: casing, then the strip itself (cased_arrows)."""
    strips = np.asarray(strips, dtype=np.float32)
    count = len(strips)
    return rr.LineStrips2D(
        np.concatenate((strips, strips)),
        colors=[CASING_COLOR] * count + [tuple(color)] * count,
        radii=[rr.Radius.ui_points(radius + CASING_POINTS)] * count
        + [rr.Radius.ui_points(radius)] * count,
        draw_order=draw_order)
