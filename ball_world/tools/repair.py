"""ball_world_repair: make a recording whose writer was killed, or whose disk damaged it,
readable by every tool again.

What it is given decides the repair: an MCAP file (tools.repair_mcap), a bag directory of
split MCAP files (tools.repair_bag, in place), an .rrd file (tools.repair_rrd, through
Rerun's own reader), or the name of a split .rrd whose parts `<name>_<i>.rrd` lie beside it
(each part repaired in place, recording.rrd_parts). This module is only the command line:
it imports the repairs, none of them imports it.

Exit status: 0 when everything is readable and nothing was lost but what a killed writer
had not finished (a torn last record); 1 when repair wrote what could be kept but recorded
data is lost for good (a damaged chunk, a listed file that is gone, a file that cannot be
read at all), each named in the report; 2 when nothing was written (one line on stderr).
"""
import argparse
import os
import sys

from ball_world.recording.mcap_reader import RecordingError
from ball_world.tools import print_report, repair_mcap
from ball_world.tools.repair_mcap import default_target, describe, repair, RepairReport

PROG = repair_mcap.PROG

__all__ = ['default_target', 'describe', 'main', 'repair', 'RepairReport']


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog=PROG,
        description='Recover a damaged recording (writer killed: an MCAP without summary, '
                    'an .rrd without footer, a torn last record; or a corrupt chunk) into a '
                    'complete file holding every readable record; a bag directory of split '
                    'files, or the parts of a split .rrd, are repaired in place. Exit 0: '
                    'nothing lost but a torn end; 1: written, but some recorded data is lost '
                    '(the report names it); 2: nothing written.')
    parser.add_argument('input', help='the damaged .mcap or .rrd (Rerun), a bag directory, or '
                                      'the .rrd name of split parts NAME_<i>.rrd')
    parser.add_argument('-o', '--output', help='where to write (default: '
                                               'INPUT.repaired.mcap or .rrd; may be INPUT '
                                               'itself)')
    parser.add_argument('--force', action='store_true',
                        help='replace the output file if it exists')
    args = parser.parse_args(argv)
    if os.path.isdir(args.input):
        return _main_bag(args)
    if args.input.endswith('.rrd'):
        return _main_rrd(args)
    target = args.output or default_target(args.input)
    return _reported(args, lambda: repair(args.input, target, args.force),
                     lambda report: (describe(report, args.input, target), report.lost_data))


def _main_bag(args):
    """A bag directory of split files: repaired in place (tools.repair_bag)."""
    from ball_world.tools.repair_bag import check_bag, repair_bag

    def work():
        if args.output:
            check_bag(args.input)
            raise RecordingError('a bag directory is repaired in place; -o is for one file')
        return repair_bag(args.input)
    return _reported(args, work, lambda report: ('\n'.join(report.lines), report.lost))


def _main_rrd(args):
    """An .rrd file (tools.repair_rrd), or the name of split parts beside it."""
    from ball_world.recording.rrd_parts import part_names
    from ball_world.tools.repair_rrd import describe as describe_rrd, repair_parts, repair_rrd
    if not os.path.lexists(args.input) and part_names(args.input):
        def work():
            if args.output:
                raise RecordingError('the parts of a split .rrd are repaired in place; -o is '
                                     'for one file')
            return repair_parts(args.input)
        return _reported(args, work, lambda report: ('\n'.join(report.lines), report.lost))
    target = args.output or default_target(args.input)
    return _reported(args, lambda: repair_rrd(args.input, target, args.force),
                     lambda report: (describe_rrd(report, args.input, target), False))


def _reported(args, work, text):
    """Do `work`, print the text of its result; return the exit code (see the module).

    text(result): (report text, whether recorded data was lost). One place for how every
    repair reports failure: an unreadable recording named with its path, an OS error
    (which names its own path) as it is.
    """
    try:
        result = work()
    except RecordingError as error:
        print(f'{PROG}: {args.input}: {error}', file=sys.stderr)
        return 2
    except OSError as error:
        print(f'{PROG}: {error}', file=sys.stderr)
        return 2
    report, lost = text(result)
    print_report(report)
    if lost:
        print(f'{PROG}: {args.input}: some recorded data could not be kept (see DAMAGED, '
              'gone or cannot be read above)', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
