"""A nav2 map's bytes to cells, checked against the map server's rules read independently.

The reference below is written from nav2_map_server's rules (map_io.cpp, Jazzy) one pixel at
a time in plain Python, never through core.occupancy_map: the quanta GraphicsMagick reads
(8-bit v -> 257 v, 16-bit as is, PNM maxval m -> v * 65535 / m rounded half up), the mean of
the channels (alpha too in trinary mode for images that have it) over 65535 as the shade, and
each mode's thresholds. Images are made here from known pixel values, so the reference never
decodes an image; the two real maps are PGMs whose header this test reads itself.
"""
from fractions import Fraction
import io
import math
from pathlib import Path

import numpy as np
from PIL import Image
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from ball_world.core import limits
from ball_world.core.occupancy_map import load_map, MapError, MapFiles, parse_map_yaml
from ball_world.map_files import load_map_file, read_map_files
from ball_world.msgs.map_cdr import decode_occupancy_grid, encode_occupancy_grid

#: The two real maps (navigation2's, as shared/maps has them), shipped in the package.
MAPS = Path(__file__).resolve().parents[1] / 'maps'
MAX = 65535


# The reference ----------------------------------------------------------------------------

def reference_cell(channels, alpha, mode, negate, occupied, free):
    """One cell from a pixel's quanta (channels: r, g, b; alpha None without alpha)."""
    averaged = list(channels) + ([alpha] if mode == 'trinary' and alpha is not None else [])
    shade = (sum(averaged) / len(averaged)) / MAX
    if mode == 'raw':
        scaled = shade * 255
        whole = int(scaled)
        percent = whole + 1 if scaled - whole >= 0.5 else whole  # std::round
        return percent if 0 <= percent <= 100 else -1
    occ = shade if negate else 1.0 - shade
    if mode == 'scale' and alpha is not None and alpha != MAX:
        return -1
    if occupied < occ:
        return 100
    if occ < free:
        return 0
    if mode == 'trinary':
        return -1
    return round((occ - free) / (occupied - free) * 100.0)  # rint: half to even


def reference_grid(pixels, alpha, mode, negate, occupied, free):
    """The grid of an image of quanta (rows top first), map rows bottom first."""
    height, width = pixels.shape[:2]
    grid = np.empty((height, width), dtype=np.int8)
    for row in range(height):
        for column in range(width):
            value = pixels[row, column]
            channels = [int(v) for v in value] if np.ndim(value) else [int(value)] * 3
            grid[height - 1 - row, column] = reference_cell(
                channels, None if alpha is None else int(alpha[row, column]), mode, negate,
                occupied, free)
    return grid


def map_yaml(image='map.pgm', mode='trinary', negate=0, occupied=0.65, free=0.196,
             origin='[-1.5, 2.25, 0.0]', resolution='0.05', extra=''):
    mode_line = f'mode: {mode}\n' if mode is not None else ''
    return (f'image: {image}\n{mode_line}resolution: {resolution}\norigin: {origin}\n'
            f'negate: {negate}\noccupied_thresh: {occupied}\nfree_thresh: {free}\n'
            f'{extra}').encode()


def pgm(values, maxval=255, ascii=False, comment=True):
    values = np.asarray(values)
    height, width = values.shape[:2]
    colour = values.ndim == 3
    magic = ('P3' if colour else 'P2') if ascii else ('P6' if colour else 'P5')
    head = f'{magic}\n' + ('# made by a test\n' if comment else '') + \
        f'{width} {height}\n{maxval}\n'
    if ascii:
        body = '\n'.join(' '.join(str(int(v)) for v in row.reshape(-1)) for row in values)
        return head.encode() + body.encode() + b'\n'
    dtype = '>u2' if maxval > 255 else np.uint8
    return head.encode() + values.astype(dtype).tobytes()


def png(array, mode, **info):
    stream = io.BytesIO()
    image = array if isinstance(array, Image.Image) else Image.fromarray(array)
    assert image.mode == mode
    image.save(stream, 'PNG', **info)
    return stream.getvalue()


def loaded(image_bytes, image_name='map.pgm', **yaml_values):
    return load_map(MapFiles('map.yaml', map_yaml(image=image_name, **yaml_values),
                             image_name, image_bytes))


#: Every 8-bit grey level once, so every shade meets every threshold.
GREYS = np.arange(256, dtype=np.uint8).reshape(16, 16)
MODES = [(mode, negate, occupied, free) for mode in ('trinary', 'scale', 'raw')
         for negate in (0, 1) for occupied, free in ((0.65, 0.196), (0.9, 0.1), (0.5, 0.5))
         if not (mode == 'scale' and occupied == free)]


# The two real maps ------------------------------------------------------------------------

def read_pgm_header(data):
    """(width, height, maxval, raster) of the real maps' P5 files, read here."""
    fields = []
    position = 2
    while len(fields) < 3:
        while data[position:position + 1].isspace():
            position += 1
        if data[position:position + 1] == b'#':
            position = data.index(b'\n', position) + 1
            continue
        end = position
        while data[end:end + 1].isdigit():
            end += 1
        fields.append(int(data[position:end]))
        position = end
    return (*fields, data[position + 1:])


@pytest.mark.parametrize('name', ['tb3_sandbox', 'depot'])
def test_real_maps_are_cell_for_cell_what_the_map_server_publishes(name):
    text = (MAPS / f'{name}.yaml').read_text()
    fields = dict(line.split(':', 1) for line in text.splitlines() if ':' in line)
    occupied, free = float(fields['occupied_thresh']), float(fields['free_thresh'])
    width, height, maxval, raster = read_pgm_header((MAPS / f'{name}.pgm').read_bytes())
    assert maxval == 255
    pixels = np.frombuffer(raster[:width * height], dtype=np.uint8).reshape(height, width)
    expected = reference_grid(pixels.astype(np.int64) * 257, None, 'trinary', 0, occupied,
                              free)
    got = load_map_file(str(MAPS / f'{name}.yaml'))
    assert got.data.dtype == np.int8 and got.data.shape == (height, width)
    assert np.array_equal(got.data, expected)
    origin = [float(v) for v in fields['origin'].strip(' []').split(',')]
    assert got.origin == (origin[0], origin[1])
    assert got.resolution == float(np.float32(float(fields['resolution'])))
    # Both kinds of cell are there, and the image's first row is the map's last.
    assert {0, 100} <= set(np.unique(got.data).tolist())
    assert np.array_equal(got.data[-1], expected[-1])


def test_the_map_message_is_the_one_rclpy_would_serialize():
    from nav_msgs.msg import OccupancyGrid
    occupancy = load_map_file(str(MAPS / 'tb3_sandbox.yaml'))
    message = OccupancyGrid()
    message.header.stamp.sec, message.header.stamp.nanosec = 3, 250_000_000
    message.header.frame_id = 'world'
    message.info.map_load_time = message.header.stamp
    message.info.resolution = float(np.float32(0.05))  # what a float32 field holds
    message.info.width, message.info.height = 384, 384
    message.info.origin.position.x = message.info.origin.position.y = -10.0
    message.info.origin.orientation.w = 1.0
    message.data = occupancy.data.reshape(-1).tolist()
    data = encode_occupancy_grid(3_250_000_000, 'world', occupancy)
    # Equal field for field (rmw leaves its padding bytes unset, so not byte for byte).
    assert deserialize_message(data, OccupancyGrid) == message
    assert len(data) == len(serialize_message(message))
    decoded = decode_occupancy_grid(data)
    assert np.array_equal(decoded.data, occupancy.data) and decoded.frame_id == 'world'


# Synthetic images, every mode -------------------------------------------------------------

@pytest.mark.parametrize('mode, negate, occupied, free', MODES)
def test_grey_pgm_in_every_mode(mode, negate, occupied, free):
    got = loaded(pgm(GREYS), mode=mode, negate=negate, occupied=occupied, free=free)
    expected = reference_grid(GREYS.astype(np.int64) * 257, None, mode, negate, occupied, free)
    assert np.array_equal(got.data, expected)


def test_mode_is_trinary_by_default_and_read_in_any_case():
    default = loaded(pgm(GREYS), mode=None)
    assert np.array_equal(default.data, loaded(pgm(GREYS), mode='trinary').data)
    assert np.array_equal(loaded(pgm(GREYS), mode='Scale').data,
                          loaded(pgm(GREYS), mode='scale').data)


@pytest.mark.parametrize('maxval', [1, 15, 1000, 65535])
@pytest.mark.parametrize('ascii', [False, True])
def test_pgm_of_any_maxval_binary_or_ascii(maxval, ascii):
    values = np.random.default_rng(maxval).integers(0, maxval + 1, (12, 17))
    values[0, :2] = 0, maxval
    quanta = [[int(Fraction(MAX * int(v), maxval) + Fraction(1, 2)) for v in row]
              for row in values]
    for mode in ('trinary', 'scale', 'raw'):
        got = loaded(pgm(values, maxval, ascii), mode=mode)
        assert np.array_equal(got.data, reference_grid(np.array(quanta), None, mode, 0, 0.65,
                                                       0.196))


def test_colour_ppm_averages_red_green_and_blue():
    values = np.random.default_rng(5).integers(0, 256, (9, 11, 3))
    for ascii in (False, True):
        got = loaded(pgm(values, ascii=ascii), mode='scale', free=0.1, occupied=0.9)
        assert np.array_equal(got.data, reference_grid(values * 257, None, 'scale', 0, 0.9, 0.1))


@pytest.mark.parametrize('mode, negate, occupied, free', MODES)
def test_png_grey_and_colour_without_alpha(mode, negate, occupied, free):
    rgb = np.random.default_rng(1).integers(0, 256, (10, 13, 3)).astype(np.uint8)
    for array, image_mode in ((GREYS, 'L'), (rgb, 'RGB')):
        got = loaded(png(array, image_mode), 'map.png', mode=mode, negate=negate,
                     occupied=occupied, free=free)
        assert np.array_equal(got.data, reference_grid(array.astype(np.int64) * 257, None,
                                                       mode, negate, occupied, free))


@pytest.mark.parametrize('mode', ['trinary', 'scale', 'raw'])
def test_png_alpha_is_averaged_in_trinary_and_unknown_in_scale(mode):
    rng = np.random.default_rng(2)
    rgba = rng.integers(0, 256, (12, 12, 4)).astype(np.uint8)
    rgba[::2, :, 3] = 255  # half the pixels opaque
    la = np.stack((GREYS, np.where(GREYS % 3 == 0, 255, GREYS)), axis=2)
    for array, image_mode in ((rgba, 'RGBA'), (la, 'LA')):
        channels = array[..., :-1] if image_mode == 'RGBA' else array[..., 0]
        got = loaded(png(array, image_mode), 'map.png', mode=mode)
        expected = reference_grid(channels.astype(np.int64) * 257,
                                  array[..., -1].astype(np.int64) * 257, mode, 0, 0.65, 0.196)
        assert np.array_equal(got.data, expected)
    if mode == 'scale':  # the rule made a difference
        assert (got.data == -1).sum() > (loaded(png(la[..., 0], 'L'), 'map.png',
                                                mode=mode).data == -1).sum()


def test_png_opaque_rgba_still_averages_its_alpha_in_trinary():
    """The map server's old behaviour: an alpha channel counts in trinary even when every
    pixel is opaque, so a grey of 100 is lighter there than in the same PNG without alpha."""
    grey = np.full((4, 4), 100, dtype=np.uint8)
    rgba = np.stack((grey, grey, grey, np.full_like(grey, 255)), axis=2)
    with_alpha = loaded(png(rgba, 'RGBA'), 'map.png', occupied=0.5, free=0.46)
    without = loaded(png(grey, 'L'), 'map.png', occupied=0.5, free=0.46)
    assert set(with_alpha.data.reshape(-1)) == {0} and set(without.data.reshape(-1)) == {100}


def test_palette_png_with_transparency_and_16_bit_grey_png():
    palette = Image.fromarray(GREYS, 'L').convert('P')
    transparent = int(np.asarray(palette)[3, 3])
    data = png(palette, 'P', transparency=transparent)
    colours = np.asarray(palette.convert('RGB')).astype(np.int64) * 257
    alpha = np.where(np.asarray(palette) == transparent, 0, MAX)
    for mode in ('trinary', 'scale'):
        got = loaded(data, 'map.png', mode=mode)
        assert np.array_equal(got.data, reference_grid(colours, alpha, mode, 0, 0.65, 0.196))
    wide = np.random.default_rng(4).integers(0, MAX + 1, (14, 9)).astype(np.uint16)
    wide[0, 0], wide[0, 1] = 0, MAX
    for mode in ('trinary', 'scale', 'raw'):
        got = loaded(png(wide, 'I;16'), 'map.png', mode=mode)
        assert np.array_equal(got.data, reference_grid(wide.astype(np.int64), None, mode, 0,
                                                       0.65, 0.196))


def test_solid_cells_are_occupied_and_unknown_unless_told_and_sit_where_map_says():
    got = loaded(pgm(GREYS), mode='trinary')
    solid = got.solid_cells()
    assert np.array_equal(solid.solid, (got.data == 100) | (got.data == -1))
    assert np.array_equal(got.solid_cells(unknown_solid=False).solid, got.data == 100)
    assert (solid.origin_x, solid.origin_y) == (-1.5, 2.25)
    assert solid.resolution == float(np.float32(0.05)) != 0.05  # /map carries a float32
    scale = loaded(pgm(GREYS), mode='scale', occupied=0.9, free=0.1)
    between = (scale.data > 0) & (scale.data < 100)
    assert between.any() and not scale.solid_cells().solid[between].any()


# The YAML ---------------------------------------------------------------------------------

@pytest.mark.parametrize('text, negate', [('0', False), ('1', True), ('-3', True),
                                          ('true', True), ('False', False), ('yes', True),
                                          ('off', False), ('0x0', False), ('010', True)])
def test_negate_is_read_as_yaml_cpp_reads_an_int_then_a_bool(text, negate):
    assert parse_map_yaml(map_yaml(negate=text)).negate is negate


def test_numbers_are_read_as_yaml_cpp_reads_doubles():
    values = parse_map_yaml(map_yaml(resolution='5e-2', origin='[1, -2.5e1, 0]',
                                     occupied='.7', free='1e-1'))
    assert (values.resolution, values.origin, values.occupied_thresh, values.free_thresh) == \
        (0.05, (1.0, -25.0, 0.0), 0.7, 0.1)


@pytest.mark.parametrize('text, words', [
    (b'image: [a\n', 'not valid YAML at line'),
    (b'- a\n- b\n', 'expected a YAML mapping'),
    (map_yaml(extra='').replace(b'negate: 0\n', b''), "'negate' is missing"),
    (map_yaml().replace(b'image: map.pgm\n', b''), "'image' is missing"),
    (map_yaml().replace(b'resolution: 0.05\n', b''), "'resolution' is missing"),
    (map_yaml().replace(b'free_thresh: 0.196\n', b''), "'free_thresh' is missing"),
    (map_yaml(image="''"), "'image' is empty"),
    (map_yaml(resolution='fine'), "'resolution' must be a number"),
    (map_yaml(resolution='0'), "'resolution' must be at least"),
    (map_yaml(resolution='.inf'), "'resolution' must be at least"),
    (map_yaml(origin='[0, 0]'), "'origin' must be [x, y, yaw], got 2 values"),
    (map_yaml(origin='[0, 0, 0.1]'), "'origin' yaw is 0.1 rad"),
    (map_yaml(origin='[.nan, 0, 0]'), "'origin' must be finite"),
    (map_yaml(occupied='1.5'), "'occupied_thresh' must be between 0 and 1, got 1.5"),
    (map_yaml(free='-0.1'), "'free_thresh' must be between 0 and 1"),
    (map_yaml(occupied='0.2', free='0.3'), "'free_thresh' (0.3) must be at most"),
    (map_yaml(mode='scale', occupied='0.3', free='0.3'), "'free_thresh' (0.3) must be below"),
    (map_yaml(mode='fancy'), "'mode' must be trinary, scale or raw, got 'fancy'"),
    (map_yaml(negate='maybe'), "'negate' must be 0, 1, true or false"),
    (b'\xff\xfe', 'not UTF-8'),
])
def test_bad_yaml_is_one_line_naming_the_key(text, words):
    with pytest.raises(MapError) as refused:
        parse_map_yaml(text, 'map.yaml')
    assert words in str(refused.value) and '\n' not in str(refused.value)


@pytest.mark.parametrize('data, words', [
    (pgm(GREYS)[:-10], 'truncated: the image needs 256 bytes of pixels, the file has 246'),
    (pgm(GREYS, ascii=True)[:-12], 'truncated: the image needs 256 pixel values'),
    (b'P5\n16 16\n', 'number 3'),
    (b'P5\n4097 4097\n255\n', 'cells; a map has at most 16,777,216'),
    (b'P5\n0 16\n255\n', 'empty'),
    (pgm(np.full((2, 2), 9)).replace(b'\n255\n', b'\n8\n'), 'above the maxval 8'),
    (b'GIF89a....', 'not a PGM (P2, P5), PPM (P3, P6) or PNG image'),
    (png(GREYS, 'L')[:40], 'the PNG cannot be decoded'),
    (png(GREYS, 'L')[:20], 'truncated: the PNG has no header'),
    (png(np.zeros((3, 3, 3), dtype=np.uint8), 'RGB')[:24] + bytes([16, 2])
     + png(np.zeros((3, 3, 3), dtype=np.uint8), 'RGB')[26:], 'a 16-bit PNG with colour'),
])
def test_bad_images_are_one_line(data, words):
    with pytest.raises(MapError) as refused:
        loaded(data)
    assert words in str(refused.value) and '\n' not in str(refused.value)


# Messages quote the input as written: a number read into a machine type (int64, double)
# can saturate, overflow to inf or round at six digits, and the message would then state a
# value the file does not hold.
BIG = '1' + '2' * 22  # 23 digits: numpy reads it as int64's largest value
TINY = '0.' + '0' * 60 + '1'  # a resolution of 1e-61, written long


@pytest.mark.parametrize('data, words', [
    (b'P2\n2 2\n255\n0 ' + BIG.encode() + b' 0 0\n', f'a pixel value {BIG} is above'),
    (b'P3\n1 1\n255\n0 0 ' + b'9' * 80 + b'\n', '999999999999999999999999... (80 characters)'),
    (b'P2\n2 2\n255\n0 0 256 0\n', 'a pixel value 256 is above the maxval 255'),
    (b'P2\n2 2\n00255\n0 0 00256 0\n', 'a pixel value 00256 is above the maxval 255'),
    (b'P5\n' + BIG.encode() + b' 2\n255\n', f'the PNM width is {BIG}: too large'),
    (b'P5\n2 ' + BIG.encode() + b'\n255\n', f'the PNM height is {BIG}: too large'),
    (b'P5\n2 2\n' + BIG.encode() + b'\n', f'the PNM maxval is {BIG}: too large'),
    (b'P5\n2 2\n' + b'7' * 5000 + b'\n', 'the PNM maxval is 777777777777777777777777... '
     '(5,000 characters)'),
    (b'P5\n2 2\n0065536\n', 'PNM maxval 0065536; it must be'),
    (b'P5\n000000000002 2\n255\n\0\0\0\0', None),  # leading zeros are no size
])
def test_pnm_messages_quote_the_numbers_as_written(data, words):
    if words is None:
        assert loaded(data).width == 2
        return
    with pytest.raises(MapError) as refused:
        loaded(data)
    assert words in str(refused.value) and '\n' not in str(refused.value)
    assert '9223372036854775807' not in str(refused.value)


@pytest.mark.parametrize('values, words', [
    ({'resolution': '1e400'}, "'resolution' must be at least 0.001 m per cell, got 1e400"),
    ({'resolution': '0.00099999999'}, 'got 0.00099999999'),
    ({'origin': '[1e999, 0, 0]'}, "'origin' must be finite, got [1e999, 0, 0]"),
    ({'origin': '[0, 0, 1e-7]'}, "'origin' yaw is 1e-7 rad"),
    ({'occupied': '1.0000001'}, "'occupied_thresh' must be between 0 and 1, got 1.0000001"),
    ({'free': '-1e-300'}, "'free_thresh' must be between 0 and 1, got -1e-300"),
    ({'free': '0.6500001', 'occupied': '0.65'},
     "'free_thresh' (0.6500001) must be at most 'occupied_thresh' (0.65)"),
    ({'resolution': TINY}, f'got {TINY[:24]}... (63 characters)'),
])
def test_yaml_messages_quote_the_numbers_as_written(values, words):
    with pytest.raises(MapError) as refused:
        parse_map_yaml(map_yaml(**values), 'map.yaml')
    assert words in str(refused.value) and '\n' not in str(refused.value)


def test_the_coordinate_limit_message_states_the_origin_exactly():
    origin = limits.COORDINATE_LIMIT - 0.4999999
    with pytest.raises(MapError) as refused:
        loaded(pgm(GREYS), origin=f'[{origin!r}, 0, 0]')
    assert f'spans ({origin!r}, 0.0)' in str(refused.value)


def test_a_map_reaching_past_the_coordinate_limit_is_refused():
    with pytest.raises(MapError, match='beyond the'):
        loaded(pgm(GREYS), origin=f'[{limits.COORDINATE_LIMIT - 0.5}, 0, 0]')


# Files ------------------------------------------------------------------------------------

def write_map(folder, image=None, **yaml_values):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'map.pgm').write_bytes(pgm(GREYS) if image is None else image)
    (folder / 'map.yaml').write_bytes(map_yaml(**yaml_values))
    return folder / 'map.yaml'


def test_files_are_read_relative_to_the_yaml_and_kept_as_bytes(tmp_path, monkeypatch):
    path = write_map(tmp_path / 'maps')
    monkeypatch.chdir(tmp_path)
    files = read_map_files('maps/map.yaml')
    assert files == MapFiles('map.yaml', (tmp_path / 'maps' / 'map.yaml').read_bytes(),
                             'map.pgm', (tmp_path / 'maps' / 'map.pgm').read_bytes())
    absolute = write_map(tmp_path / 'other', image=b'')
    absolute.write_bytes(map_yaml(image=str(path.parent / 'map.pgm')))
    assert read_map_files(str(absolute)).image_bytes == files.image_bytes


@pytest.mark.parametrize('setup, words', [
    (lambda d: write_map(d).parent.joinpath('map.pgm').unlink(),
     'the map image {d}/map.pgm (named by {d}/map.yaml) does not exist'),
    (lambda d: (write_map(d), (d / 'map.pgm').unlink(), (d / 'map.pgm').mkdir()),
     'the map image {d}/map.pgm (named by {d}/map.yaml) is a directory, not a regular file'),
    (lambda d: write_map(d, image=pgm(GREYS)[:40]), '{d}/map.pgm: truncated'),
    (lambda d: (d.mkdir(), (d / 'map.yaml').mkdir()), 'the map YAML {d}/map.yaml is a '
                                                      'directory'),
    (lambda d: d.mkdir(), 'the map YAML {d}/map.yaml does not exist'),
    (lambda d: (d.mkdir(), (d / 'map.yaml').write_bytes(b'x' * (limits.MAX_MAP_YAML_BYTES + 1))),
     'is 65,537 bytes; at most 65,536'),
    (lambda d: write_map(d, occupied='2'), "{d}/map.yaml: 'occupied_thresh' must be between"),
])
def test_file_problems_are_one_line_naming_the_file(tmp_path, setup, words):
    folder = tmp_path / 'm'
    setup(folder)
    with pytest.raises(MapError) as refused:
        load_map_file(str(folder / 'map.yaml'))
    assert words.format(d=folder) in str(refused.value)
    assert '\n' not in str(refused.value)


def test_a_two_million_cell_map_decodes_exactly(tmp_path):
    """A 3 cm warehouse: the table lookup must give the per-pixel rule on every cell."""
    rng = np.random.default_rng(11)
    pixels = rng.choice(np.array([0, 205, 254], dtype=np.uint8), size=(1024, 2048),
                        p=[0.1, 0.3, 0.6])
    got = loaded(pgm(pixels), resolution='0.03')
    shade = pixels.astype(np.float64) * 257 * 3 / 3 / MAX
    occ = 1.0 - shade
    expected = np.where(0.65 < occ, 100, np.where(occ < 0.196, 0, -1))[::-1]
    assert got.width * got.height == 2 ** 21 and np.array_equal(got.data, expected)
    assert math.isclose(got.resolution, 0.03, rel_tol=1e-7)
