"""Record the README's picture: the default world for 5 s with trails and one visible push.

Runs the Simulation without ROS, paced at the node's 60 Hz so the real-time factor plot
shows what a live run does, and logs it with the node's Rerun sink. The positions are the
same every time. At 4.75 s ball_5 gets a push, so its arrow is on screen at the last step
(impulses show for half a second). Usage: python scripts/hero_run.py OUT.rrd
"""
import sys
import time

from ball_world.recording.rerun_log import RerunSink
from ball_world.simulation import Simulation

STEPS = 300  # 5 s at 60 Hz
PUSH_AT = 285  # 4.75 s
PUSH = (5, 0.3, 0.2)  # ball, jx, jy in N s


def main(output):
    sink = RerunSink(output, trail_seconds=1.0, clock=time.monotonic)
    simulation = Simulation({}, sinks=[sink])
    period = simulation.dt_ns * 1e-9
    simulation.step()  # the first step loads what the sink needs: pace from after it
    start = time.monotonic()
    for step in range(2, STEPS + 1):
        time.sleep(max(0.0, start + (step - 1) * period - time.monotonic()))
        if step == PUSH_AT:
            ball, jx, jy = PUSH
            simulation.queue_impulse(f'ball_{ball}', jx, jy)
        simulation.step()
    simulation.close()


if __name__ == '__main__':
    main(sys.argv[1])
