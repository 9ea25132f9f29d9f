"""What the view draws of robots, read back from the .rrd with Rerun's reader: each scan as a
fan of rays from its robot, the drive's impulses apart from pushes (and counted apart), the
clock line, and colours that read on both of the viewer's themes: no text in Rerun's label
boxes (no colour reads on both themes' boxes), tags whose every colour is ours instead."""
import math
from types import SimpleNamespace

from ball_world_testing.harness import Truth
import numpy as np
import pytest
import rerun as rr
from test_rerun import read, recorded_view_feed, shown_at

from ball_world.core.lidar import hit_points
from ball_world.recording import rerun_agents, rerun_log
from ball_world.recording.rerun_agents import (AGENT_COLOR, AGENTS, BUMPER_TEXT_COLOR,
                                               BUMPER_VIEW_COLOR)
from ball_world.recording.rerun_log import (CLOCK, COLLISIONS, COLLISIONS_HEADROOM, ENERGY,
                                            ENERGY_HEADROOM, Headroom, IMPULSE_COLOR,
                                            IMPULSE_TEXT_COLOR, IMPULSES, name_color,
                                            NAMES, RerunSink, RULER_TEXT_COLOR, SCALE_LABELS)
from ball_world.recording.rerun_scans import MAX_RAYS, SCANS
from ball_world.recording.rerun_text import FONT, strokes, TAG_COLOR, TEXT_CONTRAST, width
from ball_world.simulation import Simulation
from ball_world.tools.view_tracks import TRACK_COLOR

ROBOTS = {'random.count': 8, 'agents': ['ball_0', 'ball_1'], 'agent.cmd_timeout': 0.0}
#: The backgrounds text and arrows are drawn on, measured on screenshots of the web viewer
#: (scripts/contrast.py, docs/view.md): the 2D view, and the box Rerun draws under a label.
VIEW = {'light view': (255, 255, 255), 'dark view': (13, 13, 13)}
LABEL_BOXES = {'light label box': (239, 239, 239), 'dark label box': (28, 28, 28)}


def luminance(color):
    """WCAG 2 relative luminance of an sRGB colour (0-255)."""
    channels = [c / 255.0 for c in color[:3]]
    linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in channels]
    return 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]


def contrast(a, b):
    """WCAG 2 contrast ratio, 1 to 21."""
    high, low = sorted((luminance(a), luminance(b)), reverse=True)
    return (high + 0.05) / (low + 0.05)


@pytest.fixture(scope='module')
def robot_run(tmp_path_factory):
    """Two robots driving among balls for a second, ball_3 pushed once at step 20."""
    path = tmp_path_factory.mktemp('robots') / 'robots.rrd'
    simulation = Simulation(ROBOTS, sinks=[RerunSink(path)])
    simulation.command('ball_0', 0.8, 0.0, 1.0)
    simulation.command('ball_1', 0.5, 0.0, -0.5)
    records = [simulation.last_record]
    for k in range(1, 61):
        if k == 20:
            simulation.queue_impulse('ball_3', 0.02, 0.0)
        records.append(simulation.step()[0])
    simulation.close()
    return simulation, records, read(path)[1]


def test_each_scan_is_a_fan_of_rays_from_its_robot_to_what_it_hits(robot_run):
    _, records, content = robot_run
    scanned = [r for r in records if r.agents.scans]
    assert len(scanned) >= 5  # 10 scans a second of simulated time
    for name, row in (('ball_0', 0), ('ball_1', 1)):
        rays = content[(f'/{SCANS}/{name}', 'LineStrips2D:strips')]
        hits = content[(f'/{SCANS}/{name}', 'Points2D:positions')]
        assert sorted(rays) == sorted(hits) == [r.step for r in scanned]
        for record in scanned:
            scan = record.agents.scans[row]
            x, y = record.positions[record.agents.indices[row]]
            yaw = float(record.agents.yaws[row])
            finite = np.isfinite(scan.ranges)
            # Every return is a hit point, where the beam's range puts it.
            assert np.allclose(hits[record.step], hit_points(
                (x, y), yaw, scan.fan, scan.ranges), atol=1e-5)
            # The rays: from the robot's centre, along every k-th beam to its return.
            fan = rays[record.step]
            assert 0 < len(fan) <= MAX_RAYS
            every = math.ceil(len(scan.ranges) / MAX_RAYS)
            assert len(fan) == np.count_nonzero(finite[::every])
            for (start, end), k in zip(fan, np.flatnonzero(finite[::every]) * every):
                assert start == pytest.approx([x, y], abs=1e-5)
                angle = yaw + scan.fan.angle_min + k * scan.fan.angle_increment
                assert end == pytest.approx([x + scan.ranges[k] * math.cos(angle),
                                             y + scan.ranges[k] * math.sin(angle)], abs=1e-4)


def test_the_drive_is_no_push_drawn_or_counted(robot_run):
    simulation, records, content = robot_run
    driven = [i for r in records for i in r.impulses if i.drive]
    assert len(driven) > 20  # the drives accelerated the robots for many steps
    assert {i.frame_id for i in driven} == {'ball_0', 'ball_1'}
    assert simulation.applied == 1 and simulation.drive_applied == len(driven)
    labels = content[(f'/{IMPULSES}', 'Points2D:labels')]
    # Only the push is on screen: at step 20, for half a second, and nothing before it.
    assert shown_at(labels, 19) in (None, [])
    assert shown_at(labels, 20) == ['ball_3: J = (0.02, 0) N s']
    assert all(not value or value == ['ball_3: J = (0.02, 0) N s'] for value in labels.values())
    # The robots' headings are drawn, every logged step.
    assert sorted(content[(f'/{AGENTS}', 'Arrows2D:vectors')]) == list(range(61))


def test_the_clock_line_says_the_simulated_time(robot_run):
    """A text document (drawn in the theme's own text colour), every 0.1 s of a file."""
    _, records, content = robot_run
    clock = content[(f'/{CLOCK}', 'TextDocument:text')]
    assert clock[0] == ['simulated time 0.0 s']
    assert len(clock) >= 10  # every 0.1 s of simulated time in a file
    for step, (text,) in clock.items():
        assert text.startswith(f'simulated time {records[step].stamp_ns * 1e-9:.1f} s')


def test_a_push_and_the_ruler_are_tags_their_text_kept_not_shown(robot_run):
    _, _, content = robot_run
    assert content[(f'/{IMPULSES}', 'Points2D:show_labels')][20] == [False]
    pills = content[(f'/{IMPULSES}', 'Boxes2D:centers')]
    text = content[(f'/{IMPULSES}', 'LineStrips2D:strips')]
    assert len(pills[20]) == 1 and len(text[20]) == len(strokes('ball_3: J = (0.02, 0) N s'))
    assert content[(f'/{IMPULSES}', 'LineStrips2D:colors')][20] == [
        int.from_bytes(bytes((*IMPULSE_TEXT_COLOR, 255)), 'big')] * len(text[20])
    assert shown_at(pills, 19) in (None, [])
    labels = content[(f'/{SCALE_LABELS}', 'Points2D:labels')][0]
    assert content[(f'/{SCALE_LABELS}', 'Points2D:show_labels')][0] == [False]
    assert len(content[(f'/{SCALE_LABELS}', 'Boxes2D:centers')][0]) == len(labels)
    assert len(content[(f'/{SCALE_LABELS}', 'LineStrips2D:strips')][0]) == sum(
        len(strokes(t)) for t in labels)


def test_a_live_view_draws_no_text_in_rerun_label_boxes():
    """A live feed's calls on a robot world with a push, recorded instead of sent: every
    label the view is sent is hidden (show_labels False where labels are), and every name
    is a tag (NAMES) in the ball's light hue."""
    feed, calls, clock = recorded_view_feed()
    collector = Truth()
    simulation = Simulation(ROBOTS, sinks=[collector])
    simulation.command('ball_0', 0.8, 0.0, 1.0)
    for k in range(1, 31):
        if k == 10:
            simulation.queue_impulse('ball_3', 0.02, 0.0)
        simulation.step()
    simulation.close()
    world, _ = collector.segments[0]
    feed.start_segment(world, SimpleNamespace(parameters={}, log_offset_ns=0))
    for record in collector.records[1:]:
        clock.now += 0.05
        feed.write_step(record)
    feed.close()
    shown, labelled, names = {}, set(), []
    for name, args, _ in calls:
        if name != 'log':
            continue
        for archetype in args[1:]:
            key = (args[0], type(archetype).__name__)
            flag = getattr(archetype, 'show_labels', None)
            if flag is not None:
                shown.setdefault(key, set()).update(flag.as_arrow_array().to_pylist())
            texts = getattr(archetype, 'labels', None)
            if texts is not None and texts.as_arrow_array().to_pylist():
                labelled.add(key)
            if args[0] == NAMES and isinstance(archetype, rr.LineStrips2D):
                names.append(archetype)
    assert {key[0] for key in labelled} >= {rerun_log.BALLS, IMPULSES, SCALE_LABELS}
    assert all(shown.get(key) == {False} for key in labelled), (labelled, shown)
    assert all(True not in flags for flags in shown.values())
    assert len(names) >= 10  # a frame a tenth of a second: the names at each
    colors = {color for strips in names for color in strips.colors.as_arrow_array().to_pylist()}
    hue = {int.from_bytes(bytes((*name_color(f'ball_{i}'), 255)), 'big'): i for i in range(10)}
    # Names in their balls' light hues; the robots always named, the balls where there is room.
    assert colors <= set(hue) and {hue[c] for c in colors} >= {0, 1} and len(colors) >= 6


def backgrounds_of_marks():
    """What a heading or a ring lies on: both themes' views, a map's occupied and unknown
    cells (drawn over either theme), the scans' rays and hit points, every ball's colour."""
    from ball_world.recording.rerun_map import UNKNOWN_COLOR
    from ball_world.recording.rerun_scans import RAY_ALPHA, SCAN_COLOR

    def over(color, alpha, under):
        return tuple(round((alpha * c + (255 - alpha) * u) / 255) for c, u in zip(color, under))
    found = dict(VIEW)
    for theme, view in VIEW.items():
        found[f'unknown cell on the {theme}'] = over(UNKNOWN_COLOR[:3], UNKNOWN_COLOR[3], view)
        found[f'ray on the {theme}'] = over(SCAN_COLOR, RAY_ALPHA, view)
    found['occupied cell'] = rerun_log.WALL_COLOR
    found['hit point'] = SCAN_COLOR
    found.update({f'ball_{i}': rerun_log.ball_color(f'ball_{i}') for i in range(40)})
    return found


@pytest.mark.parametrize('color', [AGENT_COLOR, TRACK_COLOR, BUMPER_VIEW_COLOR, IMPULSE_COLOR],
                         ids=['heading', 'track ring', 'bumper hit', 'push'])
def test_headings_and_rings_keep_3_to_1_on_whatever_they_lie_on(color):
    """The orange heading had 1.19:1 on a pink robot, the green ring 1.13:1 on the map's
    cells: no one colour has 3:1 on every disc, ray, cell and theme (a push's deep pink
    had 4.5:1 on both themes, but lay on the same discs, rays and cells). Cased, the mark's light
    core keeps 7:1 on its dark casing, and on anything it lies on the casing or the core
    keeps 3:1 (the casing on light things, the core on dark ones)."""
    from ball_world.recording.rerun_casing import CASING_COLOR, CORE_CONTRAST
    assert contrast(color, CASING_COLOR) >= CORE_CONTRAST
    for where, background in backgrounds_of_marks().items():
        assert max(contrast(color, background), contrast(CASING_COLOR, background)) >= 3.0, \
            where


def test_headings_and_rings_are_drawn_cased_core_over_casing(robot_run):
    """Each heading twice in one batch: the casing first (wider, dark), then the arrow."""
    from ball_world.recording.rerun_casing import CASING_COLOR, CASING_POINTS
    from ball_world.recording.rerun_agents import AGENT_RADIUS
    from ball_world.tools.view_tracks import ring_strips
    _, _, content = robot_run
    colors = content[(f'/{AGENTS}', 'Arrows2D:colors')][0]
    radii = content[(f'/{AGENTS}', 'Arrows2D:radii')][0]
    vectors = content[(f'/{AGENTS}', 'Arrows2D:vectors')][5]
    rgba = [int.from_bytes(bytes((*c, 255)), 'big') for c in (CASING_COLOR, AGENT_COLOR)]
    assert colors == [rgba[0]] * 2 + [rgba[1]] * 2  # two robots: casings, then cores
    assert radii == pytest.approx([-(AGENT_RADIUS + CASING_POINTS)] * 2 + [-AGENT_RADIUS] * 2)
    assert vectors[:2] == vectors[2:]
    rings = ring_strips(np.array([[1.0, 2.0]]), np.array([0.3]))
    strips = rings.strips.as_arrow_array().to_pylist()
    assert len(strips) == 2 and strips[0] == strips[1]
    assert [c for c in rings.colors.as_arrow_array().to_pylist()] == [
        int.from_bytes(bytes((*c, 255)), 'big') for c in (CASING_COLOR, TRACK_COLOR)]


def test_no_one_text_colour_reads_on_both_themes_label_boxes():
    """Why the view draws its text itself: Rerun draws a label's text in one colour on a
    box of the theme's, light grey or dark grey, and the best any colour can have on both
    (luminance 0.185) is 3.85:1."""
    light, dark = LABEL_BOXES.values()
    best = math.sqrt((luminance(light) + 0.05) / (luminance(dark) + 0.05))
    assert best == pytest.approx(3.85, abs=0.01)
    assert max(min(contrast((v, v, v), light), contrast((v, v, v), dark))
               for v in range(256)) < 4.0


@pytest.mark.parametrize('name', [f'ball_{i}' for i in range(30)] + ['ball', 'robot', 'ZZ 9'])
def test_a_names_text_keeps_its_contrast_on_its_tag(name):
    """A tag's fill is ours, the same on either theme: the name's light hue keeps
    TEXT_CONTRAST (7:1) on it, any hue."""
    assert contrast(name_color(name), TAG_COLOR) >= TEXT_CONTRAST


@pytest.mark.parametrize('color', [IMPULSE_TEXT_COLOR, BUMPER_TEXT_COLOR, RULER_TEXT_COLOR],
                         ids=['push', 'bumper', 'ruler'])
def test_tag_texts_keep_their_contrast(color):
    assert contrast(color, TAG_COLOR) >= TEXT_CONTRAST


def test_the_font_has_every_printable_character_inside_its_cell():
    """Glyphs lie in their cell (x 0 to 4, y from the descender to the bracket's top), so a
    tag's text stays inside the tag; a character the font lacks is drawn as '?'."""
    assert set(FONT) >= {chr(c) for c in range(32, 127)} - set('@$&^`{}~\\')
    for char, glyph in FONT.items():
        for stroke in glyph:
            assert len(stroke) >= 2, char
            assert np.all(stroke[:, 0] >= 0.0) and np.all(stroke[:, 0] <= 4.0), char
            assert np.all(stroke[:, 1] >= -2.0) and np.all(stroke[:, 1] <= 7.0), char
    assert [s.tolist() for s in strokes('~')] == [s.tolist() for s in strokes('?')]
    drawn = np.concatenate(strokes('ball_14: J = (0.02, 0) N s'))
    assert drawn[:, 0].min() >= 0.0
    assert drawn[:, 0].max() <= width('ball_14: J = (0.02, 0) N s')


def test_plots_keep_room_above_and_below_their_data(robot_run):
    """Rerun fits a plot's y axis to its data's exact extremes: the collisions' total ran
    along the top edge. Invisible series just beyond the data make the axis hold it whole."""
    _, records, content = robot_run
    energy = content[(f'/{ENERGY}', 'Scalars:scalars')]
    collisions = content[(f'/{COLLISIONS}', 'Scalars:scalars')]
    energy_room = content[(f'/{ENERGY_HEADROOM}', 'Scalars:scalars')]
    collisions_room = content[(f'/{COLLISIONS_HEADROOM}', 'Scalars:scalars')]
    assert sorted(energy_room) == sorted(collisions_room) == sorted(energy)
    assert max(abs(row[0]) for row in energy.values()) > 1.0  # the drives changed the energy
    for step in energy:
        seen = [v for k, row in energy.items() if k <= step for v in row]
        above, below = energy_room[step]
        room = max(0.08 * (max(seen) - min(seen)), 0.5)
        assert above == pytest.approx(max(seen) + room) and below == pytest.approx(
            min(seen) - room)
        most = max(max(row) for k, row in collisions.items() if k <= step)
        assert collisions_room[step] == [pytest.approx(most * 1.08 + 1.0)]
    # Drawn in no colour, at no width.
    assert content[(f'/{ENERGY_HEADROOM}', 'SeriesLines:colors')][None] == [0, 0]
    assert content[(f'/{COLLISIONS_HEADROOM}', 'SeriesLines:widths')][None] == [0.0]


def test_with_robots_the_energy_plot_shows_the_drives_part_and_the_rests(robot_run):
    """The total swung by tens of percent with robots driving, and nothing said why. Now
    beside it: what the drives put in minus what they took out, and the rest, which is
    0 until ball_3 is pushed at step 20 (collisions keep energy), then that push's work,
    m/2 (|v + J/m|^2 - |v|^2) with v its velocity before (the record of step 19)."""
    simulation, records, content = robot_run
    energy = content[(f'/{ENERGY}', 'Scalars:scalars')]
    names = content[(f'/{ENERGY}', 'SeriesLines:names')][0]
    assert len(names) == 3 and names[1].startswith("robots' drives") and \
        names[2].startswith('the rest')
    energy0 = records[0].kinetic_energy
    ball = records[19].names.index('ball_3') if records[19].names else 3
    mass = float(simulation.world.masses[ball])
    vx, vy = records[19].velocities[ball]
    push = 0.5 * mass * ((vx + 0.02 / mass) ** 2 + vy ** 2 - vx ** 2 - vy ** 2)
    for record in records[1:]:
        total, drives, rest = energy[record.step]
        assert total == pytest.approx(
            (record.kinetic_energy - energy0) / energy0 * 100.0, abs=1e-9)
        assert total == pytest.approx(drives + rest, abs=1e-9)
        expected = 0.0 if record.step < 20 else push / energy0 * 100.0
        assert rest == pytest.approx(expected, abs=1e-9)
    assert max(abs(energy[r.step][1]) for r in records) > 1.0


def test_without_robots_the_energy_plot_is_one_series(tmp_path):
    path = tmp_path / 'balls.rrd'
    simulation = Simulation({'random.count': 5}, sinks=[RerunSink(path)])
    for _ in range(3):
        simulation.step()
    simulation.close()
    content = read(path)[1]
    assert all(len(row) == 1 for row in content[(f'/{ENERGY}', 'Scalars:scalars')].values())
    [name] = content[(f'/{ENERGY}', 'SeriesLines:names')][0]
    assert name.startswith('change from')


def test_a_views_headroom_follows_the_last_seconds_it_shows():
    room = Headroom(window=30.0)
    assert room.add(0, 10.0, 0.0) == (10.5, 9.5, 1.0)
    assert room.add(10 * 10**9, 20.0, 5.0) == (20.8, 9.2, 6.4)
    # 40 s later the first rows are out of the window.
    assert room.add(40 * 10**9, 0.0, 5.0) == (21.6, -1.6, 6.4)
    assert room.add(45 * 10**9, 0.0, 5.0) == (0.5, -0.5, 6.4)


def test_a_live_view_draws_every_robots_latest_scan_in_one_entity():
    """A view is sent all robots' scans as one entity (a software-rendered page takes in few
    messages a second, whatever the number of robots): at each frame after a scan, the fans
    of both robots from where each scanned; after one robot is deleted, only the other's."""
    feed, calls, clock = recorded_view_feed()
    collector = Truth()
    simulation = Simulation(ROBOTS, sinks=[collector])
    for _ in range(30):
        simulation.step()
    simulation.delete('ball_0')
    for _ in range(30):
        simulation.step()
    simulation.close()
    world, _ = collector.segments[0]
    feed.start_segment(world, SimpleNamespace(parameters={}, log_offset_ns=0))
    logged = []  # (ray origins of each scans call, the steps' latest scanners' positions)
    latest = {}
    for record in collector.records[1:]:
        clock.now += 0.05
        for scan in record.agents.scans:
            row = record.agents.names.index(scan.name)
            latest[scan.name] = tuple(np.float32(record.positions[record.agents.indices[row]]))
        latest = {name: at for name, at in latest.items() if name in record.agents.names}
        before = len(calls)
        feed.write_step(record)
        for name, args, _ in calls[before:]:
            if name == 'log' and args[0].startswith(SCANS):
                assert args[0] == SCANS
                rays, hits = args[1], args[2]
                assert isinstance(rays, rr.LineStrips2D) and isinstance(hits, rr.Points2D)
                origins = {tuple(strip[0]) for strip in rays.strips.as_arrow_array().to_pylist()}
                logged.append((origins, set(latest.values())))
                assert len(hits.positions.as_arrow_array()) > 0
    feed.close()
    assert len(logged) >= 4
    both = [origins for origins, _ in logged if len(origins) == 2]
    alone = [origins for origins, _ in logged if len(origins) == 1]
    assert both and alone  # both robots' fans, then ball_1's alone after ball_0 was deleted
    for origins, expected in logged:
        assert origins == {tuple(np.float32(v) for v in at) for at in expected}


def test_a_live_view_keeps_a_push_on_screen_for_a_whole_flush_of_wall_time():
    """A page is sent a chunk of frames every VIEW_FLUSH_SECONDS and draws its last frame: a
    push whose half second of simulated time passes in a fifth of a second of wall time (a
    world running fast) stays drawn until VIEW_EVENT_SECONDS of wall time have passed."""
    feed, calls, clock = recorded_view_feed()
    collector = Truth()
    simulation = Simulation({'random.count': 4}, sinks=[collector])
    simulation.queue_impulse('ball_1', 0.01, 0.0)
    for _ in range(240):  # 2.4 s of wall time below
        simulation.step()
    simulation.close()
    world, _ = collector.segments[0]
    feed.start_segment(world, SimpleNamespace(parameters={}, log_offset_ns=0))
    drawn_at = cleared_at = None
    for record in collector.records[1:]:
        clock.now += 0.01  # a step of 1/60 s in 0.01 s of wall time
        before = len(calls)
        feed.write_step(record)
        for name, args, _ in calls[before:]:
            if name != 'log' or args[0] != IMPULSES:
                continue
            if args[1] is rerun_log.IMPULSES_CLEARED[0]:
                cleared_at = cleared_at if cleared_at is not None else clock.now
            elif drawn_at is None:
                drawn_at = clock.now
    feed.close()
    assert drawn_at is not None and cleared_at is not None
    # Simulated time alone would have cleared it after 0.5 s / (1/60 s) steps = 0.3 s.
    assert rerun_log.VIEW_EVENT_SECONDS <= cleared_at - drawn_at
    assert cleared_at - drawn_at <= rerun_log.VIEW_EVENT_SECONDS + 0.1 + 1e-9  # a frame later


def test_a_live_view_holds_a_bumper_hits_clear_for_a_whole_flush_of_wall_time(monkeypatch):
    """A view's BumperView clears a hit once its simulated half second and VIEW_EVENT_SECONDS
    of wall time have both passed (here the simulated time passes first)."""
    arrows = object()
    monkeypatch.setattr(rerun_agents, 'bumper_arrows', lambda record: record.hit)
    clock = SimpleNamespace(now=100.0)
    bumpers = rerun_agents.BumperView(lambda: clock.now, rerun_log.VIEW_EVENT_SECONDS)

    def at(seconds, hit=None, step=1):
        return bumpers.update(SimpleNamespace(stamp_ns=round(seconds * 1e9), step=step, hit=hit))

    assert at(0.0, arrows) == ('log', arrows)
    clock.now += 0.3
    assert at(0.6) is None  # held back: BUMPER_SHOWN of simulated time is over, not the hold
    clock.now += rerun_log.VIEW_EVENT_SECONDS - 0.3 - 0.01
    assert at(0.7) is None
    clock.now += 0.02
    assert at(0.8) == ('clear', None)
    assert at(0.9) is None  # once
    # A reset (step 0, stamps from 0 again) ends a hit's simulated time; the hold still counts.
    assert at(1.0, arrows) == ('log', arrows)
    assert at(0.0, step=0) is None
    clock.now += rerun_log.VIEW_EVENT_SECONDS
    assert at(0.1) == ('clear', None)


def test_a_live_view_thins_the_rays_as_robots_multiply():
    """Twenty robots' 72 rays each were a mesh over the depot: a view shares out
    VIEW_RAY_BUDGET rays, none below MIN_RAYS a robot; the hit points are always drawn."""
    from ball_world.recording.rerun_scans import MIN_RAYS, VIEW_RAY_BUDGET, view_rays
    assert [view_rays(n) for n in (1, 2, 3, 4, 12, 13, 20)] == [72, 72, 48, 36, 12, 0, 0]
    for robots in range(1, 40):
        rays = view_rays(robots)
        assert rays * robots <= VIEW_RAY_BUDGET and (rays == 0 or rays >= MIN_RAYS)


def test_the_legend_names_every_mark_of_the_world_it_shows():
    """A newcomer sees discs, lines, dots, arrows, rings and grey cells: the page's legend
    names each one this world draws, and no mark it does not draw."""
    from ball_world.recording.rerun_legend import legend_text
    sandbox = {'agents': ['ball_0', 'ball_1'], 'map': 'maps/tb3_sandbox.yaml',
               'map.unknown_solid': True, 'rerun.trail_seconds': 2.0}
    text = legend_text(sandbox, 0.5, 5.0)
    for mark in ('discs', 'its path over the last 2 s (trail)', "robot's heading",
                 'blue dots', 'faint blue lines', 'bumper hit', 'green rings',
                 "map's walls", 'unknown cells (solid)', 'push', 'ruler',
                 "robots' drives", 'the rest stays 0', 'every 5 s: empty until then'):
        assert mark in text, mark
    plain = legend_text({}, 0.5, None)
    for mark in ('trail', 'heading', 'blue dots', 'rings', 'unknown', 'drives', 'every'):
        assert mark not in plain, mark
    assert 'push' in plain and 'flat unless something pushes' in plain


def test_the_page_lays_the_legend_out_above_the_plots(robot_run):
    """The legend is a text document (the theme's text colour) in the plots' column."""
    from ball_world.recording.rerun_legend import LEGEND
    _, _, content = robot_run
    [text] = content[(f'/{LEGEND}', 'TextDocument:text')][None]
    assert text.startswith('**What the view draws**')


def test_a_bumper_tag_moves_off_a_name_it_would_cover():
    """"ball_5 hit 0.47 N s" lay over two names: a hit's tag goes below the arrow's middle,
    else a tag's height lower (or higher), where it covers no name tag."""
    from ball_world.recording.rerun_casing import cased_arrows
    from ball_world.recording.rerun_labels import boxes_overlap, tag_rect
    feed, _, _ = recorded_view_feed()
    collector = Truth()
    simulation = Simulation(ROBOTS, sinks=[collector])
    simulation.close()
    world, _ = collector.segments[0]
    feed.start_segment(world, SimpleNamespace(parameters={}, log_offset_ns=0))
    scale = feed._labels.scale
    text = 'ball_0 hit 0.47 N s'
    origin, vector = np.array([5.0, 5.0]), np.array([1.0, 0.0])
    middle, _ = tag_rect(origin + 0.5 * vector, text, scale)
    feed._name_rects = [middle]  # a name where the tag would go
    arrows = cased_arrows([origin], [vector], BUMPER_VIEW_COLOR, 2.5, 36.0, labels=[text])
    pills = feed._bumper_tags(arrows)[0]
    [centre] = pills.centers.as_arrow_array().to_pylist()
    [half] = pills.half_sizes.as_arrow_array().to_pylist()
    rect = (centre[0] - half[0], centre[1] - half[1], centre[0] + half[0], centre[1] + half[1])
    assert not boxes_overlap(np.asarray(rect), np.asarray(middle))
    assert centre[0] == pytest.approx(0.5 * (middle[0] + middle[2]), abs=1e-5)
    assert rect[3] < middle[1]  # a tag's height lower
    feed.close()


def test_no_name_covers_a_robots_heading(robot_run):
    """ball_0's name tag lay over part of its heading: every name's box keeps clear of the
    discs over each heading arrow (rerun_agents.heading_discs), step after step."""
    from ball_world.recording.rerun_agents import heading_discs
    from ball_world.recording.rerun_labels import box_hits_discs, LabelPlacer
    simulation, records, _ = robot_run
    placer = LabelPlacer((-1.0, -1.0, 11.0, 11.0))  # the default 10 m box and its ruler
    radii = simulation.world.radii
    names = [f'ball_{i}' for i in range(len(radii))]
    for record in records:
        clear = heading_discs(record, radii)
        kept, points = placer.place(record.positions, radii, names, record.agents.indices,
                                    clear)
        assert 0 in kept and 1 in kept  # the robots are still named
        for index, point in zip(kept, points):
            width, height = placer.size(names[index])
            x, y = point
            box = (x - 0.5 * width, y - placer.scale.gap - height, x + 0.5 * width,
                   y - placer.scale.gap)
            assert not box_hits_discs(box, *clear).any(), (record.step, names[index])
