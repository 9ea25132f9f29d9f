"""Rerun logging of a run: a Sink that writes an `.rrd` file and/or streams to a live viewer.

Layout of the recording (application id 'ball_world'):

- `arena`: a static 180-degree rotation about x. Rerun's 2D views always draw +y downwards
  (the 2D view ignores ViewCoordinates), so the arena's children are logged in true world
  coordinates and this proper rotation turns them upside down for the view: +y points up as
  in RViz, and every logged position equals the simulated one.
- `arena/balls` (Points2D): positions every logged step; radii and colours at the first
  step of a segment and again whenever the balls (their names, in pose order) change, so a
  step costs one float32 array. No labels: Rerun draws a point's label just below the point
  itself, over the lower half of a ball, and has no label offset.
- `arena/labels` (Points2D, up to LABEL_LIMIT balls; beyond, the agents only): the names
  shown at each logged step, each below, above, right or left of its ball where it collides
  with no other name and no other ball, or dropped (rerun_labels): points, names and colours
  per step. A live view without velocities gets them in `arena/balls` instead, in the
  frame's row, as Arrows2D of length 0 at the same points (see _Feed._log_balls).
- `arena/names` (a live view's; Boxes2D and LineStrips2D): the same names drawn as tags
  (rerun_text), the labels above keeping their text, not shown. Rerun draws a label's text
  in one colour on a box of the theme's, and no colour reads on both themes' boxes (3.85:1
  at best); a tag's colours are all ours. A file keeps Rerun's labels (a tag per step would
  be most of the file).
- `clock` (TextDocument): the simulated time and the real-time factor, in a strip above
  the arena, in the theme's own text colour (every frame of a view, every
  FILE_CLOCK_SECONDS of a file).
- `arena/scans/<agent>` (LineStrips2D, Points2D): each scan as a fan of rays from its robot
  and its hit points (rerun_scans), in a file at every scan. A view draws every agent's
  latest scan together at `arena/scans`, at each frame a new one came: one message however
  many robots (a software-rendered page takes in few a second).
- `arena/walls` (LineStrips2D), once per segment at its first step: not static in a file,
  because a reset may change the walls and static data would rewrite the earlier segments.
- `arena/map` (a map's cells as a SegmentationImage under its origin and scale, rerun_map),
  static, once: the map cannot change during a run.
- `arena/impulses` (Arrows2D): each push (an applied impulse that is not an agent's own drive,
  AppliedImpulse.drive) for IMPULSE_SECONDS of simulated time, in IMPULSE_COLOR over a dark
  casing (rerun_casing: seen on robots, rays, map cells and both themes), at the point where
  it was applied, pointing along the velocity change. Its length is the
  velocity change times ARROW_SECONDS, kept between a floor (a tiny push is still seen) and
  a ceiling (a huge one stays on screen) set by the size of the scene, and shortened where
  it would leave the scene, so its head is always seen.
  Its label (the ball's name and J) is a Points2D of the same entity and row, so a viewer
  never draws an arrow with another one's label: Rerun draws an arrow's own label over the
  middle of its shaft, so the label point lies under the arrow's lowest end instead, and
  when that is the tail, where the ball was, under the ball's label too. The label keeps
  the text, not shown; a tag of the same entity and row draws it (rerun_text).
- `arena/velocities` (Arrows2D, optional): each ball's velocity times VELOCITY_SECONDS.
- `arena/trails` (LineStrips2D, optional): each ball's path over the last trail seconds.
- `arena/agents` (Arrows2D): each agent's heading (rerun_agents); its name is a label.
- `arena/bumpers` (Arrows2D): each agent's bumper hit, along the impulse (rerun_agents), its
  label a tag under the arrow's middle.
- `arena/scale`, `arena/scale/labels`: the ruler (rerun_scale), its labels tags.
- `plots/energy_change` (Scalars): kinetic energy relative to step 0 of the segment, in
  percent, rounded to ENERGY_RESOLUTION: an exact simulation conserves energy to ~1e-15, and
  an autoscaled plot would blow that rounding noise up to full-height steps. Real changes
  (impulses, a bug) are far above it. The legend names the absolute energy at step 0.
- `plots/collisions` (Scalars): ball-ball and ball-wall collisions since step 0 of the
  segment. Cumulative integers stay integers when the plot aggregates many steps per pixel
  (Max of a non-decreasing series), unlike per-step counts, which averaging turns into 0.5s.
- `plots/real_time_factor` (Scalars): simulated over wall time over the last RTF_WINDOW s
  of wall clock (from step 1 of a segment on) when the sink is given a clock (live), else
  the record's own value (conversions of a recording show what was recorded).

- `plots/momentum` (Scalars x, y): total momentum. In a walled box every wall bounce changes
  it, so its plot is mostly noise to a reader: the blueprint keeps it in a tab behind the
  collisions.
- `plots/energy_change/headroom`, `plots/collisions/headroom` (Scalars, invisible): values
  just beyond the plots' data (Headroom), so the axis Rerun fits to the data holds it whole.

Timelines: `sim_time`, the record's log time (simulation time plus the segment offset, so it
never goes back across resets), and `step`, a step counter over the whole recording: the
record's step plus the number of steps of the earlier segments. The SDK's wall-clock
`log_time` and `log_tick` timelines are switched off, and the recording id is derived from
the run's parameters, so identical runs give identical recorded content.

Destinations: the file and the viewer each get their own stream with the same recording id
(see rerun_outlet), so they show one recording; either can fail alone. They are fed
differently (_Feed). The file gets every logged step, buffered and sent as columns (one
chunk per entity for many steps), which keeps logging cheap at thousands of balls; `flush()`
sends what is buffered. A live view gets frames: at most VIEW_FPS a second of wall time,
the balls with their trails and velocities in one row (always drawn in step), sent every
VIEW_FLUSH_SECONDS, the plots every VIEW_PLOT_PERIOD, and the walls and the balls' looks
logged static, so a page opened late, after a Rerun server dropped the oldest frames, still
has them. It shows now, not every step.

Balls are named: `ball_<i>` by default, or the `names` a record (and a WorldSnapshot)
carries, in pose order, so balls may appear and disappear between steps; a record may also
carry `radii` and `masses` for names its segment did not start with.
"""
from collections import deque
import functools
import json
import math
from pathlib import Path
import sys
import time
import uuid
import zlib

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ball_world.core.parameters import BY_NAME
from ball_world.recording.files import claim_output, OutputClaim
from ball_world.recording.rerun_agents import (AGENTS, BUMPER_TEXT_COLOR, BUMPERS, BumperView,
                                               heading_arrows, heading_discs)
from ball_world.recording.rerun_casing import cased_arrows
from ball_world.recording.rerun_energy import EnergyAccount
from ball_world.recording.rerun_labels import boxes_overlap, LabelPlacer, tag_rect
from ball_world.recording.rerun_legend import LEGEND, legend_document
from ball_world.recording.rerun_map import map_bounds, map_entities
from ball_world.recording.rerun_outlet import new_stream, Outlet, OutletFailed, parse_view
from ball_world.recording.rerun_scale import padded, ruler
from ball_world.recording.rerun_scans import (scan_geometry, scan_layers, SCANS, view_layers,
                                              VIEW_MAX_POINTS, view_rays)
from ball_world.recording.rerun_text import Tags
from ball_world.step_record import PACKAGE_NAME

APPLICATION_ID = PACKAGE_NAME

ARENA = 'arena'
BALLS = 'arena/balls'
WALLS = 'arena/walls'
IMPULSES = 'arena/impulses'
VELOCITIES = 'arena/velocities'
TRAILS = 'arena/trails'
LABELS = 'arena/labels'
SCALE = 'arena/scale'
SCALE_LABELS = 'arena/scale/labels'
#: The simulated time and the real-time factor: a text document, in a strip of its own above
#: the arena, drawn in the theme's own text colour.
CLOCK = 'clock'
#: A live view's names, as tags (rerun_text): the labels' text stays in the recording (the
#: balls' row, or LABELS), not shown.
NAMES = 'arena/names'
ENERGY = 'plots/energy_change'
COLLISIONS = 'plots/collisions'
MOMENTUM = 'plots/momentum'
#: Invisible series that keep room above and below a plot's data (see Headroom).
ENERGY_HEADROOM = 'plots/energy_change/headroom'
COLLISIONS_HEADROOM = 'plots/collisions/headroom'
REAL_TIME_FACTOR = 'plots/real_time_factor'

SIM_TIME = 'sim_time'
STEP = 'step'

#: Labels are logged up to this many balls; beyond, they only clutter the view and would
#: cost a second positions array per step.
LABEL_LIMIT = 30
#: A line of label text is about this fraction of the scene's larger side in the fitted view:
#: an impulse's label below the tail of its arrow goes a line further down, under the label
#: of the ball it pushed.
LABEL_LINE_FRACTION = 0.03
#: Perceived lightness (OKLCH L) and chroma of a name's text on its tag: the ball's hue, light
#: enough for TEXT_CONTRAST on the tag's dark fill.
NAME_LIGHTNESS = 0.92
NAME_CHROMA = 0.06
#: Text of a push's tag (a light pink: the push arrow's hue) and of the ruler's.
IMPULSE_TEXT_COLOR = (255, 208, 232)
RULER_TEXT_COLOR = (230, 230, 230)
#: Draw order of the names' tags (over the balls, the headings and the scans' hits) and of
#: the pushes' (over everything).
NAME_ORDER = 45.0
IMPULSE_TAG_ORDER = 50.0
#: A file's clock line is logged every this many simulated seconds (a view's every frame).
FILE_CLOCK_SECONDS = 0.1

#: A file's buffered steps are sent once this many are pending, or this many positions.
MAX_PENDING_STEPS = 64
MAX_PENDING_POSITIONS = 500_000

#: Frames per second of wall time sent to a live view. The web viewer, rendering in
#: software on a 2-core machine, takes in this and stays live (make soak ARGS=liveview); a
#: frame per step (60-100 a second, trails included) it could not take, and it fell minutes
#: behind.
VIEW_FPS = 10.0
#: A view's SDK stream sends what it gathered this often: one chunk per entity holding
#: several frames. The web viewer ingests for a short while per frame it draws, and draws
#: about one frame a second in software (Chromium's SwiftShader, 2 cores): what it takes in
#: is counted in messages more than bytes. The demo at 0.5 s (12 chunks a second from the
#: world, 10 from the tracks) left a page opened late further behind by 0.7 s every second;
#: at 1 s it shows the present (docs/view.md, Screenshots and timings).
VIEW_FLUSH_SECONDS = 1.0
#: A live view keeps a push or a bumper hit on screen at least this long of wall time too: a
#: page is sent a chunk of frames every VIEW_FLUSH_SECONDS and, following the present, draws
#: the chunk's last frame, so an arrow shown for less could fall between two chunks' ends.
VIEW_EVENT_SECONDS = VIEW_FLUSH_SECONDS + 0.25
#: A view's plots show this much simulated time up to now...
VIEW_PLOT_SECONDS = 30.0
#: ...and are sent every this many seconds of wall time, as columns.
VIEW_PLOT_PERIOD = 5.0
#: A view's trails keep a point per this much simulated time (and the ball's position now):
#: the trails are most of what a view is sent, and a frame re-sends each one whole.
VIEW_TRAIL_SPACING = 0.1

#: Fixed namespace of the recording ids (uuid5 of the parameters).
RECORDING_NAMESPACE = uuid.uuid5(uuid.NAMESPACE_DNS, 'ball_world.ros.rerun')

#: Relative energy changes are rounded to this: far above the ~1e-15 rounding noise of an
#: exact step, far below any real change.
ENERGY_RESOLUTION = 1e-12

#: An impulse stays on screen this long in simulated time (until the first logged step at
#: or after it).
IMPULSE_SECONDS = 0.5
#: An impulse arrow is the velocity change it gives times this many seconds...
ARROW_SECONDS = 0.25
#: ...but at least / at most this fraction of the scene's larger side.
ARROW_MIN_FRACTION = 0.12
ARROW_MAX_FRACTION = 0.3
#: ...and shortened so that its head stays this fraction of the scene inside its bounds.
ARROW_INSET_FRACTION = 0.01
#: Light pink over its casing (rerun_casing: 7.5:1 on it): no ball has it (theirs are darker).
#: Alone, the deep pink (225, 0, 130) of old had 4.5:1 on both themes but lay on robots' discs,
#: rays and map cells, as the headings did.
IMPULSE_COLOR = (255, 140, 200)

#: A velocity arrow is the velocity times this many seconds.
VELOCITY_SECONDS = 0.25

#: Room kept above and below a plot's data, as a fraction of its range (Headroom); the energy
#: change's at least this many percent.
HEADROOM = 0.08
ENERGY_HEADROOM_MIN = 0.5

#: The real-time factor is measured over this much wall time (plus the step just before).
RTF_WINDOW = 1.0

#: Mid grey: seen on the viewer's light theme and on its dark one (contrast over 3 to 1 on
#: both).
WALL_COLOR = (128, 128, 128)
ENERGY_COLOR = (200, 130, 0)
#: With robots: the total (ENERGY_COLOR), the drives' part (blue), the rest's (grey). The
#: drives' part is all of the total but for pushes: drawn after it, it hides it.
ENERGY_COLORS = (ENERGY_COLOR, (40, 110, 230), (128, 128, 128))
#: The energy plot's titles, without robots and with: the series by colour.
ENERGY_TITLES = ('kinetic energy change since step 0 [%]',
                 'energy change [%]: orange all, blue drives, grey rest')
#: Ball-ball blue, ball-wall brown: the walls' grey ran along the plot's grey zero line.
COLLISION_COLORS = ((90, 150, 240), (190, 110, 40))
COLLISIONS_TITLE = 'collisions since step 0: blue ball-ball, brown ball-wall'
GOLDEN_RATIO_CONJUGATE = (math.sqrt(5.0) - 1.0) / 2.0
#: Perceived lightness (OKLCH L) and the most chroma of the balls' colours (ball_color).
BALL_LIGHTNESS = 0.565
BALL_CHROMA = 0.14


#: What IMPULSES holds when no push is on screen.
IMPULSES_CLEARED = (rr.Arrows2D.cleared(), rr.Points2D.cleared(), rr.Boxes2D.cleared(),
                    rr.LineStrips2D.cleared())


def ball_color(name):
    """A stable colour per ball name, kept when other balls come and go.

    `ball_<i>` gets hue i times the golden ratio (neighbouring indices stay distinct for any
    N); any other name a hue from its CRC-32. Every hue has the same perceived lightness
    (OKLCH, BALL_LIGHTNESS), a mid tone that keeps a contrast of about 4 to 1 against white
    and against black: a ball and its label are seen on the viewer's light theme and on its
    dark one alike (light pastels vanished on the light one).
    """
    return _oklch_color(BALL_LIGHTNESS, BALL_CHROMA, _hue(name))


@functools.lru_cache(maxsize=4096)
def name_color(name):
    """The colour of a ball's name on its tag (a live view's, rerun_text): the ball's hue,
    light (NAME_LIGHTNESS), so the name reads on the tag's dark fill on either theme."""
    return _oklch_color(NAME_LIGHTNESS, NAME_CHROMA, _hue(name))


def _hue(name):
    """A ball's hue in turns: `ball_<i>` i times the golden ratio, any other name its CRC-32."""
    prefix, _, index = name.rpartition('_')
    if prefix == 'ball' and index.isdigit() and len(index) < 10:
        return (int(index) * GOLDEN_RATIO_CONJUGATE) % 1.0
    return zlib.crc32(name.encode()) / 2**32


def _oklch_color(lightness, chroma, hue):
    """sRGB (0-255) of the most colourful colour of this lightness and hue, up to `chroma`,
    that sRGB can show."""
    while True:
        linear = _oklch_to_linear_srgb(lightness, chroma, hue)
        if all(-1e-9 <= c <= 1.0 + 1e-9 for c in linear) or chroma <= 0.0:
            break
        chroma -= 0.005
    return tuple(round(_srgb_encode(min(max(c, 0.0), 1.0)) * 255) for c in linear)


def _oklch_to_linear_srgb(lightness, chroma, hue):
    """Björn Ottosson's OKLab (here in polar form, hue in turns) to linear sRGB."""
    a = chroma * math.cos(2.0 * math.pi * hue)
    b = chroma * math.sin(2.0 * math.pi * hue)
    long_ = (lightness + 0.3963377774 * a + 0.2158037573 * b) ** 3
    medium = (lightness - 0.1055613458 * a - 0.0638541728 * b) ** 3
    short = (lightness - 0.0894841775 * a - 1.2914855480 * b) ** 3
    return (4.0767416621 * long_ - 3.3077115913 * medium + 0.2309699292 * short,
            -1.2684380046 * long_ + 2.6097574011 * medium - 0.3413193965 * short,
            -0.0041960863 * long_ - 0.7034186147 * medium + 1.7076147010 * short)


def _srgb_encode(value):
    """Linear light to the sRGB transfer curve, both in [0, 1]."""
    return 12.92 * value if value <= 0.0031308 else 1.055 * value ** (1.0 / 2.4) - 0.055


def default_names(count):
    return tuple(f'ball_{i}' for i in range(count))


def names_of(item):
    """The ball names of a record or snapshot, in pose order (`ball_<i>` unless it says)."""
    names = getattr(item, 'names', None)
    return tuple(names) if names is not None else default_names(len(item.positions))


def recording_id(parameters):
    """The same parameters give the same id, so an identical run gives an identical file."""
    canonical = json.dumps(parameters, sort_keys=True, default=repr)
    return str(uuid.uuid5(RECORDING_NAMESPACE, canonical))


def scene_bounds(world):
    """(xmin, ymin, xmax, ymax) around the walls, the balls and the map, with a small
    margin."""
    walls = np.asarray(world.walls, dtype=np.float64).reshape(-1, 4)
    boxes = [np.column_stack((np.minimum(walls[:, 0:2], walls[:, 2:4]),
                              np.maximum(walls[:, 0:2], walls[:, 2:4])))]
    if len(world.radii):
        reach = np.asarray(world.radii)[:, None]
        boxes.append(np.column_stack((world.positions - reach, world.positions + reach)))
    if getattr(world, 'occupancy_map', None) is not None:
        boxes.append(np.array([known_bounds(world.occupancy_map)]))
    boxes = np.concatenate(boxes)
    if len(boxes) == 0:
        return (-1.0, -1.0, 1.0, 1.0)
    xmin, ymin = boxes[:, 0:2].min(axis=0)
    xmax, ymax = boxes[:, 2:4].max(axis=0)
    margin = 0.03 * max(xmax - xmin, ymax - ymin, 1e-9)
    return (xmin - margin, ymin - margin, xmax + margin, ymax + margin)


def known_bounds(occupancy_map):
    """(xmin, ymin, xmax, ymax) of a map's known cells (free or occupied), m: the view fits
    what was mapped, not the unknown the image holds around it (the TurtleBot3 sandbox is
    4 m across in a 19 m image). The whole grid when nothing is known."""
    known = np.asarray(occupancy_map.data) >= 0
    rows, columns = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    if not len(rows):
        return map_bounds(occupancy_map)
    x, y = occupancy_map.origin
    resolution = occupancy_map.resolution
    return (x + columns[0] * resolution, y + rows[0] * resolution,
            x + (columns[-1] + 1) * resolution, y + (rows[-1] + 1) * resolution)


def clock_text(record, rtf):
    """The clock line: simulated time, and the real-time factor where it is known."""
    text = f'simulated time {record.stamp_ns * 1e-9:.1f} s'
    if rtf is not None and math.isfinite(rtf):
        text += f', real-time factor {rtf:.2f}'
    return text


def view_bounds(world):
    """The arena view's bounds: the scene and room for the ruler's labels at the bottom and
    the left (rerun_scale.padded)."""
    return padded(scene_bounds(world))


def expected_real_time_factor(parameters):
    """The real-time factor the run's rate aims at (rate_hz x dt), or None when it runs as
    fast as it can (rate_hz 0): then no scale fits in advance."""
    rate_hz = float(parameters.get('rate_hz', BY_NAME['rate_hz'].default))
    dt = float(parameters.get('dt', BY_NAME['dt'].default))
    if rate_hz <= 0.0:
        return None
    return rate_hz * dt if dt > 0.0 else 1.0


def real_time_factor_axis(parameters):
    """The real-time factor's y axis from 0 to a quarter above its aim: an automatic range
    would blow jitter of 0.99-1.01 up to the full height (it once started at 1.04)."""
    expected = expected_real_time_factor(parameters)
    return None if expected is None else rrb.ScalarAxis(range=(0.0, 1.25 * expected))


def blueprint(world, parameters=None, plot_seconds=None):
    """The arena large on the left (+y up, bounds fitted), the plots stacked on the right.

    The 2D view's origin is the root, above the `arena` flip, so its visual bounds are in the
    flipped frame: world y in [ymin, ymax] is view y in [-ymax, -ymin]. The plots' legends
    are hidden, their titles name the series' colours. plot_seconds:
    the plots show only that much simulated time up to the time shown (a live view: what a
    viewer draws each frame stays bounded however long the run), else the whole run.
    """
    # With room at the bottom and the left for the ruler's labels (rerun_scale).
    xmin, ymin, xmax, ymax = (float(v) for v in view_bounds(world))
    arena = rrb.Vertical(
        # The clock line: a text document is drawn in the theme's text colour.
        rrb.TextDocumentView(origin=f'/{CLOCK}', name='clock'),
        rrb.Spatial2DView(
            origin='/', contents=f'/{ARENA}/**', name='arena (+y up)',
            visual_bounds=rrb.VisualBounds2D(x_range=[xmin, xmax], y_range=[-ymax, -ymin])),
        row_shares=[1, 12])
    window = {} if plot_seconds is None else {'time_ranges': rrb.VisibleTimeRange(
        SIM_TIME, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-plot_seconds),
        end=rrb.TimeRangeBoundary.cursor_relative())}
    # The plots' legends are hidden: a legend box lay over the curves (three rows of the
    # energy's covered a third of its plot); each title names its series' colours instead.
    hidden = rrb.PlotLegend(visible=False)
    robots = bool((parameters or {}).get('agents'))
    plots = rrb.Vertical(
        # What each mark is (rerun_legend), in the theme's text colour.
        rrb.TextDocumentView(origin=f'/{LEGEND}', name='legend'),
        rrb.TimeSeriesView(origin=f'/{ENERGY}', name=ENERGY_TITLES[robots],
                           plot_legend=hidden, **window),
        # Momentum is logged (it is part of the recording) but, in a walled box, mostly
        # the walls' doing: it sits in a tab behind the collisions.
        rrb.Tabs(rrb.TimeSeriesView(origin=f'/{COLLISIONS}', name=COLLISIONS_TITLE,
                                    plot_legend=hidden, **window),
                 rrb.TimeSeriesView(origin=f'/{MOMENTUM}', name='momentum [kg m/s]: red x, '
                                    'green y', plot_legend=hidden, **window)),
        rrb.TimeSeriesView(origin=f'/{REAL_TIME_FACTOR}',
                           name=f'real-time factor (last {RTF_WINDOW:g} s)', plot_legend=hidden,
                           axis_y=real_time_factor_axis(parameters or {}), **window),
        row_shares=[8, 4, 4, 4])
    return rrb.Blueprint(
        rrb.Horizontal(arena, plots, column_shares=[2, 1]),
        rrb.TimePanel(timeline=SIM_TIME, state='collapsed', play_state='following'),
        collapse_panels=True)


def clip_arrow(origin, vector, bounds):
    """The vector shortened (same direction) so that origin + vector lies within bounds.

    bounds: (xmin, ymin, xmax, ymax), which must hold the origin. An arrow pushed past the
    edge of the view would lose its head, which is what tells a push's direction.
    """
    scale = 1.0
    for axis in (0, 1):
        low, high = bounds[axis], bounds[axis + 2]
        start, length = float(origin[axis]), float(vector[axis])
        tip = start + length
        if tip > high and length > 0.0:
            scale = min(scale, max(0.0, (high - start) / length))
        elif tip < low and length < 0.0:
            scale = min(scale, max(0.0, (low - start) / length))
    return (vector[0] * scale, vector[1] * scale)


def energy_change(energy, energy0):
    """Percent change from energy0, rounded to ENERGY_RESOLUTION; the energy itself if 0."""
    if energy0 <= 0.0:
        return energy
    return round((energy - energy0) / energy0 / ENERGY_RESOLUTION) * ENERGY_RESOLUTION * 100.0


def energy_legend(energy0, split=False):
    """The energy series' names: the total's, and with robots (split) the drives' and the
    rest's (rerun_energy)."""
    total = ('kinetic energy [J] (0 J at step 0)' if energy0 <= 0.0 else
             f'all: change from {energy0:.6g} J at step 0' if split else
             f'change from {energy0:.6g} J at step 0')
    if not split:
        return total
    return [total, "robots' drives: energy put in minus taken out",
            'the rest: pushes, edits (collisions keep energy: 0)']


def energy_series(energy0, split=False):
    """rr.SeriesLines of the energy plot: names and colours (ENERGY_COLORS)."""
    names = energy_legend(energy0, split)
    if not split:
        return rr.SeriesLines(names=names, colors=ENERGY_COLOR)
    return rr.SeriesLines(names=names, colors=list(ENERGY_COLORS))


class Headroom:
    """Values just beyond a plot's data, for an invisible series that keeps them in view.

    Rerun's time series view fits its y axis to the data's exact extremes, so a curve at
    its highest (the collisions' total, always) ran along the plot's top edge, half cut off.
    Invisible series a little above and below the data (HEADROOM of its range, the energy
    change at least +-ENERGY_HEADROOM_MIN %) make the fitted axis hold it whole. Over the
    last `window` s of log time (a view's plots show that much), else the whole segment.
    """

    def __init__(self, window=None):
        self.window_ns = None if window is None else round(window * 1e9)
        self.rows = deque()  # (log ns, energy low, energy high, collisions)
        self.extremes = None  # without a window: (energy low, high, collisions high)

    def clear(self):
        self.rows.clear()
        self.extremes = None

    def add(self, time_ns, energy, collisions):
        """(energy above, energy below, collisions above) for a new row; energy: a value or
        the values of the row (all of them kept in view)."""
        if isinstance(energy, tuple):
            return self._add(time_ns, min(energy), max(energy), collisions)
        return self._add(time_ns, energy, energy, collisions)

    def _add(self, time_ns, energy_low, energy_high, collisions):
        if self.window_ns is None:
            low, high, most = self.extremes or (energy_low, energy_high, collisions)
            self.extremes = low, high, most = min(low, energy_low), max(
                high, energy_high), max(most, collisions)
        else:
            rows = self.rows
            rows.append((time_ns, energy_low, energy_high, collisions))
            while rows[0][0] < time_ns - self.window_ns:
                rows.popleft()
            low = min(row[1] for row in rows)
            high = max(row[2] for row in rows)
            most = max(row[3] for row in rows)
        room = max(HEADROOM * (high - low), ENERGY_HEADROOM_MIN)
        return high + room, low - room, most * (1.0 + HEADROOM) + 1.0


class RealTimeFactor:
    """Simulated over wall time over the last `window` s of arrivals, plus the step before.

    Keeping the last step before the window means a stall longer than the window still
    shows (one step over the whole stall) and low rates still get a value. Nothing is
    reported until the steps span half a window: the first few steps of a run (or after a
    reset) come at uneven times, and a factor over 20 ms of them would read as 2 or 3.
    """

    def __init__(self, clock, window=RTF_WINDOW):
        self.clock = clock
        self.window = window
        self._steps = deque()  # (wall s, simulation ns)

    def clear(self):
        self._steps.clear()

    def add(self, stamp_ns):
        """Note a step's arrival; return the factor, or None until there are two steps."""
        now = self.clock()
        steps = self._steps
        steps.append((now, stamp_ns))
        while len(steps) > 2 and steps[1][0] < now - self.window:
            steps.popleft()
        if len(steps) < 2:
            return None
        (wall0, sim0), (wall1, sim1) = steps[0], steps[-1]
        if wall1 - wall0 < 0.5 * self.window:
            return None
        return (sim1 - sim0) * 1e-9 / (wall1 - wall0)


class _Pending:
    """Logged steps not yet sent: one row per step, sent as columns by _send.

    A step is one tuple appended to one list, a single operation that a signal (SIGINT's
    KeyboardInterrupt runs between two bytecodes) either lets happen or not: the columns
    built from the rows always have equal lengths. With one list per column, an interrupt
    between two appends left them unequal, and the SDK refused the whole buffer at close.
    """

    def __init__(self):
        self.rows = []  # (step, log ns, positions, velocities or None, label points or
        #                  None, energy, collisions, momentum, real-time factor or None)
        self.position_count = 0  # a hint for when to send, never used to build a column

    def add(self, row):
        self.rows.append(row)
        if row[2] is not None:
            self.position_count += len(row[2])

    def clear(self):
        self.rows = []
        self.position_count = 0

    def columns(self):
        """The rows as columns: steps, times, positions and velocities (of the rows that have
        them: a file's), (steps, times, points) of the labels where they are shown, energy,
        collisions, momentum, and (steps, times, values) of the real-time factor where it
        is known."""
        steps, times, positions, velocities, labels, energy, collisions, momentum, rtf = \
            zip(*self.rows)
        return (steps, times, [p for p in positions if p is not None],
                [v for v in velocities if v is not None], _where_known(steps, times, labels),
                energy, collisions, momentum, _where_known(steps, times, rtf))

    def __len__(self):
        return len(self.rows)


def _energy_columns(rows):
    """(n,) or (n, k) float64 of the energy rows (tuples of 1 or 3 values; rows of a segment
    with fewer, before a reset, padded with NaN: no point drawn)."""
    width = max(len(row) for row in rows)
    if width == 1:
        return np.array([row[0] for row in rows], dtype=np.float64)
    out = np.full((len(rows), width), np.nan)
    for i, row in enumerate(rows):
        out[i, :len(row)] = row
    return out


def _where_known(steps, times, values):
    """(steps, times, values) of the rows whose value is not None."""
    known = [(s, t, v) for s, t, v in zip(steps, times, values) if v is not None]
    return tuple(zip(*known)) if known else ((), (), ())


class _Segment:
    """What one segment's start says about its balls: radius and mass by name."""

    def __init__(self, world):
        names = names_of(world)
        self.radius = dict(zip(names, np.asarray(world.radii, dtype=np.float64).tolist()))
        self.mass = dict(zip(names, np.asarray(world.masses, dtype=np.float64).tolist()))
        self.smallest = min(self.radius.values(), default=0.1)
        xmin, ymin, xmax, ymax = scene_bounds(world)
        self.span = max(xmax - xmin, ymax - ymin)
        # Arrow heads stay this far inside the scene's bounds (the view's edges).
        inset = ARROW_INSET_FRACTION * self.span
        self.inside = (xmin + inset, ymin + inset, xmax - inset, ymax - inset)
        self.view = view_bounds(world)


class RerunSink:
    """Logs a run to a Rerun `.rrd` file and/or a live viewer; see the module docstring.

    path: the .rrd file, or None. view: None, 'spawn' (start the native viewer) or a
    rerun+http://HOST:PORT/proxy URL. every=k logs every k-th step of a segment to the
    file, plus step 0, every step with impulses or edits and the last step before a reset
    or close; collision totals stay exact. The view gets a frame at most view_fps times a
    second of wall time instead (see _Feed). velocities, trail_seconds: the optional layers.
    clock: a wall clock in seconds (time.monotonic) to measure the real-time factor over
    the last second; without it the record's value is logged. report: called with one line
    when one destination fails while another goes on (when the last one fails, the sink
    raises instead, so its owner drops it and says so). file_process: the file is written
    by a child process (rerun_process), which keeps the SDK's per-chunk index of a long
    recording out of this process's memory. view_recording_id: the view's recording id
    (other programs may draw into the same recording); None: derived from the parameters,
    the file's.
    """

    def __init__(self, path=None, every=1, view=None, velocities=False, trail_seconds=0.0,
                 clock=None, report=None, view_fps=VIEW_FPS, file_process=False,
                 view_recording_id=None, spare=False):
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f'every must be a whole number >= 1, got {every!r}')
        if not (isinstance(trail_seconds, (int, float)) and 0.0 <= trail_seconds < math.inf):
            raise ValueError(f'trail_seconds must be >= 0, got {trail_seconds!r}')
        if not (isinstance(view_fps, (int, float)) and 0.0 < view_fps < math.inf):
            raise ValueError(f'view_fps must be > 0, got {view_fps!r}')
        if path is None and view is None:
            raise ValueError('RerunSink needs a path, a view or both')
        if view is not None:
            parse_view(view)  # refuse a bad view now, before anything is opened
        self._own_claim = None
        if path is not None and not isinstance(path, OutputClaim):
            # Claimed here: a regular file, replaced if it exists, never through a symlink.
            path = self._own_claim = claim_output(path, overwrite=True)
        self.claim = path
        self.path = None if path is None else Path(path.path)
        self.view = view
        self.report = report or (lambda line: print(f'ball_world: {line}', file=sys.stderr))
        layers = dict(velocities=bool(velocities), trail_seconds=float(trail_seconds),
                      clock=clock)
        self._feeds = []
        if self.claim is not None:
            claim = self.claim
            self._feeds.append(_Feed(lambda stream, plan: Outlet.file(claim, stream, plan),
                                     every=every,
                                     stream_factory=_file_stream(file_process, spare),
                                     **layers))
        if view is not None:
            self._feeds.append(_Feed(lambda stream, plan: Outlet.view(view, stream, plan),
                                     frame_period=1.0 / view_fps,
                                     recording_id=view_recording_id,
                                     frame_clock=clock or time.monotonic, **layers))
        self._closed = False

    def start_segment(self, world, info):
        """Open the destinations on the first segment; log the segment's walls and balls."""
        if self._closed:
            raise RuntimeError('RerunSink is closed')
        self._each_feed(lambda feed: feed.start_segment(world, info))

    def write_step(self, record):
        """Hand the step to each destination, which logs it or not (every, frame rate)."""
        if self._closed:
            raise RuntimeError('RerunSink.write_step after close')
        self._each_feed(lambda feed: feed.write_step(record))

    def flush(self):
        """Send the buffered steps and have each destination write them (bounded waits)."""
        if not self._closed:
            self._each_feed(lambda feed: feed.flush())

    def next_part(self, claim, done=None):
        """Finish the file (its last step logged, its footer written) and go on in the
        claimed one (recording.files.OutputClaim), which opens on its own: the arena's
        transform, the plots' styles, the walls, the scale and the blueprint are logged in
        it again, the balls' looks and the impulses on screen at its first step, which is
        always logged. done() is called once the old file is complete (rrd_parts)."""
        if self._closed:
            raise RuntimeError('RerunSink is closed')
        self.claim = claim
        self.path = Path(claim.path)
        self._each_feed(lambda feed: feed.next_part(claim, done), files_only=True)

    def close(self):
        """Log the final state, send everything and finish the file (footer included)."""
        if self._closed:
            return
        self._closed = True
        errors = []
        for feed in self._feeds:
            try:
                feed.close()
            except OutletFailed as error:
                errors.append(str(error))
        if self._own_claim is not None:
            self._own_claim.release()
        if errors:
            raise OutletFailed('; '.join(errors))

    def _each_feed(self, action, files_only=False):
        """Run action on every live destination (or file); drop one that failed and say so
        once.

        When the last one fails the error is raised, so the Simulation drops the sink and
        its owner reports it; the sink then holds nothing that could block.
        """
        for feed in list(self._feeds):
            if files_only and feed.live:
                continue
            try:
                action(feed)
            except OutletFailed as error:
                self._feeds.remove(feed)
                if not self._feeds:
                    self._closed = True
                    raise
                self.report(f'{error}; going on without it')


class _Feed:
    """What one destination gets, and when: the file every (k-th) step, a view by frames.

    A file (frame_period None) buffers its steps and sends them as columns, MAX_PENDING_STEPS
    at a time: cheap at thousands of balls, and the file is read later. A live view
    (frame_period, frame_clock: seconds of wall time) gets one frame at most every
    frame_period s (_log_frame): a viewer takes a bounded amount of data per second,
    whatever the world's rate. Impulses of the steps between frames are kept and drawn at
    the next frame. What changes seldom (the walls, the balls' sizes, colours and labels)
    is logged static to a view: a Rerun server keeps static data when its memory limit
    drops the oldest frames, so a page opened late still gets it.
    """

    def __init__(self, open_outlet, every=1, velocities=False, trail_seconds=0.0, clock=None,
                 frame_period=None, frame_clock=None, stream_factory=new_stream,
                 recording_id=None):
        self._open_outlet = open_outlet
        self._recording_id = recording_id  # None: derived from the run's parameters
        self._new_stream = stream_factory
        self.every = every
        self.velocities = velocities
        self.trail_seconds = trail_seconds
        self.live = frame_period is not None
        self._frame_period = frame_period
        self._frame_clock = frame_clock
        self._next_frame = None
        self._plots_sent = None
        self.outlet = None
        self._rtf = RealTimeFactor(clock) if clock is not None else None
        self._opened = False
        self._pending = _Pending()
        self._segment = None
        self._segment_base = 0  # value of the step timeline at step 0 of this segment
        self._last_global = None  # step timeline of the last record seen (logged or not)
        self._unlogged = None  # the last record seen, when it was not logged
        self._bumpers = (BumperView(frame_clock, VIEW_EVENT_SECONDS) if self.live
                         else BumperView())
        self._totals = np.zeros(2, dtype=np.int64)  # collisions since step 0 of the segment
        self._energy0 = None
        self._energy_split = False  # the segment has robots: drives and rest apart
        self._account = EnergyAccount()
        self._masses = (None, None)  # (names, masses in their order), for the account
        self._shown_names = None
        self._name_rects = []  # a view's name tags last drawn, (xmin, ymin, xmax, ymax) m
        self._labels = None  # the segment's LabelPlacer
        self._label_colors = None  # (n, 3) uint8: each ball's colour, for its label
        self._labelled = False  # every ball is named (else only the agents)
        self._labels_shown = False  # names are on screen (their last set was not empty)
        # A live view's labels are arrows of length 0 in the balls' row, unless the row's
        # arrows are the velocities (_log_balls).
        self._labels_in_row = self.live and not velocities
        self._scans = {}  # agent name -> (scan, x, y, yaw): a file's scans of the step
        self._view_scans = {}  # a view's: agent name -> (rays, hits) of its latest scan
        self._view_scans_new = False  # ...and one of them is not drawn yet
        self._clock_due = None  # a file's next clock line, log ns
        self._clock_rows = []  # a file's clock lines not sent yet: (step, log ns, text)
        self._headroom = Headroom(VIEW_PLOT_SECONDS if self.live else None)
        self._headroom_rows = []  # (step, log ns, energy above, below, collisions above)
        # On screen or due: (expires log ns, origin, vector, label, label point, a view's
        # wall-time expiry (VIEW_EVENT_SECONDS)).
        self._impulses = []
        self._impulses_changed = False
        self._trail = deque()  # (log ns, positions) of the trail's steps
        self._map_files = None  # the files of the map logged (static), if any
        self._legend = None  # rerun_legend's TextDocument, logged with the statics
        self._closed = False
        self._plan = None  # the blueprint the file was opened with
        self._start = None  # (world, info) of the segment: what a new part logs again
        self._part_begun = False  # a new part: its first step is logged whatever `every`

    # Sink protocol ----------------------------------------------------------------------

    def start_segment(self, world, info):
        """A segment's start; or, for a segment begun before (the same index: a recording
        picked up after a gap, from the state a split file resumes from), its going on,
        on the same step timeline and with the same energy at step 0."""
        same = self._start is not None and self._start[1].segment == info.segment
        if not self._opened:
            self._open(world, info.parameters)
        else:
            self._finish_segment()
            if not same:
                self._segment_base = self._last_global + 1
        self._segment = _Segment(world)
        self._labels = LabelPlacer(self._segment.view)
        self._scans = {}
        self._forget_view_scans(())
        self._clock_due = None
        if not same:
            self._headroom.clear()
            self._totals[:] = 0
            self._energy0 = None
            self._account.clear()
        self._shown_names = None
        self._impulses = []
        self._impulses_changed = False
        self._trail.clear()
        if self._rtf is not None:
            self._rtf.clear()
        self._start = (world, info)
        self._log_segment(world, info)

    def _log_segment(self, world, info):
        """The segment's walls and scale, at its start (logged again in each new part)."""
        self._set_time(self._segment_base, info.log_offset_ns)
        strips = np.asarray(world.walls, dtype=np.float64).reshape(-1, 2, 2)
        self._emit('log', WALLS, rr.LineStrips2D(
            strips, radii=rr.Radius.ui_points(1.5), colors=WALL_COLOR, draw_order=20.0),
            static=self.live)
        self._emit('log', IMPULSES, *IMPULSES_CLEARED)
        self._log_map(world)
        self._log_ruler(world)

    def _log_map(self, world):
        """The map (rerun_map), static, once per file: `map` is read-only, every segment has
        the same one."""
        occupancy_map = getattr(world, 'occupancy_map', None)
        if occupancy_map is None or occupancy_map.files == self._map_files:
            return
        self._map_files = occupancy_map.files
        for path, archetype in map_entities(occupancy_map, WALL_COLOR):
            self._emit('log', path, archetype, static=True)

    def next_part(self, claim, done=None):
        """Finish this file and go on in `claim` (RerunSink.next_part)."""
        if not self._opened or self._closed:
            raise RuntimeError('RerunSink.next_part before start_segment or after close')
        self._finish_segment()
        self._send()
        self.outlet.next_file(claim, self._plan, done)
        self._log_statics()
        self._map_files = None  # a new file: its statics again, the map among them
        if self._start is not None:
            self._log_segment(*self._start)
            if self._energy0 is not None:
                self._emit('log', ENERGY, energy_series(self._energy0, self._energy_split),
                           static=self.live)
        self._shown_names = None  # the looks, at the part's first step
        self._impulses_changed = bool(self._impulses)
        self._part_begun = True
        self._each_outlet(lambda outlet: outlet.check())

    def _log_ruler(self, world):
        """Ticks and labels in metres along the bottom and left of the scene (rerun_scale),
        per segment like the walls: a reset may change the scene."""
        ticks, places, texts = ruler(scene_bounds(world))
        self._emit('log', SCALE, rr.LineStrips2D(
            ticks, radii=rr.Radius.ui_points(1.0), colors=WALL_COLOR, draw_order=20.0),
            static=self.live)  # static for a view: a late page still has it
        tags = Tags()
        for point, text in zip(places.tolist(), texts):
            rect, unit = tag_rect(point, text, self._labels.scale)
            tags.add(text, rect, unit, RULER_TEXT_COLOR)
        # The labels keep the text (not shown); the tags draw it (rerun_text).
        self._emit('log', SCALE_LABELS, rr.Points2D(
            places, radii=0.0, labels=texts, show_labels=False, colors=WALL_COLOR),
            *tags.layers(order=NAME_ORDER), static=self.live)

    def write_step(self, record):
        """Log the step if it is one to log; a file sends its buffer when it is full."""
        if not self._opened or self._closed:
            raise RuntimeError('RerunSink.write_step before start_segment or after close')
        self._last_global = self._segment_base + record.step
        self._totals += (record.ball_ball, record.ball_wall)
        if self._energy0 is None:
            self._energy0 = float(record.kinetic_energy)
            self._energy_split = getattr(record, 'agents', None) is not None
            self._set_time(self._last_global, record.log_time_ns)
            self._emit('log', ENERGY, energy_series(self._energy0, self._energy_split),
                       static=self.live)
        if self._energy_split:
            self._account.add(record, self._masses_of(record))
        rtf = record.real_time_factor
        if self._rtf is not None:
            # Step 0 is the initial state, written when the world is built, not a step: the
            # pause before the first step (the node starting up) is no slowness.
            rtf = self._rtf.add(record.log_time_ns) if record.step else None
        impulses = getattr(record.impulses, 'pushes', lambda: record.impulses)()
        pushed = any(not getattr(impulse, 'drive', False) for impulse in impulses)
        if pushed:
            self._add_impulses(record)
        agents = getattr(record, 'agents', None)
        if agents is not None and agents.scans:
            self._take_scans(record, agents)
        if self.live:
            logged = self._frame_due(record)
        else:
            logged = (record.step % self.every == 0 or pushed or record.edits
                      or self._part_begun)
            self._part_begun = False
        if logged:
            self._log(record, rtf)
        else:
            self._unlogged = (record, rtf)
        if self._scans and not self.live:
            self._log_scans(self._segment_base + record.step, record.log_time_ns)
        bumpers = self._bumpers.update(record)
        if bumpers is not None:
            self._set_time(self._segment_base + record.step, record.log_time_ns)
            if bumpers[1] is None:
                self._emit('log', BUMPERS, rr.Arrows2D.cleared(), rr.Boxes2D.cleared(),
                           rr.LineStrips2D.cleared())
            else:
                self._emit('log', BUMPERS, bumpers[1], *self._bumper_tags(bumpers[1]))

    def flush(self):
        if self._opened and not self._closed:
            if not self.live:  # a view sends its plots on its own period (_log_frame)
                self._send()
            self._each_outlet(lambda outlet: outlet.flush())

    def close(self):
        if self._closed:
            return
        try:
            if not self._opened:
                self._open(None, {})  # closed before any segment: still a valid recording
            self._finish_segment()
            self._send()
        finally:
            self._closed = True
            if self.outlet is not None:
                self.outlet.close()

    # Destination ------------------------------------------------------------------------

    def _open(self, world, parameters):
        """Create the destination, with the blueprint fitted to the first world."""
        self._opened = True
        plan = None if world is None else blueprint(
            world, parameters, VIEW_PLOT_SECONDS if self.live else None)
        self._plan = plan
        stream = self._new_stream(APPLICATION_ID, self._recording_id or recording_id(parameters),
                                  VIEW_FLUSH_SECONDS if self.live else None)
        self.outlet = self._open_outlet(stream, plan)
        self._legend = legend_document(parameters, IMPULSE_SECONDS,
                                       VIEW_PLOT_PERIOD if self.live else None)
        self._log_statics()

    def _log_statics(self):
        """What every file and view holds static: the arena's flip and the plots' styles."""
        self._emit('log', ARENA, rr.Transform3D(
            rotation=rr.RotationAxisAngle(axis=(1.0, 0.0, 0.0), degrees=180.0)), static=True)
        # The energy series' colours come with their names (energy_series): a static colour
        # would win over the three of a world with robots.
        self._emit('log', COLLISIONS, rr.SeriesLines(
            names=['ball-ball', 'ball-wall'], colors=list(COLLISION_COLORS),
            aggregation_policy='Max', interpolation_mode='StepAfter'), static=True)
        self._emit('log', REAL_TIME_FACTOR, rr.SeriesLines(
            names='real-time factor', colors=(180, 120, 230)), static=True)
        self._emit('log', MOMENTUM, rr.SeriesLines(
            names=['x', 'y'], colors=[(230, 80, 80), (80, 200, 90)]), static=True)
        if self._legend is not None:
            self._emit('log', LEGEND, self._legend, static=True)
        for entity, count in ((ENERGY_HEADROOM, 2), (COLLISIONS_HEADROOM, 1)):
            self._emit('log', entity, rr.SeriesLines(
                names=[' '] * count, colors=[(0, 0, 0, 0)] * count, widths=[0.0] * count),
                static=True)

    def _emit(self, name, *args, **kwargs):
        """Queue an SDK call on the destination (a failure surfaces at flush)."""
        if self.outlet is not None:
            self.outlet.call(name, *args, **kwargs)

    def _each_outlet(self, action):
        """Run action on the outlet; a failure closes this feed and is raised."""
        try:
            action(self.outlet)
        except OutletFailed:
            self._closed = True
            raise

    # Logging ----------------------------------------------------------------------------

    def _frame_due(self, record):
        """A live view's cadence: step 0 of a segment, then a frame per frame_period s."""
        now = self._frame_clock()
        if record.step and self._next_frame is not None and now < self._next_frame:
            return False
        following = (self._next_frame or now) + self._frame_period
        self._next_frame = following if following > now else now + self._frame_period
        return True

    def _finish_segment(self):
        """Log the segment's last step if it was skipped, so the file ends on the truth."""
        if self._unlogged is not None:
            self._log(*self._unlogged)

    def _set_time(self, step, log_time_ns):
        self._emit('set_time', STEP, sequence=step)
        self._emit('set_time', SIM_TIME, duration=np.timedelta64(log_time_ns, 'ns'))

    def _log(self, record, rtf):
        self._unlogged = None
        step = self._segment_base + record.step
        names = names_of(record)
        if names != self._shown_names:
            self._log_balls(record, names, step)
        arrows = heading_arrows(record)
        if arrows is not None:
            self._set_time(step, record.log_time_ns)
            self._emit('log', AGENTS, arrows)
        if self.live:
            self._log_frame(record, rtf, step)
            self._show_impulses(step, record.log_time_ns)
            agents = getattr(record, 'agents', None)
            self._forget_view_scans(() if agents is None else agents.names)
            if self._view_scans_new:
                self._log_view_scans(step, record.log_time_ns)
            return
        self._buffer(record, rtf, step)
        if self._clock_due is None or record.log_time_ns >= self._clock_due:
            # Sent with the buffered columns (a writer gathers them into few chunks).
            self._clock_due = record.log_time_ns + round(FILE_CLOCK_SECONDS * 1e9)
            self._clock_rows.append((step, record.log_time_ns, clock_text(record, rtf)))
        self._show_impulses(step, record.log_time_ns)
        if self.trail_seconds:
            self._log_trails(record, names, step)
        pending = self._pending
        if (len(pending) >= MAX_PENDING_STEPS
                or pending.position_count >= MAX_PENDING_POSITIONS):
            self._send()

    def _masses_of(self, record):
        """The balls' masses in pose order (the record's, or the segment's by name)."""
        masses = getattr(record, 'masses', None)
        if masses is not None:
            return masses
        names = names_of(record)
        if self._masses[0] != names:
            self._masses = (names, np.array([self._segment.mass[name] for name in names],
                                            dtype=np.float64))
        return self._masses[1]

    def _energy_row(self, record):
        """The energy plot's values of a step: the change since step 0 (percent of the
        energy then, rounded: energy_change), and with robots the drives' and the rest's
        parts of it (rerun_energy)."""
        total = energy_change(record.kinetic_energy, self._energy0)
        if not self._energy_split:
            return (total,)
        energy0 = self._energy0
        return (total, energy_change(energy0 + self._account.drives, energy0),
                energy_change(energy0 + self._account.rest, energy0))

    def _buffer(self, record, rtf, step):
        """A file's step, sent later with others as columns (_send)."""
        positions = np.asarray(record.positions, dtype=np.float32)
        self._buffer_plots(
            record, rtf, step, positions,
            np.asarray(record.velocities, dtype=np.float32) if self.velocities else None,
            self._label_layer(record))

    def _label_layer(self, record):
        """The names shown at this step: (points (k, 2) float32, texts, colours (k, 3)), placed
        so that none collides with another or lies on a ball (rerun_labels); None when no
        ball is named (more than LABEL_LIMIT balls and no agents)."""
        agents = getattr(record, 'agents', None)
        first = () if agents is None else agents.indices
        if not self._labelled and not len(first):
            if not self._labels_shown:
                return None
            self._labels_shown = False  # an empty set hides the names shown last
            return (np.zeros((0, 2), dtype=np.float32), [], np.zeros((0, 3), dtype=np.uint8))
        self._labels_shown = True
        names = self._shown_names
        radii = getattr(record, 'radii', None)
        if radii is None:
            segment = self._segment
            radii = [segment.radius.get(name, segment.smallest) for name in names]
        clear = heading_discs(record, radii)
        if self._labelled:
            kept, points = self._labels.place(record.positions, radii, names, first, clear)
        else:  # only the agents
            rows = np.asarray(first, dtype=np.int64)
            kept, points = self._labels.place(np.asarray(record.positions)[rows],
                                              np.asarray(radii)[rows],
                                              [names[i] for i in rows], keep_clear=clear)
            kept = rows[kept].tolist()
        return (points.astype(np.float32), [names[i] for i in kept],
                self._label_colors[kept].reshape(-1, 3))

    def _buffer_plots(self, record, rtf, step, positions=None, velocities=None, labels=None):
        """The step's row (with its balls for a file; a view sends those in frames), added in
        one operation (_Pending), and the plots' headroom."""
        energy = self._energy_row(record)
        self._headroom_rows.append((step, record.log_time_ns, *self._headroom.add(
            record.log_time_ns, energy, float(self._totals.max(initial=0)))))
        self._pending.add((
            step, record.log_time_ns, positions, velocities, labels,
            energy, self._totals.copy(),
            np.asarray(record.momentum, dtype=np.float64),
            rtf if rtf is not None and math.isfinite(rtf) else None))

    def _log_frame(self, record, rtf, step):
        """A view's frame: the balls with their trails and velocities now, in one row.

        The web viewer takes in about one message per frame it draws, and draws a few a
        second in software: so a frame's layers share the balls' entity and row (one chunk
        per VIEW_FLUSH_SECONDS, never balls of one moment with trails of another), and the
        plots, which need not move smoothly, are sent as columns every VIEW_PLOT_PERIOD s.
        """
        self._set_time(step, record.log_time_ns)
        positions = np.asarray(record.positions, dtype=np.float32)
        frame = [rr.Points2D.from_fields(positions=positions)]
        if self.trail_seconds:
            frame.append(rr.LineStrips2D.from_fields(
                strips=self._trail_strips(record.log_time_ns, positions)))
        if self.velocities:
            frame.append(rr.Arrows2D.from_fields(
                origins=positions, vectors=np.asarray(record.velocities, dtype=np.float32)
                * np.float32(VELOCITY_SECONDS)))
        labels = self._label_layer(record)
        if labels is not None:
            points, texts, colors = labels
            if self._labels_in_row:
                frame.append(rr.Arrows2D.from_fields(
                    origins=points, vectors=np.zeros_like(points), labels=texts,
                    colors=colors))
            else:
                self._emit('log', LABELS, rr.Points2D.from_fields(
                    positions=points, labels=texts, colors=colors))
        self._emit('log', BALLS, *frame)
        if labels is not None:
            self._emit('log', NAMES, *self._name_tags(points, texts))
        self._log_clock(record, rtf)
        self._buffer_plots(record, rtf, step)
        now = self._frame_clock()
        if self._plots_sent is None or now - self._plots_sent >= VIEW_PLOT_PERIOD:
            self._plots_sent = now
            self._send()

    def _log_balls(self, record, names, step):
        """Radii and colours of the balls as they are now, in pose order, and how their
        labels look.

        The labels themselves (which names, where) are placed at every logged step
        (_label_layer). In a file they are an entity of their own (LABELS). A live view
        without velocities gets them in the balls' own row, as arrows of length 0 (drawn as
        nothing but their labels), so no viewer draws names of one moment under balls of
        another, and a frame stays one message.
        """
        segment = self._segment
        radii = getattr(record, 'radii', None)
        if radii is None:
            radii = [segment.radius.get(name, segment.smallest) for name in names]
        self._shown_names = names
        self._trail.clear()  # a trail follows an index: start again when the balls change
        self._set_time(step, record.log_time_ns)
        colors = np.array([ball_color(name) for name in names], dtype=np.uint8).reshape(-1, 3)
        radii = np.asarray(radii, dtype=np.float32).reshape(-1)
        self._label_colors = colors
        self._labelled = len(names) <= LABEL_LIMIT
        looks = [rr.Points2D.from_fields(radii=radii, colors=colors, draw_order=30.0)]
        if self.live and self.trail_seconds:
            looks.append(rr.LineStrips2D.from_fields(
                colors=colors, radii=rr.Radius.ui_points(1.0), draw_order=10.0))
        if self.live and self.velocities:
            looks.append(rr.Arrows2D.from_fields(colors=colors, draw_order=35.0))
        named = self._labelled or getattr(record, 'agents', None) is not None
        # A view draws the names as tags (NAMES); the labels keep the text, not shown.
        if self._labels_in_row and named:
            looks.append(rr.Arrows2D.from_fields(radii=0.0, show_labels=False))
        self._emit('log', BALLS, *looks, static=self.live)
        if not self._labels_in_row and named:
            self._emit('log', LABELS, rr.Points2D.from_fields(
                radii=0.0, show_labels=not self.live), static=self.live)

    def _bumper_tags(self, arrows):
        """Each hit's label as a tag below its arrow's middle (rerun_text), or a tag's height
        lower, or higher, when that would cover a name ("ball_5 hit 0.47 N s" lay over
        two)."""
        origins = np.asarray(arrows.origins.as_arrow_array().to_pylist(), dtype=np.float64)
        vectors = np.asarray(arrows.vectors.as_arrow_array().to_pylist(), dtype=np.float64)
        taken = list(self._name_rects)
        tags = Tags()
        for origin, vector, text in zip(origins, vectors,
                                        arrows.labels.as_arrow_array().to_pylist()):
            if not text:  # a casing (rerun_casing)
                continue
            middle = origin + 0.5 * vector
            step = np.array([0.0, self._labels.scale.size(text)[1] + self._labels.scale.gap])
            candidates = [tag_rect(point, text, self._labels.scale) for point in (
                middle, middle - step, middle + step, middle - 2.0 * step, middle + 2.0 * step)]
            rect, unit = next((c for c in candidates if not taken or not boxes_overlap(
                np.asarray(c[0]), np.asarray(taken)).any()), candidates[0])
            taken.append(rect)
            tags.add(text, rect, unit, BUMPER_TEXT_COLOR)
        return tags.layers(order=IMPULSE_TAG_ORDER)

    def _name_tags(self, points, texts):
        """A view's names as tags (rerun_text) in their labels' boxes (rerun_labels)."""
        tags = Tags()
        scale = self._labels.scale
        self._name_rects = []
        for point, text in zip(np.asarray(points, dtype=np.float64).tolist(), texts):
            rect, unit = tag_rect(point, text, scale)
            self._name_rects.append(rect)
            tags.add(text, rect, unit, name_color(text))
        return tags.layers(order=NAME_ORDER)

    def _log_clock(self, record, rtf):
        """A view's clock line: the simulated time and the real-time factor, a text document
        (the real-time factor also has its plot; this says it at a glance)."""
        self._emit('log', CLOCK, rr.TextDocument(clock_text(record, rtf)))

    def _send_headroom(self):
        rows, self._headroom_rows = self._headroom_rows, []
        if not rows:
            return
        steps, times, above, below, collisions = zip(*rows)
        index = self._index(steps, times)
        self._emit('send_columns', ENERGY_HEADROOM, index, rr.Scalars.columns(
            scalars=np.column_stack((above, below)).astype(np.float64)))
        self._emit('send_columns', COLLISIONS_HEADROOM, index, rr.Scalars.columns(
            scalars=np.asarray(collisions, dtype=np.float64)))

    def _send_clock(self):
        """A file's clock lines since the last send, as columns."""
        rows, self._clock_rows = self._clock_rows, []
        if not rows:
            return
        steps, times, texts = zip(*rows)
        self._emit('send_columns', CLOCK, self._index(steps, times),
                   rr.TextDocument.columns(text=list(texts)))

    def _add_impulses(self, record):
        """Put the step's pushes on screen for IMPULSE_SECONDS from the step on.

        An agent's drive (its cmd_vel, turned into an impulse every step it accelerates) is
        not a push: its heading arrow and its trail show what it does.
        """
        names = names_of(record)
        masses = getattr(record, 'masses', None)
        radii = getattr(record, 'radii', None)
        index_of = None
        now = record.log_time_ns
        for impulse in record.impulses:
            if getattr(impulse, 'drive', False):
                continue
            ball = impulse.ball  # its index when it was applied
            if record.edits:  # a later edit of the step may have moved or deleted the ball
                if index_of is None:
                    index_of = {name: i for i, name in enumerate(names)}
                ball = index_of.get(impulse.frame_id)
                if ball is None:
                    continue
            name = names[ball]
            segment = self._segment
            mass = masses[ball] if masses is not None else segment.mass[name]
            radius = (float(radii[ball]) if radii is not None
                      else segment.radius.get(name, segment.smallest))
            origin = np.asarray(record.positions[ball], dtype=np.float64)
            vector = self._arrow(origin, impulse.jx / mass, impulse.jy / mass)
            self._impulses.append((now + round(IMPULSE_SECONDS * 1e9), origin, vector,
                                   f'{name}: J = ({impulse.jx:.3g}, {impulse.jy:.3g}) N s',
                                   self._impulse_label_point(origin, vector, radius),
                                   self._wall_until()))
            self._impulses_changed = True

    def _impulse_label_point(self, origin, vector, radius):
        """Where an arrow's label goes: under the arrow's lowest end (the view has +y up and
        draws a label below its point), a line lower still when that end is the tail, where
        the pushed ball's own label is."""
        gap = ARROW_INSET_FRACTION * self._segment.span
        tip = (origin[0] + vector[0], origin[1] + vector[1])
        if tip[1] < origin[1]:
            return (tip[0], tip[1] - gap)
        below_ball = radius + 1.5 * LABEL_LINE_FRACTION * self._segment.span
        return (origin[0], origin[1] - max(gap, below_ball))

    def _show_impulses(self, step, now):
        """Re-log the arrows when one came or went since the last logged step."""
        wall = self._frame_clock() if self.live else math.inf
        shown = [i for i in self._impulses if i[0] > now or i[5] > wall]
        changed = self._impulses_changed or len(shown) != len(self._impulses)
        self._impulses = shown
        self._impulses_changed = False
        if not changed:
            return
        self._set_time(step, now)
        if not shown:
            self._emit('log', IMPULSES, *IMPULSES_CLEARED)
            return
        arrows = cased_arrows([i[1] for i in shown], [i[2] for i in shown], IMPULSE_COLOR,
                              3.0, 40.0)
        # The label's text is kept (not shown); a tag draws it (rerun_text).
        labels = rr.Points2D(
            [i[4] for i in shown], radii=0.0, labels=[i[3] for i in shown], show_labels=False,
            colors=IMPULSE_COLOR)
        tags = Tags()
        for _, _, _, text, point, _ in shown:
            rect, unit = tag_rect(point, text, self._labels.scale)
            tags.add(text, rect, unit, IMPULSE_TEXT_COLOR)
        self._emit('log', IMPULSES, arrows, labels, *tags.layers(order=IMPULSE_TAG_ORDER))

    def _wall_until(self):
        """When a view may take an arrow drawn now off the screen (VIEW_EVENT_SECONDS); a
        file draws it for its simulated time only."""
        return self._frame_clock() + VIEW_EVENT_SECONDS if self.live else -math.inf

    def _take_scans(self, record, agents):
        """Keep the step's scans, with where each was taken from, until they are logged (a
        view: its agents' latest, as what it draws)."""
        rows = dict(zip(agents.names, zip(agents.indices, agents.yaws)))
        for scan in agents.scans:
            index, yaw = rows[scan.name]
            x, y = record.positions[index]
            if self.live:
                self._view_scans[scan.name] = scan_geometry(
                    scan, float(x), float(y), float(yaw), VIEW_MAX_POINTS,
                    view_rays(len(agents.names)))
                self._view_scans_new = True
            else:
                self._scans[scan.name] = (scan, float(x), float(y), float(yaw))

    def _forget_view_scans(self, names):
        """A view stops drawing the scans of agents not in `names` (deleted, or a reset)."""
        gone = set(self._view_scans) - set(names)
        for name in gone:
            del self._view_scans[name]
        self._view_scans_new = self._view_scans_new or bool(gone)

    def _log_scans(self, step, log_time_ns):
        """A file's scans of this step, each as a fan of rays from its robot and its hit
        points (rerun_scans), at arena/scans/<agent>."""
        self._set_time(step, log_time_ns)
        for name, (scan, x, y, yaw) in self._scans.items():
            self._emit('log', f'{SCANS}/{name}', *scan_layers(scan, x, y, yaw))
        self._scans = {}

    def _log_view_scans(self, step, log_time_ns):
        """A view's frame: every agent's latest scan at arena/scans, together."""
        self._set_time(step, log_time_ns)
        self._emit('log', SCANS, *view_layers(self._view_scans.values()))
        self._view_scans_new = False

    def _arrow(self, origin, dvx, dvy):
        """The velocity change times ARROW_SECONDS, its length clamped to the scene's size,
        shortened if need be so that its head stays inside the scene (clip_arrow)."""
        length = math.hypot(dvx, dvy)
        if length == 0.0:
            return (0.0, 0.0)
        segment = self._segment
        shown = min(max(length * ARROW_SECONDS, ARROW_MIN_FRACTION * segment.span),
                    ARROW_MAX_FRACTION * segment.span)
        return clip_arrow(origin, (dvx / length * shown, dvy / length * shown),
                          segment.inside)

    def _trail_strips(self, now, positions):
        """Each ball's path over the last trail_seconds, ending at `positions` (now).

        A file keeps every logged step; a view a point per VIEW_TRAIL_SPACING s.
        """
        trail = self._trail
        while trail and trail[0][0] < now - self.trail_seconds * 1e9:
            trail.popleft()
        points = [kept for _, kept in trail] + [positions]
        if not self.live or not trail or now - trail[-1][0] >= VIEW_TRAIL_SPACING * 1e9:
            trail.append((now, positions))
        return np.stack(points, axis=1)

    def _log_trails(self, record, names, step):
        now = record.log_time_ns
        strips = self._trail_strips(now, np.asarray(record.positions, dtype=np.float32))
        self._set_time(step, now)
        self._emit('log', TRAILS, rr.LineStrips2D(
            strips, colors=np.array([ball_color(n) for n in names], dtype=np.uint8)
            .reshape(-1, 3), radii=rr.Radius.ui_points(1.0), draw_order=10.0))

    def _send(self):
        """Send the buffered steps as one columnar chunk per entity (the balls first: a
        writer keeps that order, so a file cut short holds the balls of its last batch)."""
        pending = self._pending
        if not len(pending):
            self._send_clock()
            self._send_headroom()
            return
        steps, times, positions, velocities, labels, energy, collisions, momentum, rtf = \
            pending.columns()
        index = self._index(steps, times)
        if positions:
            sizes = [len(p) for p in positions]
            positions = np.concatenate(positions)
            self._emit('send_columns', BALLS, index, [rr.ComponentColumn(
                rr.Points2D.descriptor_positions(), rr.components.Position2DBatch(positions),
                lengths=sizes)])
        if velocities:
            vectors = np.concatenate(velocities) * np.float32(VELOCITY_SECONDS)
            self._emit('send_columns', VELOCITIES, index, [
                rr.ComponentColumn(rr.Arrows2D.descriptor_origins(),
                                   rr.components.Position2DBatch(positions), lengths=sizes),
                rr.ComponentColumn(rr.Arrows2D.descriptor_vectors(),
                                   rr.components.Vector2DBatch(vectors), lengths=sizes)])
        label_steps, label_times, label_layers = labels
        if label_layers:
            points, texts, colors = zip(*label_layers)
            sizes = [len(p) for p in points]
            self._emit('send_columns', LABELS, self._index(label_steps, label_times), [
                rr.ComponentColumn(rr.Points2D.descriptor_positions(),
                                   rr.components.Position2DBatch(np.concatenate(points)),
                                   lengths=sizes),
                rr.ComponentColumn(rr.Points2D.descriptor_labels(),
                                   rr.components.TextBatch([t for ts in texts for t in ts]),
                                   lengths=sizes),
                rr.ComponentColumn(rr.Points2D.descriptor_colors(),
                                   rr.components.ColorBatch(np.concatenate(colors)),
                                   lengths=sizes)])
        self._emit('send_columns', ENERGY, index, rr.Scalars.columns(
            scalars=_energy_columns(energy)))
        self._emit('send_columns', COLLISIONS, index, rr.Scalars.columns(
            scalars=np.array(collisions, dtype=np.float64).reshape(-1, 2)))
        self._emit('send_columns', MOMENTUM, index, rr.Scalars.columns(
            scalars=np.array(momentum, dtype=np.float64).reshape(-1, 2)))
        rtf_steps, rtf_times, rtf_values = rtf
        if rtf_values:
            self._emit('send_columns', REAL_TIME_FACTOR, self._index(rtf_steps, rtf_times),
                       rr.Scalars.columns(scalars=np.array(rtf_values, dtype=np.float64)))
        self._send_clock()
        self._send_headroom()
        pending.clear()

    @staticmethod
    def _index(steps, times_ns):
        return [rr.TimeColumn(STEP, sequence=np.array(steps, dtype=np.int64)),
                rr.TimeColumn(SIM_TIME, duration=np.array(times_ns, dtype='timedelta64[ns]'))]


def _file_stream(in_child, spare=False):
    """What makes a file's stream: the SDK's own, or its stand-in in a child process (which
    starts now, so that it is ready by the first step), with a spare for a split .rrd."""
    if not in_child:
        return new_stream
    from ball_world.recording.rerun_process import ProcessStream
    return ProcessStream(spare=spare).open
