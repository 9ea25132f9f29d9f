"""What happened to a user's code, in one line: an exception, an exit, a signal, a deadline.

Everything here turns a way user code can end into text that names what happened and, when
it is known, where (the file and line of the user's frame nearest the failure). Values a
user returned are shown by `shown`, which never fails and never grows past a line (the repr
of an int of 5,000 digits raises, and one of 400 digits is no line to read).
"""
import os
import signal
import sys
import sysconfig
import traceback


class UserCodeError(ValueError):
    """User code that failed or returned what cannot be used; the message is one line."""


#: Longest rendering of a value in a message.
SHOWN_CHARACTERS = 60
#: The first line the worker writes when user code calls os._exit.
EXIT_NOTE = 'os._exit('
_OURS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # ball_world/
_LIBRARY = tuple(os.path.abspath(path) for path in {
    sysconfig.get_paths().get('stdlib'), sysconfig.get_paths().get('platstdlib')} if path)


def shown(value):
    """A short, safe rendering of any value for a one-line message."""
    try:
        if isinstance(value, int) and not isinstance(value, bool) and \
                value.bit_length() > 200:
            return f'an int of {len(str(abs(value))) if value.bit_length() < 10_000 else "many"}' \
                ' digits'
        text = repr(value)
    except Exception:  # noqa: B902 - a user's __repr__ may raise anything
        text = f'<a {type(value).__name__} whose repr fails>'
    text = ' '.join(text.split())
    if len(text) > SHOWN_CHARACTERS:
        text = text[:SHOWN_CHARACTERS - 3] + '...'
    return text


def _is_user_file(filename):
    path = os.path.abspath(filename)
    return not (path.startswith(_OURS + os.sep) or path.startswith(_LIBRARY)
                or filename.startswith('<'))


def where(locations):
    """' (at file.py:line)' for the nearest user frame of [(filename, line)] (innermost
    last), or of the innermost frame when none is the user's; '' when there is none."""
    if not locations:
        return ''
    users = [location for location in locations if _is_user_file(location[0])]
    filename, line = (users or locations)[-1]
    return f' (at {os.path.basename(filename)}:{line})'


def describe_exception(error):
    """One line for an exception (any BaseException) raised in a user's code."""
    frames = traceback.extract_tb(error.__traceback__)
    try:
        text = ' '.join(str(error).split())
    except Exception:  # noqa: B902 - a user's __str__ may raise anything
        text = '<its text could not be made>'
    if len(text) > 200:
        text = text[:197] + '...'
    name = type(error).__name__
    return (f'{name}: {text}' if text else name) + where(
        [(frame.filename, frame.lineno) for frame in frames])


def describe_exit(exitcode):
    """'exited with status 3', 'killed by SIGSEGV' for a process's exit code."""
    if exitcode is None:
        return 'is still running'
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f'signal {-exitcode}'
        return f'killed by {name}'
    return f'exited with status {exitcode}'


#: How a report in a dying worker's notes begins (faulthandler's, and the worker's own).
HEADERS = ('Fatal Python error', 'Timeout (', EXIT_NOTE)


def parse_notes(text):
    """(what, [(filename, line)] innermost last) of a dying worker's notes: the traceback
    faulthandler writes on a fatal signal or a deadline, or the lines the worker's os._exit
    writes. ('', []) when there are none."""
    lines = text.splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith(HEADERS)]
    if not starts:
        return '', []
    block = lines[starts[-1]:]
    locations, threads = [], 0
    for line in block[1:]:
        line = line.strip()
        if line.startswith(('Thread ', 'Current thread ')):
            threads += 1
            if threads > 1:
                break  # the first thread listed: the one that failed
        elif line.startswith('File "') and '", line ' in line:
            filename, _, rest = line[len('File "'):].partition('", line ')
            number = rest.split(' ', 1)[0]
            if number.isdigit():
                locations.append((filename, int(number)))
        elif locations and not line:
            break
    return block[0].strip(), locations[::-1]


def stderr_line(prog, text):
    """Print `prog: text` on stderr as one line."""
    print(f"{prog}: {' '.join(str(text).split())}", file=sys.stderr, flush=True)
