"""Calling user code: every way a call can end, as one UserCodeError line.

`call(what, function, *args)` returns what the function returns; any BaseException it
raises (SystemExit, GeneratorExit, a user's own; KeyboardInterrupt in a worker) becomes
UserCodeError('{what} raised {exception} (at file.py:line)'). Outside a worker a
KeyboardInterrupt is the user's Ctrl-C and passes through; in a worker SIGINT is ignored,
so one can only come from the code called. A UserCodeError raised inside (a check of what
user code returned) passes through as it is.

In a supervised worker (user_code.workers) each call also runs under a deadline:
faulthandler's watchdog thread, armed before the call and disarmed after, writes the stack
to the worker's notes and ends the process when the call outlives it, however it hangs (a
loop, a lock, a native call holding the GIL); the supervisor sees the worker end and reads
where it was.
"""
import faulthandler

from ball_world.user_code.describe import describe_exception, UserCodeError

_supervised = {'deadline': None, 'notes': None}


def supervise(deadline_s, notes):
    """Mark this process a supervised worker: calls run under `deadline_s` (None: none), the
    watchdog writing to the open file `notes`."""
    _supervised.update(deadline=deadline_s, notes=notes)


def in_worker():
    return _supervised['notes'] is not None


def call(what, function, *args):
    """function(*args), with every way it can fail turned into one UserCodeError line."""
    deadline = _supervised['deadline']
    if deadline is not None:
        faulthandler.dump_traceback_later(deadline, exit=True, file=_supervised['notes'])
    try:
        return function(*args)
    except UserCodeError:
        raise
    except BaseException as error:  # noqa: B902 - user code may raise anything
        if isinstance(error, KeyboardInterrupt) and not in_worker():
            raise
        raise UserCodeError(f'{what} raised {describe_exception(error)}') from None
    finally:
        if deadline is not None:
            faulthandler.cancel_dump_traceback_later()
