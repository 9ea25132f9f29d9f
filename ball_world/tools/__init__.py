"""Console tools for ball_world recordings and for driving a world.

Each module has main(argv=None) returning the process exit code, so tests call it directly
and setup.py's console_scripts point at it.
"""
import os
import sys


def print_report(text):
    """Print a tool's report to stdout; a reader that went away (`| head`) is no error.

    Returns False when stdout was closed by the reader: the rest of the output is then sent
    to /dev/null, so neither this print nor the interpreter's last flush raises.
    """
    try:
        print(text, flush=True)
        return True
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return False


def usage_exit(parser, message):
    """Report a command-line mistake as argparse does (one line naming the program), then
    exit 2; the tools' parsers route parser.error here to add the pointer to --help."""
    print(f'{parser.prog}: {message} (see --help)', file=sys.stderr)
    sys.exit(2)
