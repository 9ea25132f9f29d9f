"""Start the ball_world node with the installed defaults or a world, optionally with RViz.

    ros2 launch ball_world ball_world.launch.py record_mcap:=run.mcap record_rerun:=run.rrd
    ros2 launch ball_world ball_world.launch.py world:=sandbox rviz:=true
    ros2 launch ball_world ball_world.launch.py world:=./my_world.yaml

`world` is the name of an installed world (share/ball_world/worlds/<name>.yaml: sandbox,
depot) or the path of a parameters file; its values go over the defaults of `config`. A
relative `map` in an installed world names a map installed with the package
(share/ball_world/maps/); in a world given by path it is relative to the working directory,
as the node takes it.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
import yaml

#: Topics the RViz configuration names in the root namespace. RViz is started in the world's
#: namespace and these are remapped to relative names, so namespace:=sim2 shows /sim2's balls.
RVIZ_TOPICS = ('/map', '/markers', '/balls', '/ball_0/odom', '/ball_0/scan',
               '/ball_0/ground_truth', '/ball_1/ground_truth', '/bumper_markers')


def world_file(world, share):
    """The parameters file a `world` argument names: an installed world, or a path."""
    if os.sep in world or world.endswith(('.yaml', '.yml')):
        return os.path.abspath(world)
    path = os.path.join(share, 'worlds', world + '.yaml')
    if not os.path.isfile(path):
        known = sorted(name[:-5] for name in os.listdir(os.path.join(share, 'worlds'))
                       if name.endswith('.yaml'))
        raise RuntimeError(f"no installed world '{world}' (installed: {', '.join(known)}); "
                           'give a name or the path of a parameters file')
    return path


def installed_map(path, share):
    """{'map': absolute path} when an installed world's `map` is relative, else {}."""
    with open(path, encoding='utf-8') as stream:
        document = yaml.safe_load(stream) or {}
    for node in document.values():
        values = node.get('ros__parameters', {}) if isinstance(node, dict) else {}
        map_path = values.get('map')
        if isinstance(map_path, str) and map_path and not os.path.isabs(map_path):
            return {'map': os.path.join(share, map_path)}
    return {}


def _nodes(context, share):
    """The world's node (and RViz), with the files the launch arguments name."""
    namespace = LaunchConfiguration('namespace')
    world = LaunchConfiguration('world').perform(context)
    parameters = [LaunchConfiguration('config')]
    if world:
        path = world_file(world, share)
        parameters.append(path)
        if path.startswith(os.path.join(share, 'worlds') + os.sep):
            parameters.append(installed_map(path, share))
    parameters.append({'record.mcap': LaunchConfiguration('record_mcap'),
                       'record.rerun': LaunchConfiguration('record_rerun')})
    return [
        Node(
            package='ball_world',
            executable='ball_world',
            name='ball_world',
            namespace=namespace,
            output='screen',
            emulate_tty=True,
            parameters=parameters,
        ),
        Node(
            package='rviz2',
            executable='rviz2',
            name='rviz2',
            namespace=namespace,
            arguments=['-d', os.path.join(share, 'rviz', 'ball_world.rviz')],
            remappings=[(topic, topic.lstrip('/')) for topic in RVIZ_TOPICS],
            condition=IfCondition(LaunchConfiguration('rviz')),
        ),
    ]


def generate_launch_description():
    share = get_package_share_directory('ball_world')
    return LaunchDescription([
        DeclareLaunchArgument('config',
                              default_value=os.path.join(share, 'config', 'ball_world.yaml'),
                              description='ROS parameters file of the defaults'),
        DeclareLaunchArgument('world', default_value='',
                              description='an installed world (sandbox, depot) or the path '
                                          'of a parameters file, over the defaults; empty: '
                                          'the default world'),
        DeclareLaunchArgument('record_mcap', default_value='',
                              description='MCAP file to record to; empty records nothing'),
        DeclareLaunchArgument('record_rerun', default_value='',
                              description='Rerun .rrd file to log to; empty logs nothing'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='Namespace of the node, e.g. sim2'),
        DeclareLaunchArgument('rviz', default_value='false',
                              description='true: also start rviz2 with the ball_world view'),
        OpaqueFunction(function=_nodes, args=[share]),
    ])
