"""Contrast of the view's colours, measured on screenshots of the web viewer.

For each colour the view draws text or arrows in (rerun_agents, rerun_log, view_tracks), it
finds the pixels of a screenshot drawn in that colour (within TOLERANCE: antialiased edges
are left out), takes what lies around them (the most common colour in a small window that
is clearly not the colour itself: the view's background, or a label's box), and prints the
WCAG 2 contrast ratio of the colour against each background it was found on. A cased mark
(rerun_casing) is measured against its casing; the casings, as the tags' pills, against
what lies around them.

    .venv/bin/python scripts/contrast.py docs/screenshots/demo-light-40s.png ...

Backgrounds seen under fewer than MIN_PIXELS pixels of a colour are not reported (a stroke
crossing a ball or another line). docs/view.md has the figures.
"""
import argparse
from collections import Counter
from pathlib import Path
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from ball_world.recording.rerun_agents import (AGENT_COLOR, BUMPER_TEXT_COLOR,  # noqa: E402
                                               BUMPER_VIEW_COLOR)
from ball_world.recording.rerun_casing import CASING_COLOR  # noqa: E402
from ball_world.recording.rerun_log import (IMPULSE_COLOR, IMPULSE_TEXT_COLOR,  # noqa: E402
                                            LABEL_LIMIT, name_color, RULER_TEXT_COLOR)
from ball_world.recording.rerun_text import TAG_COLOR  # noqa: E402
from ball_world.tools.view_tracks import TRACK_COLOR  # noqa: E402

#: What is drawn in each colour (or any of a list): arrows on the view, texts on their tags.
COLORS = {'casings and tags': CASING_COLOR}
#: Marks drawn over a dark casing (rerun_casing): measured against the casing beside them,
#: as a tag's text against its pill; the casing itself against what lies around it.
CASED = {'heading arrow': AGENT_COLOR, 'bumper arrow': BUMPER_VIEW_COLOR,
         'track ring': TRACK_COLOR, 'push arrow': IMPULSE_COLOR}
#: Texts, measured together (a pixel is the closest of their colours) against the tag's fill
#: as drawn beside them: a pixel without it in its window is not a tag's (the names' light
#: hues are also the highlights of shaded balls). The names: each ball's light hue.
TEXTS = [('push text', IMPULSE_TEXT_COLOR), ('bumper text', BUMPER_TEXT_COLOR),
         ('ruler text', RULER_TEXT_COLOR)] + [
    ('names', name_color(f'ball_{i}')) for i in range(LABEL_LIMIT)]
#: A pixel is drawn in the colour when it is this close to it (RGB distance).
TOLERANCE = 14.0
#: Around such a pixel, a colour this far from it is background.
FAR = 90.0
#: Half the side of the window looked at around each pixel.
RADIUS = 4
MIN_PIXELS = 25


def luminance(color):
    channels = np.asarray(color[:3], dtype=np.float64) / 255.0
    linear = np.where(channels <= 0.04045, channels / 12.92,
                      ((channels + 0.055) / 1.055) ** 2.4)
    return float(0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2])


def contrast(a, b):
    high, low = sorted((luminance(a), luminance(b)), reverse=True)
    return (high + 0.05) / (low + 0.05)


def measure(image, colors, beside=None):
    """[(background, colour, pixels)] around the pixels drawn in any of `colors` (each the
    closest of them), most seen first; with `beside`, only pixels that have that colour
    (within TOLERANCE) in their window, and it, as drawn, is their background."""
    pixels = np.asarray(image.convert('RGB'), dtype=np.int16)
    palette = np.asarray(colors, dtype=np.int16).reshape(-1, 3)
    distances = np.linalg.norm(pixels[:, :, None, :] - palette[None, None], axis=3)
    closest = distances.argmin(axis=2)
    rows, cols = np.nonzero(distances.min(axis=2) <= TOLERANCE)
    seen = Counter()
    height, width = closest.shape
    for row, col in zip(rows.tolist(), cols.tolist()):
        color = palette[closest[row, col]]
        window = pixels[max(0, row - RADIUS):min(height, row + RADIUS + 1),
                        max(0, col - RADIUS):min(width, col + RADIUS + 1)].reshape(-1, 3)
        if beside is None:
            far = window[np.linalg.norm(window - color, axis=1) > FAR]
        else:
            far = window[np.linalg.norm(window - np.asarray(beside), axis=1) <= TOLERANCE]
        if len(far):
            values, counts = np.unique(far, axis=0, return_counts=True)
            seen[(tuple(int(v) for v in values[counts.argmax()]),
                  tuple(int(v) for v in color))] += 1
    return [(background, color, count) for (background, color), count in seen.most_common()
            if count >= MIN_PIXELS]


def text_contrast(image, box):
    """(text colour, background, ratio) of a box (left, top, right, bottom pixels) holding one
    line of text in a colour this script does not know (the theme's: the clock's text
    document): the background is the box's most common colour, the text the pixels farthest
    from it (the 99th percentile of the distance, so a stray pixel does not count)."""
    pixels = np.asarray(image.convert('RGB').crop(box), dtype=np.int16).reshape(-1, 3)
    values, counts = np.unique(pixels, axis=0, return_counts=True)
    background = values[counts.argmax()]
    distance = np.linalg.norm(pixels - background, axis=1)
    text = pixels[distance >= np.percentile(distance, 99.0)]
    text = tuple(int(v) for v in np.median(text, axis=0))
    background = tuple(int(v) for v in background)
    return text, background, contrast(text, background)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('screenshots', nargs='+', type=Path)
    parser.add_argument('--text-box', action='append', default=[], metavar='NAME=L,T,R,B',
                        help='also measure the text in this box of each screenshot (pixels)')
    args = parser.parse_args(argv)
    for path in args.screenshots:
        image = Image.open(path)
        print(f'{path}:')
        for spec in args.text_box:
            name, _, box = spec.partition('=')
            text, background, ratio = text_contrast(image, tuple(int(v) for v in
                                                                 box.split(',')))
            print(f'  {name} {text} on {background}: {ratio:.2f}:1')
        for name, color in CASED.items():
            found = measure(image, [color], CASING_COLOR)
            if not found:
                print(f'  {name}: not on this screenshot')
            for background, drawn, count in found[:1]:
                print(f'  {name} {drawn} on its casing {background} ({count} px): '
                      f'{contrast(drawn, background):.2f}:1')
        texts = measure(image, [color for _, color in TEXTS], TAG_COLOR)
        for name, colors, beside in ([(n, [c], None) for n, c in COLORS.items()]
                                     + [(n, [c for m, c in TEXTS if m == n], TAG_COLOR)
                                        for n in dict(TEXTS)]):
            found = (measure(image, colors) if beside is None else
                     [item for item in texts if list(item[1]) in map(list, colors)])
            if not found:
                print(f'  {name}: not on this screenshot')
                continue
            worst = min(found, key=lambda item: contrast(item[1], item[0]))
            for background, color, count in found[:3] + ([worst] if worst not in found[:3]
                                                         else []):
                print(f'  {name} {color} on {background} ({count} px): '
                      f'{contrast(color, background):.2f}:1')
    return 0


if __name__ == '__main__':
    sys.exit(main())
