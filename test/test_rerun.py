"""The Rerun sink: files Rerun itself verifies and reads back to exactly what was simulated.

Files are read with Rerun's own reader (rerun.chunk.RrdReader) and checked with its CLI
(`rerun rrd verify`, `rerun rrd compare`), the programs users open them with. What the
viewer shows at a step is the latest value logged at or before it (Rerun's latest-at), so
`shown_at` answers "what is on screen at step k" from the chunks.
"""
from dataclasses import replace
import inspect
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

from ball_world_testing.harness import finish, open_rrd, RERUN, run_rerun, start_node, Truth
import numpy as np
import pytest
import rerun as rr

from ball_world.recording import rerun_log, rerun_outlet, rerun_text
from ball_world.recording.files import claim_output
from ball_world.recording.mcap_writer import McapSink
from ball_world.recording.rerun_casing import CASING_COLOR
from ball_world.recording.rerun_labels import box_of, LabelScale, TAG_INSET_PIXELS
from ball_world.recording.rerun_log import (ARENA, ARROW_MAX_FRACTION, ARROW_MIN_FRACTION,
                                            ARROW_SECONDS, ball_color, BALLS, clip_arrow,
                                            COLLISIONS, ENERGY, IMPULSE_COLOR, IMPULSES,
                                            LABEL_LIMIT, LABEL_LINE_FRACTION, LABELS,
                                            MOMENTUM, NAMES, REAL_TIME_FACTOR, RealTimeFactor,
                                            RerunSink, scene_bounds, SIM_TIME, STEP, TRAILS,
                                            VELOCITIES, VELOCITY_SECONDS, view_bounds,
                                            VIEW_EVENT_SECONDS, VIEW_FPS, VIEW_TRAIL_SPACING,
                                            WALL_COLOR, WALLS)
from ball_world.recording.rerun_outlet import Outlet, OutletFailed, parse_view
from ball_world.simulation import Simulation
from ball_world.tools import to_rrd

IMPULSES_AT = {1: (0, 0.1, 0.0), 10: (3, 0.0, -0.2)}  # before step k: ball, jx, jy
STEPS_PER_SECOND = 60  # the default world: dt = 1/60 s
HALF_SECOND = STEPS_PER_SECOND // 2
#: Generous deadline for things that must happen (never a timing assertion).
LIVENESS_SECONDS = 20.0


def run(sinks, steps=30, parameters=None, reset_at=None, reset_parameters=None,
        impulses=IMPULSES_AT):
    """The default world with a couple of impulses; returns its Truth."""
    collector = Truth()
    simulation = Simulation(parameters or {}, sinks=[*sinks, collector])
    for k in range(1, steps + 1):
        if k in impulses:
            ball, jx, jy = impulses[k]
            simulation.queue_impulse(f'ball_{ball}', jx, jy)
        if k == reset_at:
            simulation.reset(reset_parameters or {})
        simulation.step(real_time_factor=1.0 + k / 100)
    simulation.close()
    return collector


def read(path):
    """The recording's content: {(entity, component): {step: value}}, static ones at None.

    Also returns the timelines seen and the sim_time of every step, from the chunks of
    the file's (only) recording store.
    """
    reader = open_rrd(path)  # also what `rerun --save` (a viewer) wrote: it has no footer
    (store,) = reader.recordings()
    content = {}
    timelines = set()
    sim_time = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        names = batch.schema.names
        timelines.update(chunk.timeline_names)
        steps = [None] * batch.num_rows if chunk.is_static else batch.column(STEP).to_pylist()
        if not chunk.is_static:
            times = batch.column(SIM_TIME).cast('int64').to_pylist()
            sim_time.update(zip(steps, times))
        for index, field in enumerate(batch.schema):
            if (field.metadata or {}).get(b'rerun:kind') != b'data':
                continue
            column = content.setdefault((chunk.entity_path, names[index]), {})
            for step, value in zip(steps, batch.column(index).to_pylist()):
                assert step not in column, f'two values of {names[index]} at step {step}'
                column[step] = value
    return store, content, timelines, sim_time


def shown_at(column, step):
    """What the viewer shows at `step`: the latest value logged at or before it."""
    logged = [s for s in column if s is not None and s <= step]
    return column[max(logged)] if logged else None


def cores(column):
    """A cased mark's column (rerun_casing: casings, then the marks) with the marks alone."""
    return {step: value[len(value) // 2:] if value else value
            for step, value in column.items()}


def scalars(content, entity):
    return content[(f'/{entity}', 'Scalars:scalars')]


def as_float32(points):
    return np.asarray(points, dtype=np.float32).tolist()


def percent_change(energy, energy0):
    """The closed form the plot must hold: percent change, 0 below 1e-12 relative."""
    relative = (energy - energy0) / energy0
    return 0.0 if abs(relative) < 0.5e-12 else relative * 100.0


# The file -----------------------------------------------------------------------------------

def test_recording_verifies_and_reads_back_exactly(tmp_path):
    path = tmp_path / 'run.rrd'
    collected = run([RerunSink(path)])
    result = run_rerun('rrd', 'verify', str(path))
    assert result.returncode == 0, result.stdout + result.stderr

    store, content, timelines, sim_time = read(path)
    assert store.application_id == 'ball_world'
    assert timelines == {SIM_TIME, STEP}  # no wall-clock log_time, no log_tick
    assert open_rrd(path).blueprints(), 'the blueprint travels with the file'
    records = collected.records
    world = collected.segments[0][0]
    assert [r.step for r in records] == list(range(31))

    positions = content[(f'/{BALLS}', 'Points2D:positions')]
    assert sorted(positions) == [r.step for r in records]
    for record in records:
        # Rerun stores positions as float32: the file holds exactly the float32 positions.
        assert positions[record.step] == as_float32(record.positions)
        assert sim_time[record.step] == record.log_time_ns

    walls = content[(f'/{WALLS}', 'LineStrips2D:strips')]
    assert walls == {0: world.walls.reshape(-1, 2, 2).tolist()}
    assert content[(f'/{BALLS}', 'Points2D:radii')] == {0: as_float32(world.radii)}
    labels = content[(f'/{LABELS}', 'Points2D:labels')][0]
    assert set(labels) <= {f'ball_{i}' for i in range(len(world.radii))}
    assert len(labels) >= len(world.radii) // 2  # a 10 m box has room for most names
    assert (f'/{ARENA}', 'Transform3D:rotation_axis_angle') in content
    momentum = scalars(content, MOMENTUM)
    assert momentum == {r.step: r.momentum.tolist() for r in records}
    assert not any(entity in (f'/{VELOCITIES}', f'/{TRAILS}') for entity, _ in content)


def assert_labels_clear(points, texts, positions, radii, names, bounds):
    """The rule the view keeps: each label's box, as Rerun draws it (centred below its point,
    rerun_labels' measured text size for a view fitted into its pixels), overlaps no other
    label's box and no ball but its own, lies inside the view, and names a ball beside it."""
    scale = LabelScale(bounds)
    positions = np.asarray(positions, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    boxes = [box_of(point, *scale.size(text), scale) for point, text in zip(points, texts)]
    for k, (box, text) in enumerate(zip(boxes, texts)):
        assert bounds[0] <= box[0] and box[2] <= bounds[2], (text, box, bounds)
        assert bounds[1] <= box[1] and box[3] <= bounds[3], (text, box, bounds)
        for other in boxes[k + 1:]:
            assert not (box[0] < other[2] and other[0] < box[2] and box[1] < other[3]
                        and other[1] < box[3]), (text, box, other)
        own = names.index(text)
        for i, (centre, radius) in enumerate(zip(positions, radii)):
            nearest = np.clip(centre, box[0:2], box[2:4])
            touching = np.hypot(*(centre - nearest)) < radius
            assert touching is np.False_ or i == own, (text, names[i])
        # Beside its own ball: within a box's size of the ball's edge.
        centre, radius = positions[own], radii[own]
        nearest = np.clip(centre, box[0:2], box[2:4])
        assert np.hypot(*(centre - nearest)) <= radius + 2 * (box[3] - box[1]), text


def test_labels_name_the_balls_without_colliding_and_the_balls_have_none(tmp_path):
    """Rerun draws a label just below its point, whatever else is there: names overlapped
    (ball_14 over ball_4) or lay on other balls. Each step's names are placed below, above,
    right or left of their ball, or dropped, so that none collides."""
    path = tmp_path / 'run.rrd'
    parameters = {'random.count': 28, 'random.seed': 3}
    collected = run([RerunSink(path)], steps=40, parameters=parameters)
    _, content, _, _ = read(path)
    world = collected.segments[0][0]
    names = [f'ball_{i}' for i in range(len(world.radii))]
    assert not [component for entity, component in content
                if entity == f'/{BALLS}' and component.endswith(':labels')]
    assert content[(f'/{LABELS}', 'Points2D:show_labels')] == {0: [True]}
    points = content[(f'/{LABELS}', 'Points2D:positions')]
    texts = content[(f'/{LABELS}', 'Points2D:labels')]
    colors = content[(f'/{LABELS}', 'Points2D:colors')]
    ball_colors = content[(f'/{BALLS}', 'Points2D:colors')][0]
    assert sorted(points) == sorted(texts) == list(range(41))
    bounds = view_bounds(world)
    dropped = 0
    for record in collected.records:
        shown, text = points[record.step], texts[record.step]
        assert len(shown) == len(text) == len(colors[record.step])
        assert len(set(text)) == len(text)
        assert colors[record.step] == [ball_colors[names.index(t)] for t in text]
        assert_labels_clear(shown, text, as_float32(record.positions), world.radii, names,
                            bounds)
        dropped += len(names) - len(text)
    assert dropped < 0.5 * len(names) * 41  # most names are shown


def test_beyond_the_label_limit_no_label_points_are_logged(tmp_path):
    """A world past LABEL_LIMIT balls costs one positions array per step, not two; a world
    that grows past it hides the labels it had."""
    path = tmp_path / 'many.rrd'
    run([RerunSink(path)], steps=3, parameters={'random.count': LABEL_LIMIT + 1}, impulses={})
    _, content, _, _ = read(path)
    assert not [key for key in content if key[0] == f'/{LABELS}']
    # With agents, the robots are still named (and nothing else).
    path = tmp_path / 'robots.rrd'
    run([RerunSink(path)], steps=3, parameters={'random.count': LABEL_LIMIT + 1,
                                                'agents': ['ball_3', 'ball_7']}, impulses={})
    _, content, _, _ = read(path)
    assert all(set(texts) <= {'ball_3', 'ball_7'} and texts
               for texts in content[(f'/{LABELS}', 'Points2D:labels')].values())
    assert sorted(content[(f'/{BALLS}', 'Points2D:positions')]) == [0, 1, 2, 3]

    path = tmp_path / 'grows.rrd'
    sink = RerunSink(path)
    collector = Truth()
    Simulation({'random.count': 3}, sinks=[collector])
    world, _ = collector.segments[0]
    sink.start_segment(world, SimpleNamespace(parameters={}, log_offset_ns=0))
    first = collector.records[0]
    sink.write_step(first)
    count = LABEL_LIMIT + 1
    grown = grown_past_label_limit(first)
    sink.write_step(grown)
    sink.close()
    _, content, _, _ = read(path)
    points = content[(f'/{LABELS}', 'Points2D:positions')]
    assert len(points[0]) == 3 and points[1] == []  # nothing left on screen at step 1
    assert len(content[(f'/{BALLS}', 'Points2D:positions')][1]) == count


def grown_past_label_limit(first):
    """Step 1 after `first`, in a world grown to LABEL_LIMIT + 1 still balls in a row."""
    count = LABEL_LIMIT + 1
    return SimpleNamespace(**{**vars(replace(first)), 'step': 1, 'log_time_ns': 10**7,
                              'positions': np.column_stack((np.arange(count) * 0.3 + 0.2,
                                                            np.full(count, 5.0))),
                              'velocities': np.zeros((count, 2)),
                              'names': tuple(f'ball_{i}' for i in range(count)),
                              'radii': np.full(count, 0.1), 'masses': np.ones(count)})


def test_a_live_view_hides_its_labels_when_the_world_grows_past_the_limit():
    """A live feed's calls, recorded instead of sent: the labels ride in the balls' row (as
    arrows of length 0, their text kept but not shown), each drawn as a tag in its box
    (NAMES), and go when the balls outnumber LABEL_LIMIT."""
    feed, calls, clock = recorded_view_feed()
    collector = Truth()
    Simulation({'random.count': 3}, sinks=[collector])
    world, _ = collector.segments[0]
    feed.start_segment(world, SimpleNamespace(parameters={}, log_offset_ns=0))
    first = collector.records[0]
    grown = grown_past_label_limit(first)

    def arrows_logged(record):
        """(static looks, frame) arrows of the balls when the feed logs `record`."""
        del calls[:]
        clock.now += 1.0
        feed.write_step(record)
        logged = [(kwargs.get('static', False), archetype) for name, args, kwargs in calls
                  if name == 'log' and args[0] == BALLS for archetype in args[1:]
                  if isinstance(archetype, rr.Arrows2D)]
        assert not [args for name, args, _ in calls if name == 'log' and args[0] == LABELS]
        return ([a for static, a in logged if static], [a for static, a in logged if not static])

    def tags_logged():
        """(pills, strips) of the frame's tags."""
        (tags,) = [args[1:] for name, args, _ in calls if name == 'log' and args[0] == NAMES]
        (pills,) = [a for a in tags if isinstance(a, rr.Boxes2D)]
        (strips,) = [a for a in tags if isinstance(a, rr.LineStrips2D)]
        return pills, strips

    (looks,), (frame,) = arrows_logged(first)
    assert looks.show_labels.as_arrow_array().to_pylist() == [False]
    assert sorted(frame.labels.as_arrow_array().to_pylist()) == ['ball_0', 'ball_1', 'ball_2']
    # Each name is a pill filling its label's box but for the inset, its strokes in the
    # ball's light hue, inside the pill.
    pills, strips = tags_logged()
    scale = LabelScale(view_bounds(world))
    centres = pills.centers.as_arrow_array().to_pylist()
    half_sizes = pills.half_sizes.as_arrow_array().to_pylist()
    thickness = pills.radii.as_arrow_array().to_pylist()
    lines = strips.strips.as_arrow_array().to_pylist()
    line_colors = strips.colors.as_arrow_array().to_pylist()
    assert len(centres) == 3
    used = 0
    for k, (point, text) in enumerate(zip(frame.origins.as_arrow_array().to_pylist(),
                                          frame.labels.as_arrow_array().to_pylist())):
        xmin, ymin, xmax, ymax = box_of(point, *scale.size(text), scale)
        inset = TAG_INSET_PIXELS * scale.metres_per_pixel
        (cx, cy), (hx, hy), r = centres[k], half_sizes[k], thickness[k]
        assert hy == 0.0 and r == pytest.approx(0.5 * (ymax - ymin) - inset, rel=1e-5)
        assert cx - hx - r == pytest.approx(xmin, rel=1e-5, abs=1e-6)
        assert cx + hx + r == pytest.approx(xmax, rel=1e-5, abs=1e-6)
        assert cy == pytest.approx(0.5 * (ymin + ymax), rel=1e-5, abs=1e-6)
        count = len(rerun_text.strokes(text))
        mine = np.concatenate([np.asarray(line) for line in lines[used:used + count]])
        assert np.all(mine[:, 0] >= xmin) and np.all(mine[:, 0] <= xmax)
        assert np.all(mine[:, 1] >= ymin + inset) and np.all(mine[:, 1] <= ymax - inset)
        red, green, blue = rerun_log.name_color(text)
        assert set(line_colors[used:used + count]) == {
            (red << 24) | (green << 16) | (blue << 8) | 0xFF}
        used += count
    assert used == len(lines)
    assert_labels_clear(frame.origins.as_arrow_array().to_pylist(),
                        frame.labels.as_arrow_array().to_pylist(),
                        as_float32(first.positions), world.radii,
                        ['ball_0', 'ball_1', 'ball_2'], view_bounds(world))
    assert np.all(np.asarray(frame.vectors.as_arrow_array().to_pylist()) == 0.0)
    looks, (frame,) = arrows_logged(grown)
    assert looks == []  # no label looks for a world past the limit
    assert frame.labels.as_arrow_array().to_pylist() == []  # an empty set: no names left
    assert frame.origins.as_arrow_array().to_pylist() == []
    pills, strips = tags_logged()
    assert pills.centers.as_arrow_array().to_pylist() == []
    assert strips.strips.as_arrow_array().to_pylist() == []
    feed.close()


def test_energy_is_the_change_from_step_0_and_reads_zero_when_conserved(tmp_path):
    path = tmp_path / 'run.rrd'
    collected = run([RerunSink(path)], steps=300, impulses={200: (2, 0.3, 0.1)})
    records = collected.records
    energy0 = records[0].kinetic_energy
    drift = [abs(r.kinetic_energy - energy0) / energy0 for r in records[:200]]
    assert max(drift) < 1e-13  # the physics conserves energy to rounding...
    _, content, _, _ = read(path)
    energy = scalars(content, ENERGY)
    # ...and the plot says so: exactly zero until the impulse, not rounding noise blown up.
    assert all(energy[r.step] == [0.0] for r in records[:200])
    for record in records[200:]:
        assert energy[record.step] == [pytest.approx(
            percent_change(record.kinetic_energy, energy0), rel=1e-9)]
    assert energy[200][0] > 1.0  # the push added over 1% to this world's energy
    legend = content[(f'/{ENERGY}', 'SeriesLines:names')]
    assert legend[0] == [f'change from {energy0:.6g} J at step 0']


def test_collisions_are_integer_totals_per_segment(tmp_path):
    path = tmp_path / 'run.rrd'
    collected = run([RerunSink(path)], steps=240, reset_at=200,
                    reset_parameters={'random.count': 30, 'random.seed': 4})
    records = collected.records
    _, content, _, _ = read(path)
    collisions = scalars(content, COLLISIONS)
    start = 0
    for index, record in enumerate(records):
        if record.step == 0:
            start = index
        segment = records[start:index + 1]
        expected = [sum(r.ball_ball for r in segment), sum(r.ball_wall for r in segment)]
        assert collisions[index] == expected  # index = the step timeline across the reset
    assert all(value == int(value) for row in collisions.values() for value in row)
    assert collisions[199][0] + collisions[199][1] > 0, 'the run had collisions to count'
    style = content[(f'/{COLLISIONS}', 'SeriesLines:aggregation_policy')][None]
    assert style == [rr.components.AggregationPolicy.Max.value]  # integers at any zoom


def test_impulse_stays_half_a_second_in_its_colour_with_the_ball_name(tmp_path):
    path = tmp_path / 'run.rrd'
    collected = run([RerunSink(path)], steps=60)
    records = collected.records
    world = collected.segments[0][0]
    xmin, ymin, xmax, ymax = scene_bounds(world)
    span = max(xmax - xmin, ymax - ymin)
    _, content, _, _ = read(path)
    # Each arrow is drawn twice, its dark casing then itself (rerun_casing): the cores are
    # the second half of a batch, the casings the same arrows.
    vectors = cores(content[(f'/{IMPULSES}', 'Arrows2D:vectors')])
    origins = cores(content[(f'/{IMPULSES}', 'Arrows2D:origins')])
    assert all(v[:len(v) // 2] == v[len(v) // 2:]
               for v in content[(f'/{IMPULSES}', 'Arrows2D:vectors')].values() if v)
    labels = content[(f'/{IMPULSES}', 'Points2D:labels')]
    places = content[(f'/{IMPULSES}', 'Points2D:positions')]
    colors = content[(f'/{IMPULSES}', 'Arrows2D:colors')]
    # The arrows carry no labels of their own (only the cleared, empty ones).
    assert not any(content.get((f'/{IMPULSES}', 'Arrows2D:labels'), {}).values())

    def arrow(step, ball, jx, jy):
        kick = np.array([jx, jy]) / world.masses[ball] * ARROW_SECONDS
        length = np.hypot(*kick)
        shown = min(max(length, ARROW_MIN_FRACTION * span), ARROW_MAX_FRACTION * span)
        return as_float32([kick / length * shown])[0]

    first, second = ((k, *IMPULSES_AT[k]) for k in sorted(IMPULSES_AT))
    for step in range(61):
        expected = [(k, ball, jx, jy) for k, ball, jx, jy in (first, second)
                    if k <= step < k + HALF_SECOND]
        assert shown_at(vectors, step) == [arrow(*e) for e in expected], step
        assert shown_at(origins, step) == [as_float32(records[k].positions[ball])
                                           for k, ball, _, _ in expected], step
        assert shown_at(labels, step) == [
            f'ball_{ball}: J = ({jx:.3g}, {jy:.3g}) N s' for _, ball, jx, jy in expected]
        # Each label under its arrow, never over it (Rerun draws a label below its point).
        assert len(shown_at(places, step)) == len(expected)
        for (k, ball, jx, jy), (x, y) in zip(expected, shown_at(places, step)):
            x0, y0 = records[k].positions[ball]
            vector = arrow(k, ball, jx, jy)
            lowest = min(y0, y0 + vector[1])
            assert y < lowest - 0.005 * span
            if vector[1] < 0.0:  # pointing down: under the head
                assert x == pytest.approx(x0 + vector[0], abs=1e-5)
            else:  # under the tail: under the pushed ball's own label as well
                assert x == pytest.approx(x0, abs=1e-5)
                assert y < y0 - world.radii[ball] - LABEL_LINE_FRACTION * span
    core, casing = (int.from_bytes(bytes((*c, 255)), 'big') for c in (IMPULSE_COLOR,
                                                                      CASING_COLOR))
    # One push on screen, or two, or none (cleared): casings first, then the cores.
    assert {tuple(color) for color in colors.values()} == {
        (casing, core), (casing, casing, core, core), ()}
    # 0.1 N s on a ball of ~0.1 kg is a small push: its arrow is lifted to the floor.
    assert np.hypot(*arrow(*first)[0:2]) == pytest.approx(ARROW_MIN_FRACTION * span, rel=1e-6)


def contrast(color, background):
    """WCAG 2 contrast ratio of two sRGB colours (1 to 21)."""
    def luminance(rgb):
        linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4
                  for c in (v / 255 for v in rgb)]
        return 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]
    high, low = sorted((luminance(color), luminance(background)), reverse=True)
    return (high + 0.05) / (low + 0.05)


def test_balls_pushes_and_walls_are_seen_on_light_and_dark_themes():
    # The web viewer's light theme is white, the dark one near black (the white arrow of
    # old was invisible on the light one).
    # A push's arrow is cased (rerun_casing): its dark casing or its light core keeps 4.5:1.
    for background in ((255, 255, 255), (0, 0, 0)):
        assert max(contrast(IMPULSE_COLOR, background),
                   contrast(CASING_COLOR, background)) >= 4.5
        assert contrast(WALL_COLOR, background) >= 3.0
    # ...and no ball shares the arrow's colour; balls and their labels are seen on both.
    colours = {ball_color(f'ball_{i}') for i in range(10_000)} | {ball_color('red')}
    assert IMPULSE_COLOR not in colours
    assert all(contrast(colour, (255, 255, 255)) >= 4.0 and contrast(colour, (0, 0, 0)) >= 4.0
               for colour in colours)
    assert len({ball_color(f'ball_{i}') for i in range(20)}) == 20  # neighbours differ


@pytest.mark.parametrize('origin, vector, expected', [
    ((5.0, 5.0), (2.0, 1.0), (2.0, 1.0)),        # inside: unchanged
    ((9.0, 5.0), (2.0, 1.0), (1.0, 0.5)),        # past xmax = 10: halved, same direction
    ((5.0, 1.0), (1.0, -4.0), (0.25, -1.0)),     # past ymin = 0
    ((9.5, 9.0), (2.0, 4.0), (0.5, 1.0)),        # past both: the nearer edge wins
    ((10.0, 5.0), (3.0, 0.0), (0.0, 0.0)),       # on the edge, pointing out: no length
    ((0.5, 5.0), (-2.0, 0.0), (-0.5, 0.0)),      # past xmin = 0
])
def test_an_arrow_is_shortened_to_keep_its_head_in_the_scene(origin, vector, expected):
    assert clip_arrow(origin, vector, (0.0, 0.0, 10.0, 10.0)) == pytest.approx(expected)


def test_a_push_at_a_wall_keeps_its_arrow_head_in_view(tmp_path):
    path = tmp_path / 'wall.rrd'
    parameters = {'random.count': 0, 'balls.x': [9.5], 'balls.y': [5.0], 'balls.vx': [0.0],
                  'balls.vy': [0.0], 'balls.radius': [0.2], 'balls.mass': [1.0]}
    run([RerunSink(path)], steps=3, parameters=parameters, impulses={1: (0, 5.0, 0.0)})
    _, content, _, _ = read(path)
    (_, origin) = content[(f'/{IMPULSES}', 'Arrows2D:origins')][1]  # casing, core
    (_, vector) = content[(f'/{IMPULSES}', 'Arrows2D:vectors')][1]
    world_bounds = scene_bounds(SimpleNamespace(
        walls=np.array([[0, 0, 10, 0], [10, 0, 10, 10], [10, 10, 0, 10], [0, 10, 0, 0]]),
        radii=[0.2], positions=np.array([[9.5, 5.0]])))
    tip = origin[0] + vector[0]
    assert vector[0] > 0.0 and vector[1] == 0.0  # still pointing along the push
    assert tip <= world_bounds[2]  # its head inside the view's bounds


def test_optional_velocities_and_trails(tmp_path):
    path = tmp_path / 'run.rrd'
    collected = run([RerunSink(path, velocities=True, trail_seconds=0.1)], steps=20)
    records = collected.records
    _, content, _, _ = read(path)
    vectors = content[(f'/{VELOCITIES}', 'Arrows2D:vectors')]
    origins = content[(f'/{VELOCITIES}', 'Arrows2D:origins')]
    trails = content[(f'/{TRAILS}', 'LineStrips2D:strips')]
    for record in records:
        assert vectors[record.step] == as_float32(
            np.float32(record.velocities) * np.float32(VELOCITY_SECONDS))
        assert origins[record.step] == as_float32(record.positions)
        # The steps up to this one whose log times are within 0.1 s of it.
        within = [r for r in records[:record.step + 1]
                  if record.log_time_ns - r.log_time_ns <= 100_000_000]
        assert len(within) == min(record.step + 1, 6)  # 6 steps of 16,666,667 ns > 0.1 s
        expected = np.stack([np.float32(r.positions) for r in within], axis=1)
        assert trails[record.step] == expected.tolist()


def test_every_k_and_reset_keep_timelines_and_totals(tmp_path):
    path = tmp_path / 'sparse.rrd'
    collected = run([RerunSink(path, every=4)], steps=21, reset_at=15,
                    reset_parameters={'random.count': 5, 'random.seed': 3})
    _, content, _, sim_time = read(path)
    records = collected.records
    # The step timeline counts every step of the recording, across the reset.
    segment_starts = [i for i, r in enumerate(records) if r.step == 0]
    assert segment_starts == [0, 15]
    # Every 4th step of a segment, the impulse steps 1 and 10, the last steps 14 and 22.
    expected = {0, 1, 4, 8, 10, 12, 14, 15, 19, 22}
    positions = content[(f'/{BALLS}', 'Points2D:positions')]
    assert set(positions) == expected
    for global_step in expected:
        record = records[global_step]
        assert positions[global_step] == as_float32(record.positions)
        assert sim_time[global_step] == record.log_time_ns
    assert len(positions[22]) == 5 and len(positions[14]) == 20
    # Totals at the last logged step of each segment count the skipped steps too.
    collisions = scalars(content, COLLISIONS)
    for last, segment in ((14, records[:15]), (22, records[15:])):
        assert collisions[last] == [sum(r.ball_ball for r in segment),
                                    sum(r.ball_wall for r in segment)]


def test_balls_named_by_the_record_may_come_and_go(tmp_path):
    """Records naming their balls: labels, radii and colours follow the names."""
    path = tmp_path / 'named.rrd'
    sink = RerunSink(path)
    collector = Truth()
    simulation = Simulation({'random.count': 3}, sinks=[collector])
    world, _ = collector.segments[0]
    info = SimpleNamespace(parameters={}, log_offset_ns=0)
    sink.start_segment(world, info)
    initial = collector.records[0]
    sink.write_step(initial)
    simulation.step()
    two = collector.records[1]
    # Step 1: ball_1 is gone; step 2: a ball named 'red' arrives with its own radius.
    gone = SimpleNamespace(**{**vars(replace(two)), 'positions': two.positions[[0, 2]],
                              'velocities': two.velocities[[0, 2]],
                              'names': ('ball_0', 'ball_2'), 'radii': world.radii[[0, 2]],
                              'masses': world.masses[[0, 2]]})
    sink.write_step(gone)
    arrived = SimpleNamespace(**{**vars(gone), 'step': 2, 'log_time_ns': 2 * two.log_time_ns,
                                 'positions': np.vstack([gone.positions, [[5.0, 5.0]]]),
                                 'names': ('ball_0', 'ball_2', 'red'),
                                 'radii': [*world.radii[[0, 2]], 0.5],
                                 'masses': [*world.masses[[0, 2]], 0.8]})
    sink.write_step(arrived)
    sink.close()
    _, content, _, _ = read(path)
    labels = content[(f'/{LABELS}', 'Points2D:labels')]
    radii = content[(f'/{BALLS}', 'Points2D:radii')]
    colors = content[(f'/{BALLS}', 'Points2D:colors')]
    assert {k: sorted(v) for k, v in labels.items()} == {
        0: ['ball_0', 'ball_1', 'ball_2'], 1: ['ball_0', 'ball_2'],
        2: ['ball_0', 'ball_2', 'red']}
    assert radii[1] == as_float32(world.radii[[0, 2]])
    assert radii[2] == as_float32([*world.radii[[0, 2]], 0.5])
    assert colors[1] == [colors[0][0], colors[0][2]]  # a ball keeps its colour
    assert len(content[(f'/{BALLS}', 'Points2D:positions')][2]) == 3
    # The label points follow the names too: 'red' is labelled beside its own radius.
    points = content[(f'/{LABELS}', 'Points2D:positions')]
    assert_labels_clear(points[2], labels[2], as_float32(arrived.positions), arrived.radii,
                        list(arrived.names), view_bounds(world))


def test_identical_runs_give_identical_content(tmp_path):
    first, second = tmp_path / 'first.rrd', tmp_path / 'second.rrd'
    run([RerunSink(first)])
    run([RerunSink(second)])
    store_a, content_a, _, _ = read(first)
    store_b, content_b, _, _ = read(second)
    assert store_a.recording_id == store_b.recording_id
    assert content_a == content_b
    # Chunk boundaries and row ids may differ between runs; the data may not.
    result = run_rerun('rrd', 'compare', '--unordered', str(first), str(second))
    assert result.returncode == 0, result.stdout + result.stderr


def test_mcap_converts_to_the_same_positions(tmp_path, capsys):
    live, mcap, converted = tmp_path / 'live.rrd', tmp_path / 'run.mcap', tmp_path / 'conv.rrd'
    run([RerunSink(live), McapSink(mcap)])
    assert to_rrd.main([str(mcap), '-o', str(converted)]) == 0
    assert '31/31 steps' in capsys.readouterr().err
    result = run_rerun('rrd', 'verify', str(converted))
    assert result.returncode == 0, result.stdout + result.stderr
    _, live_content, _, live_times = read(live)
    _, converted_content, _, converted_times = read(converted)
    for key in ((f'/{BALLS}', 'Points2D:positions'), (f'/{IMPULSES}', 'Arrows2D:vectors'),
                (f'/{ENERGY}', 'Scalars:scalars'), (f'/{COLLISIONS}', 'Scalars:scalars'),
                (f'/{REAL_TIME_FACTOR}', 'Scalars:scalars')):
        assert converted_content[key] == live_content[key], key
    assert converted_times == live_times


def test_converter_reports_unreadable_input(tmp_path, capsys):
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(b'not an mcap file')
    assert to_rrd.main([str(bad)]) == 2
    assert 'error' in capsys.readouterr().err


# The real-time factor -----------------------------------------------------------------------

class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class CallRecorder:
    """An outlet that keeps the calls made on it instead of sending them."""

    def __init__(self, calls):
        self.calls = calls

    def call(self, name, *args, **kwargs):
        self.calls.append((name, args, kwargs))

    def flush(self):
        pass

    def close(self):
        pass


def recorded_view_feed():
    """(a live view's feed whose calls are kept, the calls, its FakeClock): a frame every
    0.1 s of that clock."""
    calls = []
    clock = FakeClock()
    feed = rerun_log._Feed(lambda stream, plan: CallRecorder(calls), frame_period=0.1,
                           frame_clock=clock)
    return feed, calls, clock


def test_real_time_factor_is_over_the_last_second_and_shows_a_stall(tmp_path):
    """60 steps/s of wall time (RTF 1), one step that takes 3 s, then 60 steps/s again."""
    clock = FakeClock()
    path = tmp_path / 'rtf.rrd'
    dt = 16_666_667e-9  # the default world's step, 1/60 s in whole nanoseconds
    wall_per_step = {k: dt for k in range(1, 241)}
    wall_per_step[100] = 3.0

    class Ticking(Truth):
        def write_step(self, record):
            clock.now += wall_per_step.get(record.step, 0.0)

    collector = Truth()
    simulation = Simulation({}, sinks=[Ticking(), RerunSink(path, clock=clock), collector])
    for _ in range(240):
        simulation.step(real_time_factor=1.0)  # the node's value is ignored with a clock
    simulation.close()
    _, content, _, _ = read(path)
    rtf = {step: value for step, (value,) in scalars(content, REAL_TIME_FACTOR).items()}
    # No rate before the steps span half a second (31 steps of 1/60 s): the first steps of
    # a run come at uneven times.
    assert not set(range(0, 31)) & set(rtf)
    for step in range(31, 100):
        assert rtf[step] == pytest.approx(1.0, rel=1e-9)
    # Right after the stall the last second holds the stalled step: 1/60 s in 3 s.
    assert rtf[100] == pytest.approx(dt / 3.0, rel=1e-9)
    # Steps 101..159: the window still reaches back to the stalled step...
    assert rtf[130] == pytest.approx(31 * dt / (3.0 + 30 * dt), rel=1e-9)
    # ...and once a full second has passed since it, the factor is 1 again.
    assert rtf[161] == pytest.approx(1.0, rel=1e-9)
    assert rtf[240] == pytest.approx(1.0, rel=1e-9)


def test_real_time_factor_window_unit():
    clock = FakeClock()
    meter = RealTimeFactor(clock, window=1.0)
    assert meter.add(0) is None
    clock.now += 0.5
    assert meter.add(1_000_000_000) == pytest.approx(2.0)  # 1 s simulated in 0.5 s


# Destinations that fail --------------------------------------------------------------------

@pytest.mark.parametrize('value', [
    'rerun+http://127.0.0.1:9876', 'http://127.0.0.1:9876/proxy', 'rerun+http://:9876/proxy',
    'rerun+http://127.0.0.1:99999/proxy', 'Spawn', 'rerun+http://h:1/proxy?x=1', ' ',
    'rerun+http://host:0/proxy', 'rerun+http://host/proxy', 'rerun+https://example.org/proxy',
    'rerun+http://host:/proxy', 'rerun+http://host:-1/proxy'])
def test_bad_view_values_are_refused(value):
    with pytest.raises(ValueError, match='expected .spawn. or a URL like rerun'):
        parse_view(value)
    with pytest.raises(ValueError, match='expected'):
        RerunSink(view=value)


def test_good_view_values():
    assert parse_view('spawn') == ('127.0.0.1', 9876)
    assert parse_view('rerun+http://localhost:9090/proxy') == ('localhost', 9090)
    assert parse_view('rerun+https://example.org:443/proxy') == ('example.org', 443)
    assert parse_view('rerun://[::1]:9876/proxy') == ('::1', 9876)


def test_sink_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError):
        RerunSink(tmp_path / 'x.rrd', every=0)
    with pytest.raises(ValueError):
        RerunSink(tmp_path / 'x.rrd', trail_seconds=-1.0)
    with pytest.raises(ValueError):
        RerunSink()
    with pytest.raises(OSError):
        RerunSink(tmp_path / 'missing' / 'x.rrd')


class HangingStream:
    """A stream whose flush never returns, as RecordingStream.flush did on a full disk."""

    def __init__(self):
        self.release = threading.Event()
        self.entered = threading.Event()
        self.logged = []

    def log(self, *args, **kwargs):
        self.logged.append(args)

    def flush(self, timeout_sec):
        self.entered.set()
        self.release.wait()

    def disconnect(self):
        pass


def test_a_destination_that_hangs_is_dropped_without_blocking(monkeypatch):
    monkeypatch.setattr(rerun_outlet, 'STALL_SECONDS', 0.2)
    stream = HangingStream()
    outlet = Outlet('file test.rrd', stream, connect=lambda: None)
    try:
        outlet.call('log', 'a')
        outlet.flush()
        assert stream.entered.wait(LIVENESS_SECONDS)  # the worker now hangs in flush
        deadline = time.monotonic() + LIVENESS_SECONDS
        with pytest.raises(OutletFailed, match=r'file test.rrd: no answer'):
            while time.monotonic() < deadline:
                for _ in range(1000):
                    outlet.call('log', 'b')  # never blocks, even with the queue full
                outlet.flush()
                time.sleep(0.05)
        assert outlet.failed
        outlet.flush()  # reported once: later calls are dropped quietly
        outlet.close(timeout=0.1)
        assert stream.logged == [('a',)]
    finally:
        stream.release.set()


class SlowStream:
    """A stream that takes its time over every call, as a file writer on a loaded machine."""

    def __init__(self, seconds):
        self.seconds = seconds
        self.logged = []

    def log(self, *args, **kwargs):
        time.sleep(self.seconds)
        self.logged.append(args)

    def flush(self, timeout_sec):
        pass

    def disconnect(self):
        pass


def test_a_slow_file_holds_a_burst_of_steps_back_instead_of_losing_the_recording(tmp_path):
    stream = SlowStream(0.002)
    claim = claim_output(tmp_path / 'slow.rrd', overwrite=True)
    outlet = Outlet('file slow.rrd', stream, connect=lambda: None, claim=claim)
    try:
        burst = rerun_outlet.MAX_QUEUED_CALLS * 3  # more calls at once than the queue holds
        for k in range(burst):
            outlet.call('log', k)
        outlet.close(timeout=LIVENESS_SECONDS)
        assert outlet.failed is None and stream.logged == [(k,) for k in range(burst)]
    finally:
        claim.discard()


def test_a_stuck_file_with_a_full_queue_holds_the_steps_back_at_most_the_stall_time(
        monkeypatch, tmp_path):
    monkeypatch.setattr(rerun_outlet, 'STALL_SECONDS', 0.3)
    stream = HangingStream()
    claim = claim_output(tmp_path / 'stuck.rrd', overwrite=True)
    outlet = Outlet('file stuck.rrd', stream, connect=lambda: None, claim=claim)
    try:
        outlet.flush()
        assert stream.entered.wait(LIVENESS_SECONDS)  # the worker now hangs in flush
        began = time.monotonic()
        for _ in range(rerun_outlet.MAX_QUEUED_CALLS + 10):
            outlet.call('log', 'b')
        held = time.monotonic() - began
        with pytest.raises(OutletFailed, match=r'calls waiting, none begun or ended for 0.3 s'):
            outlet.flush()
        assert 0.3 <= held < LIVENESS_SECONDS  # held back once, then the calls are dropped
    finally:
        stream.release.set()
        claim.discard()


FULL_DISK_SCRIPT = """
import resource, signal, sys, time
from ball_world.recording.rerun_log import RerunSink
from ball_world.simulation import Simulation
limit = int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # as Python does: the write fails with EFBIG
failures = []
simulation = Simulation({'random.count': 3000, 'arena': [0.0, 0.0, 120.0, 120.0]},
                        sinks=[RerunSink(sys.argv[1])], on_sink_failure=failures.append)
step = 0
while step < 2000 and (not failures or step < failed_at + 300):
    simulation.step()
    step += 1
    if step % 30 == 0:
        simulation.flush()
    if failures and 'failed_at' not in globals():
        failed_at = step
        print(f'failed at step {step}: {failures[0].error}', flush=True)
simulation.close()
print(f'stepped to {step}; failures {len(failures)}', flush=True)
"""


def test_full_disk_stops_the_rrd_once_and_stepping_goes_on(tmp_path):
    """3,000 balls into an .rrd limited to 2 MB (RLIMIT_FSIZE): the write fails mid-run."""
    path = tmp_path / 'full.rrd'
    limit = 2_000_000
    result = subprocess.run(
        [sys.executable, '-c', FULL_DISK_SCRIPT, str(path), str(limit)],
        capture_output=True, text=True, timeout=LIVENESS_SECONDS * 6)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert len(lines) == 2, result.stdout
    failed_at = int(lines[0].split()[3].rstrip(':'))
    assert f'file {str(path)!r}' in lines[0]
    assert lines[1] == f'stepped to {failed_at + 300}; failures 1'
    assert path.stat().st_size <= limit


# Live view ----------------------------------------------------------------------------------

def free_port():
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


@pytest.fixture
def listener(tmp_path, processes):
    """A `rerun --save` gRPC server on a free port: what a viewer would receive."""

    def start(name='received.rrd'):
        port = free_port()
        path = tmp_path / name
        process = processes.start(
            [RERUN, '--bind', '127.0.0.1', '--port', str(port), '--save', str(path)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + LIVENESS_SECONDS
        while True:
            try:
                socket.create_connection(('127.0.0.1', port), timeout=1.0).close()
                break
            except OSError:
                assert time.monotonic() < deadline, 'rerun --save did not listen'
                time.sleep(0.1)
        return process, f'rerun+http://127.0.0.1:{port}/proxy', path

    return start


def stop_listener(process, saved=None):
    """Ctrl-C: the listener finishes its file.

    With `saved` (the listener's file), first wait until the file has stopped growing for a
    second: on a loaded machine the last messages may still be on their way when the sink
    has closed, and a listener stopped then never writes them.
    """
    if saved is not None:
        deadline = time.monotonic() + LIVENESS_SECONDS
        size = -1
        while time.monotonic() < deadline:
            now = saved.stat().st_size if saved.exists() else 0
            if now == size and now > 0:
                break
            size = now
            time.sleep(1.0)
    process.send_signal(signal.SIGINT)
    process.wait(timeout=LIVENESS_SECONDS)


#: Wall seconds per step in the live view tests: 66 steps/s, no multiple of the frame period.
WALL_STEP = 0.0151


def test_live_view_gets_frames_at_its_rate_with_balls_trails_and_pushes_in_step(
        tmp_path, listener):
    """Steps come every WALL_STEP s of (fake) wall time; the view gets VIEW_FPS frames/s."""
    process, url, received = listener()
    path = tmp_path / 'run.rrd'
    reports = []
    clock = FakeClock()

    class Ticking(Truth):
        def write_step(self, record):
            clock.now = 100.0 + record.step * WALL_STEP

    collector = Truth()
    sink = RerunSink(path, view=url, report=reports.append, clock=clock, trail_seconds=0.1)
    simulation = Simulation({}, sinks=[Ticking(), sink, collector])
    for k in range(1, 91):
        if k in IMPULSES_AT:
            ball, jx, jy = IMPULSES_AT[k]
            simulation.queue_impulse(f'ball_{ball}', jx, jy)
        simulation.step()
    simulation.close()
    stop_listener(process, received)
    assert reports == []
    store_file, content_file, _, _ = read(path)
    store_view, content_view, _, _ = read(received)
    assert store_view.recording_id == store_file.recording_id  # one recording
    assert open_rrd(received).blueprints(), 'the blueprint reached the viewer'
    records = collector.records

    # Frame n is the first step at or after n frame periods of wall time, plus the last.
    period = 1.0 / VIEW_FPS
    ratios = [n * period / WALL_STEP for n in range(1, 40)]
    assert all(abs(r - round(r)) > 1e-6 for r in ratios)  # no step exactly on a frame
    frames = {0, 90} | {math.ceil(r) for r in ratios if r <= 90}
    positions = content_view[(f'/{BALLS}', 'Points2D:positions')]
    assert set(positions) == frames
    assert all(positions[k] == as_float32(records[k].positions) for k in frames)
    # The file still has every step.
    assert sorted(content_file[(f'/{BALLS}', 'Points2D:positions')]) == list(range(91))
    # Trails and plots go with the balls: the same frames, nothing in between. The trails
    # are in the balls' rows, so no viewer can draw one without the other.
    trails = content_view[(f'/{BALLS}', 'LineStrips2D:strips')]
    assert set(trails) == frames
    for k in frames:
        # A point per VIEW_TRAIL_SPACING s of simulated time at most, and where the ball is
        # now; none older than the trail's 0.1 s.
        kept = [j for j in frames if j < k and records[k].log_time_ns
                - records[j].log_time_ns <= 100_000_000]
        assert all(strip[-1] == point for strip, point in zip(trails[k], positions[k]))
        assert 1 <= len(trails[k][0]) <= len(kept) + 1
        assert len(trails[k][0]) - 1 <= 0.1 / VIEW_TRAIL_SPACING + 1
    # The labels move with the balls, in the balls' rows (arrows of length 0, drawn as
    # their labels alone), under each ball: no frame's names under another frame's balls.
    labels = content_view[(f'/{BALLS}', 'Arrows2D:origins')]
    texts = content_view[(f'/{BALLS}', 'Arrows2D:labels')]
    assert set(labels) == set(texts) == frames
    world = collector.segments[0][0]
    names = [f'ball_{i}' for i in range(len(world.radii))]
    for k in frames:
        assert_labels_clear(labels[k], texts[k], positions[k], world.radii, names,
                            view_bounds(world))
    assert all(set(map(tuple, v)) == {(0.0, 0.0)}
               for v in content_view[(f'/{BALLS}', 'Arrows2D:vectors')].values() if v)
    assert not [key for key in content_view if key[0] == f'/{LABELS}']
    assert set(scalars(content_view, COLLISIONS)) == frames
    assert scalars(content_view, COLLISIONS)[90] == scalars(content_file, COLLISIONS)[90]
    # The push of step 10 (between frames) is drawn at the next frame, from where it was
    # applied, and stays on screen half a second of simulated time and, in a view,
    # VIEW_EVENT_SECONDS of wall time (a page draws the last frame of each chunk it gets);
    # the push of step 1 is gone by step 90, after both.
    origins = content_view[(f'/{IMPULSES}', 'Arrows2D:origins')]
    after = min(k for k in frames if k >= 10)
    pushed = as_float32(records[10].positions[3])
    for k in sorted(frames):
        if after <= k and (k - after) * WALL_STEP < VIEW_EVENT_SECONDS:
            assert pushed in shown_at(origins, k), k
    assert (90 - 1) * WALL_STEP > VIEW_EVENT_SECONDS
    assert shown_at(origins, 90) == [pushed] * 2  # its casing and itself (rerun_casing)
    # What a page opened late needs is static: it outlives the frames a server drops.
    for key in ((f'/{WALLS}', 'LineStrips2D:strips'), (f'/{BALLS}', 'Points2D:radii'),
                (f'/{BALLS}', 'Points2D:colors'), (f'/{BALLS}', 'Arrows2D:show_labels'),
                (f'/{ARENA}', 'Transform3D:rotation_axis_angle')):
        assert list(content_view[key]) == [None], key


def test_absent_viewer_is_reported_once_and_the_file_goes_on(tmp_path):
    path = tmp_path / 'run.rrd'
    reports = []
    url = f'rerun+http://127.0.0.1:{free_port()}/proxy'
    sink = RerunSink(path, view=url, report=reports.append)
    simulation = Simulation({}, sinks=[sink])
    deadline = time.monotonic() + LIVENESS_SECONDS
    while not reports:
        assert time.monotonic() < deadline, 'the absent viewer was never reported'
        for _ in range(30):
            simulation.step()
        simulation.flush()
        time.sleep(0.05)
    for _ in range(60):
        simulation.step()
    simulation.flush()
    simulation.close()
    assert reports == [f'live view at {url}: no viewer listens there (Connection refused); '
                       'going on without it']
    result = run_rerun('rrd', 'verify', str(path))
    assert result.returncode == 0, result.stdout + result.stderr
    _, content, _, _ = read(path)
    assert len(content[(f'/{BALLS}', 'Points2D:positions')]) == simulation.step_index + 1


def test_killed_viewer_is_reported_once(tmp_path, listener):
    process, url, _ = listener()
    path = tmp_path / 'run.rrd'
    reports = []
    simulation = Simulation({}, sinks=[RerunSink(path, view=url, report=reports.append)])
    for _ in range(60):
        simulation.step()
    simulation.flush()
    process.kill()
    process.wait()
    deadline = time.monotonic() + LIVENESS_SECONDS
    while not reports:
        assert time.monotonic() < deadline, 'the killed viewer was never reported'
        for _ in range(30):
            simulation.step()
        simulation.flush()
        time.sleep(0.05)
    simulation.close()
    # The SDK notices the broken connection, or else the probe finds the port closed.
    (report,) = reports
    assert report.startswith(f'live view at {url}: ') and report.endswith('; going on without it')
    result = run_rerun('rrd', 'verify', str(path))
    assert result.returncode == 0, result.stdout + result.stderr


def test_view_alone_without_a_file(listener):
    process, url, received = listener()
    collected = run([RerunSink(view=url)], steps=30)
    stop_listener(process, received)
    _, content, _, _ = read(received)
    positions = content[(f'/{BALLS}', 'Points2D:positions')]
    # Thirty steps in far less than a frame period: the first and the last are shown.
    assert {0, 30} <= set(positions)
    assert all(positions[k] == as_float32(collected.records[k].positions) for k in positions)


# The node ------------------------------------------------------------------------------------

def run_node(*parameters, timeout=LIVENESS_SECONDS * 3):
    process = start_node(*parameters)
    return subprocess.CompletedProcess(process.args, *finish(process, timeout))


def test_node_streams_to_a_viewer_and_records_one_recording(tmp_path, listener):
    process, url, received = listener()
    path = tmp_path / 'run.rrd'
    result = run_node('max_steps:=120', 'rate_hz:=120.0', 'dt:=0.0166666667',
                      f'view.rerun:={url}', f'record.rerun:={path}', 'rerun.velocities:=true',
                      'rerun.trail_seconds:=0.5')
    stop_listener(process, received)
    assert result.returncode == 0, result.stderr
    assert 'going on without it' not in result.stderr
    store_file, content_file, _, _ = read(path)
    store_view, content_view, _, _ = read(received)
    assert store_view.recording_id == store_file.recording_id
    assert sorted(content_file[(f'/{BALLS}', 'Points2D:positions')]) == list(range(121))
    # The view got frames (at most VIEW_FPS a second, so fewer than the 120 steps of one
    # second), each equal to the file's step, with the trail of the same step.
    shown = content_view[(f'/{BALLS}', 'Points2D:positions')]
    recorded = content_file[(f'/{BALLS}', 'Points2D:positions')]
    assert {0, 120} <= set(shown) and len(shown) < 121
    assert all(shown[k] == recorded[k] for k in shown)
    assert set(content_view[(f'/{BALLS}', 'LineStrips2D:strips')]) == set(shown)
    assert set(content_view[(f'/{BALLS}', 'Arrows2D:vectors')]) == set(shown)
    assert (f'/{VELOCITIES}', 'Arrows2D:vectors') in content_file
    # The row's arrows are the velocities: the labels are points of their own, per frame.
    assert set(content_view[(f'/{LABELS}', 'Points2D:positions')]) == set(shown)
    assert set(content_view[(f'/{LABELS}', 'Points2D:labels')]) == set(shown)
    assert not [key for key in content_view if key == (f'/{BALLS}', 'Arrows2D:labels')]
    assert (f'/{TRAILS}', 'LineStrips2D:strips') in content_file
    rtf = scalars(content_file, REAL_TIME_FACTOR)
    # From the first step half a second after step 1 (RealTimeFactor) to the last, every step.
    first = min(rtf)
    assert 2 < first < 120 and sorted(rtf) == list(range(first, 121))
    assert all(value > 0.0 for (value,) in rtf.values())


def test_node_without_a_viewer_says_so_once_and_runs(tmp_path):
    url = f'rerun+http://127.0.0.1:{free_port()}/proxy'
    result = run_node('max_steps:=150', f'view.rerun:={url}')
    assert result.returncode == 0, result.stderr
    assert result.stderr.count('no viewer listens there') == 1, result.stderr
    assert 'max_steps 150 reached' in result.stderr


@pytest.mark.parametrize('value', ['viewer', 'rerun+http://127.0.0.1:9876', 'http://h:1/proxy',
                                   'rerun+http://host:0/proxy'])
def test_node_refuses_a_bad_view_with_one_line(value):
    result = run_node(f'view.rerun:={value}')
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"ball_world: parameter 'view.rerun': expected 'spawn' or a URL like "
        f"rerun+http://127.0.0.1:9876/proxy, with a port from 1 to 65535, got '{value}'"]


# The native viewer (view.rerun:=spawn) ------------------------------------------------------

def test_spawn_arguments_bind_to_the_installed_sdk():
    """What Outlet.view('spawn') calls must be callable on the installed rerun-sdk as is."""
    stream = rerun_outlet.new_stream('ball_world', 'spawn-signature')
    function, arguments = rerun_outlet.spawn_call(stream, None, viewer=RERUN)
    bound = inspect.signature(function).bind(**arguments)
    assert bound.arguments['executable_path'] == str(RERUN)
    assert bound.arguments['recording'] is stream  # the outlet's stream, not a global one
    assert bound.arguments['port'] == rerun_outlet.SPAWN_PORT


FAKE_VIEWER = """#!/bin/sh
# Records how it was started, then serves as the real Rerun CLI would (saving what it gets).
case "$1" in --*version*) exec "{rerun}" "$@";; esac
echo $$ > "{pid}"
echo "$@" > "{args}"
exec "{rerun}" --bind 127.0.0.1 --save "{saved}" "$@"
"""


def test_spawn_starts_the_viewer_beside_python_and_streams_to_it(tmp_path, monkeypatch):
    """view.rerun:=spawn through the real SDK, with a viewer executable that saves to a file.

    The viewer taken is the `rerun` beside sys.executable (the .venv's); here a script that
    stands in for it on a free port, so the test neither opens a window nor needs port 9876.
    """
    bin_dir = tmp_path / 'bin'
    bin_dir.mkdir()
    pid_file, args_file, saved = tmp_path / 'pid', tmp_path / 'args', tmp_path / 'seen.rrd'
    viewer = bin_dir / 'rerun'
    viewer.write_text(FAKE_VIEWER.format(pid=pid_file, args=args_file, rerun=RERUN,
                                         saved=saved))
    viewer.chmod(0o755)
    port = free_port()
    monkeypatch.setattr(sys, 'executable', str(bin_dir / 'python3'))
    monkeypatch.setattr(rerun_outlet, 'SPAWN_PORT', port)
    reports = []
    try:
        run([RerunSink(view='spawn', report=reports.append)], steps=30)
        assert reports == []
        assert f'--port={port}' in args_file.read_text().split()
        deadline = time.monotonic() + LIVENESS_SECONDS
        while not (saved.exists() and saved.stat().st_size):
            assert time.monotonic() < deadline, 'the viewer received nothing'
            time.sleep(0.2)
    finally:
        if pid_file.exists():
            pid = int(pid_file.read_text())
            stop_listener(SimpleNamespace(send_signal=lambda s: os.kill(pid, s),
                                          wait=lambda timeout: _wait_gone(pid, timeout)),
                          saved)
    _, content, _, _ = read(saved)
    # A view is sent frames at VIEW_FPS of wall time, and the segment's first and last step:
    # these 30 steps take less than a frame.
    shown = sorted(content[(f'/{BALLS}', 'Points2D:positions')])
    assert shown[0] == 0 and shown[-1] == 30


def _wait_gone(pid, timeout):
    deadline = time.monotonic() + timeout
    while True:
        try:  # the SDK may start the viewer as this process's child: reap it
            if os.waitpid(pid, os.WNOHANG)[0] == pid:
                return
        except ChildProcessError:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return
        assert time.monotonic() < deadline, f'viewer {pid} did not stop'
        time.sleep(0.1)


# A signal in the middle of logging a step ---------------------------------------------------

#: rerun_log's colour arithmetic: pure functions of a name, which touch nothing but their
#: locals. An interrupt anywhere in them leaves the sink as one at the line that called them
#: does, and that line is interrupted every time it runs; so each of their lines is
#: interrupted only the first time it runs (1,300 of the 1,531 lines of a 20-ball step).
#: ball_color's work moved to _oklch_color and _hue (shared with name_color): without them
#: here, 605 of a step's 888 lines were their repeats, each a run of the sink of its own.
PURE = {'ball_color', '_oklch_color', '_hue', '_oklch_to_linear_srgb', '_srgb_encode'}


class InterruptAt:
    """A tracer that raises KeyboardInterrupt at the n-th line run in rerun_log (as SIGINT's
    handler would between two bytecodes), or with n None just counts those lines. A line
    of the PURE functions counts only the first time it runs."""

    def __init__(self, n=None):
        self.n = n
        self.lines = 0
        self.pure_seen = set()

    def __call__(self, frame, event, arg):
        code = frame.f_code
        if code.co_filename != rerun_log.__file__:
            return None
        if event == 'line':
            if code.co_qualname.split('.')[0] in PURE:
                if (code, frame.f_lineno) in self.pure_seen:
                    return self
                self.pure_seen.add((code, frame.f_lineno))
            self.lines += 1
            if self.lines == self.n:
                raise KeyboardInterrupt
        return self


#: Steps logged (and held in the sink's buffers) before the step that is interrupted, each
#: with a push on screen: the file must keep them all.
BUFFERED = 4
#: The lines are interrupted in this many interleaved shares, each a test of its own, so that
#: the suite's workers share them (a few hundred runs of a sink, a minute in all).
INTERRUPT_SHARES = 4


@pytest.mark.parametrize('share', range(INTERRUPT_SHARES))
def test_an_interrupt_anywhere_in_logging_a_step_loses_no_buffered_step(tmp_path, share):
    """Every line of write_step (and what it calls in rerun_log) is interrupted in turn (this
    test: every INTERRUPT_SHARES-th from line 1 + share); the buffered steps before it must
    all reach the file, in columns of one length."""

    def logged_until_interrupt(n, path):
        simulation = Simulation({}, sinks=[RerunSink(path, velocities=True, trail_seconds=0.1)])
        for _ in range(BUFFERED):
            simulation.queue_impulse('ball_1', 0.01, 0.0)
            simulation.step(real_time_factor=1.0)
        tracer = InterruptAt(n)
        simulation.queue_impulse('ball_2', 0.0, 0.01)
        sys.settrace(tracer)
        try:
            simulation.step(real_time_factor=1.0)
        except KeyboardInterrupt:
            pass
        finally:
            sys.settrace(None)
        simulation.close()  # a sink that raised here would be dropped and reported
        assert simulation.sinks == []
        return tracer.lines

    lines = logged_until_interrupt(None, tmp_path / 'whole.rrd')
    assert lines > 20
    for n in range(1 + share, lines + 1, INTERRUPT_SHARES):
        path = tmp_path / f'cut_{n}.rrd'
        logged_until_interrupt(n, path)
        _, content, _, _ = read(path)
        steps = sorted(content[(f'/{BALLS}', 'Points2D:positions')])
        # every step buffered before the interrupt
        assert steps[:BUFFERED + 1] == list(range(BUFFERED + 1)), n
        for column in ((f'/{VELOCITIES}', 'Arrows2D:vectors'), (f'/{ENERGY}', 'Scalars:scalars'),
                       (f'/{MOMENTUM}', 'Scalars:scalars')):
            assert sorted(content[column]) == steps, (n, column)
