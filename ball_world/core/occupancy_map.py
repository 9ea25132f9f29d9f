"""A nav2 map (YAML + PGM/PNG bytes) to the grid nav2_map_server publishes, and its solid cells.

Why a module of its own, and why bytes: the map is part of the world, so a recording keeps the
map's files and a re-simulation on another machine decodes the very same bytes; the node, the
scenario, the recordings and the tools all go through load_map, so /map, the physics, Rerun
and resim can never see two different maps. No file is opened here (ball_world.map_files reads
them, bounded) and no ROS is imported.

The rules are nav2_map_server's (Jazzy, map_io.cpp and map_mode.cpp), read from its source and
written again here:

- YAML (yaml-cpp's conversions): `image` (a non-empty string), `resolution` (a number),
  `origin` (three numbers x, y, yaw), `free_thresh` and `occupied_thresh` (numbers) and
  `negate` (an integer, any non-zero value true, or a yaml-cpp boolean: y/yes/true/on,
  n/no/false/off) are required; `mode` is optional, trinary by default, `trinary`, `scale` or
  `raw` in any letter case. Other keys are ignored, as the map server ignores them.
- Pixels are read as GraphicsMagick (16-bit quanta, MaxRGB 65535) reads them: an 8-bit value
  v is the quantum 257 v, a 16-bit one is itself, a PNM sample v with maxval m is
  (65535 v + m // 2) // m. A pixel's shade is the mean of its red, green and blue quanta (and,
  in trinary mode, of its alpha too when the image has an alpha channel: the map server keeps
  that old behaviour) divided by 65535; occ = shade if negate else 1 - shade.
- trinary: 100 where occupied_thresh < occ, 0 where occ < free_thresh, -1 between.
  scale: -1 where the pixel is not fully opaque, else as trinary but between the thresholds
  rint((occ - free_thresh) / (occupied_thresh - free_thresh) * 100). raw: round(shade * 255)
  (half away from zero) where that is 0 to 100, else -1; negate does not apply.
- The image's first row is the map's last (row 0 of the grid is the image's bottom row).

ball_world adds refusals where the map server would publish something the physics cannot
take, each one line naming the key: a resolution or origin that is not finite or too small, a
threshold outside 0 to 1, free_thresh above occupied_thresh (or equal to it in scale mode,
where the map server would divide by zero), an origin yaw other than 0 (the contract: cells
are axis-aligned squares), a map past limits.MAX_MAP_CELLS or reaching beyond
limits.COORDINATE_LIMIT, a 16-bit PNG with colour or alpha (the PNG decoder keeps only 8 bits
of those, and a cell could then differ from the map server's).

Solid cells (core.solid_cells): 100, and -1 unless unknown_solid is false; everything outside
the image is solid by SolidCells' own rule. Their resolution is the one /map carries (nav_msgs
MapMetaData.resolution is a float32), so the physics, RViz and a Nav2 costmap put every cell
edge at the same place.
"""
import io
import math
import re
from typing import NamedTuple
import warnings

import numpy as np
import yaml

from ball_world.core import limits
from ball_world.core.solid_cells import SolidCells

#: The map server's cell values (nav2_util/occ_grid_values.hpp).
OCCUPIED = 100
FREE = 0
UNKNOWN = -1
#: GraphicsMagick's largest quantum (Q16, the build ROS's nav2_map_server links).
MAX_QUANTUM = 65535
MODES = ('trinary', 'scale', 'raw')
#: yaml-cpp's boolean spellings (convert<bool>): each in lower, Capitalised and UPPER case.
_TRUE_WORDS = ('y', 'yes', 'true', 'on')
_FALSE_WORDS = ('n', 'no', 'false', 'off')
_BOOLEANS = {**{form: True for word in _TRUE_WORDS
                for form in (word, word.capitalize(), word.upper())},
             **{form: False for word in _FALSE_WORDS
                for form in (word, word.capitalize(), word.upper())}}
#: A number as std::stringstream >> double reads one whole (no hex, no digit separators).
_DECIMAL = re.compile(r'[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?')
_INFINITE = re.compile(r'[+-]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)')
#: An integer as std::stringstream >> int reads one (decimal, 0x hex or 0 octal).
_INTEGER = re.compile(r'([+-]?)(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)')
_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
_PNM_MAGICS = (b'P2', b'P3', b'P5', b'P6')
_PNM_WHITESPACE = b' \t\r\n\v\f'
_PNM_FIELDS = ('width', 'height', 'maxval')


class MapError(ValueError):
    """A map that cannot be loaded; str() is one line saying what and where."""


class MapFiles(NamedTuple):
    """A map's two files as bytes, with the names they had: what a recording keeps.

    yaml_name: the YAML file's name (its base name); image_name: the `image` entry as the
    YAML writes it (relative to the YAML, or absolute).
    """

    yaml_name: str
    yaml_bytes: bytes
    image_name: str
    image_bytes: bytes


class MapYaml(NamedTuple):
    """The YAML's values, converted as nav2_map_server converts them."""

    image: str
    resolution: float  # m per cell, as written (a double)
    origin: tuple  # (x, y, yaw): m, m, rad
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str  # 'trinary', 'scale' or 'raw'


class OccupancyMap(NamedTuple):
    """A loaded map: its files, its YAML values and the grid /map carries.

    data: int8 (height, width) in OccupancyGrid order (row 0 is the image's last row):
    100 occupied, 0 free, -1 unknown, 1..99 between the thresholds in scale mode, 0..100 in
    raw mode.
    """

    files: MapFiles
    yaml: MapYaml
    data: np.ndarray

    @property
    def width(self):
        return self.data.shape[1]

    @property
    def height(self):
        return self.data.shape[0]

    @property
    def resolution(self):
        """m per cell as /map carries it (float32): where every cell edge is."""
        return float(np.float32(self.yaml.resolution))

    @property
    def origin(self):
        """(x, y) of the grid's lower-left corner, m."""
        return self.yaml.origin[0], self.yaml.origin[1]

    @property
    def counts(self):
        """(occupied, free, unknown) cells: 100, 0 and -1 (scale mode's 1..99 not counted)."""
        values = np.bincount((self.data.reshape(-1).astype(np.int16) + 1), minlength=102)
        return int(values[OCCUPIED + 1]), int(values[FREE + 1]), int(values[UNKNOWN + 1])

    def solid_cells(self, unknown_solid=True):
        """SolidCells: occupied cells, and unknown ones too when unknown_solid."""
        solid = self.data == OCCUPIED
        if unknown_solid:
            solid |= self.data == UNKNOWN
        x, y = self.origin
        return SolidCells(origin_x=x, origin_y=y, resolution=self.resolution,
                          solid=solid).checked()

    def describe(self):
        """'tb3_sandbox.yaml: 384 x 384 cells of 0.05 m at (-10, -10), trinary'."""
        x, y = self.origin
        return (f'{self.files.yaml_name}: {self.width} x {self.height} cells of '
                f'{self.yaml.resolution:g} m at ({x:g}, {y:g}), {self.yaml.mode}')


def load_map(files, where=None, image_where=None):
    """The OccupancyMap of a map's bytes (MapFiles), or MapError naming the problem.

    where, image_where: how messages name the two files (default: their names).
    """
    where = where or files.yaml_name or 'the map YAML'
    values = parse_map_yaml(files.yaml_bytes, where)
    channels, alpha = decode_image(files.image_bytes,
                                   image_where or files.image_name or values.image)
    data = occupancy(channels, alpha, values)
    _check_extent(values, data.shape, where)
    return OccupancyMap(files=files, yaml=values, data=data)


# The YAML ----------------------------------------------------------------------------------

def parse_map_yaml(text, where='the map YAML'):
    """MapYaml from the YAML's bytes or text (MapError names the key that is wrong)."""
    if isinstance(text, bytes):
        try:
            text = text.decode('utf-8')
        except UnicodeDecodeError as error:
            raise MapError(f'{where}: not UTF-8 text (byte {error.start})') from None
    if len(text) > limits.MAX_MAP_YAML_BYTES:
        raise MapError(f'{where}: {len(text):,} characters; a map YAML is at most '
                       f'{limits.MAX_MAP_YAML_BYTES:,}')
    loader = getattr(yaml, 'CBaseLoader', yaml.BaseLoader)  # every scalar as its text
    try:
        document = yaml.load(text, Loader=loader)
    except RecursionError:
        raise MapError(f'{where}: the YAML nests too deeply') from None
    except yaml.YAMLError as error:
        mark = getattr(error, 'problem_mark', None)
        at = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        problem = getattr(error, 'problem', None) or str(error).splitlines()[0]
        raise MapError(f'{where}: not valid YAML{at}: {problem}') from None
    if not isinstance(document, dict):
        raise MapError(f'{where}: expected a YAML mapping with image, resolution, origin, '
                       'negate, occupied_thresh and free_thresh')

    def required(key):
        if key not in document:
            raise MapError(f"{where}: the key '{key}' is missing (nav2 map YAMLs need image, "
                           'resolution, origin, negate, occupied_thresh, free_thresh)')
        return document[key]

    image = required('image')
    if not isinstance(image, str):
        raise MapError(f"{where}: 'image' must be a file name, got a "
                       f'{"list" if isinstance(image, list) else "mapping"}')
    if not image:
        raise MapError(f"{where}: 'image' is empty")
    given = {key: required(key) for key in ('resolution', 'origin', 'free_thresh',
                                            'occupied_thresh')}
    resolution = _double(given['resolution'], 'resolution', where)
    origin = given['origin']
    if not isinstance(origin, list) or len(origin) != 3:
        count = f'{len(origin)} values' if isinstance(origin, list) else 'not a list'
        raise MapError(f"{where}: 'origin' must be [x, y, yaw], got {count}")
    origin = tuple(_double(value, 'origin', where) for value in origin)
    free = _double(given['free_thresh'], 'free_thresh', where)
    occupied = _double(given['occupied_thresh'], 'occupied_thresh', where)
    mode = document.get('mode', 'trinary')
    if not isinstance(mode, str) or mode.lower() not in MODES:
        raise MapError(f"{where}: 'mode' must be trinary, scale or raw, got "
                       f'{_shown(mode)}')
    mode = mode.lower()
    negate = _negate(required('negate'), where)
    values = MapYaml(image=image, resolution=resolution, origin=origin, negate=negate,
                     occupied_thresh=occupied, free_thresh=free, mode=mode)
    _check_values(values, given, where)
    return values


def _shown(value):
    text = repr(value) if isinstance(value, str) else f'a {type(value).__name__}'
    return text if len(text) <= 40 else text[:37] + '...'


def _as_given(text):
    """A number's text as the file writes it, for a message: a value that overflows (1e400 is
    inf once read) or rounds (0.00099999 is 0.001 at 6 digits) would misstate the input. Long
    texts keep their start and say how long they are."""
    text = str(text)
    return text if len(text) <= 30 else f'{text[:24]}... ({len(text):,} characters)'


def _number(value):
    """A number computed from the input, exactly (the shortest text that reads back as it)."""
    return repr(float(value))


def _double(value, key, where):
    """A YAML scalar as yaml-cpp's as<double> reads it (.inf and .nan included)."""
    if isinstance(value, str):
        if _DECIMAL.fullmatch(value):
            return float(value)
        if _INFINITE.fullmatch(value):
            return float(value.replace('.', '').replace('INF', 'inf').replace('Inf', 'inf'))
    raise MapError(f"{where}: '{key}' must be a number, got {_shown(value)}")


def _negate(value, where):
    """yaml-cpp: as<int> first (non-zero is true), then as<bool>."""
    if isinstance(value, str):
        number = _integer(value)
        if number is not None:
            return number != 0
        if value in _BOOLEANS:
            return _BOOLEANS[value]
    raise MapError(f"{where}: 'negate' must be 0, 1, true or false, got {_shown(value)}")


def _integer(text):
    """An int as std::stringstream >> int reads it (0x hex, leading-0 octal), or None."""
    match = _INTEGER.fullmatch(text)
    if match is None:
        return None
    sign, digits = match.groups()
    base = 16 if digits[:2] in ('0x', '0X') else 8 if len(digits) > 1 and digits[0] == '0' \
        else 10
    value = int(digits, base) * (-1 if sign == '-' else 1)
    return value if -2 ** 31 <= value < 2 ** 31 else None


def _check_values(values, given, where):
    """ball_world's refusals of values the map server would take (see the module docstring);
    `given` holds the numbers' texts as written, which the messages quote."""
    if not (math.isfinite(values.resolution)
            and values.resolution >= limits.MIN_MAP_RESOLUTION):
        raise MapError(f"{where}: 'resolution' must be at least "
                       f'{limits.MIN_MAP_RESOLUTION:g} m per cell, got '
                       f"{_as_given(given['resolution'])}")
    origin = ', '.join(_as_given(text) for text in given['origin'])
    if not all(math.isfinite(value) for value in values.origin):
        raise MapError(f"{where}: 'origin' must be finite, got [{origin}]")
    if values.origin[2] != 0.0:
        raise MapError(f"{where}: 'origin' yaw is {_as_given(given['origin'][2])} rad; "
                       'ball_world takes only maps with yaw 0 (cells are axis-aligned '
                       'squares): rotate the image instead')
    for key in ('free_thresh', 'occupied_thresh'):
        value = getattr(values, key)
        if not 0.0 <= value <= 1.0:
            raise MapError(f"{where}: '{key}' must be between 0 and 1, got "
                           f'{_as_given(given[key])}')
    if values.free_thresh > values.occupied_thresh or (
            values.mode == 'scale' and values.free_thresh == values.occupied_thresh):
        relation = 'below' if values.mode == 'scale' else 'at most'
        raise MapError(f"{where}: 'free_thresh' ({_as_given(given['free_thresh'])}) must be "
                       f"{relation} 'occupied_thresh' ({_as_given(given['occupied_thresh'])})")


def _check_extent(values, shape, where):
    """The grid lies within limits.COORDINATE_LIMIT, as every wall of a world must."""
    height, width = shape
    x, y = values.origin[0], values.origin[1]
    resolution = float(np.float32(values.resolution))
    corners = (x, y, x + width * resolution, y + height * resolution)
    if max(abs(value) for value in corners) > limits.COORDINATE_LIMIT:
        raise MapError(f'{where}: the map spans ({_number(x)}, {_number(y)}) to '
                       f'({_number(corners[2])}, {_number(corners[3])}) m, beyond the '
                       f'{limits.COORDINATE_LIMIT:g} m a world may reach')


# The image ---------------------------------------------------------------------------------

def decode_image(data, where='the map image'):
    """(channels, alpha) of a PGM/PPM or PNG image, as GraphicsMagick's 16-bit quanta.

    channels: uint16 (height, width) for grey images or (height, width, 3) for colour ones;
    alpha: uint16 (height, width) for images with an alpha channel (or a tRNS transparent
    colour), 65535 opaque, else None. MapError for anything else, truncated or too large.
    """
    if len(data) > limits.MAX_MAP_IMAGE_BYTES:
        raise MapError(f'{where}: {len(data):,} bytes; a map image is at most '
                       f'{limits.MAX_MAP_IMAGE_BYTES:,}')
    head = bytes(data[:8])
    if head[:2] in _PNM_MAGICS:
        return _decode_pnm(data, where), None
    if head == _PNG_SIGNATURE:
        return _decode_png(data, where)
    raise MapError(f'{where}: not a PGM (P2, P5), PPM (P3, P6) or PNG image (it starts with '
                   f'{head[:4]!r})')


def _check_cells(width, height, where):
    if width < 1 or height < 1:
        raise MapError(f'{where}: the image is {width} x {height} pixels: empty')
    if width * height > limits.MAX_MAP_CELLS:
        raise MapError(f'{where}: {width:,} x {height:,} = {width * height:,} cells; a map '
                       f'has at most {limits.MAX_MAP_CELLS:,}')


class _PnmHeader(NamedTuple):
    magic: bytes
    width: int
    height: int
    maxval: int
    raster_at: int  # where the samples start


def _pnm_header(data, where):
    """Magic, width, height, maxval ('#' comments skipped) and where the raster starts."""
    position = 2
    numbers = []
    size = len(data)
    while len(numbers) < 3:
        while position < size and (data[position] in _PNM_WHITESPACE
                                   or data[position] == ord('#')):
            if data[position] == ord('#'):
                end = data.find(b'\n', position)
                position = size if end < 0 else end + 1
            else:
                position += 1
        start = position
        while position < size and 48 <= data[position] <= 57:
            position += 1
        if position == start:
            found = 'its end' if position >= size else repr(bytes(data[position:position + 1]))
            raise MapError(f'{where}: a PNM header needs width, height and maxval; found '
                           f'{found} instead of number {len(numbers) + 1}')
        text = bytes(data[start:position]).decode('ascii')
        if len(text.lstrip('0')) > 9:  # int() of a few thousand digits raises
            name = _PNM_FIELDS[len(numbers)]
            raise MapError(f'{where}: the PNM {name} is {_as_given(text)}: too large (a map '
                           f'has at most {limits.MAX_MAP_CELLS:,} cells; maxval is 1 to 65535)')
        numbers.append((int(text), text))
    if position >= size or data[position] not in _PNM_WHITESPACE:
        raise MapError(f'{where}: the PNM header does not end in whitespace after maxval')
    (width, _), (height, _), (maxval, maxval_text) = numbers
    if not 1 <= maxval <= MAX_QUANTUM:
        raise MapError(f'{where}: PNM maxval {maxval_text}; it must be 1 to 65535')
    _check_cells(width, height, where)
    return _PnmHeader(bytes(data[:2]), width, height, maxval, position + 1)


def _decode_pnm(data, where):
    """Grey (P2, P5) or RGB (P3, P6) quanta: sample v of maxval m is (65535 v + m // 2) // m."""
    header = _pnm_header(data, where)
    samples_per_pixel = 3 if header.magic in (b'P3', b'P6') else 1
    count = header.width * header.height * samples_per_pixel
    if header.magic in (b'P5', b'P6'):
        wide = header.maxval > 255
        needed = count * (2 if wide else 1)
        raster = data[header.raster_at:header.raster_at + needed]
        if len(raster) < needed:
            raise MapError(f'{where}: truncated: the image needs {needed:,} bytes of pixels, '
                           f'the file has {len(raster):,}')
        samples = np.frombuffer(raster, dtype='>u2' if wide else np.uint8)
    else:
        samples = _ascii_samples(data, header.raster_at, count, header.maxval, where)
    largest = int(samples.max())
    if largest > header.maxval:
        raise MapError(f'{where}: a pixel value {largest} is above the maxval {header.maxval}')
    if header.maxval == MAX_QUANTUM:
        quanta = samples.astype(np.uint16)
    else:
        levels = np.arange(header.maxval + 1, dtype=np.int64)
        table = ((MAX_QUANTUM * levels + header.maxval // 2) // header.maxval).astype(
            np.uint16)
        quanta = table[samples]
    shape = (header.height, header.width) + ((3,) if samples_per_pixel == 3 else ())
    return quanta.reshape(shape)


def _ascii_samples(data, start, count, maxval, where):
    """The first `count` whitespace-separated decimal samples of a P2/P3 raster; MapError
    quoting the first one above `maxval` as written (numpy reads a number past int64 as
    its largest value: a sample of 23 digits must not be reported as 9223372036854775807)."""
    text = bytes(data[start:])
    if b'#' in text:
        text = re.sub(rb'#[^\n]*', b' ', text)
    if text.translate(None, b'0123456789' + _PNM_WHITESPACE):
        raise MapError(f'{where}: the pixel values hold something other than whole numbers')
    with warnings.catch_warnings():
        warnings.simplefilter('error')  # numpy warns, and stops, at a number it cannot read
        try:
            values = np.fromstring(text, dtype=np.int64, sep=' ')
        except (ValueError, DeprecationWarning):
            raise MapError(f'{where}: the pixel values cannot be read') from None
    if len(values) < count:
        raise MapError(f'{where}: truncated: the image needs {count:,} pixel values, the file '
                       f'has {len(values):,}')
    values = values[:count]
    above = values > maxval
    if above.any():
        written = _sample_text(text, int(np.argmax(above)))
        raise MapError(f'{where}: a pixel value {_as_given(written)} is above the maxval '
                       f'{maxval}')
    return values


def _sample_text(text, index):
    """The `index`-th whitespace-separated number of `text` (digits and whitespace only), as
    written."""
    digit = np.frombuffer(text, dtype=np.uint8)
    digit = (digit >= 48) & (digit <= 57)
    edges = np.flatnonzero(np.diff(digit.astype(np.int8), prepend=0, append=0))
    begin, end = edges[0::2], edges[1::2]
    return text[begin[index]:end[index]].decode('ascii')


def _decode_png(data, where):
    """A PNG's quanta through Pillow; 16-bit colour or alpha is refused (Pillow keeps 8 bits)."""
    if len(data) < 33 or data[12:16] != b'IHDR':
        raise MapError(f'{where}: truncated: the PNG has no header')
    width = int.from_bytes(data[16:20], 'big')
    height = int.from_bytes(data[20:24], 'big')
    depth, colour_type = data[24], data[25]
    _check_cells(width, height, where)
    if depth == 16 and colour_type != 0:
        raise MapError(f'{where}: a 16-bit PNG with colour or alpha (colour type '
                       f'{colour_type}) cannot be read exactly; save it as 8-bit or as 16-bit '
                       'grey')
    from PIL import Image  # only PNG maps need the decoder
    try:
        with Image.open(io.BytesIO(data), formats=('PNG',)) as image:
            image.load()
            return _png_quanta(image, where)
    except MapError:
        raise
    except Exception as error:  # noqa: B902 - a damaged PNG raises many kinds of error
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise MapError(f'{where}: the PNG cannot be decoded: {reason}') from None


def _png_quanta(image, where):
    """(channels, alpha) quanta of a decoded Pillow image (see decode_image)."""
    mode = image.mode
    transparency = image.info.get('transparency')
    if mode in ('P', 'PA'):
        keep_alpha = mode == 'PA' or transparency is not None
        image = image.convert('RGBA' if keep_alpha else 'RGB')
        mode, transparency = image.mode, None
    pixels = np.asarray(image)
    if mode == '1':
        grey = pixels.astype(np.uint16) * MAX_QUANTUM
        return grey, None
    if mode in ('L', 'I;16', 'I;16B', 'I'):
        grey = pixels.astype(np.uint16) * (257 if mode == 'L' else 1)
        alpha = None
        if isinstance(transparency, int):
            alpha = np.where(pixels == transparency, 0, MAX_QUANTUM).astype(np.uint16)
        return grey, alpha
    if mode == 'LA':
        return pixels[..., 0].astype(np.uint16) * 257, pixels[..., 1].astype(np.uint16) * 257
    if mode == 'RGB':
        alpha = None
        if isinstance(transparency, tuple) and len(transparency) == 3:
            hidden = (pixels == np.array(transparency, dtype=pixels.dtype)).all(axis=2)
            alpha = np.where(hidden, 0, MAX_QUANTUM).astype(np.uint16)
        return pixels.astype(np.uint16) * 257, alpha
    if mode == 'RGBA':
        return pixels[..., :3].astype(np.uint16) * 257, pixels[..., 3].astype(np.uint16) * 257
    raise MapError(f'{where}: PNG pixels of mode {mode} are not supported')


# Pixels to cells ---------------------------------------------------------------------------

def occupancy(channels, alpha, values):
    """The int8 grid (OccupancyGrid order) of decoded quanta under the YAML's rules.

    The shade depends only on the integer sum of the channels averaged and on how many
    there are, so every cell value is looked up in a table over the possible sums, computed
    once with the map server's arithmetic: exact, and cheap for millions of cells.
    """
    colour = channels.ndim == 3
    averaged = 3 + (1 if values.mode == 'trinary' and alpha is not None else 0)
    if colour:
        total = channels.astype(np.uint32).sum(axis=2, dtype=np.uint32)
    else:
        total = channels.astype(np.uint32) * 3
    if averaged == 4:
        total += alpha
    table = cell_table(averaged, values)
    cells = table[total]
    if values.mode == 'scale' and alpha is not None:
        cells[alpha != MAX_QUANTUM] = UNKNOWN
    return np.ascontiguousarray(cells[::-1])


def cell_table(channel_count, values):
    """int8 cell value of every channel sum 0 .. 65535 * channel_count (see the docstring)."""
    sums = np.arange(MAX_QUANTUM * channel_count + 1, dtype=np.float64)
    shade = (sums / float(channel_count)) / float(MAX_QUANTUM)
    if values.mode == 'raw':
        scaled = shade * 255.0
        whole = np.floor(scaled)
        rounded = whole + (scaled - whole >= 0.5)  # std::round: half away from zero
        return np.where(rounded <= OCCUPIED, rounded, UNKNOWN).astype(np.int8)
    occ = shade if values.negate else 1.0 - shade
    table = np.full(sums.shape, UNKNOWN, dtype=np.int8)
    if values.mode == 'scale':
        between = np.rint((occ - values.free_thresh)
                          / (values.occupied_thresh - values.free_thresh) * 100.0)
        inside = (occ <= values.occupied_thresh) & (occ >= values.free_thresh)
        table[inside] = between[inside].astype(np.int8)
    table[occ < values.free_thresh] = FREE
    table[values.occupied_thresh < occ] = OCCUPIED
    return table
