"""/clock by default, and a reset's time jump between the old timeline's /tf and the new one's.

A use_sim_time client (benchmarks.clock_order.TfOrder: an rclpy node whose clock follows
/clock, with tf2_ros's Buffer's jump callback, clearing on a jump back of more than 1 s)
checks every /tf it handles against what a tf2 buffer would hold then. The world runs 12 s of
simulated time per wall second, so each reset jumps back by more than tf2's threshold.
"""
from ball_world_testing.harness import finish, node_command
from benchmarks.clock_order import TfOrder
from std_srvs.srv import Trigger

WORLD = ('rate_hz:=60.0', 'dt:=0.2', 'random.speed:=0.1', 'random.count:=5',
         'agents:=[ball_0]', 'agent.scan.samples:=0', 'markers.rate_hz:=0.0')
RESETS = 8


def test_every_reset_jumps_the_clock_between_the_two_timelines_transforms(processes):
    process = processes.start(node_command(*WORLD))
    client = TfOrder()
    try:
        reset = client.node.create_client(Trigger, '/ball_world/reset')
        # /clock by default: the client's clock follows the world's.
        client.wait_for(lambda: reset.service_is_ready() and client.transforms
                        and client.node.get_clock().now().nanoseconds > 0, process)
        for _ in range(RESETS):
            # Past tf2's 1 s, and the client keeping up with the world (a client starved of
            # the CPU for seconds loses best-effort /clock messages, which no order can help).
            client.wait_for(lambda: client.newest_ns and client.newest_ns > 2 * 10**9
                            and client.node.get_clock().now().nanoseconds
                            >= client.newest_ns - 10**9, process)
            clears = client.clears
            future = reset.call_async(Trigger.Request())
            while not future.done() or client.clears == clears:  # the jump back arrives
                client.executor.spin_once(timeout_sec=0.05)
            assert future.result().success, future.result().message
        client.spin(0.5)
        assert client.transforms > 100
        assert client.late == [] and client.early == []
    finally:
        client.close()
    process.send_signal(2)
    assert finish(process)[0] == 0
