"""Ground truth, bumper and drifting odometry through the node, as a Stage user meets them.

The world starts paused (so the probe hears everything), then ball_1 (1 kg, 3 m/s) hits
the agent ball_0 (2 kg, at rest, heading 0.5 rad) head on. The bumper says 2 m1 m2 /
(m1 + m2) x 3 m/s = 4 N s in ball_0/base_link; ground truth is the balls' pose bit for bit;
odom drifts (agent.odom.noise) and /tf carries exactly its pose; RViz gets an arrow.
"""
import math

from ball_world_testing.harness import finish, node_command
from geometry_msgs.msg import PoseArray, Vector3Stamped
from nav_msgs.msg import Odometry
import pytest
from std_srvs.srv import SetBool
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

WORLD = ('rate_hz:=50.0', 'markers.rate_hz:=0.0', 'random.count:=0', 'start_paused:=true',
         'arena:=[0, 0, 100, 100]', 'balls.x:=[50.0, 53.0]', 'balls.y:=[50.0, 50.0]',
         'balls.vx:=[0.0, -3.0]', 'balls.vy:=[0.0, 0.0]', 'balls.radius:=[0.5, 0.5]',
         'balls.mass:=[2.0, 1.0]', 'agents:=[ball_0]', 'agent.scan.samples:=0',
         'agent.odom.noise:=[0.1, 0.05, 0.1, 0.05]')


def stamp_ns(message):
    return message.header.stamp.sec * 10**9 + message.header.stamp.nanosec


def test_a_hit_rings_the_bumper_ground_truth_holds_and_tf_is_odom(probe, processes):
    from simulation_interfaces.srv import SetEntityState
    process = processes.start(node_command(*WORLD))
    bumper = probe.listen(Vector3Stamped, 'ball_0/bumper')
    truth = probe.listen(Odometry, 'ball_0/ground_truth')
    odom = probe.listen(Odometry, 'ball_0/odom')
    tf = probe.listen(TFMessage, '/tf')
    balls = probe.listen(PoseArray, 'balls')
    markers = probe.listen(MarkerArray, 'bumper_markers')
    probe.spin_until(lambda: all(probe.node.count_publishers(topic) for topic in (
        'ball_0/bumper', 'ball_0/ground_truth', 'bumper_markers')), 'the agent topics',
        process=process)
    turn = SetEntityState.Request(entity='ball_0')
    turn.state.pose.position.x, turn.state.pose.position.y = 50.0, 50.0
    turn.state.pose.orientation.z, turn.state.pose.orientation.w = math.sin(0.25), math.cos(0.25)
    assert probe.call(SetEntityState, '/ball_world/set_entity_state', turn).result.result == 1
    assert probe.call(SetBool, '/ball_world/pause', SetBool.Request(data=False)).success
    probe.spin_until(lambda: bumper and markers and len(odom) > 60, 'a hit and 60 steps',
                     process=process)
    [hit] = bumper
    assert hit.header.frame_id == 'ball_0/base_link'
    # 4 N s along -x in the world: in a frame turned by 0.5 rad, (-4 cos 0.5, 4 sin 0.5).
    assert (hit.vector.x, hit.vector.y, hit.vector.z) == pytest.approx(
        (-4.0 * math.cos(0.5), 4.0 * math.sin(0.5), 0.0), abs=1e-12)
    [arrow] = markers[0].markers
    assert arrow.header.frame_id == 'world' and arrow.ns == 'bumpers'
    assert arrow.points[1].x < arrow.points[0].x  # along the impulse, -x
    positions = {stamp_ns(m): (m.poses[0].position.x, m.poses[0].position.y) for m in balls}
    compared = 0
    for message in truth:
        assert (message.header.frame_id, message.child_frame_id) == ('world',
                                                                     'ball_0/base_link')
        seen = positions.get(stamp_ns(message))
        if seen is not None:
            assert (message.pose.pose.position.x, message.pose.pose.position.y) == seen
            compared += 1
    assert compared > 30
    poses = {stamp_ns(m): m.pose.pose for m in odom}
    drifted = 0
    for message in tf:
        [transform] = message.transforms
        pose = poses.get(stamp_ns(transform))
        if pose is None:
            continue
        assert (transform.transform.translation.x, transform.transform.translation.y,
                transform.transform.rotation.z, transform.transform.rotation.w) == (
            pose.position.x, pose.position.y, pose.orientation.z, pose.orientation.w)
        seen = positions.get(stamp_ns(transform))
        drifted += seen is not None and (pose.position.x, pose.position.y) != seen
    assert drifted > 10  # pushed by the hit, the odometry no longer says where it is
    assert odom[-1].pose.covariance[0] > 0.0
    process.send_signal(2)
    assert finish(process)[0] == 0
