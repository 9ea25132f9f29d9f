"""Contrast of the view's colours, measured on screenshots of the web viewer.

For each colour the view draws text or arrows in (rerun_agents, rerun_log, view_tracks), it
finds the pixels of a screenshot drawn in that colour (within TOLERANCE: antialiased edges
are left out), takes what lies around them (the most common colour in a small window that
is clearly not the colour itself: the view's background, or a label's box), and prints the
WCAG 2 contrast ratio of the colour against each background it was found on.

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

from ball_world.recording.rerun_agents import AGENT_COLOR  # noqa: E402
from ball_world.recording.rerun_log import CLOCK_COLOR, IMPULSE_COLOR  # noqa: E402
from ball_world.tools.view_tracks import TRACK_COLOR  # noqa: E402

COLORS = {'heading arrow': AGENT_COLOR, 'push arrow and label': IMPULSE_COLOR,
          'clock line': CLOCK_COLOR, 'track ring': TRACK_COLOR}
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


def measure(image, color):
    """[(background, pixels)] around the pixels drawn in `color`, most seen first."""
    pixels = np.asarray(image.convert('RGB'), dtype=np.int16)
    distance = np.linalg.norm(pixels - np.asarray(color, dtype=np.int16), axis=2)
    rows, cols = np.nonzero(distance <= TOLERANCE)
    seen = Counter()
    height, width = distance.shape
    for row, col in zip(rows.tolist(), cols.tolist()):
        window = pixels[max(0, row - RADIUS):min(height, row + RADIUS + 1),
                        max(0, col - RADIUS):min(width, col + RADIUS + 1)].reshape(-1, 3)
        far = window[np.linalg.norm(window - np.asarray(color), axis=1) > FAR]
        if len(far):
            values, counts = np.unique(far, axis=0, return_counts=True)
            seen[tuple(int(v) for v in values[counts.argmax()])] += 1
    return [(background, count) for background, count in seen.most_common()
            if count >= MIN_PIXELS]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('screenshots', nargs='+', type=Path)
    args = parser.parse_args(argv)
    for path in args.screenshots:
        image = Image.open(path)
        print(f'{path}:')
        for name, color in COLORS.items():
            found = measure(image, color)
            if not found:
                print(f'  {name} {color}: not on this screenshot')
                continue
            for background, count in found[:3]:
                print(f'  {name} {color} on {background} ({count} px): '
                      f'{contrast(color, background):.2f}:1')
    return 0


if __name__ == '__main__':
    sys.exit(main())
