"""Edits made after a segment's last step are recorded (issue 19, item 8).

Pause, step, push, spawn, delete, then stop (Ctrl-C, SetSimulationState QUITTING) or reset:
no step follows to carry the edits, so the Simulation hands them to the sinks as a closing
record (step_record.PendingEvents) at the log time of the step they would have preceded.
Every tool must read it: info counts it, resim makes the edits again without a step and
checks them, feed_sinks passes it on, and a changed closing edit is a difference.
"""
import signal

from ball_world_testing.harness import (finish, RECEIVE_QOS, rewrite_recording, run_tool,
                                        Truth)
from geometry_msgs.msg import Vector3Stamped
from mcap.records import Channel, Message
from rclpy.duration import Duration
from simulation_interfaces.msg import Result, SimulationState
from simulation_interfaces.srv import DeleteEntity, SetSimulationState, SpawnEntity
from std_srvs.srv import SetBool, Trigger
from test_edit_recordings import call, FIRST, pose_at, rewrite_edits, SECOND, spawn

from ball_world.recording.mcap_reader import feed_sinks, Recording
from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation
from ball_world.tools import info, repair, resim, to_rrd


def edit_after_the_last_step(simulation):
    """Three steps, then a push that the spawn applies, a spawn and a deletion."""
    for _ in range(3):
        simulation.step()
    simulation.queue_impulse('ball_1', 0.1, 0.2)
    spawn(simulation, 'late', 5.0, 5.0, 1.0, -0.5, radius=0.3, mass=1.5)
    simulation.delete('ball_0')


def test_edits_after_the_last_step_are_recorded_at_close(tmp_path):
    path = tmp_path / 'closed.mcap'
    truth = Truth()
    simulation = Simulation(FIRST, sinks=[McapSink(path), truth])
    edit_after_the_last_step(simulation)
    simulation.close()
    assert [record.step for record in truth.records] == [0, 1, 2, 3]  # no step was added

    (*steps, closing) = Recording(path).steps()
    assert [step.step for step in steps] == [0, 1, 2, 3] and all(s.complete for s in steps)
    assert closing.closing and closing.step == 4 and closing.stamp_ns == 4 * 50_000_000
    assert [(e.kind, e.name, e.impulses_before) for e in closing.edits] == [
        ('spawn', 'late', 1), ('delete', 'ball_0', 1)]
    assert [(i.frame_id, i.x, i.y, i.stamp_ns) for i in closing.impulses] == [
        ('ball_1', 0.1, 0.2, 4 * 50_000_000)]

    code, out, err = call(info, path)
    assert code == 0, err
    assert 'impulses:    1' in out
    assert 'edits:       2 (1 spawn, 1 delete)' in out
    assert '  segment 0 step 4: spawn late at (5, 5)' in out
    code, out, err = call(resim, path)
    assert code == 0, out + err
    assert ('segment 0: 4 steps compared (last step 3), 0 impulses; after the last step 1 '
            'impulses and 2 edits: identical') in out

    copy = tmp_path / 'copy.mcap'
    assert feed_sinks(path, [McapSink(copy)]) == 4
    assert call(info, copy)[1].count('edits:       2 (1 spawn, 1 delete)') == 1
    assert call(resim, copy)[0] == 0
    repaired = tmp_path / 'repaired.mcap'
    assert call(repair, path, '-o', repaired)[0] == 0
    assert call(info, repaired)[1].count('edits:       2 (1 spawn, 1 delete)') == 1
    rrd = tmp_path / 'closed.rrd'
    code, out, err = call(to_rrd, path, '-o', rrd)
    assert code == 0 and '4 steps' in err + out, err


def test_edits_after_the_last_step_of_a_segment_are_recorded_before_a_reset(tmp_path):
    path = tmp_path / 'reset.mcap'
    simulation = Simulation(FIRST, sinks=[McapSink(path)])
    edit_after_the_last_step(simulation)
    simulation.reset(SECOND)
    for _ in range(2):
        simulation.step()
    simulation.close()

    recording = Recording(path)
    # The closing record keeps the log time of step 4 of segment 0; segment 1 starts after it.
    assert recording.segments[1].log_offset_ns == 5 * 50_000_000
    closing = [step for step in recording.steps() if step.closing]
    assert [(s.segment, s.step, len(s.edits)) for s in closing] == [(0, 4, 2)]
    code, out, err = call(resim, path)
    assert code == 0, out + err
    assert 'after the last step 1 impulses and 2 edits: identical' in out
    assert 'segment 1: 3 steps compared (last step 2), 0 impulses: identical' in out


def test_a_closing_edit_the_world_refuses_is_a_difference(tmp_path):
    """No step follows a closing record, so its values cannot be checked against a later
    state; what is checked is that the world takes each edit (and each impulse) as the node
    did, under the same name."""
    path = tmp_path / 'closed.mcap'
    simulation = Simulation(FIRST, sinks=[McapSink(path)])
    edit_after_the_last_step(simulation)
    simulation.close()
    for position, change, first in (
            (1, {'name': 'ball_9'}, "segment 0 step 4 delete refused: recorded 'ball_9'"),
            (0, {'x': 2.0, 'y': 2.0}, "segment 0 step 4 spawn refused: recorded 'late'")):
        changed = rewrite_edits(path, tmp_path / f'changed_{position}.mcap', lambda at, fields: {
            **fields, **change} if at == position else fields)
        code, out, err = call(resim, changed)
        assert code == 1, out + err
        assert f'first difference: {first}' in out, out


def _node_edits_then_stops(probe, processes, tmp_path, how, *extra):
    """extra: more parameters (a split recording: path is then a bag directory)."""
    path = tmp_path / f'{how}.mcap'
    node = processes.start_node('random.count:=0', 'balls.x:=[2.0, 8.0]', 'balls.y:=[2.0, 2.0]',
                                'balls.vx:=[1.0, 0.0]', 'balls.vy:=[0.0, 0.0]',
                                'balls.radius:=[0.3, 0.3]', 'balls.mass:=[1.0, 1.0]',
                                'markers.rate_hz:=0.0', f'record.mcap:={path}', *extra)
    assert probe.call(SetBool, '/ball_world/pause', SetBool.Request(data=True)).success
    assert probe.call(Trigger, '/ball_world/step', Trigger.Request()).success
    pusher = probe.node.create_publisher(Vector3Stamped, 'impulse', RECEIVE_QOS)
    probe.spin_until(lambda: pusher.get_subscription_count() > 0, 'the impulse reader')
    push = Vector3Stamped()
    push.header.frame_id = 'ball_1'
    push.vector.x = 0.25
    pusher.publish(push)
    assert pusher.wait_for_all_acked(Duration(seconds=30.0))
    probe.spin_for(0.5)  # the node takes it into its queue; the spawn applies it
    spawned = probe.call(SpawnEntity, '/ball_world/spawn_entity', SpawnEntity.Request(
        name='late', uri='ball', resource_string='{radius: 0.3, mass: 2.0}',
        initial_pose=pose_at(5.0, 5.0)))
    assert spawned.result.result == Result.RESULT_OK, spawned.result.error_message
    deleted = probe.call(DeleteEntity, '/ball_world/delete_entity',
                         DeleteEntity.Request(entity='ball_0'))
    assert deleted.result.result == Result.RESULT_OK, deleted.result.error_message
    if how == 'sigint':
        node.send_signal(signal.SIGINT)
    else:
        quitting = probe.call(SetSimulationState, '/ball_world/set_simulation_state',
                              SetSimulationState.Request(state=SimulationState(
                                  state=SimulationState.STATE_QUITTING)))
        assert quitting.result.result == Result.RESULT_OK
    code, _, err = finish(node)
    assert code == 0, err
    return path


def test_the_node_records_edits_made_after_its_last_step(probe, processes, tmp_path):
    for how in ('sigint', 'quitting'):
        path = _node_edits_then_stops(probe, processes, tmp_path, how)
        code, out, err = run_tool('ball_world_info', str(path))
        assert code == 0, err
        assert 'impulses:    1' in out, (how, out)
        assert 'edits:       2 (1 spawn, 1 delete)' in out, (how, out)
        code, out, err = run_tool('ball_world_resim', str(path))
        assert code == 0, out + err
        assert 'after the last step 1 impulses and 2 edits: identical' in out, (how, out)


def test_a_closing_record_in_the_middle_of_a_segment_is_refused(tmp_path):
    """A crafted file: step 4's poses, state and stats taken out, so its edits look like a
    closing record, and step 5 follows. resim says so in one line and exits 2."""
    path = tmp_path / 'edited.mcap'
    simulation = Simulation(FIRST, sinks=[McapSink(path)])
    edit_after_the_last_step(simulation)
    simulation.step()
    simulation.step()
    simulation.close()
    channels = {}
    step_4 = 4 * 50_000_000

    def drop_step_4(item):
        if isinstance(item, Channel):
            channels[item.id] = item.topic
        if isinstance(item, Message) and item.log_time == step_4 and \
                channels[item.channel_id] in ('/balls', '/state', '/stats'):
            return None
        return item

    crafted = rewrite_recording(path, tmp_path / 'crafted.mcap', edit=drop_step_4)
    code, out, err = call(resim, crafted)
    assert code == 2, out + err
    assert err.strip().endswith('segment 0 has step 5 after the closing record of its last '
                                'step'), err
