"""ball_world_view: a world live in the browser, in one command (what `make view` runs).

Starts Rerun's web viewer server on localhost (the page on --web-port, the gRPC stream the
page reads and the world sends to on --grpc-port), then the world streaming to it, prints
the address to open, and runs until Ctrl-C (or until the world stops: --steps). Any way out
stops both, the world first so it closes its recordings; the server never outlives this
program (tools/processes.py), so its ports are free again as soon as it has returned.

The server keeps only the last SERVER_MEMORY of what it relayed, for pages opened
later: a web viewer rendering in software takes in a backlog slowly and shows nothing new
meanwhile, so a page opened an hour in gets the last seconds, not the hour. The world logs
the layout, the arena's flip, the map, the ruler and the balls' looks static; the server
drops timed data first, but once none is left it drops the oldest static data too, so
SERVER_MEMORY holds a world's statics (123-176 kB for the shipped worlds,
test/test_view_server_memory.py) with room for the last second or two of frames.

    ball_world_view [--world FILE] [--steps N] [--ros-args -p NAME:=VALUE ...]
"""
import argparse
from pathlib import Path
import sys
import time
import uuid

from ball_world.tools import usage_exit
from ball_world.tools.processes import (Children, hold_signals, port_free, raise_on_signals,
                                        rerun_binary, say, Stop, wait_for_port)

PROG = 'ball_world_view'
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
#: What the server keeps for pages opened later (see the module doc).
SERVER_MEMORY = '256KiB'
#: Seconds of path drawn behind each ball.
TRAIL_SECONDS = 1.0


def proxy_url(grpc_port):
    return f'rerun+http://127.0.0.1:{grpc_port}/proxy'


def page_url(web_port, grpc_port):
    """The address of the page that shows the stream of grpc_port."""
    return (f'http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}'
            '%2Fproxy')


def server_command(grpc_port, web_port, memory=SERVER_MEMORY):
    """Rerun's web viewer and gRPC proxy on 127.0.0.1, keeping `memory` for late pages."""
    return [rerun_binary(), '--serve-web', '--bind', '127.0.0.1', '--port', str(grpc_port),
            '--web-viewer-port', str(web_port), '--server-memory-limit', memory,
            '--hide-welcome-screen']


def world_command(grpc_port, world=None, steps=0, ros_args=(), recording_id=None,
                  executable=None):
    """The world node streaming to the server; the user's ROS arguments come last, so they
    override these."""
    executable = executable or Path(sys.executable).parent / 'ball_world'
    command = [executable, '--ros-args']
    if world is not None:
        command += ['--params-file', world]
    command += ['-p', f'view.rerun:={proxy_url(grpc_port)}',
                '-p', f'rerun.trail_seconds:={TRAIL_SECONDS}', '-p', f'max_steps:={steps}',
                '-p', f'view.recording_id:={recording_id or uuid.uuid4()}']
    return command + [arg for arg in ros_args if arg != '--ros-args']


def split_ros_args(argv):
    """(this program's arguments, the ROS arguments from --ros-args on)."""
    if '--ros-args' in argv:
        at = argv.index('--ros-args')
        return argv[:at], argv[at:]
    return argv, []


def parser(prog=PROG, description=None):
    parser = argparse.ArgumentParser(
        prog=prog, description=description or __doc__.splitlines()[0],
        epilog='ROS arguments for the world go after --ros-args, e.g. '
               f'{prog} --world worlds/sandbox.yaml --ros-args -p agents:=[ball_0]')
    parser.add_argument('--world', type=Path, metavar='FILE',
                        help='a ROS parameters file for the world (default: the default '
                             'world)')
    parser.add_argument('--steps', type=int, default=0, metavar='N',
                        help='stop after N steps (default 0: run until Ctrl-C)')
    parser.add_argument('--web-port', type=int, default=DEFAULT_WEB_PORT, metavar='PORT',
                        help=f'port of the viewer page (default {DEFAULT_WEB_PORT})')
    parser.add_argument('--grpc-port', type=int, default=DEFAULT_GRPC_PORT, metavar='PORT',
                        help=f'port of the stream the page reads (default {DEFAULT_GRPC_PORT})')
    parser.add_argument('--server-memory', default=SERVER_MEMORY, metavar='SIZE',
                        help='what the server keeps for pages opened later: the '
                             "world's static data and the last frames "
                             f'(default {SERVER_MEMORY})')
    parser.add_argument('--log-dir', type=Path, default=Path('runs/view'), metavar='DIR',
                        help="where the server's log goes (default runs/view)")
    parser.error = lambda message: usage_exit(parser, message)
    return parser


def check_arguments(parser, args):
    """Refuse what cannot work, in one line, before anything starts."""
    if args.world is not None and not args.world.is_file():
        parser.error(f'--world {str(args.world)!r}: no such file')
    if args.steps < 0:
        parser.error(f'--steps must be >= 0, got {args.steps}')
    for name in ('web_port', 'grpc_port'):
        port = getattr(args, name)
        if not 1 <= port <= 65535:
            parser.error(f"--{name.replace('_', '-')} must be from 1 to 65535, got {port}")
    if args.web_port == args.grpc_port:
        parser.error('--web-port and --grpc-port must differ')
    for port in (args.grpc_port, args.web_port):
        if not port_free(port):
            say(parser.prog, f'port {port} on 127.0.0.1 is taken (another viewer?); free it '
                             'or choose others with --web-port / --grpc-port')
            sys.exit(1)


def start_server(children, args, prog=PROG):
    """The Rerun server, up and accepting the world's stream; None if it did not start."""
    server = children.start('rerun_server', server_command(args.grpc_port, args.web_port,
                                                           args.server_memory))
    if not wait_for_port(args.grpc_port, server):
        say(prog, f'the Rerun server did not start; see {args.log_dir / "rerun_server.log"}')
        return None
    return server


def watch(children, prog=PROG):
    """Wait until a child ends (the world at --steps, or a crash); say which if unexpected."""
    while True:
        ended = children.first_ended()
        if ended is not None:
            code = ended.process.returncode
            if ended.name != 'world' or code != 0:
                say(prog, f'{ended.name} ended (exit {code}); stopping the rest')
            return 0 if code == 0 else 1
        time.sleep(0.2)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    own, ros_args = split_ros_args(argv)
    command_line = parser()
    args = command_line.parse_args(own)
    check_arguments(command_line, args)
    children = Children(args.log_dir)
    code = 0
    raise_on_signals()
    try:
        if start_server(children, args) is None:
            return 1
        print(f'\n  Open {page_url(args.web_port, args.grpc_port)}\n'
              '  (the page takes 5-30 s to load; Ctrl-C stops the world and the server)\n',
              flush=True)
        children.start('world', world_command(args.grpc_port, args.world, args.steps,
                                              ros_args), log=False)
        code = watch(children)
    except Stop:
        code = 0
    finally:
        hold_signals()
        children.stop()
    return code


if __name__ == '__main__':
    sys.exit(main())
