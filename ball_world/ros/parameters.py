"""The node's ROS parameters, declared from the one table in core.parameters.

What this adds to the table is ROS: descriptors (type, range, read-only, description with
when the value takes effect), and the conversions users expect of a ROS node but rclpy does
not make: integers given for doubles (`-p rate_hz:=60`, `arena:=[0, 0, 10, 10]`,
`ros2 param set /ball_world rate_hz 30`) are converted, and an empty list (`-p arena:=[]`,
`arena: []` in a file, which rcl hands over untyped) means an empty double array.
"""
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from ball_world.core import parameters as table

_ROS_TYPES = {
    table.DOUBLE: Parameter.Type.DOUBLE,
    table.INTEGER: Parameter.Type.INTEGER,
    table.STRING: Parameter.Type.STRING,
    table.BOOL: Parameter.Type.BOOL,
    table.DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
    table.STRING_ARRAY: Parameter.Type.STRING_ARRAY,
}
_WHEN = {table.ON_RESET: 'Takes effect on ~/reset.', table.AT_ONCE: 'Takes effect at once.',
         table.AT_START: 'Read-only: set it at start.'}
#: Names rclpy and rcl declare or read themselves: never reported as misspelled.
_ROS_OWN = ('use_sim_time', 'start_type_description_service')
_ROS_OWN_PREFIXES = ('qos_overrides.',)


class ParameterError(ValueError):
    """A parameter override the node cannot take; the message names the parameter."""


def descriptor(parameter):
    """The ParameterDescriptor `ros2 param describe` shows for a table entry."""
    text = f'{parameter.description} {_WHEN[parameter.applies]}'
    if parameter.range_text():
        text += f' Range: {parameter.range_text()}.'
    result = ParameterDescriptor(name=parameter.name, type=_ROS_TYPES[parameter.kind].value,
                                 description=text, read_only=parameter.read_only)
    if parameter.low is not None and parameter.kind == table.DOUBLE:
        result.floating_point_range = [FloatingPointRange(
            from_value=float(parameter.low), to_value=float(parameter.high), step=0.0)]
    elif parameter.low is not None and parameter.kind == table.INTEGER:
        result.integer_range = [IntegerRange(
            from_value=int(parameter.low), to_value=int(parameter.high), step=0)]
    return result


def as_ros_value(parameter, value):
    """A value for `parameter` in the type rclpy wants, converting where users expect it.

    Integers become doubles for double parameters, any empty or integer list becomes a
    double array, and an untyped empty value (None) an empty array. Anything else is left
    as it is, for the checks to refuse with a clear reason.
    """
    if parameter.kind == table.DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if parameter.kind == table.DOUBLE_ARRAY:
        if value is None:
            return []
        if hasattr(value, '__len__') and not isinstance(value, (str, bytes)) and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return [float(v) for v in value]
    if parameter.kind == table.STRING_ARRAY and (value is None or (
            hasattr(value, '__len__') and not isinstance(value, (str, bytes))
            and not len(value))):
        return []
    return value


def converted(parameters):
    """A pre-set-parameters callback: `ros2 param set` values converted as at start."""
    result = []
    for item in parameters:
        parameter = table.BY_NAME.get(item.name)
        if parameter is None or item.type_ == Parameter.Type.NOT_SET:
            result.append(item)
            continue
        value = as_ros_value(parameter, item.value)
        try:
            result.append(Parameter(item.name, _ROS_TYPES[parameter.kind], value))
        except (TypeError, ValueError):
            result.append(item)  # a type that cannot convert: refused with the reason
    return result


def declare_all(node, overrides):
    """Declare every parameter of the table on the node, with the user's overrides.

    overrides: name -> rclpy Parameter given on the command line or in a parameters file
    (rclpy's Node._parameter_overrides). Each is converted as users expect, then checked
    against the table, so a bad value stops the start with one line naming it. Returns the
    names given that the node does not have (probably misspelled).
    """
    for parameter in table.PARAMETERS:
        value = parameter.default
        if parameter.name in overrides:
            value = as_ros_value(parameter, overrides[parameter.name].value)
            try:
                value = parameter.check(value)
            except table.ParameterError as error:
                raise ParameterError(str(error)) from None
        ros_type = _ROS_TYPES[parameter.kind]
        try:
            ros_value = Parameter(parameter.name, ros_type, value).value
        except (TypeError, ValueError):
            raise ParameterError(f"parameter '{parameter.name}': expected {parameter.kind}, "
                                 f'got {value!r}') from None
        if parameter.kind in (table.DOUBLE_ARRAY, table.STRING_ARRAY) and not ros_value:
            # rclpy infers an empty list's type as a byte array: declare the type, then set
            # the empty double array, so `ros2 param get` and `dump` show it rather than
            # "not set" (and GetParameters for all names does not come back empty).
            node.declare_parameter(parameter.name, ros_type, descriptor(parameter),
                                   ignore_override=True)
            node.set_parameters([Parameter(parameter.name, ros_type, [])])
        else:
            node.declare_parameter(parameter.name, ros_value, descriptor(parameter),
                                   ignore_override=True)
    return sorted(name for name in overrides
                  if name not in table.BY_NAME and name not in _ROS_OWN
                  and not name.startswith(_ROS_OWN_PREFIXES))


def current_values(node):
    """All parameters as plain Python values, in their canonical form."""
    values = {}
    for parameter in table.PARAMETERS:
        value = node.get_parameter(parameter.name).value
        if parameter.kind == table.DOUBLE_ARRAY:
            value = [float(v) for v in value]
        elif parameter.kind == table.STRING_ARRAY:
            value = list(value)
        values[parameter.name] = value
    return values
