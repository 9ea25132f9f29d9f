"""A controller in the node: the same run as ball_world_sim's, bit for bit; a failure is one
line and exit 1; `controller` cannot be set while the node runs."""
from ball_world_testing.harness import InProcessWorld, read_mcap, run_tool
from rclpy.parameter import Parameter

from ball_world.tools import sim

WORLD = ('/**:\n  ros__parameters:\n    dt: 0.05\n    rate_hz: 0.0\n'
         '    arena: [0.0, 0.0, 10.0, 10.0]\n    random.count: 40\n'
         '    random.radius: [0.1, 0.2]\n    agents: [ball_0, ball_1, ball_2, ball_3]\n'
         '    agent.drive: diff\n    agent.topics: {topics}\n    agent.scan.samples: 24\n'
         '    agent.scan.range_max: 2.0\n    agent.odom.noise: [0.02, 0.02, 0.02, 0.02]\n'
         '    controller: ball_world.controllers.flocking:Flocking\n'
         '    controller.rate_hz: 7.0\n')
STEPS = 80


def recorded_steps(path):
    """(topic, log time, bytes) of every message of a run, but /stats' real-time factor
    (the node's is its wall clock's) and the bytes of /markers (rclpy leaves stray bytes in
    a marker's CDR padding: msgs.markers), whose log times are kept."""
    kept = []
    for topic, log_time, data in read_mcap(path):
        if topic == '/stats':
            data = data[:-8]  # the last double is the real-time factor
        elif topic == '/markers':
            data = b''
        kept.append((topic, log_time, data))
    return kept


def test_the_node_and_ball_world_sim_run_a_controller_to_the_same_bytes(tmp_path, capsys):
    params = tmp_path / 'world.yaml'
    params.write_text(WORLD.format(topics='each'))
    node_run, sim_run = tmp_path / 'node.mcap', tmp_path / 'sim.mcap'
    code, _, err = run_tool('ball_world', '--ros-args', '--params-file', str(params),
                            '-p', f'max_steps:={STEPS}', '-p', f'record.mcap:={node_run}')
    assert code == 0, err
    assert 'controller ball_world.controllers.flocking:Flocking at 7 Hz driving 4 agents' in err
    assert sim.main(['--params-file', str(params), '--steps', str(STEPS),
                     '--record', str(sim_run)]) == 0
    from_node, from_sim = recorded_steps(node_run), recorded_steps(sim_run)
    topics = {topic for topic, _, _ in from_node}
    assert {'/balls', '/state', '/ball_1/cmd_vel', '/ball_1/odom', '/ball_1/scan'} <= topics
    # balls, state, stats, /tf, each agent's odom and ground truth a step, scans, commands;
    # not the drives' impulses (on `impulse` and `<name>/drive` before they were left out)
    assert len(from_node) > 15 * STEPS
    assert not {'/impulse', '/ball_1/drive'} & topics
    assert from_node == from_sim  # every message, its log time and its bytes


def test_a_failing_controller_stops_the_node_with_one_line_and_status_1(tmp_path):
    bad = tmp_path / 'bad.py'
    bad.write_text('class Late:\n    def act(self, obs):\n        if obs.time > 0.5:\n'
                   '            raise RuntimeError("lost")\n'
                   '        return [[0.1, 0.0, 0.0]] * len(obs.names)\n')
    params = tmp_path / 'world.yaml'
    params.write_text(WORLD.format(topics='none'))
    recording = tmp_path / 'run.mcap'
    code, _, err = run_tool('ball_world', '--ros-args', '--params-file', str(params),
                            '-p', f'controller:={bad}:Late', '-p', 'max_steps:=1000',
                            '-p', f'record.mcap:={recording}')
    assert code == 1, err
    errors = [line for line in err.splitlines() if 'ERROR' in line]
    assert len(errors) == 1 and 'Traceback' not in err, err
    # 7 Hz of 50 ms steps: asked after steps 0, 3, 6, 9 and 12 (0.6 s), before step 13.
    assert (f'step 13: controller {bad}:Late: Late.act raised RuntimeError: lost (at bad.py:4)'
            ' (at t = 0.6 s); stopping') in errors[0]
    code, out, err = run_tool('ball_world_resim', str(recording))
    assert code == 0 and 'bit-identically' in out, out + err  # closed whole at step 12


def test_controller_is_read_only_while_the_node_runs():
    world = InProcessWorld(**{'random.count': 3, 'agents': ['ball_0'], 'rate_hz': 20.0,
                              'controller': 'ball_world.controllers.wander:Wander',
                              'agent.topics': 'none', 'markers.rate_hz': 0.0})
    try:
        node = world.node
        assert node.describe_parameters(['controller'])[0].read_only
        result = node.set_parameters([Parameter('controller', value='os:system')])[0]
        assert not result.successful
        assert node.get_parameter('controller').value == 'ball_world.controllers.wander:Wander'
        world.spin_until(lambda: node.simulation.agents.control.calls >= 2,
                         'the controller to be asked twice')
    finally:
        world.close()
