"""What a live view's Rerun server keeps for pages opened late fits in its memory limit.

The server (ball_world_view, ball_world_demo) drops the oldest messages beyond
SERVER_MEMORY: first the timed ones, then the static ones (the layout stays). A world whose
static data (the arena's flip, the map, the balls' looks, the plots' styles, the ruler) does
not fit loses its oldest statics for every page opened late: the arena drawn upside down,
without its map. So the statics of every shipped world, and of the default one, must fit
with room for the latest frames; the limit is small so that a late page, which takes in a
few messages per frame in software rendering, has little to catch up.
"""
from pathlib import Path
import re

import pytest
import yaml

from ball_world.recording import rerun_log
from ball_world.simulation import Simulation
from ball_world.tools.view import SERVER_MEMORY

ROOT = Path(__file__).resolve().parents[1]
#: What the server must keep beside the statics: about a second of the demo's frames.
LATEST_FRAMES_BYTES = 64 * 1024


class FileOutlet:
    """An outlet that makes each call on the stream itself, saved to a file: encoded as it is
    for the wire (LZ4-compressed chunks)."""

    def __init__(self, stream, plan, path):
        self.stream = stream
        stream.save(path)
        if plan is not None:
            stream.send_blueprint(plan)

    def call(self, name, *args, **kwargs):
        getattr(self.stream, name)(*args, **kwargs)

    def flush(self):
        self.stream.flush()

    def close(self):
        self.stream.flush()


def limit_bytes(text):
    number, unit = re.fullmatch(r'(\d+)(KiB|MiB)', text).groups()
    return int(number) * {'KiB': 1024, 'MiB': 1024 ** 2}[unit]


def world_parameters(name):
    if name == 'default':
        return {'agents': ['ball_0']}
    document = yaml.safe_load((ROOT / 'worlds' / f'{name}.yaml').read_text())
    parameters = dict(document['/**']['ros__parameters'])
    if parameters.get('map'):
        parameters['map'] = str(ROOT / parameters['map'])
    return parameters


@pytest.mark.parametrize('name', ['default'] + sorted(
    path.stem for path in (ROOT / 'worlds').glob('*.yaml')))
def test_a_views_statics_and_first_frame_fit_the_servers_memory(name, tmp_path):
    path = tmp_path / 'view.rrd'

    def open_outlet(stream, plan):
        return FileOutlet(stream, plan, path)

    feed = rerun_log._Feed(open_outlet, trail_seconds=1.0, frame_period=0.1,
                           frame_clock=lambda: 0.0)
    simulation = Simulation(world_parameters(name), sinks=[feed])
    simulation.step()
    feed.flush()
    simulation.close()
    sent = path.stat().st_size
    # The layout, the statics and the first frame, as encoded for the wire (LZ4 chunks).
    assert 20_000 < sent <= limit_bytes(SERVER_MEMORY) - LATEST_FRAMES_BYTES, sent
