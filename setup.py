"""Installs ball_world as an ament_python package (colcon) or into a virtual environment (pip)."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'ball_world'

setup(
    name=package_name,
    version='0.1.0',
    # ball_world only: not benchmarks/ nor the test harness ball_world_testing/.
    packages=find_packages(include=['ball_world', 'ball_world.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/rviz', glob('rviz/*.rviz')),
        # Worlds to start from and the two nav2 maps they use (Apache-2.0, see maps/README.md).
        ('share/' + package_name + '/worlds', glob('worlds/*.yaml')),
        ('share/' + package_name + '/maps', glob('maps/*.yaml') + glob('maps/*.pgm')
         + ['maps/README.md']),
    ],
    install_requires=['setuptools', 'numpy'],
    zip_safe=True,
    maintainer='ball_world developers',
    maintainer_email='ball_world@example.com',
    description='An exact 2D elastic-collision world as a ROS 2 node, with MCAP and Rerun output.',
    license='Apache-2.0',
    # What colcon test reads (setuptools dropped tests_require); the full test environment is
    # requirements/base.txt and benchmarks/requirements.txt.
    extras_require={'test': ['pytest']},
    entry_points={
        'console_scripts': [
            'ball_world = ball_world.ros.node:main',
            'ball_world_info = ball_world.tools.info:main',
            'ball_world_repair = ball_world.tools.repair:main',
            'ball_world_replay = ball_world.tools.replay:main',
            'ball_world_resim = ball_world.tools.resim:main',
            'ball_world_to_rrd = ball_world.tools.to_rrd:main',
            'ball_world_sim = ball_world.tools.sim:main',
            'ball_world_teleop = ball_world.tools.teleop:main',
            'ball_world_goal = ball_world.tools.goal:main',
            'ball_world_cli = ball_world.tools.cli:main',
            'ball_world_tracker = ball_world.tools.tracker:main',
            'ball_world_score = ball_world.tools.score:main',
            'ball_world_score_scenes = ball_world.tools.score_scenes:main',
            'ball_world_view = ball_world.tools.view:main',
            'ball_world_demo = ball_world.tools.demo:main',
            'ball_world_wander = ball_world.tools.wander:main',
            'ball_world_navigate = ball_world.tools.navigate:main',
            'ball_world_view_tracks = ball_world.tools.view_tracks:main',
            'ball_world_learn = ball_world.tools.learn:main',
        ],
    },
)
