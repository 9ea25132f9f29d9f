"""Start the ball_world node with the installed defaults, optionally recording and with RViz.

    ros2 launch ball_world ball_world.launch.py record_mcap:=run.mcap record_rerun:=run.rrd
    ros2 launch ball_world ball_world.launch.py rviz:=true
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

#: Topics the RViz configuration names in the root namespace. RViz is started in the world's
#: namespace and these are remapped to relative names, so namespace:=sim2 shows /sim2's balls.
RVIZ_TOPICS = ('/markers', '/balls', '/ball_0/odom', '/ball_0/scan')


def generate_launch_description():
    share = get_package_share_directory('ball_world')
    namespace = LaunchConfiguration('namespace')
    return LaunchDescription([
        DeclareLaunchArgument('config',
                              default_value=os.path.join(share, 'config', 'ball_world.yaml'),
                              description='ROS parameters file of the world'),
        DeclareLaunchArgument('record_mcap', default_value='',
                              description='MCAP file to record to; empty records nothing'),
        DeclareLaunchArgument('record_rerun', default_value='',
                              description='Rerun .rrd file to log to; empty logs nothing'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='Namespace of the node, e.g. sim2'),
        DeclareLaunchArgument('rviz', default_value='false',
                              description='true: also start rviz2 with the ball_world view'),
        Node(
            package='ball_world',
            executable='ball_world',
            name='ball_world',
            namespace=namespace,
            output='screen',
            emulate_tty=True,
            parameters=[
                LaunchConfiguration('config'),
                {'record.mcap': LaunchConfiguration('record_mcap'),
                 'record.rerun': LaunchConfiguration('record_rerun')},
            ],
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
    ])
