"""ball_world_cli on bad input, through the installed command: every argument of every
subcommand is checked before anything is sent, and bad input is one line on stderr and a
non-zero exit, never a traceback, never a hang (finding 6 of the hostile review)."""
import os

from ball_world_testing.harness import run_tool
import pytest

#: A world nobody runs: commands that get past their checks fail fast (exit 1), so a check
#: that is missing shows as exit 1 instead of 2, not as a hang.
NOBODY = ('--ns', '/cli_nobody', '--timeout', '1')
HUGE = 'x' * 100_000
UINT64_PAST = str(2 ** 64)


def one_line_error(args, code=2):
    result, out, err = run_tool('ball_world_cli', *args)
    assert result == code, (result, out, err)
    assert out == '' and 'Traceback' not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and len(lines[0]) < 600, err
    return lines[0]


@pytest.mark.parametrize('args, problem', [
    # integers: the field's own range (StepSimulation.steps, SimulateSteps.steps: uint64)
    (('step', UINT64_PAST), 'steps must be between 0 and 18446744073709551615'),
    (('simulate', UINT64_PAST), 'steps must be between 0 and 18446744073709551615'),
    (('step', '-1'), 'steps must be between 0'),
    (('step', '0'), 'steps must be at least 1'),
    (('step', '1e3'), "not an integer: '1e3'"),
    (('step', '9' * 5000), 'not an integer'),
    # numbers: finite ('1e400' reads as inf)
    (('push', 'ball_0', 'nan', '0'), "must be a finite number, got 'nan'"),
    (('push', 'ball_0', '1e400', '0'), "must be a finite number, got '1e400'"),
    (('push', 'ball_0', '0', 'inf'), "must be a finite number, got 'inf'"),
    (('spawn', 'red', 'nan', '1'), 'must be a finite number'),
    (('spawn', 'red', '1', '1', '--mass', 'inf'), 'must be a finite number'),
    (('set-state', 'ball_0', '1', '1', 'nan', '0'), 'must be a finite number'),
    (('drive', 'ball_0', 'nan', '0'), 'must be a finite number'),
    (('drive', 'ball_0', '1', '0', '--vy', '1e999'), 'must be a finite number'),
    # timeouts, durations and rates: finite, positive, bounded
    (('--timeout', 'inf', 'status'), "must be a finite number, got 'inf'"),
    (('status', '--timeout', 'inf'), "must be a finite number, got 'inf'"),
    (('status', '--timeout', 'nan'), 'must be a finite number'),
    (('status', '--timeout', '0'), 'must be more than 0 and at most 3600 s'),
    (('status', '--timeout', '-1'), 'must be more than 0'),
    (('status', '--timeout', '1e9'), 'at most 3600 s'),
    (('drive', 'ball_0', '1', '0', '--rate', '0'), 'must be more than 0 and at most 1000 Hz'),
    (('drive', 'ball_0', '1', '0', '--rate', 'inf'), 'must be a finite number'),
    (('drive', 'ball_0', '1', '0', '--rate', 'nan'), 'must be a finite number'),
    (('drive', 'ball_0', '1', '0', '--rate', '-5'), 'must be more than 0'),
    (('drive', 'ball_0', '1', '0', '--for', '0'), 'must be more than 0'),
    (('drive', 'ball_0', '1', '0', '--for', 'inf'), 'must be a finite number'),
    (('drive', 'ball_0', '1', '0', '-w', '0'), '0 is not a count from 1 to 1000'),
    (('drive', 'ball_0', '1', '0', '-w', '1001'), '1001 is not a count from 1 to 1000'),
    (('drive', 'ball_0', '1', '0', '--wait-matching-subscriptions', '1.5'),
     "not an integer: '1.5'"),
    (('hz', 'balls', '--for', '-2'), 'must be more than 0'),
    (('hz', 'balls', '--window', '1'), '--window must be between 2 and 1000000'),
    (('echo', 'balls', '--for', 'nan'), 'must be a finite number'),
    (('record', '-o', 'x', 'balls', '--for', '0'), 'must be more than 0'),
    # names: printable, bounded
    (('push', 'ball\x1b[31m', '1', '0'), 'may not hold control characters'),
    (('state', 'a\nb'), 'may not hold control characters'),
    (('delete', HUGE), 'longer than the 256 the world takes'),
    (('get-param', 'rate\x00hz'.replace('\x00', '\x01')), 'may not hold control characters'),
    (('drive', 'ball\t0', '1', '0'), 'may not hold control characters'),
    (('echo', 'bal\x07ls'), 'may not hold control characters'),
    (('hz', HUGE), 'longer than the 1024 taken'),
    (('record', '-o', 'x', 'balls', 'st ate'), 'Invalid topic name'),
    (('echo', 'bad topic!'), 'Invalid topic name'),
    (('drive', 'no such/../agent', '1', '0'), 'Invalid topic name'),
    (('--node', 'a b', 'status'), 'node name'),
    (('--ns', HUGE, 'status'), 'namespace'),
    (('--ns', 'bad ns!', 'status'), 'namespace'),
    # values and arguments argparse reads
    (('set-param', 'rate_hz', '[' * 5000), 'is not YAML rclpy can read'),
    (('fly',), 'invalid choice'),
    (('status', '--ros-args', '-r'), 'bad ROS arguments'),
    (('push', 'ball_0', '1'), 'the following arguments are required'),
])
def test_bad_arguments_are_one_line_and_exit_2(args, problem):
    line = one_line_error(args)
    assert line.startswith('ball_world_cli') and problem in line, line
    assert '\x1b' not in line and '\x07' not in line  # nothing typed reaches the terminal raw


@pytest.mark.parametrize('position', ['before', 'after'])
def test_global_options_go_before_or_after_the_subcommand(position):
    args = [*NOBODY, 'status'] if position == 'before' else ['status', *NOBODY]
    line = one_line_error(args, code=1)
    assert line == ('ball_world_cli: no world answers /cli_nobody/ball_world/'
                    'get_simulation_state within 1 s: is ball_world running in namespace '
                    "/cli_nobody (--ns), named 'ball_world' (--node)?")


@pytest.mark.parametrize('command', [('echo', 'no_such_topic'), ('hz', 'no_such_topic'),
                                     ('echo', '/no/such/topic', '--once'),
                                     ('record', '-o', '{tmp}/bag', 'no_such_topic')])
def test_a_topic_not_on_the_graph_is_said_after_the_deadline(command, tmp_path):
    args = [part.format(tmp=tmp_path) for part in command]
    line = one_line_error([*NOBODY, *args], code=1)
    assert 'on the graph within 1 s' in line and 'no_such_topic' in line \
        or '/no/such/topic' in line, line
    assert not (tmp_path / 'bag').exists()  # a recording that never began leaves nothing


def test_drive_to_no_agent_is_one_line(tmp_path):
    line = one_line_error([*NOBODY, 'drive', 'ball_7', '1', '0', '--for', '1'], code=1)
    assert line.startswith("ball_world_cli: no agent 'ball_7': nothing subscribes to "
                           '/cli_nobody/ball_7/cmd_vel within 1 s'), line


def test_record_refuses_an_existing_directory_and_a_symlink(tmp_path):
    existing = tmp_path / 'run'
    existing.mkdir()
    (existing / 'keep.txt').write_text('mine')
    line = one_line_error([*NOBODY, 'record', '-o', str(existing), 'balls'], code=1)
    assert line == f'ball_world_cli: record: {existing}: already exists; pass --overwrite to ' \
                   'replace it'
    target = tmp_path / 'elsewhere'
    target.mkdir()
    link = tmp_path / 'link'
    os.symlink(target, link)
    line = one_line_error([*NOBODY, 'record', '-o', str(link), 'balls', '--overwrite'], code=1)
    assert f'{link}: is a symbolic link' in line and 'never writes through one' in line
    assert (existing / 'keep.txt').read_text() == 'mine' and os.listdir(target) == []
