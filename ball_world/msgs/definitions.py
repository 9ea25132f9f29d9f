"""Message definitions and type hashes for writing MCAP files the way rosbag2 Jazzy does.

Why: MCAP readers (Foxglove, mcap_ros2, rosbags) decode a channel from its schema alone, so
the schema must be the complete 'ros2msg' text. We reproduce rosbag2_cpp's
LocalMessageDefinitionSource byte for byte, so a ball_world recording is indistinguishable
from `ros2 bag record` output:

- the root type's .msg file verbatim (comments, constants and blank lines kept);
- then every dependency, depth-first, each once, as '\\n' + 80 '=' + '\\n' + 'MSG: pkg/Type\\n'
  + that file verbatim. A type's dependencies are visited in sorted order (rosbag2 keeps them
  in a std::set), and named as written in the .msg ('geometry_msgs/Pose', no '/msg/').

Dependencies are found with rosbag2's own regex: the first token of a line, stripped of an
array suffix, unless it is a primitive type. Two deliberate differences, both for types
rosbag2 would fail on: a bare 'Header' means std_msgs/Header (as in ROS 1 .msg files), and
'wstring' counts as primitive. Neither occurs in the installed message packages we record.
"""
import functools
import json
import os
from pathlib import Path
import re
import sys

SEPARATOR = '=' * 80

# rosbag2_cpp MSG_FIELD_TYPE_REGEX: 'foo_msgs/Bar' in 'foo_msgs/Bar[] bar'. Without
# re.MULTILINE, '^' only matches at the start of the text, as in std::regex ECMAScript.
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'))
_NAME = r'[a-zA-Z][a-zA-Z0-9_]*'
_TYPE_NAME = re.compile(rf'^({_NAME})(?:/({_NAME}))?/({_NAME})$')


def _split(type_name: str) -> tuple:
    """'pkg/msg/Type' or 'pkg/Type' -> (pkg, 'msg', Type)."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise ValueError(f'not a ROS interface type name: {type_name!r}')
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def _share_dirs(package: str) -> list:
    """Where `package`'s share directory may be: the ament index first, then the venv.

    The PyPI ROS 2 wheels install share/<pkg> under sys.prefix without setting
    AMENT_PREFIX_PATH, so the ament index alone would miss them.
    """
    dirs = []
    if os.environ.get('AMENT_PREFIX_PATH'):
        try:
            from ament_index_python.packages import get_package_share_directory
            dirs.append(Path(get_package_share_directory(package)))
        except (ImportError, LookupError, ValueError):
            pass
    dirs.append(Path(sys.prefix) / 'share' / package)
    return dirs


def _interface_file(type_name: str, suffix: str):
    """The installed share/<pkg>/<ns>/<Type><suffix> for a type, or None."""
    package, namespace, name = _split(type_name)
    for share in _share_dirs(package):
        path = share / namespace / (name + suffix)
        if path.is_file():
            return path
    return None


@functools.lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    path = _interface_file(type_name, '.msg')
    if path is None:
        raise LookupError(f'no .msg definition found for {type_name}')
    # newline='' keeps the bytes verbatim, as rosbag2 reads them (no CRLF translation).
    with open(path, encoding='utf-8', newline='') as f:
        return f.read()


def _dependencies(text: str, package: str) -> list:
    """Non-primitive field types of a .msg text, as rosbag2 names them, in sorted order."""
    found = set()
    for match in _FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        if field_type == 'Header':
            found.add('std_msgs/Header')
        elif '/' in field_type:
            found.add(field_type)
        else:
            found.add(f'{package}/{field_type}')
    return sorted(found)


@functools.lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """The complete 'ros2msg' schema text rosbag2 Jazzy records for `type_name`.

    `type_name` is 'pkg/msg/Type' (or 'pkg/Type'). Raises LookupError when a .msg file of the
    type or one of its dependencies is not installed.
    """
    seen = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise RecursionError(f'message definition of {type_name} nests too deeply')
        text = _msg_text(name)
        for dep in _dependencies(text, _split(name)[0]):
            if dep not in seen:
                seen.add(dep)
                text += f'\n{SEPARATOR}\nMSG: {dep}\n' + append(dep, depth - 1)
        return text

    return append(type_name, 50)


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """The RIHS01_... type hash from the installed type description, or '' if unavailable.

    rosbag2 (Iron and later) records it as each topic's type_description_hash.
    """
    try:
        package, namespace, name = _split(type_name)
    except ValueError:
        return ''
    path = _interface_file(type_name, '.json')
    if path is None:
        return ''
    try:
        with open(path, encoding='utf-8') as f:
            hashes = json.load(f).get('type_hashes', [])
    except (OSError, ValueError):
        return ''
    full_name = f'{package}/{namespace}/{name}'
    for entry in hashes:
        if entry.get('type_name') == full_name:
            return entry.get('hash_string', '')
    return ''
