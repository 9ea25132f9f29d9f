"""A test's probe survives the peers the test kills (issue 33, item 8).

Test workers died of SIGSEGV in a probe's destroy_node, after a node or replay that wrote to
it was SIGKILLed (`test_map_node.py::test_replay_republishes_the_map_latched`). Reproduced
by a loop of probes hearing a publisher process that is killed at random (3 crashes in about
1,000 closes); each core's backtrace is Fast DDS deleting the probe's participant:
`SharedMemTransport::CloseInputChannel` -> `SharedMemChannelResource::release` ->
`interprocess_mutex::lock` on a port segment no longer mapped. A peer killed while it
writes into a shared-memory port leaves that port's mutex locked; Fast DDS gives the port
up, and the close later touches it. So a probe's participant never uses shared memory
(harness.PROBE_TRANSPORTS): what is checked here, in a process of its own, against a plain
node of the same process, which does.
"""
import os
from pathlib import Path
import subprocess
import sys

from ball_world_testing.harness import DEADLINE

SCRIPT = """
import subprocess, sys
import rclpy
from geometry_msgs.msg import PoseArray
from ball_world_testing.harness import Probe

PUBLISHER = '''
import time, rclpy
from geometry_msgs.msg import Pose, PoseArray
rclpy.init()
node = rclpy.create_node('talker')
publisher = node.create_publisher(PoseArray, '/balls', 10)
message = PoseArray(poses=[Pose() for _ in range(100)])
while True:
    publisher.publish(message)
    time.sleep(0.005)
'''


def shared_memory_mapped():
    with open('/proc/self/maps') as maps:
        return sorted({line.split()[-1] for line in maps if '/dev/shm/fastrtps_' in line})


talker = subprocess.Popen([sys.executable, '-c', PUBLISHER])
try:
    probe = Probe('probe')
    heard = probe.listen(PoseArray, '/balls')
    probe.spin_until(lambda: len(heard) >= 5, 'the talker')
    print('probe', len(shared_memory_mapped()), *shared_memory_mapped(), flush=True)
    talker.kill()  # while it writes to the probe, as a test's SIGKILL
    talker.wait()
    probe.close()
    talker = subprocess.Popen([sys.executable, '-c', PUBLISHER])
    rclpy.init()
    plain = rclpy.create_node('plain')
    got = []
    plain.create_subscription(PoseArray, '/balls', got.append, 10)
    while len(got) < 5:
        rclpy.spin_once(plain, timeout_sec=0.1)
    print('plain', len(shared_memory_mapped()), *shared_memory_mapped(), flush=True)
finally:
    talker.kill()
"""


def test_a_probe_uses_no_shared_memory_and_outlives_a_killed_peer():
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run(
        [sys.executable, '-c', SCRIPT], capture_output=True, text=True, timeout=2 * DEADLINE,
        env=dict(os.environ, PYTHONPATH=str(root)))
    assert result.returncode == 0, result.stderr[-2000:]
    mapped = {line.split()[0]: line.split()[2:] for line in result.stdout.splitlines()}
    assert mapped['probe'] == []  # no shared-memory segment: no lock a killed peer can hold
    assert mapped['plain']  # what a participant with Fast DDS's defaults maps
