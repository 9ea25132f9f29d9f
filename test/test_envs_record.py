"""Navigate-v0's episodes recorded (ball_world.envs.record): ball_world_resim re-simulates the
file bit for bit, and the file holds the robot's scans as the episode observed them (after
step 0, recorded before the robot is turned to its start heading)."""
import gymnasium
import numpy as np

import ball_world.envs  # noqa: F401 - registers Navigate-v0
from ball_world.envs.record import RecordEpisodes
from ball_world.msgs.agent_cdr import decode_laser_scan
from ball_world.recording.mcap_reader import Recording
from ball_world.tools import resim

BOX = {'arena': [-2.0, -1.5, 2.0, 1.5], 'random.count': 4, 'random.radius': [0.08, 0.15],
       'random.speed': 0.6, 'agent.max_speed': 0.4, 'agent.scan.range_max': 3.0}


def test_a_recorded_episode_resimulates_bit_for_bit(tmp_path, capsys):
    env = RecordEpisodes(gymnasium.make('ball_world/Navigate-v0', world=BOX, beams=20,
                                        max_episode_steps=15), tmp_path)
    seen = [env.reset(seed=6)[0]['scan']]
    env.action_space.seed(2)
    for _ in range(15):
        observed, _, terminated, truncated, _ = env.step(env.action_space.sample())
        seen.append(observed['scan'])
        if terminated or truncated:
            break
    env.reset(seed=7)
    env.close()
    assert [path.name for path in env.paths] == ['episode_0000.mcap', 'episode_0001.mcap']
    assert resim.main([str(env.paths[0])]) == 0
    assert 'bit-identically' in capsys.readouterr().out
    recorded = []
    for message in Recording(env.paths[0]).messages(['/ball_0/scan']):
        ranges = decode_laser_scan(message.data).ranges
        recorded.append(np.clip(np.nan_to_num(ranges, posinf=3.0, neginf=0.0), 0.0, 3.0)
                        .astype(np.float32).tobytes())
    # Step 0 is recorded when the run starts, before the edit that turns the robot to the
    # episode's heading; every scan after it is the one the episode observed.
    assert len(recorded) == len(seen)
    assert recorded[1:] == [scan.tobytes() for scan in seen[1:]]
