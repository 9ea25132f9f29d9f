"""A user's code (a tracker class, its module) failing: one line that says what and where.

The benchmark runs trackers it did not write; their exceptions are reported as the tool's
own errors are, in one line (the exception and the file and line it was raised at), never
as a traceback of ball_world's internals.
"""
import os
import traceback


def describe_exception(error):
    """One line for an exception raised in a user's code: what and where."""
    where = ''
    frames = traceback.extract_tb(error.__traceback__)
    if frames:
        last = frames[-1]
        where = f' (at {os.path.basename(last.filename)}:{last.lineno})'
    return f'{type(error).__name__}: {error}{where}'
