"""The example tracker in the TurtleBot3 sandbox with and without the map: how many of its
rings lie on a ball, and its figures (docs/scoring.md).

`ball_1` of worlds/sandbox.yaml drives a circle (0.15 m/s, 0.3 rad/s) for 90 simulated
seconds, headless (tools.score_bench); the tracker has the demo's options (radius 0.05-0.1 m,
gate 0.3 m) and runs on the same scans twice, once given the map (use_map) and once not.

    .venv/bin/python scripts/tracker_map.py
"""
from pathlib import Path
import sys

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from ball_world.scoring import figures  # noqa: E402
from ball_world.tools import score_bench, score_frames  # noqa: E402
from ball_world.tools.tracker import Options, ScanTracker  # noqa: E402

#: A ring within this of a ball's centre is on it (the sandbox's balls are 0.05-0.1 m).
ON_BALL = 0.2


def main():
    root = Path(__file__).resolve().parent.parent
    params = yaml.safe_load((root / 'worlds/sandbox.yaml').read_text())['/**'][
        'ros__parameters']
    params['map'] = str(root / params['map'])
    params.pop('agents')
    scene = score_bench._scene('sandbox', params, 'ball_1', (0.15, 0.0, 0.3), 90.0)
    scans = score_bench.simulated_scans(scene)
    occupancy = score_bench._scene_map(scene)
    for label, grid in (('without the map', None), ('with the map', occupancy)):
        frames = score_frames.frames_with_tracker(
            scans, ScanTracker(Options(0.05, 0.1, 0.3)), 'the example tracker', grid)
        found = figures.score_tracks(frames, 0.5).figures()
        rings = sum(len(f.track_xy) for f in frames)
        on_ball = sum(int(len(f.truth_xy) and np.min(np.hypot(*(f.truth_xy - xy).T)) < ON_BALL)
                      for f in frames for xy in f.track_xy)
        print(f'{label}: {rings} rings over {len(frames)} scans, {on_ball} '
              f'({on_ball / max(rings, 1):.0%}) within {ON_BALL:g} m of a ball; HOTA '
              f"{found['HOTA']:.3f} DetA {found['DetA']:.3f} MOTA {found['MOTA']:.3f} "
              f"IDF1 {found['IDF1']:.3f}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
