"""rclpy.init with one line for the user when rcl refuses the command line.

rcl reports a bad `--ros-args` (a params file that is missing or is not valid YAML, a
malformed `-p`) by logging its own `[ERROR] ... [rcl]: Failed to parse global arguments`
straight to the process's stderr, then raising an exception whose text names C source
files. The node promises one clear line for bad input, so rcl's own output is held back
while it parses (file descriptor 2 goes to a temporary file), and the failure is told in
one line without the source locations. When rcl starts fine, what it wrote is passed on.
"""
import os
import re
import sys
import tempfile

import rclpy

#: ", at /project/src/rcl/arguments.c:415" and the like: where in rcl, not what is wrong.
_SOURCE_LOCATION = re.compile(r',? at [^\s,]+\.c:\d+')


def init_quietly(args):
    """rclpy.init(args=args); None when it started, else the one line saying why not."""
    unreadable = _unreadable_params_file(sys.argv if args is None else args)
    if unreadable is not None:
        return unreadable
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as held:
            os.dup2(held.fileno(), 2)
            try:
                rclpy.init(args=args)
                failure = None
            except Exception as error:  # noqa: B902 - rcl reports bad arguments generically
                failure = error
            finally:
                os.dup2(saved, 2)
            if failure is None:
                held.seek(0)
                sys.stderr.write(held.read().decode('utf-8', errors='replace'))
                return None
    finally:
        os.close(saved)
    return describe(failure)


def _unreadable_params_file(argv):
    """Why a --params-file of the ROS arguments cannot be read (rcl says only "Error
    opening YAML file"), or None."""
    argv = list(argv)
    for flag, path in zip(argv, argv[1:]):
        if flag == '--params-file':
            try:
                with open(path, 'rb'):
                    pass
            except OSError as error:
                return f'params file {path!r}: {error.strerror or error}'
    return None


def describe(error):
    """rcl's exception text as one line, without its C source locations."""
    text = _SOURCE_LOCATION.sub('', ' '.join(str(error).split()))
    text = text.replace('failed to initialize rcl: ', '')
    return text.rstrip('. ') or type(error).__name__
