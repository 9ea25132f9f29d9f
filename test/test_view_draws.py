"""What the view draws of robots, read back from the .rrd with Rerun's reader: each scan as a
fan of rays from its robot, the drive's impulses apart from pushes (and counted apart), the
clock line, and colours that read on both of the viewer's themes."""
import math

import numpy as np
import pytest
from test_rerun import read, shown_at

from ball_world.core.lidar import hit_points
from ball_world.recording.rerun_agents import AGENT_COLOR, AGENTS
from ball_world.recording.rerun_log import (CLOCK, CLOCK_COLOR, COLLISIONS,
                                            COLLISIONS_HEADROOM, ENERGY, ENERGY_HEADROOM,
                                            Headroom, IMPULSE_COLOR, IMPULSES, RerunSink)
from ball_world.recording.rerun_scans import MAX_RAYS, SCANS
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
    _, records, content = robot_run
    clock = content[(f'/{CLOCK}', 'Points2D:labels')]
    assert clock[0] == ['simulated time 0.0 s']
    assert len(clock) >= 10  # every 0.1 s of simulated time in a file
    for step, (text,) in clock.items():
        assert text.startswith(f'simulated time {records[step].stamp_ns * 1e-9:.1f} s')


@pytest.mark.parametrize('color', [AGENT_COLOR, IMPULSE_COLOR, TRACK_COLOR],
                         ids=['heading', 'push', 'track'])
def test_arrows_keep_4_to_1_on_both_themes(color):
    """The heading was yellow (1.3:1 on the light theme). Every arrow and ring keeps at
    least 4:1 against the view's background, light theme and dark."""
    for where, background in VIEW.items():
        assert contrast(color, background) >= 4.0, where


@pytest.mark.parametrize('color', [IMPULSE_COLOR, CLOCK_COLOR], ids=['push', 'clock'])
def test_label_text_keeps_the_most_one_colour_can_on_both_themes(color):
    """Rerun draws a label's text in its colour on a box of the theme's: light grey or dark
    grey. No one colour has 4:1 on both (the best, luminance 0.185, has 3.85:1 on each), so
    each text colour is within 0.2 of that best on both."""
    light, dark = LABEL_BOXES.values()
    best = math.sqrt((luminance(light) + 0.05) / (luminance(dark) + 0.05))
    assert best == pytest.approx(3.85, abs=0.01)
    for where, background in LABEL_BOXES.items():
        assert contrast(color, background) >= best - 0.2, where


def test_plots_keep_room_above_and_below_their_data(robot_run):
    """Rerun fits a plot's y axis to its data's exact extremes: the collisions' total ran
    along the top edge. Invisible series just beyond the data make the axis hold it whole."""
    _, records, content = robot_run
    energy = content[(f'/{ENERGY}', 'Scalars:scalars')]
    collisions = content[(f'/{COLLISIONS}', 'Scalars:scalars')]
    energy_room = content[(f'/{ENERGY_HEADROOM}', 'Scalars:scalars')]
    collisions_room = content[(f'/{COLLISIONS_HEADROOM}', 'Scalars:scalars')]
    assert sorted(energy_room) == sorted(collisions_room) == sorted(energy)
    assert max(abs(v) for (v,) in energy.values()) > 1.0  # the drives changed the energy
    for step in energy:
        seen = [v for k, (v,) in energy.items() if k <= step]
        above, below = energy_room[step]
        room = max(0.08 * (max(seen) - min(seen)), 0.5)
        assert above == pytest.approx(max(seen) + room) and below == pytest.approx(
            min(seen) - room)
        most = max(max(row) for k, row in collisions.items() if k <= step)
        assert collisions_room[step] == [pytest.approx(most * 1.08 + 1.0)]
    # Drawn in no colour, at no width.
    assert content[(f'/{ENERGY_HEADROOM}', 'SeriesLines:colors')][None] == [0, 0]
    assert content[(f'/{COLLISIONS_HEADROOM}', 'SeriesLines:widths')][None] == [0.0]


def test_a_views_headroom_follows_the_last_seconds_it_shows():
    room = Headroom(window=30.0)
    assert room.add(0, 10.0, 0.0) == (10.5, 9.5, 1.0)
    assert room.add(10 * 10**9, 20.0, 5.0) == (20.8, 9.2, 6.4)
    # 40 s later the first rows are out of the window.
    assert room.add(40 * 10**9, 0.0, 5.0) == (21.6, -1.6, 6.4)
    assert room.add(45 * 10**9, 0.0, 5.0) == (0.5, -0.5, 6.4)
