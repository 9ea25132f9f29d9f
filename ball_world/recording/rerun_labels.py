"""Where the balls' names go in the Rerun arena, so that no two collide and none lies on a ball.

Rerun draws a point's label as a box of text centred below the point, in screen pixels,
whatever the zoom; it has no label offset and no collision avoidance of its own. So the
labels are points placed here, in world coordinates, for a view of the scene fitted into
VIEW_PIXELS: each name is tried below its ball, then above, right and left, and dropped when
every place would overlap another label or another ball. Agents come first (a robot is
always named when it can be), then the balls in pose order; a name keeps the place it had
at the previous step while that place stays free, so names do not jump around.

A live view draws each name as a tag (rerun_text) filling its box but for TAG_INSET_PIXELS
above and below (tag_rect); a file keeps Rerun's own labels, a little narrower than the box.

Pure geometry (numpy), no Rerun: rerun_log logs the points it returns, and the tests check
the boxes these functions describe.
"""
import numpy as np

from ball_world.recording.rerun_text import ADVANCE

#: The arena view's larger side is assumed to be this many pixels: a 1600 x 900 page gives
#: about 800, a 1280 x 720 laptop window about 600. Assuming fewer pixels than there are makes
#: boxes larger than drawn, so a label judged free is free on any window at least that big.
VIEW_PIXELS = 600.0
#: A glyph unit of a tag's text (rerun_text), pixels: its characters are ADVANCE units apart.
UNIT_PIXELS = 1.2
#: A label's box: the width of a character (a tag's; Rerun's labels, Inter at 12 px, are 6.4
#: on screenshots of the web viewer), the box's padding, its height (Rerun's, measured), and
#: the gap between a point and the box.
CHAR_PIXELS = ADVANCE * UNIT_PIXELS
PAD_PIXELS = 14.0
BOX_PIXELS = 24.0
GAP_PIXELS = 4.0
#: Room kept between a label box and a ball or another box, pixels.
CLEARANCE_PIXELS = 2.0
#: A tag is its label's box less this much at the top and at the bottom, pixels.
TAG_INSET_PIXELS = 3.0

BELOW, ABOVE, RIGHT, LEFT = range(4)
PLACES = (BELOW, ABOVE, RIGHT, LEFT)


class LabelScale:
    """Pixels per metre of the fitted view, and the box of a text in metres."""

    def __init__(self, view_bounds):
        xmin, ymin, xmax, ymax = view_bounds
        self.bounds = tuple(float(v) for v in view_bounds)
        self.metres_per_pixel = max(xmax - xmin, ymax - ymin, 1e-9) / VIEW_PIXELS

    def size(self, text):
        """(width, height) of a label box, m."""
        return ((CHAR_PIXELS * len(text) + PAD_PIXELS) * self.metres_per_pixel,
                BOX_PIXELS * self.metres_per_pixel)

    @property
    def gap(self):
        return GAP_PIXELS * self.metres_per_pixel

    @property
    def clearance(self):
        return CLEARANCE_PIXELS * self.metres_per_pixel


def label_point(place, x, y, radius, width, height, scale):
    """The point to log so that the box lies `place` of the ball at (x, y)."""
    gap = scale.gap
    if place == BELOW:
        return x, y - radius - scale.clearance
    if place == ABOVE:
        return x, y + radius + scale.clearance + height + gap
    side = radius + scale.clearance + 0.5 * width
    return x + (side if place == RIGHT else -side), y + 0.5 * height + gap


def box_of(point, width, height, scale):
    """(xmin, ymin, xmax, ymax) of the box Rerun draws for a label at `point` (+y up: the
    box hangs below the point)."""
    x, y = point
    return (x - 0.5 * width, y - scale.gap - height, x + 0.5 * width, y - scale.gap)


def tag_rect(point, text, scale):
    """(rect (xmin, ymin, xmax, ymax), glyph unit in metres) of the tag drawn for a label of
    `text` at `point`: the label's box, TAG_INSET_PIXELS shorter at either end."""
    width, height = scale.size(text)
    xmin, ymin, xmax, ymax = box_of(point, width, height, scale)
    inset = TAG_INSET_PIXELS * scale.metres_per_pixel
    return (xmin, ymin + inset, xmax, ymax - inset), UNIT_PIXELS * scale.metres_per_pixel


def boxes_overlap(a, b):
    """Whether axis-aligned boxes a and b ((..., 4) arrays) overlap."""
    return ((a[..., 0] < b[..., 2]) & (b[..., 0] < a[..., 2])
            & (a[..., 1] < b[..., 3]) & (b[..., 1] < a[..., 3]))


def box_hits_discs(box, centres, radii):
    """Which discs (centres (n, 2), radii (n,)) the box overlaps (n,) bool."""
    nearest_x = np.clip(centres[:, 0], box[0], box[2])
    nearest_y = np.clip(centres[:, 1], box[1], box[3])
    dx, dy = centres[:, 0] - nearest_x, centres[:, 1] - nearest_y
    return dx * dx + dy * dy < radii * radii


class LabelPlacer:
    """Places the labels of one scene step after step (see the module doc)."""

    def __init__(self, view_bounds):
        self.scale = LabelScale(view_bounds)
        self._places = {}  # name -> the place it had at the last step
        self._sizes = {}  # text -> (width, height)

    def size(self, text):
        size = self._sizes.get(text)
        if size is None:
            size = self._sizes[text] = self.scale.size(text)
        return size

    def place(self, positions, radii, names, first=(), keep_clear=None):
        """Label points for this step: (indices of the labelled balls, their points (k, 2)).

        positions (n, 2), radii (n,), names (n,); first: indices labelled before the others
        (the agents); keep_clear: (centres (m, 2), radii (m,)) of discs no label may cover
        either (the robots' heading arrows: a name tag lay over ball_0's).
        """
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        radii = np.asarray(radii, dtype=np.float64).reshape(-1)
        first = [int(i) for i in first]
        ahead = set(first)
        order = first + [i for i in range(len(names)) if i not in ahead]
        padded_radii = radii + self.scale.clearance
        if keep_clear is None:
            clear = (np.zeros((0, 2)), np.zeros(0))
        else:
            clear = (np.asarray(keep_clear[0], dtype=np.float64).reshape(-1, 2),
                     np.asarray(keep_clear[1], dtype=np.float64).reshape(-1)
                     + self.scale.clearance)
        kept = self._as_before(positions, radii, padded_radii, names, order, clear)
        if kept is not None:
            return kept
        xmin, ymin, xmax, ymax = self.scale.bounds
        kept, points, boxes = [], [], []
        for index in order:
            name = names[index]
            width, height = self.size(name)
            x, y = positions[index]
            radius = radii[index]
            previous = self._places.get(name)
            tried = ([previous] if previous is not None else []) + [
                p for p in PLACES if p != previous]
            others = np.ones(len(radii), dtype=bool)
            others[index] = False
            for place in tried:
                point = label_point(place, x, y, radius, width, height, self.scale)
                box = box_of(point, width, height, self.scale)
                if box[0] < xmin or box[1] < ymin or box[2] > xmax or box[3] > ymax:
                    continue
                if boxes and boxes_overlap(np.asarray(box), np.asarray(boxes)).any():
                    continue
                if box_hits_discs(box, positions[others], padded_radii[others]).any():
                    continue
                if box_hits_discs(box, *clear).any():
                    continue
                self._places[name] = place
                kept.append(index)
                points.append(point)
                boxes.append(box)
                break
            else:
                self._places.pop(name, None)
        return kept, np.asarray(points, dtype=np.float64).reshape(-1, 2)

    def _as_before(self, positions, radii, padded_radii, names, order, clear):
        """The answer when every name can keep its last place (the usual step): checked for
        all labels at once; None when one has no place yet or its place is taken."""
        places = [self._places.get(name) for name in names]
        if any(place is None for place in places) or not len(names):
            return None
        scale = self.scale
        sizes = np.array([self.size(name) for name in names]).reshape(-1, 2)
        width, height = sizes[:, 0], sizes[:, 1]
        places = np.array(places)
        x, y = positions[:, 0], positions[:, 1]
        side = radii + scale.clearance + 0.5 * width
        px = np.where(places == RIGHT, x + side, np.where(places == LEFT, x - side, x))
        py = np.select([places == BELOW, places == ABOVE],
                       [y - radii - scale.clearance,
                        y + radii + scale.clearance + height + scale.gap],
                       y + 0.5 * height + scale.gap)
        boxes = np.column_stack((px - 0.5 * width, py - scale.gap - height, px + 0.5 * width,
                                 py - scale.gap))
        xmin, ymin, xmax, ymax = scale.bounds
        if ((boxes[:, 0] < xmin) | (boxes[:, 1] < ymin) | (boxes[:, 2] > xmax)
                | (boxes[:, 3] > ymax)).any():
            return None
        overlap = boxes_overlap(boxes[:, None, :], boxes[None, :, :])
        np.fill_diagonal(overlap, False)
        if overlap.any():
            return None
        nearest_x = np.clip(x[None, :], boxes[:, 0:1], boxes[:, 2:3])
        nearest_y = np.clip(y[None, :], boxes[:, 1:2], boxes[:, 3:4])
        hits = (x[None, :] - nearest_x) ** 2 + (y[None, :] - nearest_y) ** 2 \
            < padded_radii[None, :] ** 2
        np.fill_diagonal(hits, False)
        if hits.any():
            return None
        if len(clear[1]) and any(box_hits_discs(box, *clear).any() for box in boxes):
            return None
        return order, np.column_stack((px, py))[order]
