"""Console tools for ball_world recordings: info, repair, resim, replay.

Each module has main(argv=None) returning the process exit code, so tests call it directly
and setup.py's console_scripts point at it.
"""
