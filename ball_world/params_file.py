"""A ROS 2 parameters file, read as the node reads its own section: dotted names and values.

Why a module of its own: `ball_world --ros-args --params-file FILE` is how a world is
written down, and the tools that run a world without ROS (ball_world_sim, the learning
environments) take the same file. rcl applies the wildcard sections ('/**') first and the
node's own name after; nested mappings are dotted names (`agent: {scan: {samples: 16}}` is
`agent.scan.samples`). Nothing is checked here but the file's shape: the values are the
parameter table's to check (core.parameters.checked).
"""
from pathlib import Path

import yaml

#: The node names a parameters file may hold the node's parameters under, in the order rcl
#: applies them (the wildcard first, the node's own name after it).
NODE_KEYS = ('/**', '**', 'ball_world', '/ball_world')


class ParamsFileError(ValueError):
    """A parameters file that cannot be read as one; the message is one line."""


def flatten(node, prefix=''):
    """Nested parameters ({'balls': {'x': [...]}}) as dotted names ({'balls.x': [...]})."""
    flat = {}
    for key, value in node.items():
        name = f'{prefix}.{key}' if prefix else str(key)
        if isinstance(value, dict):
            flat.update(flatten(value, name))
        else:
            flat[name] = value
    return flat


def read_parameters(path, what='parameters file'):
    """The node's parameters in the file `path`, as dotted names (ParamsFileError, whose
    message starts with `what` and the path)."""
    shown = f'{what} {str(path)[:200]}'
    try:
        document = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        reason = getattr(error, 'strerror', None) or str(error).splitlines()[0]
        raise ParamsFileError(f'{shown}: cannot read it: {reason}') from None
    found = {}
    keys = [key for key in NODE_KEYS if isinstance(document, dict) and key in document]
    for key in keys:
        section = document[key]
        if not isinstance(section, dict) or not isinstance(section.get('ros__parameters'),
                                                           dict):
            raise ParamsFileError(f"{shown}: '{key}' holds no ros__parameters mapping")
        found.update(flatten(section['ros__parameters']))
    if not keys:
        raise ParamsFileError(f"{shown}: not a parameters file (no '/**:' or "
                              "'ball_world:' with ros__parameters)")
    return found
