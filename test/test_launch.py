"""What a user gets from the RViz configuration and from the launch file's rviz:=true.

RViz, ros2launch and the `launch` / `launch_ros` Python packages are neither on PyPI nor in
Debian, so the launch file is loaded against stand-ins with the constructor signatures of the
real classes (launch 3.4, launch_ros 0.26, Jazzy), which record what they are given; an argument
the real class does not take is a TypeError here too. Which actions start is then decided by
IfCondition's documented rule (the expanded text, stripped and lower-cased, is 'true' or '1',
'false' or '0', anything else an error). ament_index_python is the real one, on the .venv
prefix, so the path handed to rviz2 -d is the file setup.py installed.
"""
import importlib.util
from pathlib import Path
import sys
import types

from geometry_msgs.msg import PoseArray
import pytest
import rclpy
from visualization_msgs.msg import MarkerArray
import yaml

from ball_world.core.parameters import DEFAULTS
from ball_world.ros.node import BallWorld, MARKER_QOS, STEP_QOS

ROOT = Path(__file__).resolve().parents[1]
RVIZ_FILE = ROOT / 'rviz' / 'ball_world.rviz'
LAUNCH_FILE = ROOT / 'launch' / 'ball_world.launch.py'
#: RViz's names for the QoS policies of a display's topic.
RVIZ_DURABILITY = {'Transient Local': 'transient_local', 'Volatile': 'volatile'}
RVIZ_RELIABILITY = {'Reliable': 'reliable', 'Best Effort': 'best_effort'}
#: Pixels of RViz's window that are not the render panel (title, menu, tool bar, status).
RVIZ_CHROME_PX = 150


# --- The RViz configuration ---------------------------------------------------------------

@pytest.fixture(scope='module')
def rviz():
    return yaml.safe_load(RVIZ_FILE.read_text())


def displays(rviz):
    return {d['Class']: d for d in rviz['Visualization Manager']['Displays']}


@pytest.fixture(scope='module')
def node_publishers():
    """{message type: publisher} of a real BallWorld, so a renamed topic fails these tests."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = BallWorld(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('random.count', value=1)])
    try:
        yield {publisher.msg_type: publisher for publisher in node.publishers}
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_rviz_fixed_frame_is_the_nodes_default_frame(rviz):
    assert (rviz['Visualization Manager']['Global Options']['Fixed Frame']
            == DEFAULTS['frame_id'])


@pytest.mark.parametrize('display_class, message_type, qos', [
    ('rviz_default_plugins/MarkerArray', MarkerArray, MARKER_QOS),
    ('rviz_default_plugins/PoseArray', PoseArray, STEP_QOS),
])
def test_rviz_displays_subscribe_to_the_nodes_topics_with_matching_qos(
        rviz, node_publishers, display_class, message_type, qos):
    publisher = node_publishers[message_type]
    # the display of the node's topic (RViz has others of the class: the bumpers' markers)
    (display,) = [d for d in rviz['Visualization Manager']['Displays']
                  if d['Class'] == display_class
                  and d['Topic']['Value'] == publisher.topic_name]
    assert display['Enabled'] is True
    # A transient-local display on a volatile topic would see nothing; the reverse would
    # miss the markers published before RViz started.
    assert RVIZ_DURABILITY[display['Topic']['Durability Policy']] == qos.durability.name.lower()
    assert RVIZ_RELIABILITY[display['Topic']['Reliability Policy']] == \
        qos.reliability.name.lower()


def test_rviz_view_is_top_down_on_the_default_arena_with_y_up(rviz):
    xmin, ymin, xmax, ymax = DEFAULTS['arena']
    view = rviz['Visualization Manager']['Views']['Current']
    assert view['Class'] == 'rviz_default_plugins/TopDownOrtho'
    assert view['Angle'] == 0  # x to the right, y up
    assert (view['X'], view['Y']) == ((xmin + xmax) / 2, (ymin + ymax) / 2)
    render_height = rviz['Window Geometry']['Height'] - RVIZ_CHROME_PX
    assert view['Scale'] * (ymax - ymin) <= render_height, 'the arena does not fit'
    assert view['Scale'] * (ymax - ymin) >= render_height / 2, 'the arena is needlessly small'
    grid = displays(rviz)['rviz_default_plugins/Grid']
    assert (grid['Offset']['X'], grid['Offset']['Y']) == (view['X'], view['Y'])
    assert grid['Plane Cell Count'] * grid['Cell Size'] == xmax - xmin


# --- The launch file ----------------------------------------------------------------------

class _Recorder:
    def __repr__(self):
        return f'{type(self).__name__}({vars(self)})'


class LaunchDescription(_Recorder):
    def __init__(self, initial_entities=None, *, deprecated_reason=None):
        self.entities = list(initial_entities or [])


class DeclareLaunchArgument(_Recorder):
    def __init__(self, name, *, default_value=None, description=None, choices=None,
                 **action_kwargs):
        self.name, self.default_value = name, default_value


class IfCondition(_Recorder):
    def __init__(self, predicate_expression):
        self.predicate_expression = predicate_expression


class LaunchConfiguration(_Recorder):
    def __init__(self, variable_name, *, default=None):
        self.variable_name = variable_name

    def perform(self, context):
        return context.launch_configurations[self.variable_name]


class OpaqueFunction(_Recorder):
    def __init__(self, *, function, args=None, kwargs=None, **left_over_kwargs):
        self.function, self.args, self.kwargs = function, list(args or []), dict(kwargs or {})


class _Context:
    """What an OpaqueFunction's function reads of launch's LaunchContext."""

    def __init__(self, configuration):
        self.launch_configurations = dict(configuration)


#: Keyword arguments launch_ros's Node passes on to ExecuteProcess and Action (Jazzy).
EXECUTE_PROCESS_KWARGS = {'condition', 'output', 'emulate_tty', 'additional_env', 'env',
                          'cwd', 'prefix', 'respawn', 'respawn_delay', 'sigterm_timeout',
                          'sigkill_timeout', 'shell', 'log_cmd', 'cached_output', 'on_exit'}


class Node(_Recorder):
    def __init__(self, *, executable, package=None, name=None, namespace=None, exec_name=None,
                 parameters=None, remappings=None, ros_arguments=None, arguments=None,
                 **kwargs):
        unknown = set(kwargs) - EXECUTE_PROCESS_KWARGS
        if unknown:
            raise TypeError(f'Node() got unexpected keyword arguments {sorted(unknown)}')
        self.executable, self.package, self.namespace = executable, package, namespace
        self.arguments, self.remappings = list(arguments or []), list(remappings or [])
        self.parameters = list(parameters or [])
        self.condition = kwargs.get('condition')


def _stand_in_modules():
    modules = {}
    for name, classes in {
            'launch': [LaunchDescription],
            'launch.actions': [DeclareLaunchArgument, OpaqueFunction],
            'launch.conditions': [IfCondition], 'launch.substitutions': [LaunchConfiguration],
            'launch_ros': [], 'launch_ros.actions': [Node]}.items():
        module = types.ModuleType(name)
        for cls in classes:
            setattr(module, cls.__name__, cls)
        modules[name] = module
    return modules


@pytest.fixture
def description(monkeypatch):
    for name, module in _stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setenv('AMENT_PREFIX_PATH', sys.prefix)
    spec = importlib.util.spec_from_file_location('ball_world_launch', LAUNCH_FILE)
    launch_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch_file)
    described = launch_file.generate_launch_description()
    described.rviz_topics = launch_file.RVIZ_TOPICS
    return described


def _expand(substitution, configuration):
    if isinstance(substitution, LaunchConfiguration):
        return configuration[substitution.variable_name]
    return str(substitution)


def _is_true(text):
    """IfCondition's rule for an expanded predicate."""
    value = text.strip().lower()
    if value not in ('true', '1', 'false', '0'):
        raise ValueError(f'invalid condition expression {text!r}')
    return value in ('true', '1')


def configured(description, **arguments):
    """The launch configuration: the arguments given, the defaults for the rest."""
    configuration = {a.name: a.default_value for a in description.entities
                     if isinstance(a, DeclareLaunchArgument)}
    unknown = set(arguments) - set(configuration)
    assert not unknown, f'not a launch argument: {unknown}'
    configuration.update(arguments)
    return configuration


def nodes(description, **arguments):
    """The Nodes of the description, its OpaqueFunctions run as launch runs them."""
    context = _Context(configured(description, **arguments))
    found = []
    for entity in description.entities:
        if isinstance(entity, OpaqueFunction):
            found += entity.function(context, *entity.args, **entity.kwargs)
        elif isinstance(entity, Node):
            found.append(entity)
    return found


def started(description, **arguments):
    """Executables the description starts, given launch arguments (defaults for the rest)."""
    configuration = configured(description, **arguments)
    return [n.executable for n in nodes(description, **arguments) if (
        n.condition is None or _is_true(_expand(n.condition.predicate_expression,
                                                configuration)))]


def rviz_node(description):
    (node,) = [n for n in nodes(description) if n.executable == 'rviz2']
    return node


def test_launch_starts_rviz_only_when_asked(description):
    assert started(description) == ['ball_world']
    for no in ('false', 'False', '0'):
        assert started(description, rviz=no) == ['ball_world']
    for yes in ('true', 'True', '1'):
        assert started(description, rviz=yes) == ['ball_world', 'rviz2']
    with pytest.raises(ValueError):
        started(description, rviz='yes please')


def test_launch_gives_rviz_the_installed_configuration(description):
    node = rviz_node(description)
    assert node.package == 'rviz2'
    flag, path = node.arguments
    assert flag == '-d'
    assert Path(path) == Path(sys.prefix) / 'share' / 'ball_world' / 'rviz' / 'ball_world.rviz'
    assert Path(path).read_text() == RVIZ_FILE.read_text(), (
        'the installed configuration is not the one in rviz/: run make setup')


def test_launch_points_rviz_at_the_worlds_namespace(description, rviz):
    (world,) = [n for n in nodes(description) if n.executable == 'ball_world']
    node = rviz_node(description)
    assert isinstance(node.namespace, LaunchConfiguration)
    assert node.namespace.variable_name == world.namespace.variable_name
    # Every topic the configuration names is remapped to its relative name, which rcl
    # expands in RViz's namespace: with namespace:=sim2, /markers becomes /sim2/markers.
    named = {d['Topic']['Value'] for d in rviz['Visualization Manager']['Displays']
             if 'Topic' in d}
    assert named == set(description.rviz_topics)
    assert dict(node.remappings) == {topic: topic.lstrip('/') for topic in named}


def world_parameters(description, **arguments):
    (world,) = [n for n in nodes(description, **arguments) if n.executable == 'ball_world']
    return world.parameters


def test_launch_takes_an_installed_world_by_name_with_its_installed_map(description):
    share = Path(sys.prefix) / 'share' / 'ball_world'
    default, *rest = world_parameters(description)
    assert isinstance(default, LaunchConfiguration) and default.variable_name == 'config'
    assert [type(p) for p in rest] == [dict]  # only the record.* values over the defaults
    for name, map_name in (('sandbox', 'tb3_sandbox'), ('depot', 'depot')):
        _, world, map_override, record = world_parameters(description, world=name)
        assert Path(world) == share / 'worlds' / f'{name}.yaml'
        assert Path(world).read_text() == (ROOT / 'worlds' / f'{name}.yaml').read_text(), (
            'the installed world is not the one in worlds/: run make setup')
        # The world names its map relative to the repository; installed, the map is the
        # package's copy, whatever the working directory.
        assert map_override == {'map': str(share / 'maps' / f'{map_name}.yaml')}
        assert Path(map_override['map']).is_file()
        assert set(record) == {'record.mcap', 'record.rerun'}


def test_launch_takes_a_world_by_path_and_refuses_an_unknown_name(description, tmp_path):
    world = tmp_path / 'mine.yaml'
    world.write_text('/**:\n  ros__parameters:\n    map: maps/mine.yaml\n')
    _, path, record = world_parameters(description, world=str(world))
    assert path == str(world)  # its map stays relative to the working directory
    assert set(record) == {'record.mcap', 'record.rerun'}
    with pytest.raises(RuntimeError, match='installed: depot, sandbox'):
        world_parameters(description, world='warehouse')
