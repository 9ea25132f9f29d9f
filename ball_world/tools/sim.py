"""ball_world_sim: run a world without ROS, as fast as it goes, and say how fast.

`ball_world_sim --params-file FILE.yaml [--controller MODULE:Class] --steps N [--record
FILE.mcap]` steps the Simulation the node would run from the same parameters file (its
`/**` or `ball_world` section, `map` relative to the working directory, as the node reads
it), with the controller of `--controller` (or of the file's `controller`) driving its
agents exactly as it does in the node: the same observations at the same steps, so the
same trajectories bit for bit. `--record` writes the node's MCAP (the controller's
commands in it), which ball_world_resim re-simulates without the controller's code. It
prints the world, then steps per second and the real-time factor (simulated seconds per
wall second). Without --params-file it runs the default world.

Exit status: 0 done, 1 the controller failed (one line says how and when), 2 bad input,
130 interrupted (the recording is closed whole up to the last step).
"""
import argparse
import difflib
import sys
import time

from ball_world.core import parameters as table
from ball_world.core.parameters import ParameterError
from ball_world.core.scenario import describe, ScenarioError
from ball_world.params_file import ParamsFileError, read_parameters
from ball_world.user_code.describe import UserCodeError

PROGRAM = 'ball_world_sim'
#: Most steps one run may take (a day at 1 kHz is 86,400,000).
MAX_STEPS = 10**12


def _steps(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a whole number of steps, got '
                                         f'{text[:40]!r}') from None
    if not 1 <= value <= MAX_STEPS:
        raise argparse.ArgumentTypeError(f'{value:,} steps: expected 1 to {MAX_STEPS:,}')
    return value


def parser():
    made = argparse.ArgumentParser(prog=PROGRAM, description=__doc__.split('\n\n')[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    made.add_argument('--params-file', metavar='FILE.yaml',
                      help="the world's parameters, as the node takes them "
                           '(--ros-args --params-file); default: the default world')
    made.add_argument('--controller', metavar='MODULE:Class',
                      help="a controller driving the agents (overrides the file's "
                           "`controller`): 'package.module:Class' or 'path/to/file.py:Class'")
    made.add_argument('--steps', type=_steps, default=600, help='steps to run (default 600)')
    made.add_argument('--record', metavar='FILE.mcap',
                      help='record the run as the node records it (MCAP)')
    made.add_argument('--overwrite', action='store_true',
                      help='record over an existing file')
    return made


def parameters_of(args):
    """The run's parameters, checked (ValueError: one line)."""
    values = {}
    if args.params_file:
        values = read_parameters(args.params_file)
        for name in values:
            if name not in table.BY_NAME:
                close = difflib.get_close_matches(name, table.BY_NAME, n=1)
                print(f"{PROGRAM}: warning: ignoring unknown parameter '{name}'"
                      + (f"; did you mean '{close[0]}'?" if close else ''), file=sys.stderr)
    if args.controller is not None:
        values['controller'] = args.controller
    return table.checked(values)


def run(args):
    """Build, step and report; returns the exit status."""
    from ball_world.simulation import build, Simulation
    try:
        values = parameters_of(args)
        built = build(values)
    except (ParamsFileError, ParameterError, ScenarioError) as error:
        print(f'{PROGRAM}: {error}', file=sys.stderr)
        return 2
    controller = None
    sinks = []
    try:
        if values['controller']:
            from ball_world.user_code.controller import ControllerProcess
            controller = ControllerProcess(values['controller'])
        if args.record:
            from ball_world.recording.mcap_writer import McapSink
            sinks.append(McapSink(args.record, overwrite=args.overwrite))
    except UserCodeError as error:
        print(f"{PROGRAM}: parameter 'controller': {error}", file=sys.stderr)
        _close(controller, sinks)
        return 2
    except OSError as error:
        print(f'{PROGRAM}: --record: cannot record to {error}', file=sys.stderr)
        _close(controller, sinks)
        return 2
    simulation = Simulation(values, sinks, built=built, controller=controller)
    if not sinks:
        # Nobody reads the robots' messages (odom, ground truth, /tf, LaserScan bytes):
        # none is made, as the node makes none nobody subscribes to.
        simulation.agents.encode = frozenset()
    print(describe(simulation.world, simulation.dt_ns)
          + (f"; controller {values['controller']} at {values['controller.rate_hz']:g} Hz"
             if controller is not None else ''), flush=True)
    status = 0
    taken = 0
    start = time.perf_counter()
    try:
        for _ in range(args.steps):
            if simulation.out_of_time:
                print(f'{PROGRAM}: one more step would pass the last time a ROS stamp can '
                      'carry (2^31 s); stopping', file=sys.stderr)
                break
            simulation.step()
            taken += 1
    except UserCodeError as error:
        print(f'{PROGRAM}: step {simulation.step_index + 1}: {error}', file=sys.stderr)
        status = 1
    except KeyboardInterrupt:
        print(f'{PROGRAM}: interrupted at step {simulation.step_index}', file=sys.stderr)
        status = 130
    finally:
        elapsed = time.perf_counter() - start
        simulation.close()
        if controller is not None:
            controller.close()
    simulated = taken * simulation.dt_ns * 1e-9
    rate = taken / elapsed if elapsed > 0 else float('inf')
    factor = simulated / elapsed if elapsed > 0 else float('inf')
    print(f'{taken:,} steps in {elapsed:.3f} s: {rate:,.0f} steps/s, real-time factor '
          f'{factor:.3g} ({simulated:.6g} s simulated)'
          + (f'; recorded to {args.record}' if args.record else ''))
    return status


def _close(controller, sinks):
    if controller is not None:
        controller.close()
    for sink in sinks:
        sink.close()


def main(argv=None):
    args = parser().parse_args(argv)
    try:
        return run(args)
    except KeyboardInterrupt:
        print(f'{PROGRAM}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
