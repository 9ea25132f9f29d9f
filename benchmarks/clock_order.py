"""python -m benchmarks.clock_order: does a reset's /clock reach a use_sim_time client before
its first /tf? Counted over many resets, as a tf2 buffer would see them.

A use_sim_time client (a node whose clock follows /clock) keeps transforms in a tf2 buffer
that clears itself when its clock jumps back by more than a second (tf2_ros's Buffer: a jump
callback with min_backward -1 s on the node's clock) and drops a transform older than its
cache (10 s) behind the newest one (TF_OLD_DATA). After a reset the world's time jumps back
to 0: if a /tf of the new timeline is handled before that jump, it lands in the buffer of
the old timeline (dropped as TF_OLD_DATA, or wiped by the clear a moment later), and lookups
fail until the next /tf.

TfOrder is such a client without tf2's C++ core: the same jump callback on an rclpy node's
clock clears what it holds, and each /tf is checked against what the buffer holds then. A
late /tf is one of a new timeline (an earlier stamp than the newest held) handled before the
clear. The run resets the world `--resets` times, a reset every `--every` s of wall time,
with `--hogs` busy processes beside it, and reports the late ones.
"""
import argparse
import os
import subprocess
import sys
import time

import rclpy
from rclpy.clock import JumpThreshold
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

#: tf2's defaults: a buffer keeps 10 s, and clears on a jump back of more than 1 s.
CACHE_SECONDS = 10.0
CLEAR_JUMP = Duration(seconds=-1)
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


class TfOrder:
    """A use_sim_time node that checks each /tf against a buffer tf2 would have held then."""

    def __init__(self, name='tf_order', domain_id=None):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        # use_sim_time first: the clock's subscription is the node's first, as in any
        # node started with -p use_sim_time:=true.
        self.node = rclpy.create_node(name, context=self.context, parameter_overrides=[
            Parameter('use_sim_time', value=True)])
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.newest_ns = None  # newest stamp the buffer holds (None: empty)
        self.clears = 0
        self.transforms = 0
        self.late = []  # (stamp_ns, newest_ns, clock_ns) of /tf handled before the clear
        # Those of a timeline that went back by less than tf2's 1 s: tf2 clears nothing then,
        # whatever the order (a reset within the first second of simulated time).
        self.within_threshold = 0
        self.early = []  # (stamp_ns, clock_ns): /tf of the old timeline after the jump
        self.old_data = 0  # of those, older than the cache: what tf2 warns TF_OLD_DATA for
        self._jump = self.node.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=CLEAR_JUMP, on_clock_change=True),
            post_callback=self._cleared)
        self.node.create_subscription(TFMessage, '/tf', self._on_tf, TF_QOS)

    def _cleared(self, jump):
        self.newest_ns = None
        self.clears += 1

    def _on_tf(self, message):
        clock_ns = self.node.get_clock().now().nanoseconds
        for transform in message.transforms:
            stamp = transform.header.stamp
            stamp_ns = stamp.sec * 10**9 + stamp.nanosec
            self.transforms += 1
            newest = self.newest_ns
            if stamp_ns > clock_ns - CLEAR_JUMP.nanoseconds:
                self.early.append((stamp_ns, clock_ns))
            if newest is not None and stamp_ns < newest:
                if newest - stamp_ns <= -CLEAR_JUMP.nanoseconds:
                    self.within_threshold += 1
                    continue
                self.late.append((stamp_ns, newest, clock_ns))
                if stamp_ns < newest - CACHE_SECONDS * 1e9:
                    self.old_data += 1
                continue
            self.newest_ns = stamp_ns

    def wait_for(self, predicate, process, timeout=120.0):
        """Spin until predicate() holds; AssertionError if `process` ends or time runs out."""
        end = time.monotonic() + timeout
        while not predicate():
            assert process.poll() is None, f'the world exited with {process.returncode}'
            assert time.monotonic() < end, f'nothing within {timeout:g} s'
            self.executor.spin_once(timeout_sec=0.05)

    def spin(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def world_command(node):
    """The node under test: one agent, 12 s of simulated time per wall second."""
    values = ('rate_hz:=60.0', 'dt:=0.2', 'random.speed:=0.1', 'random.count:=5',
              'agents:=[ball_0]', 'agent.scan.samples:=0', 'markers.rate_hz:=0.0')
    return [node, '--ros-args'] + [word for value in values for word in ('-p', value)]


def hog():
    """A busy process: load beside the node and the client."""
    return subprocess.Popen([sys.executable, '-c', 'while True: pass'])


def run(resets, every, hogs, node):
    """(resets done, TfOrder) of one run."""
    world = subprocess.Popen(world_command(node), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    busy = [hog() for _ in range(hogs)]
    client = TfOrder()
    done = 0
    try:
        reset = client.node.create_client(Trigger, '/ball_world/reset')
        deadline = time.monotonic() + 60.0
        while not reset.service_is_ready() or client.transforms == 0:
            if time.monotonic() > deadline:
                raise RuntimeError('the world did not come up within 60 s')
            client.spin(0.1)
        client.spin(every)
        for _ in range(resets):
            future = reset.call_async(Trigger.Request())
            end = time.monotonic() + 30.0
            while not future.done() and time.monotonic() < end:
                client.executor.spin_once(timeout_sec=0.01)
            done += bool(future.done() and future.result().success)
            client.spin(every)
    finally:
        for process in busy:
            process.kill()
            process.wait()
        world.send_signal(2)
        try:
            world.wait(30)
        except subprocess.TimeoutExpired:
            world.kill()
            world.wait()
        client.close()
    return done, client


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m benchmarks.clock_order', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--resets', type=int, default=100)
    parser.add_argument('--every', type=float, default=0.5, help='wall s between resets')
    parser.add_argument('--hogs', type=int, default=2, help='busy processes beside the run')
    parser.add_argument('--node', default=os.path.join(os.path.dirname(sys.executable),
                                                       'ball_world'))
    args = parser.parse_args(argv)
    done, client = run(args.resets, args.every, args.hogs, args.node)
    print(f'resets {done}, clock jumps seen {client.clears}, transforms {client.transforms}, '
          f'late /tf {len(client.late)} (older than the cache: {client.old_data}), '
          f'/tf of the old timeline after the jump {len(client.early)}; /tf after a jump '
          f'back of less than 1 s, which tf2 does not clear: {client.within_threshold}')
    for stamp_ns, newest_ns, clock_ns in client.late[:5]:
        print(f'  /tf at {stamp_ns / 1e9:.3f} s handled with {newest_ns / 1e9:.3f} s held, '
              f'clock {clock_ns / 1e9:.3f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
