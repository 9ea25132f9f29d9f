"""The simulation_interfaces and tf2_msgs types are the released ones, byte for byte on the wire.

Whether the types were built from interfaces/<package> (wheels set-up) or come from the
distribution (sourced ROS 2 Jazzy), a client of the real package must be able to talk to
ball_world. ROS 2 checks that through the RIHS01 type hash, so every generated type's hash must
equal the one the release published (interfaces/<package>-jazzy-<version>.json).
"""
import importlib
import json
from pathlib import Path
import re

from ball_world_testing.harness import DEADLINE
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import TransformStamped
import pytest
from rclpy.action import ActionClient, ActionServer
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.type_support import check_for_type_support
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Result, SimulatorFeatures
from simulation_interfaces.srv import GetSimulatorFeatures
from tf2_msgs.action import LookupTransform
from tf2_msgs.msg import TF2Error, TFMessage
from tf2_msgs.srv import FrameGraph

ROOT = Path(__file__).resolve().parents[1]
RELEASES = {
    'simulation_interfaces': 'simulation_interfaces-jazzy-1.5.1.json',
    'tf2_msgs': 'tf2_msgs-jazzy-0.36.4.json',
}
# How many types rosidl generates from each release's definition files.
TYPE_COUNTS = {'simulation_interfaces': 116, 'tf2_msgs': 19}
MESSAGE_COUNTS = {'simulation_interfaces': 15, 'tf2_msgs': 2}


def release(package):
    """The released declarations and type hashes of a package, from interfaces/."""
    return json.loads((ROOT / 'interfaces' / RELEASES[package]).read_text())


def declarations(path):
    """The lines of a definition file that declare something: comments and blanks removed."""
    lines = (re.sub(r'\s+', ' ', line.split('#', 1)[0]).strip()
             for line in path.read_text().splitlines())
    return [line for line in lines if line]


def installed_share_dir(package):
    """share/<package> of the prefix the imported Python package belongs to."""
    module_file = importlib.import_module(package).__file__
    for prefix in Path(module_file).resolve().parents:
        share = prefix / 'share' / package
        if (share / 'package.xml').is_file():
            return share
    raise AssertionError(f'no share/{package} above {module_file}')


def generated_type_hashes(package):
    """Type name -> RIHS01 hash of every type of a package, as rosidl generated them.

    Each installed type description file lists the hash of its own type and of every type it
    refers to (a service's Request, Response and Event, an action's Goal, SendGoal...).
    """
    hashes = {}
    for description in sorted(installed_share_dir(package).glob('*/*.json')):
        for entry in json.loads(description.read_text())['type_hashes']:
            if entry['type_name'].startswith(f'{package}/'):
                hashes[entry['type_name']] = entry['hash_string']
    return hashes


@pytest.mark.parametrize('package', sorted(RELEASES))
def test_definition_files_declare_exactly_what_the_release_declares(package):
    folder = ROOT / 'interfaces' / package
    standard = release(package)
    files = sorted(str(p.relative_to(folder)) for p in folder.glob('*/*')
                   if p.suffix in ('.msg', '.srv', '.action'))
    assert files == sorted(standard['definitions'])
    for name, expected in standard['definitions'].items():
        assert declarations(folder / name) == expected, name


@pytest.mark.parametrize('package', sorted(RELEASES))
def test_every_generated_type_hash_equals_the_releases(package):
    published = release(package)['rihs01']
    assert len(published) == TYPE_COUNTS[package]
    generated = generated_type_hashes(package)
    assert sorted(set(published) - set(generated)) == [], 'types missing'
    assert sorted(set(generated) - set(published)) == [], 'types the standard does not have'
    differing = {name: (generated[name], published[name])
                 for name in published if generated[name] != published[name]}
    assert differing == {}


@pytest.mark.parametrize('package', sorted(RELEASES))
def test_compiled_message_typesupport_announces_the_released_hash(probe, package):
    node = probe.node
    messages = importlib.import_module(f'{package}.msg')
    message_types = [getattr(messages, name) for name in dir(messages)
                     if not name.startswith('_')]
    assert len(message_types) == MESSAGE_COUNTS[package]
    published = release(package)['rihs01']
    for message_type in message_types:
        node.create_publisher(message_type, f'hash_{message_type.__name__}', QoSProfile(depth=1))
    for message_type in message_types:
        (endpoint,) = node.get_publishers_info_by_topic(f'hash_{message_type.__name__}')
        name = f'{package}/msg/{message_type.__name__}'
        assert str(endpoint.topic_type_hash) == published[name], name


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
    assert client.wait_for_service(timeout_sec=DEADLINE)
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
    assert client.wait_for_server(timeout_sec=DEADLINE)
    goal = probe.result(client.send_goal_async(SimulateSteps.Goal(steps=3)))
    assert goal.accepted
    outcome = probe.result(goal.get_result_async())
    assert outcome.result.result.result == Result.RESULT_OK
    client.destroy()
    server.destroy()


def test_tf2_msgs_types_load_with_their_c_typesupport_and_keep_their_constants():
    for interface in (TFMessage, TF2Error, FrameGraph, LookupTransform):
        check_for_type_support(interface)
    codes = [TF2Error.NO_ERROR, TF2Error.LOOKUP_ERROR, TF2Error.CONNECTIVITY_ERROR,
             TF2Error.EXTRAPOLATION_ERROR, TF2Error.INVALID_ARGUMENT_ERROR,
             TF2Error.TIMEOUT_ERROR, TF2Error.TRANSFORM_ERROR]
    assert codes == list(range(7))


def test_tf_message_of_many_transforms_round_trips_through_the_c_serializer():
    transforms = []
    for index in range(3):
        transform = TransformStamped()
        transform.header.stamp = Time(sec=index, nanosec=7 * index)
        transform.header.frame_id = f'ball_{index}/odom'
        transform.child_frame_id = f'ball_{index}/base_link'
        transform.transform.translation.x = 0.5 * index
        transform.transform.rotation.z = 0.25 * index
        transforms.append(transform)
    decoded = deserialize_message(serialize_message(TFMessage(transforms=transforms)), TFMessage)
    assert decoded.transforms == transforms


def test_lookup_transform_action_round_trips_a_goal_in_process(probe):
    node = probe.node

    def lookup(goal_handle):
        goal_handle.succeed()
        result = LookupTransform.Result()
        result.transform.header.frame_id = goal_handle.request.target_frame
        result.transform.child_frame_id = goal_handle.request.source_frame
        result.error = TF2Error(error=TF2Error.TIMEOUT_ERROR, error_string='late')
        return result

    server = ActionServer(node, LookupTransform, 'lookup_transform', lookup)
    client = ActionClient(node, LookupTransform, 'lookup_transform')
    assert client.wait_for_server(timeout_sec=DEADLINE)
    goal = probe.result(client.send_goal_async(LookupTransform.Goal(
        target_frame='world', source_frame='ball_0/base_link', timeout=Duration(sec=1))))
    assert goal.accepted
    outcome = probe.result(goal.get_result_async()).result
    assert (outcome.transform.header.frame_id, outcome.transform.child_frame_id) == (
        'world', 'ball_0/base_link')
    assert (outcome.error.error, outcome.error.error_string) == (TF2Error.TIMEOUT_ERROR, 'late')
    client.destroy()
    server.destroy()
