"""Record the run docs/scoring.png shows: 7 s of the default world, ball_0 driving a circle.

Runs the Simulation without ROS (as fast as it goes) with the node's MCAP sink; the same
run every time. It ends at 7 s, a scan where the example tracker misses a ball, keeps a
false positive and switches an id, so the picture shows each mark. Usage:
python scripts/score_run.py OUT.mcap
"""
import sys

from ball_world.recording.mcap_writer import McapSink
from ball_world.simulation import Simulation

SECONDS = 7.0


def main(output):
    simulation = Simulation({'agents': ['ball_0'], 'random.seed': 3}, sinks=[McapSink(output)])
    for _ in range(round(SECONDS / (simulation.dt_ns * 1e-9))):
        simulation.command('ball_0', 0.5, 0.0, 0.4)
        simulation.step()
    simulation.close()


if __name__ == '__main__':
    main(sys.argv[1])
