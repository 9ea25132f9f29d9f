"""The world file an environment reads (ball_world.envs.world_file): a node's parameters file
under any of its node keys, its map found beside it from any working directory, the file's
agents made the robot's size, and every unreadable file refused in one line."""
import numpy as np
import pytest

from ball_world.envs.navigate import NavigateEnv
from ball_world.envs.world_file import load, WorldError

#: A 40 x 30 cell room at 0.1 m: solid border, free inside (PGM: 0 black = occupied).
ROOM = """image: room.pgm
resolution: 0.1
origin: [-2.0, -1.5, 0.0]
negate: 0
occupied_thresh: 0.65
free_thresh: 0.196
"""


def write_room(folder):
    pixels = np.full((30, 40), 254, dtype=np.uint8)
    pixels[[0, -1], :] = 0
    pixels[:, [0, -1]] = 0
    (folder / 'maps').mkdir()
    (folder / 'maps' / 'room.pgm').write_bytes(b'P5\n40 30\n255\n' + pixels.tobytes())
    (folder / 'maps' / 'room.yaml').write_text(ROOM)


def test_a_parameters_file_and_its_map_from_another_directory(tmp_path, monkeypatch):
    write_room(tmp_path)
    (tmp_path / 'worlds').mkdir()
    path = tmp_path / 'worlds' / 'room.yaml'
    path.write_text("""ball_world:
  ros__parameters:
    map: maps/room.yaml
    arena: []
    balls:
      x: [0.0, 1.0]
      y: [0.0, 0.5]
      vx: [0.0, 0.2]
      vy: [0.0, 0.0]
      radius: [0.12, 0.1]
      mass: [2.0, 0.5]
    agents: [ball_0]
    random.count: 3
    random.radius: [0.05, 0.08]
""")
    monkeypatch.chdir(tmp_path / 'worlds')  # maps/room.yaml is one folder up from here
    world = load(str(path))
    assert (world.robot_radius, world.robot_mass) == (0.12, 2.0)  # the file's first agent
    assert world.explicit == 1 and world.parameters['agents'] == []
    assert world.parameters['agent.drive'] == 'diff'
    env = NavigateEnv(world=str(path), beams=16)
    observed, _ = env.reset(seed=1)
    assert env.observation_space.contains(observed)
    balls = env.task.arenas.worlds[0]
    assert len(balls) == 1 + 1 + 3  # the robot, the fixed ball, the random ones
    assert balls.positions[1].tolist() == [1.0, 0.5]  # the fixed ball where the file says


@pytest.mark.parametrize('text, words', [
    ('ball_world: [unclosed', 'cannot read it'),
    ('other_node:\n  ros__parameters: {}\n', 'not a parameters file'),
    ("'/**':\n  parameters: {}\n", "'/**' holds no ros__parameters mapping"),
    ("'/**':\n  ros__parameters:\n    arena: [1, 2]\n", 'arena'),
])
def test_an_unusable_world_file_is_refused_in_one_line(tmp_path, text, words):
    path = tmp_path / 'world.yaml'
    path.write_text(text)
    with pytest.raises(WorldError) as caught:
        load(str(path))
    assert words in str(caught.value) and '\n' not in str(caught.value)
