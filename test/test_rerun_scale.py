"""The ruler of the Rerun arena (recording/rerun_scale.py): round ticks covering the scene,
labels in metres, room for them in the view."""
import numpy as np
import pytest

from ball_world.recording.rerun_scale import PAD_FRACTION, padded, ruler, tick_step


@pytest.mark.parametrize('span, step', [(10.6, 2.0), (10.0, 2.0), (1.0, 0.2), (47.0, 5.0),
                                        (0.003, 0.0005), (2000.0, 200.0), (14.0, 2.0)])
def test_tick_step_is_round_and_gives_five_to_twelve_intervals(span, step):
    assert tick_step(span) == pytest.approx(step, rel=1e-12)
    assert 5 <= span / tick_step(span) < 12.5


def test_default_arena_gets_ticks_every_2_m_under_and_left_of_the_scene():
    bounds = (-0.3, -0.3, 10.3, 10.3)  # the default arena with the view's margin
    ticks, places, texts = ruler(bounds)
    assert texts == ['0', '2', '4', '6', '8', '10 m', '0', '2', '4', '6', '8', '10']
    assert np.array_equal(ticks[:6, 0], [[x, -0.3] for x in (0, 2, 4, 6, 8, 10)])
    assert np.all(ticks[:6, 1, 1] < -0.3)  # below the scene, pointing down
    assert np.array_equal(ticks[6:, 0], [[-0.3, y] for y in (0, 2, 4, 6, 8, 10)])
    assert np.all(ticks[6:, 1, 0] < -0.3)  # left of it
    assert np.all(places[:6, 1] < ticks[:6, 1, 1]) and np.all(places[6:, 0] < ticks[6:, 1, 0])


def test_labels_keep_the_decimals_of_the_step_and_fit_in_the_padded_view():
    bounds = (0.0, 0.0, 0.25, 0.1)
    _, places, texts = ruler(bounds)
    assert texts[:6] == ['0.00', '0.05', '0.10', '0.15', '0.20', '0.25 m']
    xmin, ymin, xmax, ymax = padded(bounds)
    assert (xmax, ymax) == (0.25, 0.1) and xmin == ymin == -PAD_FRACTION * 0.25
    assert np.all(places >= [xmin, ymin])
