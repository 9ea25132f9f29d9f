"""The watchdog of a process joining the ROS graph: run as a child (ros/rcl_init.py starts it).

rcl_node_init can spin for good inside a C call that holds Python's GIL: Fast DDS's
shared-memory transport waits in Boost.Interprocess's open_or_create for a port segment in
/dev/shm that a process killed while making it left half-made (docs/reliability.md). Then no
thread of that process runs Python and no signal handler runs either, so nothing in it can
say why it is silent or act on Ctrl-C. This process can: its parent writes ARM before it
creates a node and DISARM after, and (while armed) Python's C-level signal handler writes the
number of every SIGINT or SIGTERM to the same pipe (signal.set_wakeup_fd), which needs no GIL.

- Armed for SECONDS: one line on stderr naming the likely cause (the half-made segments found
  in /dev/shm, or the machine's load) and the remedy.
- A signal while armed: if the parent has not disarmed GRACE seconds later, it cannot act on
  it; one line, and the parent is killed (SIGKILL: nothing is open yet, its recordings
  are opened after its node).
- The parent gone (the pipe's end, or another parent): this exits.

Only the standard library, no package import: it runs as `python -I -S node_watchdog.py`.
"""
import os
import select
import signal
import sys
import time

#: What the parent writes: a node is being created, or it is made.
ARM, DISARM = b'A', b'D'
#: Fast DDS's files in /dev/shm: its segments, port segments and their locks.
SHM = '/dev/shm'
#: Boost.Interprocess's flag at the start of a managed segment: 0 and 1 are a segment still
#: being made (a process killed then never finishes it), 2 a made one.
MADE = 2
#: How many half-made files a line names.
NAMED = 3
#: The command that clears them, safe when no ROS process runs on the machine.
REMEDY = 'rm -f /dev/shm/fastrtps_* /dev/shm/sem.fastrtps_*'


def half_made(folder=SHM, before=None):
    """Fast DDS segments in `folder` that were never finished (their Boost flag not MADE),
    last changed before `before` (a time.time(): not those being made right now)."""
    found = []
    try:
        names = sorted(os.listdir(folder))
    except OSError:
        return found
    for name in names:
        if not name.startswith('fastrtps_') or name.endswith('_el'):
            continue
        path = os.path.join(folder, name)
        try:
            with open(path, 'rb') as segment:
                if before is not None and os.fstat(segment.fileno()).st_mtime >= before:
                    continue
                head = segment.read(4)
        except OSError:
            continue
        if len(head) < 4 or int.from_bytes(head, sys.byteorder) < MADE:
            found.append(path)
    return found


def likeliest_first(found, domain):
    """The half-made files in the order a reader should see them: port segments of `domain`
    (RTPS ports 7400 + 250 d to 7649 + 250 d: the ones this process's participant opens),
    then other port segments, then the rest.

    Why: a machine where processes were killed may hold hundreds of half-made files, and a
    line names only NAMED of them; sorted by name, participants' segments (fastrtps_0...)
    came first and the port that hangs this process was left among the 'more'.
    """
    low = 7400 + 250 * domain

    def rank(path):
        name = os.path.basename(path)
        port = name.removeprefix('fastrtps_port')
        if port == name or not port.isdigit():
            return 2
        return 0 if low <= int(port) < low + 250 else 1

    return sorted(found, key=rank)  # stable: by name within a rank


def _domain():
    try:
        return int(os.environ.get('ROS_DOMAIN_ID', '0') or 0)
    except ValueError:
        return 0


def diagnosis(folder=SHM, before=None):
    """The likely cause and the remedy, as the end of one line."""
    found = likeliest_first(half_made(folder, before), _domain())
    if found:
        named = ', '.join(found[:NAMED]) + (f' and {len(found) - NAMED} more'
                                            if len(found) > NAMED else '')
        cause = ("most likely Fast DDS's shared-memory transport waiting on a segment that a "
                 f'killed process left half-made ({named})')
    else:
        load = os.getloadavg()[0]
        cause = (f"no half-made Fast DDS segment in {folder}; the machine's load average is "
                 f'{load:.1f} on {os.cpu_count()} cores')
    return (f"{cause}. With no ROS process running, remove Fast DDS's files: {REMEDY} (or run "
            'with FASTDDS_BUILTIN_TRANSPORTS=UDPv4, no shared memory)')


def watch(parent, fd, prog, seconds, grace, folder=SHM, say=None):
    """The loop (see the module doc); returns when the parent is gone or was killed."""
    say = say or (lambda line: print(line, file=sys.stderr, flush=True))
    armed = said = signalled = since = None
    while True:
        now = time.monotonic()
        waits = [1.0]  # the parent's pid is checked at least this often
        if armed is not None and not said:
            waits.append(armed + seconds - now)
        if signalled is not None:
            waits.append(signalled[0] + grace - now)
        readable, _, _ = select.select([fd], [], [], max(0.0, min(waits)))
        if readable:
            data = os.read(fd, 256)
            if not data:
                return
            for byte in data:
                if byte == ARM[0]:
                    armed, said, signalled = time.monotonic(), False, None
                    since = time.time()
                elif byte == DISARM[0]:
                    armed = signalled = None
                elif armed is not None and signalled is None:
                    signalled = (time.monotonic(), byte)
        if os.getppid() != parent:
            return
        now = time.monotonic()
        if armed is not None and not said and now - armed >= seconds:
            said = True
            say(f'{prog}: no ROS node after {seconds:g} s (rcl_node_init has not returned): '
                f'{diagnosis(folder, since)}; Ctrl-C ends this')
        if signalled is not None and now - signalled[0] >= grace:
            name = _signal_name(signalled[1])
            say(f'{prog}: {name} while its ROS node was being made, and rcl_node_init has not '
                f'returned for {now - armed:.1f} s: ending it'
                + ('' if said else f'; {diagnosis(folder, since)}'))
            try:
                os.kill(parent, signal.SIGKILL)
            except OSError:
                pass
            return


def _signal_name(number):
    try:
        return signal.Signals(number).name
    except ValueError:
        return f'signal {number}'


def main(argv):
    parent, fd, prog, seconds, grace = argv[1:6]
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # its parent's signals come through the pipe
    watch(int(parent), int(fd), prog, float(seconds), float(grace))


if __name__ == '__main__':
    main(sys.argv)
