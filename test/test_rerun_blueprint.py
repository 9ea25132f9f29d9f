"""The blueprint a recording opens with, read back from the .rrd as the viewer gets it: the
real-time factor on an honest scale, and no legend over the curves."""
from ball_world_testing.harness import open_rrd
import pytest

from ball_world.recording.rerun_log import RerunSink
from ball_world.simulation import Simulation


def blueprint_values(path, component):
    """Every value of `component` (e.g. 'ScalarAxis:range') in the file's blueprint."""
    reader = open_rrd(path)
    found = []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if component in batch.schema.names:
                found += batch.column(component).to_pylist()
    return found


def recorded(tmp_path, **parameters):
    path = tmp_path / 'run.rrd'
    simulation = Simulation({'random.count': 3, **parameters}, sinks=[RerunSink(path)])
    simulation.step()
    simulation.close()
    return path


@pytest.mark.parametrize('parameters, top', [
    ({}, 1.25),  # 60 Hz, dt 1/60 s: aims at 1
    ({'rate_hz': 50.0, 'dt': 0.01}, 0.625),  # half speed: aims at 0.5
])
def test_real_time_factor_axis_runs_from_0_to_a_quarter_above_its_aim(tmp_path, parameters, top):
    assert blueprint_values(recorded(tmp_path, **parameters), 'ScalarAxis:range') == [
        [[0.0, top]]]


def test_a_run_as_fast_as_it_can_gets_an_automatic_scale(tmp_path):
    assert blueprint_values(recorded(tmp_path, rate_hz=0.0, dt=0.01), 'ScalarAxis:range') == []


def test_no_plot_legend_lies_on_the_data_the_titles_name_the_colours(tmp_path):
    """The energy plot's three legend rows covered a third of its curves: every plot's
    legend is hidden, and each title names its series by colour."""
    path = recorded(tmp_path, agents=['ball_0'])
    assert blueprint_values(path, 'PlotLegend:visible') == [[False]] * 4
    names = [name for [name] in blueprint_values(path, 'ViewBlueprint:display_name')]
    assert 'energy change [%]: orange all, blue drives, grey rest' in names
    assert 'collisions since step 0: blue ball-ball, brown ball-wall' in names
    assert 'legend' in names
