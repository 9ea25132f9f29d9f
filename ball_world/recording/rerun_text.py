"""Text the arena draws itself: names, push and bumper labels as tags, a dark pill with light
strokes, so their contrast does not depend on the viewer's theme.

Rerun draws a label's text in one colour on a box of the theme's: light grey (239) in the
light theme, dark grey (28) in the dark one. No colour has 4:1 on both (the best has 3.85:1
on each), and a label's text cannot take the theme's own text colour from a 2D archetype:
Rerun 0.41 gives a Points2D, Arrows2D, LineStrips2D or Boxes2D without colours its entity's
automatic colour, and that colour draws the text too (screenshots of both themes, docs/
view.md). So the view draws its texts itself, as geometry whose every colour is ours:
a tag is a capsule of TAG_COLOR (a Boxes2D of no height whose outline is as thick as the
tag), the text over it as line strips of a small monospaced stroke font (FONT). A tag's
text keeps TEXT_CONTRAST or more against TAG_COLOR on either theme.

Glyphs are polylines on a grid: x from 0 to 4, the baseline at y 0, lower case 4 high,
capitals and digits 6, descenders to -2, ADVANCE units from one character to the next.
A character the font does not have is drawn as '?'. Each polyline is kept as its segments
(strokes of two points): the SDK converts strips of one length from a single numpy array,
but polylines of mixed lengths one by one in Python, which took 7 ms a step for the names of
a 20-ball world.
"""
import functools

import numpy as np

#: Advance from one character to the next, in glyph units.
ADVANCE = 5.0
#: Lowest and highest y a glyph reaches, glyph units (descender, top of a bracket).
DESCENT, ASCENT = -2.0, 7.0
#: A tag's fill: a dark slate, under every tag on either theme.
TAG_COLOR = (30, 34, 42)
#: Each tag's text keeps at least this contrast against TAG_COLOR (WCAG 2).
TEXT_CONTRAST = 7.0

_GLYPHS = {
    ' ': '',
    '0': '1,0 3,0 4,1 4,5 3,6 1,6 0,5 0,1 1,0|3.5,5.5 0.5,0.5',
    '1': '1,5 2,6 2,0|1,0 3,0',
    '2': '0,5 1,6 3,6 4,5 4,4 0,0 4,0',
    '3': '0,5 1,6 3,6 4,5 4,4 3,3 1.5,3|3,3 4,2 4,1 3,0 1,0 0,1',
    '4': '3,0 3,6 0,2 4,2',
    '5': '4,6 0,6 0,3 3,3 4,2 4,1 3,0 0,0',
    '6': '3,6 1,6 0,5 0,1 1,0 3,0 4,1 4,2 3,3 0,3',
    '7': '0,6 4,6 1,0',
    '8': '1,3 0,4 0,5 1,6 3,6 4,5 4,4 3,3 1,3 0,2 0,1 1,0 3,0 4,1 4,2 3,3',
    '9': '4,3 1,3 0,4 0,5 1,6 3,6 4,5 4,1 3,0 1,0',
    'a': '4,4 4,0|4,1 3,0 1,0 0,1 0,3 1,4 3,4 4,3',
    'b': '0,6 0,0|0,1 1,0 3,0 4,1 4,3 3,4 1,4 0,3',
    'c': '4,3 3,4 1,4 0,3 0,1 1,0 3,0 4,1',
    'd': '4,6 4,0|4,1 3,0 1,0 0,1 0,3 1,4 3,4 4,3',
    'e': '0,2 4,2 4,3 3,4 1,4 0,3 0,1 1,0 3,0 4,1',
    'f': '4,5.5 3.5,6 2.5,6 1.5,5 1.5,0|0,4 3.5,4',
    'g': '4,4 4,-1 3,-2 1,-2 0,-1|4,1 3,0 1,0 0,1 0,3 1,4 3,4 4,3',
    'h': '0,6 0,0|0,3 1,4 3,4 4,3 4,0',
    'i': '2,4 2,0|2,5.4 2,6',
    'j': '3,4 3,-1 2,-2 1,-2|3,5.4 3,6',
    'k': '0,6 0,0|4,4 0,1.5|1.5,2.5 4,0',
    'l': '1,6 2,6 2,1 3,0',
    'm': '0,4 0,0|0,3 1,4 2,3 2,0|2,3 3,4 4,3 4,0',
    'n': '0,4 0,0|0,3 1,4 3,4 4,3 4,0',
    'o': '1,0 3,0 4,1 4,3 3,4 1,4 0,3 0,1 1,0',
    'p': '0,4 0,-2|0,1 1,0 3,0 4,1 4,3 3,4 1,4 0,3',
    'q': '4,4 4,-2|4,1 3,0 1,0 0,1 0,3 1,4 3,4 4,3',
    'r': '0,4 0,0|0,2.5 1.5,4 3,4 4,3.5',
    's': '4,3.5 3,4 1,4 0,3.2 1,2.2 3,1.8 4,0.8 3,0 1,0 0,0.5',
    't': '1.5,6 1.5,1 2.5,0 3.5,0|0,4 3.5,4',
    'u': '0,4 0,1 1,0 3,0 4,1|4,4 4,0',
    'v': '0,4 2,0 4,4',
    'w': '0,4 1,0 2,3 3,0 4,4',
    'x': '0,4 4,0|0,0 4,4',
    'y': '0,4 2,0|4,4 1,-2 0,-2',
    'z': '0,4 4,4 0,0 4,0',
    'A': '0,0 2,6 4,0|0.7,2 3.3,2',
    'B': '0,0 0,6 3,6 4,5 4,4 3,3 0,3|3,3 4,2 4,1 3,0 0,0',
    'C': '4,5 3,6 1,6 0,5 0,1 1,0 3,0 4,1',
    'D': '0,0 0,6 2.5,6 4,4.5 4,1.5 2.5,0 0,0',
    'E': '4,6 0,6 0,0 4,0|0,3 3,3',
    'F': '4,6 0,6 0,0|0,3 3,3',
    'G': '4,5 3,6 1,6 0,5 0,1 1,0 3,0 4,1 4,3 2,3',
    'H': '0,0 0,6|4,0 4,6|0,3 4,3',
    'I': '1,6 3,6|2,6 2,0|1,0 3,0',
    'J': '3,6 3,1 2,0 1,0 0,1',
    'K': '0,0 0,6|4,6 0,2|1.3,3.3 4,0',
    'L': '0,6 0,0 4,0',
    'M': '0,0 0,6 2,3 4,6 4,0',
    'N': '0,0 0,6 4,0 4,6',
    'O': '1,0 3,0 4,1 4,5 3,6 1,6 0,5 0,1 1,0',
    'P': '0,0 0,6 3,6 4,5 4,4 3,3 0,3',
    'Q': '1,0 3,0 4,1 4,5 3,6 1,6 0,5 0,1 1,0|2.5,1.5 4,-0.5',
    'R': '0,0 0,6 3,6 4,5 4,4 3,3 0,3|2,3 4,0',
    'S': '4,5 3,6 1,6 0,5 0,4 1,3 3,3 4,2 4,1 3,0 1,0 0,1',
    'T': '0,6 4,6|2,6 2,0',
    'U': '0,6 0,1 1,0 3,0 4,1 4,6',
    'V': '0,6 2,0 4,6',
    'W': '0,6 1,0 2,4 3,0 4,6',
    'X': '0,6 4,0|0,0 4,6',
    'Y': '0,6 2,3 4,6|2,3 2,0',
    'Z': '0,6 4,6 0,0 4,0',
    '_': '0,-1 4,-1',
    '.': '2,0 2,0.6',
    ',': '2,0.6 2,0 1.4,-1',
    ':': '2,3.4 2,4|2,0 2,0.6',
    ';': '2,3.4 2,4|2,0.6 2,0 1.4,-1',
    '-': '0.5,2.5 3.5,2.5',
    '+': '0.5,2.5 3.5,2.5|2,1 2,4',
    '=': '0.5,1.8 3.5,1.8|0.5,3.2 3.5,3.2',
    '(': '3,7 2,5.5 1.5,3 2,0.5 3,-1',
    ')': '1,7 2,5.5 2.5,3 2,0.5 1,-1',
    '[': '3,7 2,7 2,-1 3,-1',
    ']': '1,7 2,7 2,-1 1,-1',
    '/': '0.5,-1 3.5,7',
    '*': '2,1.5 2,4.5|0.7,2.2 3.3,3.8|0.7,3.8 3.3,2.2',
    '%': '0,0 4,6|0,6 1,6 1,5 0,5 0,6|3,1 4,1 4,0 3,0 3,1',
    '#': '1,0 1.5,6|2.5,0 3,6|0,2 4,2|0,4 4,4',
    "'": '2,6 2,4.5',
    '"': '1.3,6 1.3,4.5|2.7,6 2.7,4.5',
    '!': '2,6 2,1.6|2,0 2,0.6',
    '?': '0,5 1,6 3,6 4,5 4,4 2,2.6 2,1.6|2,0 2,0.6',
    '<': '4,5 0,2.5 4,0',
    '>': '0,5 4,2.5 0,0',
    '|': '2,7 2,-1',
}


def _parse(spec):
    """A glyph's polylines ('x,y x,y|x,y ...') as an (n, 2, 2) array of segments (a lone point
    as a segment of no length)."""
    segments = []
    for stroke in spec.split('|'):
        points = [[float(v) for v in point.split(',')] for point in stroke.split()]
        if len(points) == 1:
            points = points * 2
        segments.extend([a, b] for a, b in zip(points, points[1:]))
    return np.array(segments, dtype=np.float64).reshape(-1, 2, 2)


FONT = {char: _parse(spec) for char, spec in _GLYPHS.items()}


@functools.lru_cache(maxsize=4096)
def _strokes(text):
    glyphs = [FONT.get(char, FONT['?']) + (column * ADVANCE, 0.0)
              for column, char in enumerate(text)]
    out = np.concatenate(glyphs) if glyphs else np.zeros((0, 2, 2))
    out.flags.writeable = False  # shared by every tag of the same text
    return out


def strokes(text):
    """The text's strokes in glyph units from its left end on the baseline: an (n, 2, 2)
    array of segments (kept for each text: names repeat every step)."""
    return _strokes(text)


def width(text):
    """Glyph units from the first character's left edge to the last one's right edge."""
    return max(ADVANCE * len(text) - (ADVANCE - 4.0), 0.0)


class Tags:
    """Tags of one step, gathered and turned into Rerun archetypes in one go (layers)."""

    def __init__(self):
        self.rects = []  # (xmin, ymin, xmax, ymax)
        self.strips = []  # per tag, its (n, 2, 2) segments in world coordinates
        self.strip_colors = []  # per tag, the (r, g, b) of its segments

    def add(self, text, rect, unit, color):
        """A tag filling rect (xmin, ymin, xmax, ymax), the text centred in it, glyph unit
        `unit` (world units per glyph unit), its strokes in `color`."""
        xmin, ymin, xmax, ymax = rect
        self.rects.append(rect)
        left = 0.5 * (xmin + xmax) - 0.5 * width(text) * unit
        baseline = 0.5 * (ymin + ymax) - 0.5 * (DESCENT + 6.0) * unit
        self.strips.append(strokes(text) * unit + (left, baseline))
        self.strip_colors.append(color)

    def layers(self, stroke_points=0.8, order=60.0):
        """[rr.Boxes2D of the pills, rr.LineStrips2D of the text]: the pills drawn at `order`,
        the text just over them, `stroke_points` UI points thick (half on either side)."""
        import rerun as rr
        rects = np.asarray(self.rects, dtype=np.float64).reshape(-1, 4)
        centres = 0.5 * (rects[:, 0:2] + rects[:, 2:4])
        half_height = 0.5 * (rects[:, 3] - rects[:, 1])
        # A box of no size is not drawn: a tag narrower than high is a disc, just.
        half_length = np.maximum(0.5 * (rects[:, 2] - rects[:, 0]) - half_height,
                                 1e-3 * half_height)
        counts = [len(segments) for segments in self.strips]
        colors = np.repeat(np.asarray(self.strip_colors, dtype=np.uint8).reshape(-1, 3), counts,
                           axis=0)
        segments = (np.concatenate(self.strips) if self.strips else np.zeros((0, 2, 2)))
        return [rr.Boxes2D(centers=centres.astype(np.float32),
                           half_sizes=np.column_stack((half_length, np.zeros(len(rects))))
                           .astype(np.float32),
                           radii=half_height.astype(np.float32), colors=TAG_COLOR,
                           draw_order=order),
                rr.LineStrips2D(segments.astype(np.float32), colors=colors,
                                radii=rr.Radius.ui_points(stroke_points), draw_order=order + 1.0)]
