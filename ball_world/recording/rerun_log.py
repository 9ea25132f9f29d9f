"""Rerun logging of a run: a Sink that writes a `.rrd` file the Rerun Viewer opens as is.

Layout of the recording (application id 'ball_world'):

- `arena`: a static 180-degree rotation about x. Rerun's 2D views always draw +y downwards
  (the 2D view ignores ViewCoordinates), so the arena's children are logged in true world
  coordinates and this proper rotation turns them upside down for the view: +y points up as
  in RViz, and every logged position equals the simulated one.
- `arena/balls` (Points2D): positions every logged step; radii, colours and labels once per
  segment at its first step, so a step costs one float32 array.
- `arena/walls` (LineStrips2D), once per segment at its first step: not static, because a
  reset may change the walls and static data would rewrite the earlier segments.
- `arena/impulses` (Arrows2D): the impulses applied before a step, at their ball, drawn as
  the velocity change J/m times ARROW_SECONDS (how far the kick alone carries the ball in
  that time) and labelled with J; cleared at the next logged step.
- `plots/kinetic_energy`, `plots/momentum` (x, y), `plots/collisions` (ball-ball,
  ball-wall), `plots/real_time_factor` (Scalars).

Timelines: `sim_time`, the record's log time (simulation time plus the segment offset, so it
never goes back across resets), and `step`, a step counter over the whole recording: the
record's step plus the number of steps of the earlier segments, so with a constant dt
`sim_time = step * dt`. The SDK's wall-clock `log_time` and `log_tick` timelines are
switched off, and the recording id is derived from the run's parameters, so identical runs
give identical recorded content.

Per-step data is buffered and sent as columns (one chunk per entity for many steps), which
is what keeps logging cheap at thousands of balls; `flush()` sends what is buffered.
"""
import colorsys
import json
import math
import os
from pathlib import Path
import uuid

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ball_world.step_record import PACKAGE_NAME

APPLICATION_ID = PACKAGE_NAME

ARENA = 'arena'
BALLS = 'arena/balls'
WALLS = 'arena/walls'
IMPULSES = 'arena/impulses'
ENERGY = 'plots/kinetic_energy'
MOMENTUM = 'plots/momentum'
COLLISIONS = 'plots/collisions'
REAL_TIME_FACTOR = 'plots/real_time_factor'

SIM_TIME = 'sim_time'
STEP = 'step'

#: Labels are drawn by default up to this many balls; beyond, they only clutter the view.
LABEL_LIMIT = 30

#: Buffered steps are sent once this many are pending, or this many positions.
MAX_PENDING_STEPS = 64
MAX_PENDING_POSITIONS = 500_000

#: Fixed namespace of the recording ids (uuid5 of the parameters).
RECORDING_NAMESPACE = uuid.uuid5(uuid.NAMESPACE_DNS, 'ball_world.ros.rerun')

#: An impulse arrow is the velocity change it gives times this many seconds.
ARROW_SECONDS = 0.25

WALL_COLOR = (200, 200, 200)
GOLDEN_RATIO_CONJUGATE = (math.sqrt(5.0) - 1.0) / 2.0


def ball_colors(count):
    """A stable colour per ball index: hues a golden-ratio step apart stay distinct for any N."""
    colors = np.empty((count, 3), dtype=np.uint8)
    for i in range(count):
        red, green, blue = colorsys.hsv_to_rgb((i * GOLDEN_RATIO_CONJUGATE) % 1.0, 0.65, 0.95)
        colors[i] = (round(red * 255), round(green * 255), round(blue * 255))
    return colors


def recording_id(parameters):
    """The same parameters give the same id, so an identical run gives an identical file."""
    canonical = json.dumps(parameters, sort_keys=True, default=repr)
    return str(uuid.uuid5(RECORDING_NAMESPACE, canonical))


def scene_bounds(world):
    """(xmin, ymin, xmax, ymax) around the walls and the balls, with a small margin."""
    walls = np.asarray(world.walls, dtype=np.float64).reshape(-1, 4)
    boxes = [np.column_stack((np.minimum(walls[:, 0:2], walls[:, 2:4]),
                              np.maximum(walls[:, 0:2], walls[:, 2:4])))]
    if len(world.radii):
        reach = world.radii[:, None]
        boxes.append(np.column_stack((world.positions - reach, world.positions + reach)))
    boxes = np.concatenate(boxes)
    if len(boxes) == 0:
        return (-1.0, -1.0, 1.0, 1.0)
    xmin, ymin = boxes[:, 0:2].min(axis=0)
    xmax, ymax = boxes[:, 2:4].max(axis=0)
    margin = 0.03 * max(xmax - xmin, ymax - ymin, 1e-9)
    return (xmin - margin, ymin - margin, xmax + margin, ymax + margin)


def blueprint(world):
    """The arena large on the left (+y up, bounds fitted), the four plots stacked on the right.

    The 2D view's origin is the root, above the `arena` flip, so its visual bounds are in the
    flipped frame: world y in [ymin, ymax] is view y in [-ymax, -ymin].
    """
    xmin, ymin, xmax, ymax = (float(v) for v in scene_bounds(world))
    arena = rrb.Spatial2DView(
        origin='/', contents=f'/{ARENA}/**', name='arena (+y up)',
        visual_bounds=rrb.VisualBounds2D(x_range=[xmin, xmax], y_range=[-ymax, -ymin]))
    plots = rrb.Vertical(
        rrb.TimeSeriesView(origin=f'/{ENERGY}', name='kinetic energy [J]'),
        rrb.TimeSeriesView(origin=f'/{MOMENTUM}', name='momentum [kg m/s]'),
        rrb.TimeSeriesView(origin=f'/{COLLISIONS}', name='collisions per step'),
        rrb.TimeSeriesView(origin=f'/{REAL_TIME_FACTOR}', name='real-time factor'))
    return rrb.Blueprint(
        rrb.Horizontal(arena, plots, column_shares=[3, 2]),
        rrb.TimePanel(timeline=SIM_TIME, state='collapsed', play_state='following'),
        collapse_panels=True)


class _Pending:
    """Logged steps not yet sent: one row per step, sent as columns by _send."""

    def __init__(self):
        self.clear()

    def clear(self):
        self.steps = []
        self.times_ns = []
        self.positions = []
        self.energy = []
        self.momentum = []
        self.collisions = []
        self.rtf_steps = []
        self.rtf_times_ns = []
        self.rtf = []
        self.position_count = 0

    def __len__(self):
        return len(self.steps)


class RerunSink:
    """Logs a run to a Rerun `.rrd` file; see the module docstring for what goes where.

    every=k logs every k-th step of a segment, plus step 0, every step with impulses and the
    last step before a reset or close; collision counts are summed over the skipped steps so
    their totals stay right.
    """

    def __init__(self, path, every=1):
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ValueError(f'every must be a whole number >= 1, got {every!r}')
        self.path = Path(path)
        directory = self.path.parent
        if not directory.is_dir() or not os.access(directory, os.W_OK):
            raise OSError(f'{str(self.path)!r}: {str(directory)!r} is not a writable directory')
        # The SDK opens the file only at the first segment, on its own thread; try it now so
        # a path that cannot be written (/proc/..., /dev/full) fails at start, not silently.
        try:
            with open(self.path, 'wb') as probe:
                probe.write(b'\0')
                probe.flush()
        except OSError as error:
            raise OSError(f'{str(self.path)!r}: {error.strerror or error}') from None
        self.every = every
        self.stream = None
        self._pending = _Pending()
        self._segment_base = 0  # value of the step timeline at step 0 of this segment
        self._last_global = None  # step timeline of the last record seen (logged or not)
        self._unlogged = None  # the last record seen, when it was not logged
        self._collisions = np.zeros(2, dtype=np.int64)  # since the last logged step
        self._arrows_shown = False
        self._masses = np.empty(0)
        self._colors = np.empty((0, 3), dtype=np.uint8)
        self._closed = False

    # Sink protocol ----------------------------------------------------------------------

    def start_segment(self, world, info):
        """Open the file on the first segment; log the segment's walls and ball styles."""
        if self._closed:
            raise RuntimeError('RerunSink is closed')
        if self.stream is None:
            self._open(world, info.parameters)
        else:
            self._finish_segment()
            self._segment_base = self._last_global + 1
        count = len(world.radii)
        self._masses = np.asarray(world.masses, dtype=np.float64)
        self._colors = ball_colors(count)
        self._collisions[:] = 0
        self._set_time(self._segment_base, info.log_offset_ns)
        self.stream.log(BALLS, rr.Points2D.from_fields(
            radii=np.asarray(world.radii, dtype=np.float32), colors=self._colors,
            labels=[f'ball_{i}' for i in range(count)], show_labels=count <= LABEL_LIMIT,
            draw_order=30.0))
        strips = np.asarray(world.walls, dtype=np.float64).reshape(-1, 2, 2)
        self.stream.log(WALLS, rr.LineStrips2D(
            strips, radii=rr.Radius.ui_points(1.5), colors=WALL_COLOR, draw_order=20.0))
        self.stream.log(IMPULSES, rr.Arrows2D.cleared())
        self._arrows_shown = False

    def write_step(self, record):
        """Buffer the step if it is one to log; send the buffer when it is full."""
        if self.stream is None or self._closed:
            raise RuntimeError('RerunSink.write_step before start_segment or after close')
        self._last_global = self._segment_base + record.step
        self._collisions += (record.ball_ball, record.ball_wall)
        if record.step % self.every == 0 or record.impulses:
            self._log(record)
        else:
            self._unlogged = record

    def flush(self):
        """Send the buffered steps and wait until the stream has written them."""
        if self.stream is None or self._closed:
            return
        self._send()
        self.stream.flush()

    def close(self):
        """Log the final state, send everything and finish the file (footer included)."""
        if self._closed:
            return
        if self.stream is None:
            self._open(None, {})  # closed before any segment: still a valid, empty recording
        self._finish_segment()
        self._send()
        self.stream.flush()
        self.stream.disconnect()
        self.stream = None
        self._closed = True

    # Internals --------------------------------------------------------------------------

    def _open(self, world, parameters):
        """Create the stream and the file: with the blueprint fitted to the first world."""
        self.stream = rr.RecordingStream(
            APPLICATION_ID, recording_id=recording_id(parameters), send_properties=False)
        self.stream.set_log_time_enabled(False)
        self.stream.set_log_tick_enabled(False)
        self.stream.save(self.path, default_blueprint=None if world is None else blueprint(world))
        self.stream.log(ARENA, rr.Transform3D(
            rotation=rr.RotationAxisAngle(axis=(1.0, 0.0, 0.0), degrees=180.0)), static=True)
        self.stream.log(ENERGY, rr.SeriesLines(names='kinetic energy', colors=(230, 180, 40)),
                        static=True)
        self.stream.log(MOMENTUM, rr.SeriesLines(
            names=['x', 'y'], colors=[(230, 80, 80), (80, 200, 90)]), static=True)
        self.stream.log(COLLISIONS, rr.SeriesLines(
            names=['ball-ball', 'ball-wall'], colors=[(90, 150, 240), (200, 200, 200)]),
            static=True)
        self.stream.log(REAL_TIME_FACTOR, rr.SeriesLines(
            names='real-time factor', colors=(180, 120, 230)), static=True)

    def _finish_segment(self):
        """Log the segment's last step if every=k skipped it, so the file ends on the truth."""
        if self._unlogged is not None:
            self._log(self._unlogged)

    def _set_time(self, step, log_time_ns):
        self.stream.set_time(STEP, sequence=step)
        self.stream.set_time(SIM_TIME, duration=np.timedelta64(log_time_ns, 'ns'))

    def _log(self, record):
        self._unlogged = None
        step = self._segment_base + record.step
        pending = self._pending
        pending.steps.append(step)
        pending.times_ns.append(record.log_time_ns)
        pending.positions.append(np.asarray(record.positions, dtype=np.float32))
        pending.position_count += len(record.positions)
        pending.energy.append(record.kinetic_energy)
        pending.momentum.append(record.momentum)
        pending.collisions.append(self._collisions.copy())
        self._collisions[:] = 0
        rtf = record.real_time_factor
        if rtf is not None and math.isfinite(rtf):
            pending.rtf_steps.append(step)
            pending.rtf_times_ns.append(record.log_time_ns)
            pending.rtf.append(rtf)
        if record.impulses:
            self._log_impulses(record, step)
        elif self._arrows_shown:
            self._set_time(step, record.log_time_ns)
            self.stream.log(IMPULSES, rr.Arrows2D.cleared())
            self._arrows_shown = False
        if (len(pending) >= MAX_PENDING_STEPS
                or pending.position_count >= MAX_PENDING_POSITIONS):
            self._send()

    def _log_impulses(self, record, step):
        balls = np.array([impulse.ball for impulse in record.impulses], dtype=np.int64)
        impulse = np.array([(i.jx, i.jy) for i in record.impulses], dtype=np.float64)
        self._set_time(step, record.log_time_ns)
        self.stream.log(IMPULSES, rr.Arrows2D(
            origins=record.positions[balls],
            vectors=impulse / self._masses[balls, None] * ARROW_SECONDS,
            colors=self._colors[balls], radii=rr.Radius.ui_points(2.0), draw_order=40.0,
            labels=[f'{i.frame_id}: J = ({i.jx:.3g}, {i.jy:.3g}) N s'
                    for i in record.impulses]))
        self._arrows_shown = True

    def _send(self):
        """Send the buffered steps as one columnar chunk per entity."""
        pending = self._pending
        if not len(pending):
            return
        stream = self.stream
        index = self._index(pending.steps, pending.times_ns)
        positions = rr.components.Position2DBatch(np.concatenate(pending.positions))
        sizes = [len(p) for p in pending.positions]
        stream.send_columns(BALLS, index, [
            rr.ComponentColumn(rr.Points2D.descriptor_positions(), positions, lengths=sizes)])
        stream.send_columns(ENERGY, index, rr.Scalars.columns(
            scalars=np.array(pending.energy, dtype=np.float64)))
        stream.send_columns(MOMENTUM, index, rr.Scalars.columns(
            scalars=np.array(pending.momentum, dtype=np.float64).reshape(-1, 2)))
        stream.send_columns(COLLISIONS, index, rr.Scalars.columns(
            scalars=np.array(pending.collisions, dtype=np.float64).reshape(-1, 2)))
        if pending.rtf:
            stream.send_columns(
                REAL_TIME_FACTOR, self._index(pending.rtf_steps, pending.rtf_times_ns),
                rr.Scalars.columns(scalars=np.array(pending.rtf, dtype=np.float64)))
        pending.clear()

    @staticmethod
    def _index(steps, times_ns):
        return [rr.TimeColumn(STEP, sequence=np.array(steps, dtype=np.int64)),
                rr.TimeColumn(SIM_TIME, duration=np.array(times_ns, dtype='timedelta64[ns]'))]
