"""A flood of bad impulses from another process must not stop the world (issue 19, item 3).

Each rejection once called rclpy's throttled warning (0.7 ms even when it suppressed the
line) and the node drained the subscription until it was empty, so 2,000 bad impulses a
second stopped stepping (and every service) for the flood and long after it. Here a separate
process floods the node's `impulse` topic with impulses it must reject (unknown balls,
non-finite vectors, a z component), and a probe counts the node's steps from outside: during
the flood and after it the node keeps stepping at a healthy fraction of its rate, a service
call made during the flood is answered during it, it warns a few times rather than
once per impulse, and a valid impulse sent after the flood is applied (so the whole flood
was taken and judged, in order).
"""
import json
import math
import select
import signal
import sys
import time

from ball_world_testing.harness import finish, RECEIVE_QOS
from geometry_msgs.msg import Vector3Stamped
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool

from ball_world.ros.node import IMPULSE_QUEUE_DEPTH

RATE_HZ = 100.0
FLOOD_RATE = 2000  # bad impulses per second
FLOOD_SECONDS = 6.0
AFTER_SECONDS = 2.0
#: Share of the steps the rate asks for that must be seen. The bug was a stall (0 steps/s
#: for the flood and long after it); a node on a busy shared machine (CI: 2 cores for the
#: node, the flooder, this probe and more) still takes a fifth of its steps, since its own
#: work at 100 Hz is a small part of its time. Lower than what a quiet machine shows (0.9
#: and more), so that only a stall fails, not a machine's load.
HEALTHY = 0.2
MASS = 2.0
PUSH = 0.5  # N s, after the flood: the ball then moves at PUSH / MASS

FLOODER = """
import json, math, sys, time
import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, ReliabilityPolicy
from geometry_msgs.msg import Vector3Stamped
from ball_world.msgs.cdr import encode_vector3_stamped

rate, seconds, depth = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
context = rclpy.Context()
rclpy.init(context=context)
node = rclpy.create_node('flooder', context=context)
qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
publisher = node.create_publisher(Vector3Stamped, 'impulse', qos)
while publisher.get_subscription_count() == 0:
    time.sleep(0.05)
bad = [encode_vector3_stamped(0, 'no_such_ball', 0.1, 0.0, 0.0),
       encode_vector3_stamped(0, 'ball_0', math.nan, 0.0, 0.0),
       encode_vector3_stamped(0, 'ball_0', math.inf, -math.inf, 0.0),
       encode_vector3_stamped(0, 'ball_0', 0.1, 0.0, 1.0)]
began = time.monotonic()
print('flooding', flush=True)
sent = 0
while time.monotonic() < began + seconds:
    due = int((time.monotonic() - began) * rate)
    if sent >= due:
        time.sleep(0.0005)
        continue
    for _ in range(due - sent):
        publisher.publish(bad[sent % len(bad)])
        sent += 1
ended = time.monotonic()
acked = publisher.wait_for_all_acked(Duration(seconds=60.0))
print(json.dumps({'began': began, 'ended': ended, 'sent': sent, 'acked': acked}))
node.destroy_node()
rclpy.try_shutdown(context=context)
"""


def test_a_flood_of_rejected_impulses_leaves_the_world_stepping(processes, probe):
    node = processes.start_node(
        f'rate_hz:={RATE_HZ}', 'random.count:=0', 'markers.rate_hz:=0.0', 'balls.x:=[5.0]',
        'balls.y:=[5.0]', 'balls.vx:=[0.0]', 'balls.vy:=[0.0]', 'balls.radius:=[0.5]',
        f'balls.mass:=[{MASS}]')
    arrivals = probe.listen(Float64MultiArray, 'state',
                            keep=lambda msg: (time.monotonic(), msg.data[2]))
    probe.spin_until(lambda: len(arrivals) > 10, 'the first steps', process=node)

    # The node's queue depth passed in: importing the node there would cost the flooder
    # seconds of start-up (numba) on a busy machine.
    flooder = processes.start([sys.executable, '-c', FLOODER, str(FLOOD_RATE),
                               str(FLOOD_SECONDS), str(IMPULSE_QUEUE_DEPTH)])
    # Spinning all along, so that every state is counted when it arrives.
    probe.spin_until(lambda: select.select([flooder.stdout], [], [], 0)[0] or
                     flooder.poll() is not None, 'the flood to start', process=node)
    assert flooder.stdout.readline() == 'flooding\n', finish(flooder)
    # The node's services answer during the flood.
    answer = probe.call(SetBool, '/ball_world/pause', SetBool.Request(data=False))
    assert answer.success and answer.message.startswith('already running')
    answered = time.monotonic()
    probe.spin_until(lambda: flooder.poll() is not None, 'the flood to end', process=node)
    code, out, err = finish(flooder)
    assert code == 0, err
    flood = json.loads(out)
    assert answered < flood['ended'], 'the service answered only after the flood'
    assert flood['acked'] and flood['sent'] >= 0.9 * FLOOD_RATE * FLOOD_SECONDS

    pusher = probe.node.create_publisher(Vector3Stamped, 'impulse', RECEIVE_QOS)
    push = Vector3Stamped()
    push.header.frame_id = 'ball_0'
    push.vector.x = PUSH
    pusher.publish(push)
    after = time.monotonic()
    seen = len(arrivals)
    probe.spin_until(lambda: time.monotonic() > after + AFTER_SECONDS, 'the time after',
                     process=node)
    # The push waits behind every impulse of the flood: once it moved the ball, the node had
    # taken and rejected all of them.
    probe.spin_until(lambda: any(math.isclose(vx, PUSH / MASS, rel_tol=1e-12)
                                 for _, vx in arrivals[seen:]),
                     'the push sent after the flood', process=node)

    def steps(start, end):
        return sum(1 for t, _ in arrivals if start <= t < end)

    during = steps(flood['began'], flood['ended'])
    later = steps(after, after + AFTER_SECONDS)
    wanted = RATE_HZ * (flood['ended'] - flood['began'])
    print(f"{flood['sent']:,} bad impulses in {flood['ended'] - flood['began']:.2f} s: "
          f'{during} steps seen during the flood ({during / wanted:.2f} of the rate), '
          f'{later} in the {AFTER_SECONDS:g} s after it')
    assert during >= HEALTHY * wanted
    assert later >= HEALTHY * RATE_HZ * AFTER_SECONDS

    node.send_signal(signal.SIGINT)
    code, out, err = finish(node)
    assert code == 0, err
    warnings = [line for line in err.splitlines() if 'rejected impulse (' in line]
    # Throttled: one warning per REJECTION_WARNING_PERIOD (5 s) at most, each naming the
    # rejections it stood for.
    assert 1 <= len(warnings) <= FLOOD_SECONDS / 5.0 + 2, warnings
    assert 'more rejected since the last warning' in '\n'.join(warnings)
