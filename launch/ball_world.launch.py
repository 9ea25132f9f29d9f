"""Start the ball_world node with the installed defaults, optionally recording.

    ros2 launch ball_world ball_world.launch.py record_mcap:=run.mcap record_rerun:=run.rrd
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_config = os.path.join(
        get_package_share_directory('ball_world'), 'config', 'ball_world.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('config', default_value=default_config,
                              description='ROS parameters file of the world'),
        DeclareLaunchArgument('record_mcap', default_value='',
                              description='MCAP file to record to; empty records nothing'),
        DeclareLaunchArgument('record_rerun', default_value='',
                              description='Rerun .rrd file to log to; empty logs nothing'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='Namespace of the node, e.g. sim2'),
        Node(
            package='ball_world',
            executable='ball_world',
            name='ball_world',
            namespace=LaunchConfiguration('namespace'),
            output='screen',
            emulate_tty=True,
            parameters=[
                LaunchConfiguration('config'),
                {'record.mcap': LaunchConfiguration('record_mcap'),
                 'record.rerun': LaunchConfiguration('record_rerun')},
            ],
        ),
    ])
