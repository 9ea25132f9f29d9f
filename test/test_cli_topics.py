"""ball_world_cli's ros2-like commands against real world processes: drive (ros2 topic pub -r
to an agent's cmd_vel, of the type the world takes), echo, hz, record (a rosbag2 MCAP bag
that rosbags, mcap and ball_world_info read) and status; each command a process of its own,
checked by what the world and a probe then see."""
import signal

from ball_world_testing.harness import (Children, executable, finish, read_mcap_ros2,
                                        read_rosbags, run_tool, start)
from geometry_msgs.msg import Twist, TwistStamped
import pytest
from std_msgs.msg import Float64MultiArray
import yaml

NAMESPACE = '/cli_topics'
STAMPED = '/cli_stamped'
#: Three balls at rest, ball_0 an agent, paused at step 0; dt = 1/50 s.
WORLD = ['random.count:=0', 'balls.x:=[2.0, 5.0, 8.0]', 'balls.y:=[5.0, 5.0, 5.0]',
         'balls.vx:=[0.0, 0.0, 0.0]', 'balls.vy:=[0.0, 0.0, 0.0]',
         'balls.radius:=[0.3, 0.3, 0.3]', 'balls.mass:=[4.0, 4.0, 2.0]', 'rate_hz:=50.0',
         'start_paused:=true', 'agents:=[ball_0]', 'agent.scan.samples:=0']
TIMEOUT = ('--timeout', '60')


def cli(*args, namespace=NAMESPACE):
    return run_tool('ball_world_cli', '--ns', namespace, *TIMEOUT, *args)


def ok(*args, namespace=NAMESPACE):
    code, out, err = cli(*args, namespace=namespace)
    assert code == 0 and 'Traceback' not in err, (code, out, err)
    return out.splitlines()


def started(*args, namespace=NAMESPACE):
    """The command as a running process (to be ended by a signal, as a user's Ctrl-C)."""
    return start([executable('ball_world_cli'), '--ns', namespace, *TIMEOUT, *args])


def interrupt_when(probe, process, predicate, what):
    """SIGINT to `process` once predicate() holds (spinning the probe meanwhile)."""
    probe.spin_until(predicate, what, process=process)
    process.send_signal(signal.SIGINT)
    return finish(process)


@pytest.fixture(scope='module')
def worlds():
    """Two worlds: one whose agent takes Twist, one whose agent takes TwistStamped."""
    with Children() as children:
        plain = children.start_node(*WORLD, ros_args=['-r', f'__ns:={NAMESPACE}'])
        stamped = children.start_node(*WORLD, 'agent.cmd_vel_stamped:=true',
                                      ros_args=['-r', f'__ns:={STAMPED}'])
        yield plain, stamped


@pytest.fixture
def world(worlds):
    yield worlds
    for process in worlds:
        assert process.poll() is None, process.communicate()


def test_status_of_a_paused_world_then_after_steps(world):
    lines = ok('status')
    assert lines == ['state: stopped (paused at step 0)', 'step: 0', 'simulation time: 0 s',
                     'real-time factor: 0 (not playing)', 'balls: 3', 'agents: 1 (ball_0)']
    assert ok('step', '3') == ['stepped 3']
    lines = ok('status')
    assert lines[:3] == ['state: paused', 'step: 3', 'simulation time: 0.06 s']
    assert ok('reset') == ['reset to step 0']


def test_state_prints_readable_numbers_and_masses(world):
    lines = ok('state')
    assert lines[0] == 't = 0 s, frame world, 3 balls'
    assert lines[1].split() == ['name', 'x', 'm', 'y', 'm', 'vx', 'm/s', 'vy', 'm/s',
                                'radius', 'm', 'mass', 'kg']
    assert [line.split() for line in lines[2:]] == [
        ['ball_0', '2', '5', '0', '0', '0.3', '4'], ['ball_1', '5', '5', '0', '0', '0.3', '4'],
        ['ball_2', '8', '5', '0', '0', '0.3', '2']]
    assert ok('state', 'ball_2')[2].split() == ['ball_2', '8', '5', '0', '0', '0.3', '2']


@pytest.mark.parametrize('namespace, message_type', [(NAMESPACE, Twist),
                                                     (STAMPED, TwistStamped)])
def test_drive_sends_the_type_the_agent_takes_and_a_zero_command_last(
        world, probe, namespace, message_type):
    heard = probe.listen(message_type, f'{namespace}/ball_0/cmd_vel')
    # -w 2: the world and this probe (discovery under load can show the probe late).
    # --for counts from the command's start: 3 s leave time for commands after joining.
    lines = ok('drive', 'ball_0', '0.5', '1.25', '--vy', '-0.25', '--rate', '20', '--for',
               '3', '-w', '2', namespace=namespace)
    assert len(lines) == 1 and lines[0].startswith(
        'drove ball_0: ') and f'{message_type.__name__} commands' in lines[0], lines
    sent = int(lines[0].split()[2])
    probe.spin_until(lambda: len(heard) == sent + 1, 'every command and the stop')
    twists = [m.twist if message_type is TwistStamped else m for m in heard]
    assert all((t.linear.x, t.linear.y, t.angular.z) == (0.5, -0.25, 1.25)
               for t in twists[:-1]) and sent >= 1
    last = twists[-1]
    assert (last.linear.x, last.linear.y, last.angular.z) == (0.0, 0.0, 0.0)


def test_drive_waiting_for_more_subscriptions_than_come_says_so_and_sends_nothing(
        world, probe):
    heard = probe.listen(Twist, f'{NAMESPACE}/ball_0/cmd_vel')
    # 8 s: the agent must be found first, and DDS discovery takes up to about 3 s here.
    code, out, err = run_tool('ball_world_cli', '--ns', NAMESPACE, '--timeout', '8', 'drive',
                              'ball_0', '1', '0', '-w', '3')
    assert (code, out) == (1, '') and err == (
        f'ball_world_cli: {NAMESPACE}/ball_0/cmd_vel: fewer than the 3 subscriptions asked '
        'for (-w) matched within 8 s\n'), err
    assert heard == []


def test_drive_ended_by_ctrl_c_still_sends_the_zero_command(world, probe):
    heard = probe.listen(Twist, f'{NAMESPACE}/ball_0/cmd_vel')
    process = started('drive', 'ball_0', '1', '0')
    code, out, err = interrupt_when(probe, process, lambda: len(heard) >= 3,
                                    'three commands')
    assert code == 0 and 'until Ctrl-C, then a zero command' in out, (code, out, err)
    probe.spin_until(lambda: heard[-1].linear.x == 0.0, 'the zero command')
    assert [m.linear.x for m in heard[:-1]] == [1.0] * (len(heard) - 1)


def test_echo_once_prints_the_message_as_yaml(world):
    ok('resume')
    try:
        lines = ok('echo', 'state', '--once')
    finally:
        ok('pause')
    assert lines[-1] == '---'
    message = yaml.safe_load('\n'.join(lines[:-1]))
    assert [d['label'] for d in message['layout']['dim']] == ['ball', 'x_y_vx_vy']
    assert len(message['data']) == 12 and message['data'][4:6] == [5.0, 5.0]  # ball_1 at rest
    # A latched topic is heard however late the echo comes, as with ros2 topic echo.
    assert ok('echo', 'entity_names', '--once') == ["data: 'ball_0", '', '  ball_1', '',
                                                    "  ball_2'", '---']
    ok('reset')


def test_echo_once_of_a_silent_topic_says_so(world):
    # 8 s: the topic must be found first, and DDS discovery takes up to about 3 s here.
    code, out, err = run_tool('ball_world_cli', '--ns', NAMESPACE, '--timeout', '8', 'echo',
                              'state', '--once')
    assert (code, out) == (1, '') and err == (
        f'ball_world_cli: no message on {NAMESPACE}/state within 8 s (1 publisher; a paused '
        'world publishes nothing: resume or step it)\n')


def test_hz_reports_each_second_and_echo_runs_until_ctrl_c(world, probe, tmp_path):
    ok('resume')
    try:
        code, out, err = cli('hz', 'stats', '--for', '3.5')
        assert code == 0, err
        rates = [line for line in out.splitlines() if line.startswith('average rate: ')]
        details = [line for line in out.splitlines() if line.startswith('\tmin: ')]
        assert len(rates) >= 1 and len(rates) == len(details), out
        assert all(float(line.split()[2]) > 0 for line in rates)
        # Interrupted once it has printed two messages (each is flushed as it comes, so its
        # output, a file here, shows them while it runs).
        log = tmp_path / 'echo.log'
        process = start([executable('ball_world_cli'), '--ns', NAMESPACE, *TIMEOUT, 'echo',
                         'stats'], log=log)
        probe.spin_until(lambda: log.read_text().count('---') >= 2, 'two messages echoed',
                         process=process)
        process.send_signal(signal.SIGINT)
        code, _, _ = finish(process)
        text = log.read_text()
        assert code == 0 and 'real_time_factor' in text and 'Traceback' not in text, text
    finally:
        ok('pause')
        ok('reset')


def test_record_makes_a_bag_every_reader_opens(world, probe, tmp_path):
    bag = tmp_path / 'run'
    ok('resume')
    try:
        process = started('record', '-o', str(bag), 'balls', 'stats', 'ball_0/odom',
                          'entity_names')
        stats = probe.listen(Float64MultiArray, f'{NAMESPACE}/stats')
        # Recording once it subscribed to its last topic (the world only publishes it).
        probe.spin_until(
            lambda: probe.node.count_subscribers(f'{NAMESPACE}/entity_names') >= 1,
            'the recorder subscribed', process=process)
        heard = len(stats)
        code, out, err = interrupt_when(probe, process, lambda: len(stats) >= heard + 30,
                                        'thirty steps')
    finally:
        ok('pause')
    assert code == 0 and out.splitlines()[-1].startswith('recorded '), (code, out, err)
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'run_0.mcap']
    metadata = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in metadata['topics_with_message_count']}
    messages = read_rosbags(bag)
    by_topic = {}
    for topic, _, message in messages:
        by_topic.setdefault(topic, []).append(message)
    assert {topic: len(items) for topic, items in by_topic.items()} == counts
    assert counts[f'{NAMESPACE}/balls'] >= 2 and counts[f'{NAMESPACE}/entity_names'] == 1
    assert by_topic[f'{NAMESPACE}/entity_names'][0].data == 'ball_0\nball_1\nball_2'
    assert len(by_topic[f'{NAMESPACE}/balls'][0].poses) == 3
    assert len(read_mcap_ros2(bag / 'run_0.mcap')) == len(messages) == metadata['message_count']
    code, out, err = run_tool('ball_world_info', str(bag))
    assert code == 0 and f'messages:    {len(messages):,}' in out, (out, err)
    assert f'{NAMESPACE}/ball_0/odom' in out and 'nav_msgs/msg/Odometry' in out
    # Again into the same directory: refused, then replaced with --overwrite.
    code, out, err = cli('record', '-o', str(bag), 'balls', '--for', '1')
    assert code == 1 and 'already exists; pass --overwrite' in err
    assert ok('record', '-o', str(bag), 'balls', '--overwrite', '--for', '1')[-1].startswith(
        'recorded 0 messages of 1 topics')  # paused: nothing published
    ok('reset')


def test_simulate_interrupted_cancels_its_goal_and_quit_answers(worlds, probe):
    """Last: it ends the stamped world. A goal interrupted by Ctrl-C is cancelled (the world
    does not step on for nobody), and quit then says the world quit."""
    _, stamped_world = worlds
    stats = probe.listen(Float64MultiArray, f'{STAMPED}/stats')
    process = started('simulate', '100000000', namespace=STAMPED)
    code, out, err = interrupt_when(probe, process, lambda: len(stats) >= 10, 'ten steps')
    assert code == 1 and 'interrupted: the goal was cancelled after' in err, (code, out, err)
    probe.drain(lambda: len(stats))  # what was sent before the cancel, queued here under load
    heard = len(stats)
    probe.spin_for(1.0)
    assert len(stats) - heard < 20  # the world stopped stepping (a few were on their way)
    assert ok('quit', namespace=STAMPED)[0] in (
        'the world is quitting', 'the world quit (it left the graph before its answer '
        'reached us)')
    assert finish(stamped_world)[0] == 0
