"""Start-up refusals that rcl or the ROS parameter layer used to garble (issue 19, Unfriendly).

Each must be one line on stderr and exit code 2: rcl's own `[ERROR] ... [rcl]` lines about a
params file it cannot parse are held back, and an integer that does not fit in 64 bits
(which the ROS layer turns into a double, losing its digits) is refused as such rather than
echoed as another number.
"""
from ball_world_testing.harness import run_tool
import pytest


def one_line_refusal(*ros_args):
    code, out, err = run_tool('ball_world', '--ros-args', *ros_args)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, (code, err)
    assert 'Traceback' not in err + out and '[rcl]' not in err
    return lines[0]


@pytest.mark.parametrize('content, words', [
    ('ball_world:\n  ros__parameters:\n    rate_hz: [1,\n', 'Error parsing a event near line'),
    ('ball_world: [unclosed\n', "Couldn't parse params file"),
])
def test_a_params_file_rcl_cannot_parse_is_one_line(tmp_path, content, words):
    params = tmp_path / 'broken.yaml'
    params.write_text(content)
    line = one_line_refusal('--params-file', str(params))
    assert line.startswith('ball_world: cannot start: ') and words in line, line
    assert '.c:' not in line  # no C source locations


def test_a_params_file_that_cannot_be_read_names_the_reason(tmp_path):
    line = one_line_refusal('--params-file', str(tmp_path / 'missing.yaml'))
    assert line == (f"ball_world: cannot start: params file '{tmp_path / 'missing.yaml'}': No "
                    'such file or directory')
    line = one_line_refusal('--params-file', str(tmp_path))
    assert line.endswith('Is a directory')


@pytest.mark.parametrize('value', ['99999999999999999999999', '9223372036854775808',
                                   '-99999999999999999999999'])
def test_an_integer_beyond_64_bits_is_refused_not_mangled(value):
    line = one_line_refusal('-p', f'random.seed:={value}')
    assert line.startswith("ball_world: parameter 'random.seed': does not fit in a 64-bit "
                           'integer'), line
    assert '99,999,999,999,999,991,611,392' not in line


def test_the_largest_seed_still_starts():
    code, _, err = run_tool('ball_world', '--ros-args', '-p', 'random.seed:=9223372036854775807',
                            '-p', 'max_steps:=1', '-p', 'rate_hz:=0.0', '-p', 'dt:=0.01')
    assert code == 0, err
