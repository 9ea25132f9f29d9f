"""Test isolation for ROS: every pytest process gets its own DDS domain, on localhost only.

Tests that start the node as a subprocess inherit these variables, so two test runs on
one machine (or a user's own nodes) can never hear each other.
"""
import os

if 'BALL_WORLD_TEST_DOMAIN' not in os.environ:
    os.environ['BALL_WORLD_TEST_DOMAIN'] = str(1 + os.getpid() % 200)
os.environ['ROS_DOMAIN_ID'] = os.environ['BALL_WORLD_TEST_DOMAIN']
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
