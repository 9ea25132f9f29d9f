"""The node's ROS parameters: names, types, defaults, descriptions and ranges, in one table.

Declaring them from one table keeps `ros2 param describe`, the defaults in
config/ball_world.yaml and the README in step. Parameters that describe the world take
effect on ~/reset; the others take effect at once; file paths are read-only.
"""
from dataclasses import dataclass
from typing import Any, Optional

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterUninitializedException)
from rclpy.parameter import Parameter

from ball_world.core.scenario import DEFAULTS

_TYPES = {
    float: ParameterType.PARAMETER_DOUBLE,
    int: ParameterType.PARAMETER_INTEGER,
    str: ParameterType.PARAMETER_STRING,
    bool: ParameterType.PARAMETER_BOOL,
    list: ParameterType.PARAMETER_DOUBLE_ARRAY,
}


@dataclass(frozen=True)
class Spec:
    """One parameter: its default, what it means, when it applies, and its range."""

    name: str
    default: Any
    description: str
    applies: str = 'reset'  # 'reset': on ~/reset; 'now': at once; 'start': read-only
    low: Optional[float] = None
    high: Optional[float] = None

    @property
    def kind(self):
        return _TYPES[type(self.default)]

    def descriptor(self):
        when = {'reset': 'Takes effect on ~/reset.', 'now': 'Takes effect at once.',
                'start': 'Read-only: set it at start.'}[self.applies]
        descriptor = ParameterDescriptor(
            name=self.name, type=self.kind, description=f'{self.description} {when}',
            read_only=self.applies == 'start')
        if self.low is not None and self.kind == ParameterType.PARAMETER_DOUBLE:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.low), to_value=float(self.high), step=0.0)]
        elif self.low is not None and self.kind == ParameterType.PARAMETER_INTEGER:
            descriptor.integer_range = [IntegerRange(
                from_value=int(self.low), to_value=int(self.high), step=0)]
        return descriptor


_INT_MAX = 2**63 - 1

SPECS = (
    Spec('rate_hz', DEFAULTS['rate_hz'], 'Steps per second of wall time; 0 runs as fast as '
         'possible (then dt must be > 0).', 'now', 0.0, 1e6),
    Spec('dt', DEFAULTS['dt'], 'Simulated seconds per step; 0 means 1 / rate_hz.', 'reset',
         0.0, 3600.0),
    Spec('max_steps', DEFAULTS['max_steps'], 'Stop after this many steps, close the '
         'recordings and exit 0; 0 runs until shutdown.', 'now', 0, _INT_MAX),
    Spec('frame_id', DEFAULTS['frame_id'], 'Frame of balls and markers.', 'now'),
    Spec('arena', DEFAULTS['arena'], 'xmin, ymin, xmax, ymax of a box of four walls, in m; '
         'empty: no box.'),
    Spec('walls', DEFAULTS['walls'], 'More wall segments, flat x1, y1, x2, y2, ... in m.'),
    Spec('balls.x', DEFAULTS['balls.x'], 'Explicit balls: x of each centre, m.'),
    Spec('balls.y', DEFAULTS['balls.y'], 'Explicit balls: y of each centre, m.'),
    Spec('balls.vx', DEFAULTS['balls.vx'], 'Explicit balls: x velocity, m/s.'),
    Spec('balls.vy', DEFAULTS['balls.vy'], 'Explicit balls: y velocity, m/s.'),
    Spec('balls.radius', DEFAULTS['balls.radius'], 'Explicit balls: radius, m (> 0).'),
    Spec('balls.mass', DEFAULTS['balls.mass'], 'Explicit balls: mass, kg (> 0).'),
    Spec('random.count', DEFAULTS['random.count'], 'Balls added at random after the explicit '
         'ones, never overlapping anything.', 'reset', 0, 10_000_000),
    Spec('random.seed', DEFAULTS['random.seed'], 'Seed of the random balls.', 'reset',
         0, _INT_MAX),
    Spec('random.radius', DEFAULTS['random.radius'], 'min, max radius of random balls, m.'),
    Spec('random.speed', DEFAULTS['random.speed'], 'Max initial speed of random balls, m/s.',
         'reset', 0.0, 1e9),
    Spec('random.density', DEFAULTS['random.density'], 'Mass of a random ball = density x '
         'area, kg/m^2.', 'reset', 1e-12, 1e12),
    Spec('physics.backend', DEFAULTS['physics.backend'], "How the world steps: 'numpy' (pure "
         "numpy) or 'numba' (compiled kernels, several times faster; a "
         'different but equally exact resolution order, so trajectories differ).'),
    Spec('publish_clock', DEFAULTS['publish_clock'], 'Publish /clock after each step.', 'now'),
    Spec('markers.rate_hz', 10.0, 'Wall-clock rate of the RViz markers; 0 turns them off. '
         'Lower it for large worlds: a marker per ball is costly.', 'now', 0.0, 1000.0),
    Spec('record.mcap', DEFAULTS['record.mcap'], 'MCAP file to record to; empty records '
         'nothing.', 'start'),
    Spec('record.rerun', DEFAULTS['record.rerun'], 'Rerun .rrd file to log to; empty logs '
         'nothing.', 'start'),
    Spec('record.rerun_every', 1, 'Log every k-th step to the .rrd (steps with impulses are '
         'always logged).', 'start', 1, 1_000_000),
)

SPEC_BY_NAME = {spec.name: spec for spec in SPECS}


_TYPE_NAMES = {
    ParameterType.PARAMETER_DOUBLE: 'a double (write 1.0, not 1)',
    ParameterType.PARAMETER_INTEGER: 'an integer',
    ParameterType.PARAMETER_STRING: 'a string',
    ParameterType.PARAMETER_BOOL: 'true or false',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'a list of doubles (write [0.0, 10.0], not [0, 10])',
}


class ParameterError(ValueError):
    """A parameter override the node cannot take; the message names the parameter."""


def declare_all(node):
    """Declare every parameter on the node (with its override from the command line/file).

    rclpy's own errors name the parameter at the end of a long sentence; these say what
    was expected in the form users write in a parameters file.
    """
    for spec in SPECS:
        try:
            if spec.kind == ParameterType.PARAMETER_DOUBLE_ARRAY and not spec.default:
                # rclpy cannot infer a type from [], so declare it typed and unset.
                node.declare_parameter(spec.name, Parameter.Type.DOUBLE_ARRAY,
                                       spec.descriptor())
            else:
                node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except InvalidParameterTypeException:
            raise ParameterError(f"parameter '{spec.name}': expected {_TYPE_NAMES[spec.kind]}")
        except InvalidParameterValueException:
            raise ParameterError(f"parameter '{spec.name}': must be between {spec.low} and "
                                 f'{spec.high}')


def current_values(node):
    """All parameters as plain Python values (unset arrays as [])."""
    values = {}
    for spec in SPECS:
        try:
            value = node.get_parameter(spec.name).value
        except ParameterUninitializedException:
            value = None
        if value is None:
            value = list(spec.default)
        elif spec.kind == ParameterType.PARAMETER_DOUBLE_ARRAY:
            value = [float(v) for v in value]
        values[spec.name] = value
    return values
