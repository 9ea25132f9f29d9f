"""Read a nav2 map's two files (the YAML and the image it names), bounded, as bytes.

Why apart from core.occupancy_map: the core decodes bytes and never opens a file, so a
recording's copy of the map decodes exactly as the files did; this module is the one place a
map is read from disk (the node at start, tools given a map path). Paths follow nav2's
`yaml_filename`: the YAML path as given (relative to the working directory, `~/` expanded),
the image relative to the YAML's directory unless absolute.

Every surprise is a MapError with one line naming the file: a missing file, a directory, a
FIFO or device (opened without blocking, recording.files.open_regular), a file that cannot be
read, or one past limits.MAX_MAP_YAML_BYTES / MAX_MAP_IMAGE_BYTES; the YAML and the image are
then checked by core.occupancy_map.load_map. Symbolic links are followed: a colcon
--symlink-install share directory holds maps as links.
"""
import os

from ball_world.core import limits
from ball_world.core.occupancy_map import load_map, MapError, MapFiles, parse_map_yaml
from ball_world.recording.files import FileRefused, open_regular


def map_path(path):
    """The YAML's path as nav2_map_server takes `yaml_filename`: `~/` expanded."""
    if path.startswith('~/'):
        return os.path.expanduser(path)
    return path


def _read_bounded(path, limit, label):
    """The bytes of a regular file of at most `limit` bytes (MapError otherwise).

    label: how the message names the file ('the map YAML maps/a.yaml').
    """
    try:
        with open_regular(path) as stream:
            size = os.fstat(stream.fileno()).st_size
            if size > limit:
                raise MapError(f'{label} is {size:,} bytes; at most {limit:,} are accepted')
            data = stream.read(limit + 1)
    except FileNotFoundError:
        raise MapError(f'{label} does not exist') from None
    except FileRefused as error:  # a directory, a FIFO, a device
        raise MapError(f'{label} {error.strerror}') from None
    except OSError as error:
        reason = error.strerror or str(error)
        raise MapError(f'{label} cannot be read: {reason}') from None
    if len(data) > limit:
        raise MapError(f'{label} grew past {limit:,} bytes while being read')
    return data


def read_map_files(path):
    """MapFiles of the map whose YAML is at `path` (MapError with one line otherwise)."""
    return _read(path)[0]


def load_map_file(path):
    """The OccupancyMap of the map whose YAML is at `path` (MapError with one line)."""
    files, yaml_path, image_path = _read(path)
    return load_map(files, where=yaml_path, image_where=image_path)


def _read(path):
    """(MapFiles, the YAML's path, the image's path)."""
    if not path:
        raise MapError('no map file given')
    yaml_path = map_path(path)
    yaml_bytes = _read_bounded(yaml_path, limits.MAX_MAP_YAML_BYTES,
                               f'the map YAML {yaml_path}')
    yaml_name = os.path.basename(yaml_path)
    image = parse_map_yaml(yaml_bytes, yaml_path).image
    image_path = image if image.startswith('/') else os.path.join(
        os.path.dirname(yaml_path), image)
    image_bytes = _read_bounded(image_path, limits.MAX_MAP_IMAGE_BYTES,
                                f'the map image {image_path} (named by {yaml_path})')
    files = MapFiles(yaml_name=yaml_name, yaml_bytes=yaml_bytes, image_name=image,
                     image_bytes=image_bytes)
    return files, yaml_path, image_path
