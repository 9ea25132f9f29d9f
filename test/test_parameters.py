"""One table of parameters (core.parameters) behind the node, the file, the reference page and
--help.

A default, range or description changed in the table and not in config/ball_world.yaml or
docs/reference.md fails here; so does a parameter added in one place and forgotten in another.
"""
from pathlib import Path

import pytest
import yaml

from ball_world.core import parameters as table
from ball_world.core.scenario import build_world

ROOT = Path(__file__).resolve().parents[1]


def test_config_file_holds_every_parameter_at_its_default():
    document = yaml.safe_load((ROOT / 'config' / 'ball_world.yaml').read_text())
    values = document['/**']['ros__parameters']
    assert list(values) == [parameter.name for parameter in table.PARAMETERS]
    for parameter in table.PARAMETERS:
        assert parameter.check(values[parameter.name]) == parameter.default, parameter.name


def test_reference_table_is_the_table():
    reference = (ROOT / 'docs' / 'reference.md').read_text()
    start = reference.index('\n', reference.index('<!-- parameters:')) + 1
    end = reference.index('<!-- /parameters -->')
    assert reference[start:end].rstrip('\n') == table.markdown_table()


def test_defaults_check_and_build_the_default_world():
    for parameter in table.PARAMETERS:
        assert parameter.check(parameter.default) == parameter.default, parameter.name
    assert len(build_world(table.DEFAULTS)) == table.DEFAULTS['random.count']


@pytest.mark.parametrize('name, value, words', [
    ('rate_hz', True, 'expected a number'),
    ('rate_hz', 2e6, 'between 0 and 1000000'),
    ('random.count', 1.5, 'whole number'),
    ('arena', [0.0, 0.0, 10.0], 'expected 0 or 4 numbers'),
    ('arena', [0.0, 0.0, -1.0, 10.0], 'xmin < xmax'),
    ('walls', [1.0, 2.0, 3.0], 'not a multiple of 4'),
    ('balls.x', [0.0, float('nan')], 'entry 1 is not finite'),
    ('balls.x', [True], 'entry 0 is not a number'),
    ('balls.radius', [1e-9], 'entry 0 is 1e-09; entries must be between 0.001 and 1000'),
    ('random.radius', [0.5, 0.1], 'min <= max'),
    ('frame_id', '', 'must name a frame'),
    ('frame_id', 'a\x00b', 'control characters'),
    ('frame_id', 'f' * 257, 'at most 256'),
    ('physics.mode', 'fast', 'expected one of seed, exact'),
])
def test_each_value_is_checked_with_a_reason_in_plain_numbers(name, value, words):
    with pytest.raises(table.ParameterError) as refused:
        table.check(name, value)
    assert str(refused.value).startswith(f"parameter '{name}': ")
    assert words in str(refused.value)
    assert 'np.float64' not in str(refused.value)


def test_integers_are_taken_for_doubles():
    assert table.check('rate_hz', 60) == 60.0
    assert table.check('arena', [0, 0, 10, 10]) == [0.0, 0.0, 10.0, 10.0]
