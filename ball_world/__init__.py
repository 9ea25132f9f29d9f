"""ball_world: an exact, deterministic 2D elastic-collision world for ROS 2."""

__version__ = '0.1.0'
