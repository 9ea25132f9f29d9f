"""The simulation_interfaces types are the standard's, byte for byte on the wire.

Whether the types were built from interfaces/simulation_interfaces (wheels set-up) or come from
the distribution (sourced ROS 2 Jazzy), a client of the real package must be able to talk to
ball_world. ROS 2 checks that through the RIHS01 type hash, so every generated type's hash must
equal the one the standard published (interfaces/simulation_interfaces-jazzy-1.5.1.json).
"""
import json
from pathlib import Path
import re

from rclpy.action import ActionClient, ActionServer
from rclpy.qos import QoSProfile
import simulation_interfaces
from simulation_interfaces.action import SimulateSteps
import simulation_interfaces.msg
from simulation_interfaces.msg import Result, SimulatorFeatures
from simulation_interfaces.srv import GetSimulatorFeatures

ROOT = Path(__file__).resolve().parents[1]
STANDARD = json.loads(
    (ROOT / 'interfaces' / 'simulation_interfaces-jazzy-1.5.1.json').read_text())
PACKAGE = ROOT / 'interfaces' / 'simulation_interfaces'


def declarations(path):
    """The lines of a definition file that declare something: comments and blanks removed."""
    lines = (re.sub(r'\s+', ' ', line.split('#', 1)[0]).strip()
             for line in path.read_text().splitlines())
    return [line for line in lines if line]


def installed_share_dir():
    """share/simulation_interfaces of the prefix the imported Python package belongs to."""
    for prefix in Path(simulation_interfaces.__file__).resolve().parents:
        share = prefix / 'share' / 'simulation_interfaces'
        if (share / 'package.xml').is_file():
            return share
    raise AssertionError(f'no share/simulation_interfaces above {simulation_interfaces.__file__}')


def generated_type_hashes():
    """Type name -> RIHS01 hash of every simulation_interfaces type, as rosidl generated them.

    Each installed type description file lists the hash of its own type and of every type it
    refers to (a service's Request, Response and Event, an action's Goal, SendGoal...).
    """
    hashes = {}
    for description in sorted(installed_share_dir().glob('*/*.json')):
        for entry in json.loads(description.read_text())['type_hashes']:
            if entry['type_name'].startswith('simulation_interfaces/'):
                hashes[entry['type_name']] = entry['hash_string']
    return hashes


def test_definition_files_declare_exactly_what_the_standard_declares():
    files = sorted(str(p.relative_to(PACKAGE)) for p in PACKAGE.glob('*/*')
                   if p.suffix in ('.msg', '.srv', '.action'))
    assert files == sorted(STANDARD['definitions'])
    for name, expected in STANDARD['definitions'].items():
        assert declarations(PACKAGE / name) == expected, name


def test_every_generated_type_hash_equals_the_standards():
    published = STANDARD['rihs01']
    assert len(published) == 116
    generated = generated_type_hashes()
    assert sorted(set(published) - set(generated)) == [], 'types missing'
    assert sorted(set(generated) - set(published)) == [], 'types the standard does not have'
    differing = {name: (generated[name], published[name])
                 for name in published if generated[name] != published[name]}
    assert differing == {}


def test_compiled_message_typesupport_announces_the_standard_hash(probe):
    node = probe.node
    message_types = [getattr(simulation_interfaces.msg, name) for name in dir(
        simulation_interfaces.msg) if not name.startswith('_')]
    assert len(message_types) == 15
    for message_type in message_types:
        node.create_publisher(message_type, f'hash_{message_type.__name__}', QoSProfile(depth=1))
    for message_type in message_types:
        (endpoint,) = node.get_publishers_info_by_topic(f'hash_{message_type.__name__}')
        name = f'simulation_interfaces/msg/{message_type.__name__}'
        assert str(endpoint.topic_type_hash) == STANDARD['rihs01'][name], name


def test_service_round_trips_a_request_in_process(probe):
    node = probe.node

    def answer(request, response):
        response.features.features = [SimulatorFeatures.SPAWNING,
                                      SimulatorFeatures.STEP_SIMULATION_ACTION]
        response.features.spawn_formats = ['yaml']
        response.features.custom_info = 'ball_world'
        return response

    node.create_service(GetSimulatorFeatures, 'get_simulator_features', answer)
    client = node.create_client(GetSimulatorFeatures, 'get_simulator_features')
    assert client.wait_for_service(timeout_sec=10.0)
    features = probe.result(client.call_async(GetSimulatorFeatures.Request()))
    assert list(features.features.features) == [0, 33]
    assert features.features.spawn_formats == ['yaml']
    assert features.features.custom_info == 'ball_world'


def test_action_round_trips_a_goal_in_process(probe):
    node = probe.node

    def simulate(goal_handle):
        steps = goal_handle.request.steps
        for done in range(1, steps + 1):
            goal_handle.publish_feedback(
                SimulateSteps.Feedback(completed_steps=done, remaining_steps=steps - done))
        goal_handle.succeed()
        return SimulateSteps.Result(result=Result(result=Result.RESULT_OK))

    server = ActionServer(node, SimulateSteps, 'simulate_steps', simulate)
    client = ActionClient(node, SimulateSteps, 'simulate_steps')
    assert client.wait_for_server(timeout_sec=10.0)
    goal = probe.result(client.send_goal_async(SimulateSteps.Goal(steps=3)))
    assert goal.accepted
    outcome = probe.result(goal.get_result_async())
    assert outcome.result.result.result == Result.RESULT_OK
    client.destroy()
    server.destroy()
