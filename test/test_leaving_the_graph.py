"""A closed world leaves the graph at once, its DDS participant with it.

rclpy's Node.destroy_node destroys publishers, subscriptions, services, clients and timers,
but not waitables such as the SimulateSteps action server, whose handle holds the node's and,
through it, the context's. Until BallWorld.destroy_node destroyed the server itself, every
world a process made and closed kept its Fast DDS participant (9 threads, discovering every
later one) until a garbage collection found the cycle between server and node, and then it
was torn down at that moment, on whatever thread ran the collection. A CI test worker
crashed (SIGSEGV) in test_sim_interfaces on 2026-12-02 with such participants alive; the
crash was not reproduced here (24 runs of that file), and this is the fault found under it.
Counting the process's threads is how a participant is seen from here.
"""
import gc
import os

from ball_world_testing.harness import InProcessWorld
from rclpy.action import ActionClient
from simulation_interfaces.action import SimulateSteps

WORLD = {'random.count': 3, 'rate_hz': 100.0, 'markers.rate_hz': 0.0}


def thread_count():
    return len(os.listdir('/proc/self/task'))


def run_a_goal(world):
    """Send SimulateSteps and wait for its result, so the server holds a goal handle."""
    client = ActionClient(world.probe.node, SimulateSteps, '/ball_world/simulate_steps')
    try:
        world.spin_until(client.server_is_ready, 'the action server')
        goal = world.probe.result(client.send_goal_async(SimulateSteps.Goal(steps=3)))
        assert goal.accepted
        world.probe.result(goal.get_result_async())
    finally:
        client.destroy()


def test_a_closed_world_takes_its_participant_with_it_without_a_garbage_collection():
    first = InProcessWorld(**WORLD)  # the first world of a process starts threads that stay
    first.close()
    gc.collect()
    before = thread_count()
    gc.disable()
    try:
        world = InProcessWorld(**WORLD)
        run_a_goal(world)
        assert thread_count() > before, 'the world runs a participant of its own'
        world.close()
        assert thread_count() <= before, 'the participant outlived its closed world'
    finally:
        gc.enable()


def test_destroying_the_node_twice_is_harmless():
    world = InProcessWorld(**WORLD)
    run_a_goal(world)
    world.node.destroy_node()
    world.close()  # destroys the node again
    assert not list(world.node.waitables)
