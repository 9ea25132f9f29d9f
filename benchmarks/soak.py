"""ball_world_soak: long reliability runs of the node, each ending in one result table row.

The test suite checks each failure mode once, quickly; these runs repeat them long enough to
give figures: how much a SIGKILL loses over many kills, whether an impulse flood is applied
in full, whether the core stays exact over a million steps, whether memory grows over
minutes of recording, what a full disk under both recordings does to the node. Two cases
measure the node's speed the way a user meets it: `rtf` (the real-time factor of a 10,000
ball world at 100 Hz while publishing and recording, with the CPU time of each thread) and
`startup` (process start to the first `balls` message a probe hears). Every case prints
progress to stderr and one Markdown table row (case | what happened | figure) to stdout, and
exits 0 when its checks held, 1 when one failed, 2 when it could not run.

The node runs as a subprocess (the installed `ball_world`, found as the tests find it), in its
own namespace /soak_<pid>, so a soak never hears another ball_world on the same ROS domain.
The node process, the listener, the readers and the Rerun CLI are the test harness's
(ball_world_testing.harness), imported by the cases that use them with ROS and Rerun, so
`steps` runs without ROS.
"""
import argparse
import contextlib
import io
import math
import multiprocessing
import os
from pathlib import Path
import re
import shutil
import signal
import sys
import tempfile
import time

import numpy as np

from ball_world.msgs.cdr import decode_pose_array, decode_state_layout

#: Simulated seconds per step in every node run here.
DT = 0.01
#: Seconds to wait for DDS discovery, a node to start or to stop, before calling it a hang.
DEADLINE = 120.0
#: The real-time factor in the node's progress line ('step 1000: 99.9 steps/s, real-time
#: factor 0.999; impulses applied ...').
REAL_TIME_FACTOR = re.compile(r'real-time factor (\d+(?:\.\d*)?)')
TABLE_HEADER = '| case | what happened | figure |\n|---|---|---|'


class SoakError(Exception):
    """The run could not be carried out (exit 2); the message says why."""


def progress(text):
    print(text, file=sys.stderr, flush=True)


_header_printed = []


def row(case, what, figure):
    """Print a result row, under the table header the first time."""
    if not _header_printed:
        print(TABLE_HEADER)
        _header_printed.append(True)
    print(f'| {case} | {what} | {figure} |', flush=True)


def rss_mb(pid=None):
    """Resident memory of a process (this one by default), MiB."""
    import psutil
    return psutil.Process(pid).memory_info().rss / 2**20


def rrd_writers(pid=None):
    """The .rrd writer processes (recording.rerun_process) that a process started."""
    import psutil
    found = []
    for child in psutil.Process(pid).children():
        try:
            if 'ball_world.recording.rerun_process' in child.cmdline():
                found.append(child)
        except psutil.Error:
            pass
    return found


def writer_rss_mb(pid=None):
    """Resident memory of the .rrd writer that a process started, MiB; 0 without one."""
    import psutil
    try:
        return sum(writer.memory_info().rss for writer in rrd_writers(pid)) / 2**20
    except psutil.Error:
        return 0.0


# The node as a subprocess ---------------------------------------------------------------------

def _harness():
    """The test harness, imported by the cases that use it: with it come ROS and Rerun."""
    from ball_world_testing import harness
    return harness


class NodeProcess:
    """The node in a subprocess, with its output in a log file (a pipe could fill and block)."""

    def __init__(self, workdir, namespace, name, parameters, **options):
        """options: the harness's start() options (env, limit_file_size...)."""
        self.log_path = Path(workdir) / f'{name}.log'
        self.process = _harness().start_node(
            *(f'{key}:={value}' for key, value in parameters.items()),
            ros_args=['-r', f'__ns:={namespace}'], log=self.log_path, **options)
        self.pid = self.process.pid

    def log(self):
        return self.log_path.read_text(errors='replace')

    def check_alive(self):
        _harness().check_running(self.process)

    def stop(self, sig=signal.SIGINT):
        """Send sig and wait for the exit code (SIGKILL and a failure after DEADLINE)."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        return _harness().finish(self.process, DEADLINE)[0]

    def kill(self):
        _harness().kill(self.process)

    def real_time_factors(self):
        """The real-time factors of the node's 10 s progress lines."""
        return [float(value) for value in REAL_TIME_FACTOR.findall(self.log())]


def world_parameters(args, seed=0):
    """Node parameters of a world of args.balls random balls, loosely packed (~8% of a box)."""
    side = arena_side(args.balls)
    return {'random.count': args.balls, 'random.seed': seed,
            'arena': f'[0.0, 0.0, {side}, {side}]', 'markers.rate_hz': 0.0, 'dt': DT,
            'physics.backend': args.backend, 'physics.mode': args.mode}


def arena_side(balls):
    """Side of a square arena that random balls (mean area ~0.13 m^2) fill to about 8%."""
    return float(max(10, math.ceil(math.sqrt(balls * 0.13 / 0.08))))


class Listener:
    """A probe (a node in its own context) that hears the soaked node's `balls` and `stats`.

    It takes the messages as CDR bytes and decodes only what it needs with ball_world.msgs.cdr:
    rclpy's conversion of a 1,000-pose PoseArray would cost this process a whole core at
    100 Hz, taken from the node it measures.
    """

    def __init__(self, namespace, stats=False, dt=None):
        from geometry_msgs.msg import PoseArray
        self.dt = DT if dt is None else dt
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64MultiArray
        self.probe = _harness().Probe('soak_listener')
        self.last_step = -1
        self.heard = 0
        #: time.perf_counter() at the first two `balls` messages (step 0, then step 1).
        self.first_arrivals = []
        self.real_time_factor = math.nan
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.subscription = self.probe.node.create_subscription(
            PoseArray, f'{namespace}/balls', self._on_balls, qos, raw=True)
        if stats:
            self.probe.node.create_subscription(Float64MultiArray, f'{namespace}/stats',
                                                self._on_stats, qos, raw=True)

    def _on_balls(self, data):
        if len(self.first_arrivals) < 2:
            self.first_arrivals.append(time.perf_counter())
        stamp_ns = decode_pose_array(data)[0]
        self.last_step = max(self.last_step, round(stamp_ns / (self.dt * 1e9)))
        self.heard += 1

    def _on_stats(self, data):
        self.real_time_factor = float(decode_state_layout(data)[2][-1])

    def spin(self, seconds=0.05):
        self.probe.executor.spin_once(timeout_sec=seconds)

    def spin_until(self, predicate, what, node):
        """Spin until predicate() holds; fail after DEADLINE or if the node exits first."""
        self.probe.spin_until(predicate, what, DEADLINE, node.process)

    def drain(self):
        """Take what is already queued: messages the node sent just before it died."""
        self.probe.drain(lambda: self.heard)

    def close(self):
        self.probe.close()


def namespace():
    return f'/soak_{os.getpid()}'


# kill -----------------------------------------------------------------------------------------

def check_readers(path, topic):
    """Open a repaired file with mcap, mcap_ros2 and rosbags; {reader: `topic` count or error}.

    Each reader decodes what it reads (but mcap, which gives bytes and must find the summary).
    """
    seen = {}
    for name, read in _harness().READERS.items():
        try:
            seen[name] = len(read(path, [topic]))
        except Exception as error:  # noqa: B902 - any reader failure is the finding
            seen[name] = f'{type(error).__name__}: {error}'
    return seen


def rerun_cli(*args):
    """Run the Rerun CLI: (exit code, what it said, files as <file>)."""
    done = _harness().run_rerun(*args, timeout=DEADLINE)
    text = done.stdout + done.stderr
    for arg in args:
        if isinstance(arg, Path):
            text = text.replace(f'"{arg}"', '<file>').replace(str(arg), '<file>')
    lines = [line.strip() for line in text.splitlines() if line.strip() and 'INFO' not in line]
    return done.returncode, ' / '.join(lines)


def rrd_steps(path):
    """The steps of ball positions Rerun's Python reader reads (all recordings), or its error."""
    try:
        return sorted(step for steps in _harness().rrd_ball_steps(path) for step in steps)
    except Exception as error:  # noqa: B902 - what the reader does is the finding
        return f'{type(error).__name__}: {error}'.replace(str(path), '<file>')


def rrd_findings(path, last_mcap_step):
    """What a SIGKILLed .rrd keeps, as Rerun's own tools see it (a dict of findings).

    verify: `rerun rrd verify` (checks the footer); lenient: the same with --check-footers
    false; reader: the steps rr.chunk.RrdReader reads from the file as it is (or its error);
    merged: whether `rerun rrd merge` rewrites it into a file that verifies, and its steps.
    """
    path = Path(path)
    merged = path.with_suffix('.merged.rrd')
    findings = {'verify': rerun_cli('rrd', 'verify', path),
                'lenient': rerun_cli('rrd', 'verify', '--check-footers', 'false', path),
                'reader': rrd_steps(path)}
    merge = rerun_cli('rrd', 'merge', path, '-o', merged)
    findings['merged_verify'] = rerun_cli('rrd', 'verify', merged) if merge[0] == 0 else merge
    findings['merged'] = rrd_steps(merged) if merge[0] == 0 else merge[1]
    if merged.exists():
        merged.unlink()
    findings['last_mcap_step'] = last_mcap_step
    return findings


def _steps_text(steps):
    if isinstance(steps, str):
        return f'fails ({steps})'
    return f'steps {steps[0]}-{steps[-1]}' if steps else 'no steps'


def _rrd_row(findings):
    """The 'kill .rrd' result row from the findings of every kill."""
    count = len(findings)
    verify = sum(f['verify'][0] == 0 for f in findings)
    lenient = sum(f['lenient'][0] == 0 for f in findings)
    read = [f for f in findings if isinstance(f['reader'], list)]
    merged = [f for f in findings if f['merged_verify'][0] == 0 and isinstance(f['merged'], list)]
    ahead = [f['merged'][-1] - f['last_mcap_step'] for f in merged if f['merged']]
    errors = sorted({f['verify'][1] for f in findings if f['verify'][0] != 0})
    reader_errors = [f['reader'] for f in findings if isinstance(f['reader'], str)]
    what = (f'{count} SIGKILLed .rrd files: `rerun rrd verify` passes {verify}/{count}'
            + (f' ({"; ".join(errors)})' if errors else '')
            + f', with --check-footers false {lenient}/{count}; rr.chunk.RrdReader reads '
            f'{len(read)}/{count} as they are'
            + (f' (the others raise, e.g. {reader_errors[0]})' if reader_errors else '')
            + f'; `rerun rrd merge` rewrites {len(merged)}/{count} into files that verify')
    figure = ('last step of the merged .rrd minus last step of the repaired MCAP: '
              f'{min(ahead)} to {max(ahead)}' if ahead else 'nothing recovered')
    return what, figure


def run_kill(args, workdir):
    from ball_world.recording.mcap_reader import Recording, RecordingError
    from ball_world.tools import repair, resim
    rng = np.random.default_rng(args.seed)
    losses, problems, rrd_results = [], [], []
    ns = namespace()
    for attempt in range(args.times):
        path = Path(workdir) / f'kill{attempt}.mcap'
        rrd = Path(workdir) / f'kill{attempt}.rrd'
        parameters = {**world_parameters(args, seed=attempt), 'rate_hz': args.rate,
                      'record.mcap': path}
        if args.rerun:
            parameters['record.rerun'] = rrd
        node = NodeProcess(workdir, ns, f'kill{attempt}', parameters)
        listener = Listener(ns)
        try:
            listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
            kill_at = listener.last_step + int(rng.integers(150, 450))  # 1.5-4.5 s on
            listener.spin_until(lambda: listener.last_step >= kill_at, f'step {kill_at}', node)
            time.sleep(rng.uniform(0.0, 1.0 / args.rate))  # anywhere within a step
            for writer in rrd_writers(node.process.pid):
                writer.kill()  # killed together, as a power cut does (alone, it would
                #                finish the .rrd: nothing to repair)
            node.kill()
            listener.drain()
        finally:
            node.kill()
            listener.close()
        heard = listener.last_step
        repaired = Path(workdir) / f'kill{attempt}.repaired.mcap'
        try:
            report = repair.repair(str(path), str(repaired))
            steps = [step.step for step in Recording(repaired).steps() if step.complete]
        except RecordingError as error:
            problems.append(f'kill {attempt}: repair failed: {error}')
            losses.append(heard + 1)
            progress(f'kill {attempt + 1}/{args.times}: repair failed: {error}')
            continue
        consecutive = steps == list(range(len(steps)))
        last = steps[-1] if steps else -1
        lost = heard - last
        losses.append(lost)
        readers = check_readers(repaired, Recording(repaired).topic_of('balls'))
        with contextlib.redirect_stdout(io.StringIO()) as out, \
                contextlib.redirect_stderr(io.StringIO()):
            resim_code = resim.main([str(repaired)])
        fine = (consecutive and all(v == len(steps) for v in readers.values())
                and resim_code == 0)
        if not fine:
            problems.append(f'kill {attempt}: steps consecutive {consecutive}, readers '
                            f'{readers}, resim exit {resim_code}: {out.getvalue()[-300:]}')
        progress(f'kill {attempt + 1}/{args.times}: killed after hearing step {heard}; '
                 f'repaired {last + 1} steps ({report.source_bytes - report.kept_bytes} torn '
                 f'bytes dropped); lost {lost} steps ({lost / args.rate:.2f} s); readers '
                 f'{readers}; resim exit {resim_code}')
        if args.rerun:
            findings = rrd_findings(rrd, last)
            rrd_results.append(findings)
            progress(f'  .rrd: verify exit {findings["verify"][0]} ({findings["verify"][1]}); '
                     f'with --check-footers false exit {findings["lenient"][0]}; RrdReader '
                     f'{_steps_text(findings["reader"])}; merged: verify exit '
                     f'{findings["merged_verify"][0]}, {_steps_text(findings["merged"])}')
        if not args.keep:
            for leftover in (path, repaired, rrd):
                if leftover.exists():
                    leftover.unlink()
    # What a SIGKILL may lose: the steps of one 1 s flush period, plus a few steps by which a
    # flush can wait behind the step timer; as wall time at the node's rate.
    limit_steps = args.rate * 1.0 + 10
    worst = max(losses)
    what = (f'{args.times} SIGKILLs ({args.balls} balls, {args.rate:g} Hz, recording MCAP'
            + (' and .rrd' if args.rerun else '') + '): '
            f'{args.times - len(problems)}/{args.times} repaired files open in mcap, '
            f'mcap_ros2 and rosbags with steps 0..last and resim identical; steps lost '
            f'{min(losses)}-{max(losses)}')
    row(f'kill --times {args.times} --balls {args.balls}' + (' --rerun' if args.rerun else ''),
        what + ('; ' + '; '.join(problems) if problems else ''),
        f'max lost {worst} steps = {worst / args.rate:.2f} s of stepping at {args.rate:g} Hz '
        f'(limit {limit_steps / args.rate:.2f} s)')
    if args.rerun:
        row('kill .rrd', *_rrd_row(rrd_results))
    return 0 if not problems and worst <= limit_steps else 1


# flood ----------------------------------------------------------------------------------------

def _sender(ns, rate, seconds, balls, seed, start, results):
    """One flooding process: wait for the node's impulse reader, publish paced, report."""
    from geometry_msgs.msg import Vector3Stamped
    import rclpy
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from ball_world.msgs.cdr import encode_vector3_stamped
    from ball_world.ros.node import IMPULSE_QUEUE_DEPTH
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(f'soak_sender_{seed}', context=context)
    try:
        # As deep as the node's reader: KEEP_LAST would overwrite unacknowledged impulses.
        qos = QoSProfile(depth=IMPULSE_QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        publisher = node.create_publisher(Vector3Stamped, f'{ns}/impulse', qos)
        deadline = time.monotonic() + DEADLINE
        while publisher.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                results.put(('error', seed, 'the node never matched the impulse publisher'))
                return
            time.sleep(0.05)
        rng = np.random.default_rng(seed)
        # Tiny, valid impulses (1e-6 N s) on random balls, encoded once.
        pool = [encode_vector3_stamped(0, f'ball_{int(ball)}', float(x), float(y), 0.0)
                for ball, x, y in zip(rng.integers(0, balls, 4096),
                                      rng.uniform(-1e-6, 1e-6, 4096),
                                      rng.uniform(-1e-6, 1e-6, 4096))]
        results.put(('ready', seed, None))
        start.wait()
        began = time.monotonic()
        end = began + seconds
        sent = 0
        while True:
            now = time.monotonic()
            if now >= end:
                break
            due = int((now - began) * rate)
            if sent >= due:
                time.sleep(0.0005)
                continue
            for _ in range(min(due - sent, 2000)):
                publisher.publish(pool[sent % len(pool)])
                sent += 1
        elapsed = time.monotonic() - began
        acked = publisher.wait_for_all_acked(Duration(seconds=DEADLINE))
        results.put(('done', seed, (sent, elapsed, acked)))
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def run_flood(args, workdir):
    from ball_world.recording.mcap_reader import Recording
    ns = namespace()
    path = Path(workdir) / 'flood.mcap'
    node = NodeProcess(workdir, ns, 'flood', {**world_parameters(args), 'rate_hz': 100.0,
                                              'record.mcap': path})
    listener = Listener(ns, stats=True)
    spawn = multiprocessing.get_context('spawn')
    start, results = spawn.Event(), spawn.Queue()
    per_sender = args.rate / args.senders
    senders = [spawn.Process(target=_sender, args=(ns, per_sender, args.seconds, args.balls, k,
                                                   start, results))
               for k in range(args.senders)]
    peak_rss = 0.0
    try:
        for sender in senders:
            sender.start()
        listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
        ready = 0
        while ready < args.senders:
            kind, seed, detail = _next_result(results, listener, node)
            if kind == 'error':
                raise SoakError(f'sender {seed}: {detail}')
            ready += 1
        progress(f'flood: {args.senders} sender(s) matched; flooding {args.rate:g} '
                 f'impulses/s for {args.seconds:g} s')
        first_step, began = listener.last_step, time.monotonic()
        start.set()
        outcomes = []
        last_sample = 0.0
        while len(outcomes) < args.senders:
            if time.monotonic() - last_sample > 0.2:
                peak_rss = max(peak_rss, rss_mb(node.pid))
                last_sample = time.monotonic()
            kind, seed, detail = _next_result(results, listener, node, block=False)
            if kind == 'done':
                outcomes.append(detail)
                if len(outcomes) == 1:
                    flood_steps = listener.last_step - first_step
                    flood_wall = time.monotonic() - began
            elif kind == 'error':
                raise SoakError(f'sender {seed}: {detail}')
        # Every impulse is acknowledged by the node's reader; the next steps apply them.
        settled = listener.last_step + 5
        listener.spin_until(lambda: listener.last_step >= settled, f'step {settled}', node)
        stats_rtf = listener.real_time_factor
        code = node.stop(signal.SIGINT)
    finally:
        node.kill()
        listener.close()
        for sender in senders:
            sender.join(timeout=DEADLINE)
            if sender.is_alive():
                sender.kill()
    sent = sum(outcome[0] for outcome in outcomes)
    send_rate = sum(outcome[0] / outcome[1] for outcome in outcomes)
    acked = all(outcome[2] for outcome in outcomes)
    recording = Recording(path)
    impulse_topic = recording.topic_of('impulse')
    recorded = recording.topics[impulse_topic].message_count if impulse_topic else 0
    log = node.log()
    rejected = [line for line in log.splitlines() if 'rejected impulse (' in line]
    flood_rtf = flood_steps * DT / flood_wall
    log_rtf = node.real_time_factors()
    fine = recorded == sent and code == 0 and acked and recording.has_summary
    if not args.keep:
        path.unlink()
    what = (f'{args.balls} balls at 100 Hz recording MCAP; {args.senders} sender '
            f'process(es) asked for {args.rate:g}/s for {args.seconds:g} s, achieved '
            f'{send_rate:,.0f}/s; sent {sent:,}, recorded (applied) {recorded:,}'
            + ('' if acked else ', NOT all acknowledged')
            + (f', {len(rejected)} rejection warnings' if rejected else '')
            + f'; node exit {code}')
    figure = (f'dropped {sent - recorded}; real-time factor {flood_rtf:.2f} during the flood '
              f'(cumulative per `stats` {stats_rtf:.2f}'
              + (f', 10 s log lines {min(log_rtf):.2f}-{max(log_rtf):.2f}' if log_rtf else '')
              + f'); node peak RSS {peak_rss:.0f} MB')
    row(f'flood --rate {args.rate:g} --senders {args.senders} --mode {args.mode}', what, figure)
    return 0 if fine else 1


def _next_result(results, listener, node, block=True):
    """The next sender message, spinning the listener meanwhile; (None,)*3 if none."""
    import queue
    deadline = time.monotonic() + DEADLINE
    while True:
        try:
            return results.get_nowait()
        except queue.Empty:
            pass
        if not block:
            listener.spin(0.01)
            return None, None, None
        if time.monotonic() > deadline:
            raise SoakError('a sender process did not report in time')
        node.check_alive()
        listener.spin(0.05)


# steps ----------------------------------------------------------------------------------------

def run_steps(args, workdir):
    from ball_world.simulation import Simulation
    side = arena_side(args.balls)
    simulation = Simulation({'random.count': args.balls, 'random.seed': args.seed,
                             'arena': [0.0, 0.0, side, side], 'dt': DT,
                             'physics.backend': args.backend, 'physics.mode': args.mode})
    world = simulation.world
    energy = world.kinetic_energy()
    rss_start = rss_mb()
    began = time.monotonic()
    bad = None
    report_every = max(1, args.count // 10)
    worst_drift = 0.0
    for k in range(1, args.count + 1):
        record, _ = simulation.step()
        positions = record.positions
        if not (np.isfinite(positions).all() and np.isfinite(record.velocities).all()):
            bad = f'a non-finite position or velocity at step {k}'
            break
        if not ((positions > 0.0) & (positions < side)).all():
            bad = f'a ball outside the arena at step {k}'
            break
        if k % report_every == 0:
            drift = (world.kinetic_energy() - energy) / energy
            worst_drift = max(worst_drift, abs(drift))
            elapsed = time.monotonic() - began
            progress(f'steps: {k:,}/{args.count:,} ({100 * k // args.count}%) in '
                     f'{elapsed:.0f} s, {k / elapsed:,.0f} steps/s, energy drift {drift:.2e}, '
                     f'RSS {rss_mb():.0f} MB')
    elapsed = time.monotonic() - began
    drift = (world.kinetic_energy() - energy) / energy
    rss_end = rss_mb()
    what = (f'Simulation ({world.backend}, {args.mode} mode), {args.balls} balls in a '
            f'{side:g} m box, '
            f'{simulation.step_index:,} steps in {elapsed:.0f} s '
            f'({simulation.step_index / elapsed:,.0f} steps/s): '
            + (bad or 'no NaN, every centre inside the arena'))
    row(f'steps --count {args.count:,} --mode {args.mode}', what,
        f'energy drift {drift:.2e} (largest at the 10% marks '
        f'{max(worst_drift, abs(drift)):.2e}); RSS '
        f'{rss_start:.0f} -> {rss_end:.0f} MB')
    return 0 if bad is None and abs(drift) < 1e-9 else 1


# memory ---------------------------------------------------------------------------------------

def children_rss(pid):
    """{pid: (RSS MiB, what)} of every process `pid` started (its .rrd writer and spare)."""
    import psutil
    found = {}
    for child in psutil.Process(pid).children(recursive=True):
        try:
            what = 'rrd writer' if 'rerun_process' in ' '.join(child.cmdline()) else \
                child.name()
            found[child.pid] = (child.memory_info().rss / 2**20, what)
        except psutil.Error:
            pass
    return found


class StallWatch:
    """Tells when the probe stops hearing `balls` while the node goes on, and finds out whose
    side stopped: whether the probe's subscription still matches the node's publisher,
    whether the node said a subscriber left, whether a fresh probe (another participant)
    hears the node. Its findings go into the row."""

    #: Seconds without a message that count as the probe having stopped hearing.
    QUIET = 10.0

    def __init__(self, listener, node, namespace):
        self.listener, self.node, self.namespace = listener, node, namespace
        self.heard, self.since = listener.heard, time.monotonic()
        self.findings = []

    def check(self):
        now = time.monotonic()
        if self.listener.heard != self.heard:
            self.heard, self.since = self.listener.heard, now
            return
        if now - self.since < self.QUIET:
            return
        self.since = now  # look again in QUIET s if it stays silent
        matched = self.listener.subscription.get_publisher_count()
        left = [line for line in self.node.log().splitlines() if 'a subscriber left' in line]
        fresh = Listener(self.namespace)
        try:
            fresh.probe.spin_for(5.0)
            fresh_heard = fresh.heard
        finally:
            fresh.close()
        finding = (f'at {time.strftime("%H:%M:%S")} the probe had heard nothing for '
                   f'{self.QUIET:g} s (last step {self.listener.last_step}); its subscription '
                   f'matched {matched} publisher(s); the node said a subscriber left '
                   f'{len(left)}x; a fresh probe heard {fresh_heard} messages in 5 s')
        self.findings.append(finding)
        progress(f'memory: STALL: {finding}')


def _fit(times, values, since):
    """(slope MB/min of the per-minute medians, max - min) of values from `since` s on.

    Per-minute medians: the .rrd writer's memory is a saw-tooth (it grows through a part, a
    fresh writer takes over every half minute or so, its spare is small while it starts),
    and samples every 10 s catch it at random phases; a fit of every sample reads that noise
    as growth, a fit of each minute's median does not.
    """
    later = times >= since
    if later.sum() < 2:
        return 0.0, 0.0
    minutes = np.floor(times[later] / 60.0)
    marks = np.unique(minutes)
    medians = np.array([np.median(values[later][minutes == mark]) for mark in marks])
    slope = float(np.polyfit(marks, medians, 1)[0]) if len(marks) >= 2 else 0.0
    return slope, float(values[later].max() - values[later].min())


def run_memory(args, workdir):
    """The node recording over minutes: its memory and its children's, the files it keeps.

    With --split-seconds the MCAP is a bag directory and the .rrd is split at the same steps
    (parts memory_<i>.rrd), at most --max-files of each kept; every part is then checked
    with `rerun rrd verify`, and the parts must begin at the steps their MCAP files do.
    Memory is flat when, from --flat-after minutes on, the fitted growth of the node and of
    its children together stays under --flat-slope MB a minute.
    """
    from ball_world.recording.recording_set import open_recording
    from ball_world.recording.rrd_parts import part_names
    ns = namespace()
    mcap_path, rrd_path = Path(workdir) / 'memory.mcap', Path(workdir) / 'memory.rrd'
    recordings = {}
    if args.record in ('mcap', 'both'):
        recordings['record.mcap'] = mcap_path
    if args.record in ('rrd', 'both'):
        recordings['record.rerun'] = rrd_path
    if args.split_seconds and recordings:  # a bag directory, .rrd parts (issue 23, 26)
        recordings.update({'record.max_seconds': args.split_seconds,
                           'record.max_files': args.max_files})
    node = NodeProcess(workdir, ns, 'memory', {**world_parameters(args), 'rate_hz': 100.0,
                                               **recordings})
    listener = Listener(ns)
    samples = []  # (s since the first step, node RSS MiB, children's RSS MiB, children)
    load = []
    try:
        listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
        watch = StallWatch(listener, node, ns)
        began = time.monotonic()
        end = began + args.minutes * 60.0
        next_sample = began + args.every
        while time.monotonic() < end:
            node.check_alive()
            listener.spin(0.1)
            watch.check()
            if time.monotonic() >= next_sample:
                children = children_rss(node.pid)
                samples.append((time.monotonic() - began, rss_mb(node.pid),
                                sum(rss for rss, _ in children.values()), len(children)))
                load.append(os.getloadavg()[0])
                next_sample += args.every
                progress(f'memory: {samples[-1][0]:.0f} s, node RSS {samples[-1][1]:.1f} MB, '
                         f'{len(children)} children {samples[-1][2]:.1f} MB, '
                         f'step {listener.last_step}, MCAP {_size_mb(mcap_path):.0f} MB, '
                         f'.rrd {_rrd_mb(rrd_path):.0f} MB, load {load[-1]:.1f}')
        steps = listener.last_step
        code = node.stop(signal.SIGINT)
    finally:
        node.kill()
        listener.close()
    if len(samples) < 2:
        raise SoakError('fewer than two RSS samples: give --minutes more than --every')
    times = np.array([t for t, _, _, _ in samples])
    rss = np.array([r for _, r, _, _ in samples])
    kids = np.array([c for _, _, c, _ in samples])
    flat_after = min(args.flat_after * 60.0, times[-1] / 2)
    slope, spread = _fit(times, rss, flat_after)
    kids_slope, kids_spread = _fit(times, kids, flat_after)
    total_slope, _ = _fit(times, rss + kids, flat_after)
    checks = [f'SIGINT exit {code}']
    fine = code == 0 and not watch.findings
    if 'record.mcap' in recordings:
        recording = open_recording(mcap_path)
        finished = recording.has_summary
        kept = len(getattr(recording, 'files', [recording]))
        fine = fine and finished and (not args.split_seconds or kept <= args.max_files)
        split = (f' in {kept} files kept of {args.split_seconds:g} s each '
                 f'(record.max_files {args.max_files})' if args.split_seconds else '')
        checks.append(f'MCAP {_size_mb(mcap_path):,.0f} MB{split}, summary {finished}')
    if 'record.rerun' in recordings:
        parts = ([Path(workdir) / name for _, name in part_names(rrd_path)]
                 if args.split_seconds else [rrd_path])
        verified = [rerun_cli('rrd', 'verify', part) for part in parts]
        passed = sum(code == 0 for code, _ in verified)
        fine = fine and parts and passed == len(parts) and (
            not args.split_seconds or len(parts) <= args.max_files)
        failed = [said for code, said in verified if code != 0]
        checks.append(f'.rrd {_rrd_mb(rrd_path):,.0f} MB in {len(parts)} file(s) kept '
                      f'({", ".join(p.name for p in parts)}), `rerun rrd verify` passes '
                      f'{passed}/{len(parts)}' + (f' ({failed[0][-200:]})' if failed else ''))
        if args.split_seconds and 'record.mcap' in recordings:
            same = _parts_follow(recording, parts)
            fine = fine and same
            checks.append('each part begins at the step its MCAP file begins at'
                          if same else 'the parts do NOT begin where the MCAP files do')
    if not args.keep:
        for path in [mcap_path, rrd_path, *Path(workdir).glob('memory_*.rrd')]:
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
    fine = fine and slope <= args.flat_slope and total_slope <= args.flat_slope
    rtf = node.real_time_factors()
    recorded = {'both': 'MCAP and .rrd', 'mcap': 'MCAP', 'rrd': '.rrd', 'none': 'nothing'}
    what = (f'{args.balls} balls at 100 Hz recording {recorded[args.record]} for '
            f'{args.minutes:g} min ({steps:,} steps, the probe in another process hearing '
            + ('them all' if not watch.findings else
               f'NOT all: {"; ".join(watch.findings)}')
            + '); real-time factor '
            + (f'{min(rtf):.2f}-{max(rtf):.2f}' if rtf else 'n/a')
            + f'; load average {min(load):.1f}-{max(load):.1f}; ' + ', '.join(checks))
    split = (f' --split-seconds {args.split_seconds:g} --max-files {args.max_files}'
             if args.split_seconds else '')
    per_minute = ' '.join(f'{t / 60:.0f}:{r:.0f}+{c:.0f}' for t, r, c, _ in samples
                          if round(t) % 60 < args.every)
    row(f'memory --minutes {args.minutes:g} --record {args.record}{split}', what,
        f'from minute {flat_after / 60:g} on, fitted to the per-minute medians: node '
        f'{slope:+.2f} MB/min (within {spread:.1f} MB), its children (.rrd writer and spare) '
        f'{kids_slope:+.2f} MB/min (within {kids_spread:.1f} MB), together '
        f'{total_slope:+.2f} MB/min (flat: at most {args.flat_slope:g}); node RSS '
        f'{rss[0]:.0f} -> {rss[-1]:.0f} MB, children {kids[0]:.0f} -> {kids[-1]:.0f} MB; '
        f'minute:node+children MB {per_minute}')
    return 0 if fine else 1


def _parts_follow(recording, parts):
    """Whether each .rrd part holds the steps of the MCAP file of its number."""
    files = {int(Path(f.path).stem.rpartition('_')[2]): f for f in recording.files}
    for part in parts:
        number = int(part.stem.rpartition('_')[2])
        if number not in files:
            return False
        mcap = [s.step for s in files[number].steps() if s.complete]
        rrd = rrd_steps(part)
        if not isinstance(rrd, list) or rrd != mcap:
            return False
    return True


def _rrd_mb(path):
    """An .rrd's size, or that of its parts beside it, MB."""
    if path.exists():
        return _size_mb(path)
    return sum(_size_mb(part) for part in path.parent.glob(f'{path.stem}_*.rrd'))


def _sink_for_memory(args, path):
    """The sink the sinkmemory case records through, as the node wraps it."""
    from ball_world.recording.writer_thread import BackgroundSink
    if args.sinks in ('rrd', 'rrd-process'):  # the SDK's stream here, or in a child
        from ball_world.recording.rerun_log import RerunSink
        return RerunSink(path.with_suffix('.rrd'), file_process=args.sinks == 'rrd-process')
    if args.sinks == 'split':
        from ball_world.recording.split_writer import SplitMcapSink
        return BackgroundSink(SplitMcapSink(path, max_seconds=args.split_seconds,
                                            max_files=args.max_files))
    from ball_world.recording.mcap_writer import McapSink
    return BackgroundSink(McapSink(path.with_suffix('.mcap')))


def run_sink_memory(args, workdir):
    """RSS per simulated minute of a Simulation writing through one kind of sink (no ROS).

    Where recording memory goes, without the node: a simulated minute (6,000 steps at
    100 Hz) takes seconds, so tens of minutes are measured in a few, flushed every 100 steps
    as the node flushes every second.
    """
    from ball_world.simulation import Simulation
    side = arena_side(args.balls)
    path = Path(workdir) / 'sinkmemory'
    simulation = Simulation({'random.count': args.balls, 'random.seed': 1, 'rate_hz': 100.0,
                             'arena': [0.0, 0.0, side, side],
                             'physics.backend': args.backend, 'physics.mode': args.mode},
                            sinks=[_sink_for_memory(args, path)])
    began = time.monotonic()
    samples = []
    writer = []  # RSS of the .rrd writer process (rrd-process)
    for k in range(1, round(args.minutes * 6000) + 1):
        simulation.step()
        if k % 100 == 0:
            simulation.flush()
        if k % 6000 == 0:
            samples.append(rss_mb())
            writer.append(writer_rss_mb())
            progress(f'sinkmemory: {k // 6000} simulated min, RSS {samples[-1]:.1f} MB '
                     f'(.rrd writer {writer[-1]:.1f} MB)')
    simulation.close()
    elapsed = time.monotonic() - began
    for leftover in [] if args.keep else Path(workdir).glob('sinkmemory*'):
        if leftover.is_dir():
            shutil.rmtree(leftover)
        else:
            leftover.unlink()
    if len(samples) < 4:
        raise SoakError('fewer than four samples: give --minutes 4 or more')
    minutes = np.arange(1, len(samples) + 1)
    slope = np.polyfit(minutes[2:], np.array(samples[2:]), 1)[0]
    split = (f' --split-seconds {args.split_seconds:g} --max-files {args.max_files}'
             if args.sinks == 'split' else '')
    row(f'sinkmemory --sinks {args.sinks}{split} --minutes {args.minutes:g}',
        f'Simulation of {args.balls} balls ({args.mode} mode), {len(samples) * 6000:,} steps '
        f'at 100 Hz in {elapsed:.0f} s; RSS per simulated minute '
        + ' '.join(f'{value:.1f}' for value in samples) + ' MB'
        + ('; its .rrd writer process ' + ' '.join(f'{value:.1f}' for value in writer) + ' MB'
           if any(writer) else ''),
        f'{slope:+.2f} MB per simulated minute, fitted from minute 3 on'
        + (f'; the writer {np.polyfit(minutes[2:], np.array(writer[2:]), 1)[0]:+.2f}'
           if any(writer) else ''))
    return 0


def _size_mb(path):
    """A file's size, or the sum of a bag directory's, MB."""
    if path.is_dir():
        return sum(part.stat().st_size for part in path.iterdir()) / 2**20
    return path.stat().st_size / 2**20 if path.exists() else 0.0


# rtf ------------------------------------------------------------------------------------------

def thread_cpu(pid):
    """CPU seconds (user + system) of each thread of a process, by thread id, with its name."""
    import psutil
    times = {}
    for thread in psutil.Process(pid).threads():
        try:
            name = Path(f'/proc/{pid}/task/{thread.id}/comm').read_text().strip()
        except OSError:  # the thread ended meanwhile
            continue
        times[thread.id] = (name, thread.user_time + thread.system_time)
    return times


def cpu_by_part(pid, before, after, seconds):
    """Share of one core each part of the node used between two thread_cpu() samples.

    The main thread steps, encodes and publishes; the node's other Python threads (named as
    the process: Python 3.12 does not name them for the OS) write the recordings; the rest
    are the middleware's (DDS), named by it.
    """
    main_name = after.get(pid, before.get(pid, ('', 0.0)))[0]
    parts = {}
    for tid, (name, cpu) in after.items():
        used = cpu - before.get(tid, (name, 0.0))[1]
        part = ('main (step, encode, publish)' if tid == pid else
                'other threads named as the process (recording writer...)' if name == main_name
                else 'DDS')
        parts[part] = parts.get(part, 0.0) + used / seconds
    return parts


def rtf_parameters(args, path):
    """The node scene: equal balls of radius 0.5 m at 20% of a square box, 100 Hz; with
    --map, balls of radius 0.1-0.2 m (robots' sizes) placed in the map's free cells."""
    side = round(0.5 * math.sqrt(args.balls * math.pi / 0.2), 3)
    parameters = {'random.count': args.balls, 'random.radius': '[0.5, 0.5]',
                  'random.speed': args.speed, 'arena': f'[0.0, 0.0, {side}, {side}]',
                  'dt': DT, 'rate_hz': 100.0, 'physics.backend': args.backend,
                  'physics.mode': args.mode}
    if getattr(args, 'map', None):
        parameters.update({'map': args.map, 'arena': '[]', 'random.radius': '[0.1, 0.2]'})
    if getattr(args, 'drive', None):
        parameters['agent.drive'] = args.drive
    if args.record:
        parameters['record.mcap'] = path
    if args.agents:
        parameters['agents'] = '[' + ', '.join(agent_names(args.agents)) + ']'
        parameters['agent.scan.samples'] = 0  # agents alone; --scanning-agents scan
        parameters['agent.odom.rate_hz'] = getattr(args, 'odom_rate', 0.0)
    if getattr(args, 'scanning_agents', 0):
        parameters['agents'] = '[' + ', '.join(agent_names(args.scanning_agents)) + ']'
        parameters.pop('agent.scan.samples', None)
    return parameters, side


#: The node's (throttled) warning that it fell more than pacing.MAX_LAG behind: its total.
DROPPED_LINE = re.compile(r'behind the [^ ]+ Hz schedule: dropped \d+ steps of wall time '
                          r'\((\d+) so far\)')


def agent_names(count):
    return [f'ball_{i}' for i in range(count)]


class OdomListener:
    """Subscribes to the odometry of the first `count` agents (as a fleet monitor would) and
    counts what arrives, taking the bytes raw."""

    def __init__(self, node, namespace, count):
        from nav_msgs.msg import Odometry
        self.heard = 0
        self.subscriptions = [node.create_subscription(
            Odometry, f'{namespace}/{name}/odom', self._on_odom, 10, raw=True)
            for name in agent_names(count)]

    def _on_odom(self, data):
        self.heard += 1


class Commander:
    """Drives every agent as a controller at COMMAND_HZ would: a Twist on each cmd_vel."""

    COMMAND_HZ = 10.0

    def __init__(self, node, namespace, count):
        from geometry_msgs.msg import Twist
        self.message = Twist()
        self.message.linear.x, self.message.angular.z = 1.0, 0.5
        self.publishers = [node.create_publisher(Twist, f'{namespace}/{name}/cmd_vel', 10)
                           for name in agent_names(count)]
        self.due = 0.0
        self.sent = 0
        self.count = count

    def tick(self):
        now = time.monotonic()
        if now < self.due:
            return
        self.due = now + 1.0 / self.COMMAND_HZ
        for publisher in self.publishers:
            publisher.publish(self.message)
        self.sent += len(self.publishers)


def run_rtf(args, workdir):
    import psutil
    ns = namespace()
    path = Path(workdir) / f'rtf-{args.mode}.mcap'
    parameters, side = rtf_parameters(args, path)
    node = NodeProcess(workdir, ns, f'rtf-{args.mode}', parameters)
    listener = Listener(ns, stats=True)
    commander = Commander(listener.probe.node, ns,
                          max(args.agents, getattr(args, 'scanning_agents', 0)))
    odom = OdomListener(listener.probe.node, ns, min(args.listen, args.agents))
    me = psutil.Process()
    try:
        listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
        listener.probe.spin_for(2.0)  # past the first steps (lists built, writer started)
        first_step, began = listener.last_step, time.monotonic()
        threads_before, mine_before = thread_cpu(node.pid), sum(me.cpu_times()[:2])
        rss_start = rss_mb(node.pid)
        end = began + args.seconds
        while time.monotonic() < end:
            node.check_alive()
            commander.tick()
            listener.spin(0.05)
        elapsed = time.monotonic() - began
        steps = listener.last_step - first_step
        threads_after, mine_after = thread_cpu(node.pid), sum(me.cpu_times()[:2])
        rss_end = rss_mb(node.pid)
        stats_rtf = listener.real_time_factor
        code = node.stop(signal.SIGINT)
    finally:
        node.kill()
        listener.close()
    parts = cpu_by_part(node.pid, threads_before, threads_after, elapsed)
    windows = node.real_time_factors()
    dropped = DROPPED_LINE.findall(node.log())
    load = os.getloadavg()[0]
    size = _size_mb(path)
    if path.exists() and not args.keep:
        path.unlink()
    overall = steps * DT / elapsed
    scene = (f'in the map {args.map}, r 0.1-0.2 m' if getattr(args, 'map', None)
             else f'r 0.5 m, 20% of a {side:g} m box')
    what = (f'{args.balls:,} balls ({scene}, speeds up to '
            f'{args.speed:g} m/s), {args.mode} mode ({args.backend} backend), rate_hz 100, '
            f'dt {DT:g} s, markers at their default rate, a probe subscribed to `balls` and '
            '`stats`' + (f', recording MCAP ({size:,.0f} MB)' if args.record else '')
            + (f', {commander.count} agents commanded at {Commander.COMMAND_HZ:g} Hz '
               f'({commander.sent:,} cmd_vel sent; each publishes odom and /tf'
               + (f' at {args.odom_rate:g} Hz' if args.odom_rate else ' every step')
               + (f"; {len(odom.subscriptions)} agents' odom listened to, {odom.heard:,} "
                  'messages heard' if odom.subscriptions else '') + ')'
               if commander.count else '')
            + (f', agent.drive {args.drive}' if getattr(args, 'drive', None) else '')
            + f'; {steps:,} steps in {elapsed:.1f} s; node exit {code}; CPU (share of one '
            'core): ' + ', '.join(f'{part} {share:.2f}' for part, share in sorted(parts.items()))
            + f', this probe {(mine_after - mine_before) / elapsed:.2f}; node RSS '
            f'{rss_start:.0f} -> {rss_end:.0f} MB; load average {load:.1f} at the end; '
            + (f'the node dropped lag {len(dropped)}x ({dropped[-1]} steps by its last '
               'warning)' if dropped else 'the node dropped no lag (it made up every hiccup)'))
    figure = (f'real-time factor {overall:.3f} over {elapsed:.0f} s (probe: steps heard x dt / '
              'wall time); node log, every 10 s window: '
              + (', '.join(f'{rtf:.3f}' for rtf in windows) if windows else 'none')
              + f'; `stats` since start {stats_rtf:.3f}')
    agents = getattr(args, 'scanning_agents', 0)
    if agents:
        what += f'; {agents} agents, each scanning 360 beams at 10 Hz (recorded)'
    row(f'rtf --mode {args.mode} --balls {args.balls} --speed {args.speed:g}'
        + (f' --agents {args.agents}' if args.agents else '')
        + (f' --odom-rate {args.odom_rate:g}' if args.odom_rate else '')
        + (f' --listen {args.listen}' if args.listen else '')
        + (f' --scanning-agents {agents}' if agents else '')
        + (f' --map {args.map}' if getattr(args, 'map', None) else '')
        + (f' --drive {args.drive}' if getattr(args, 'drive', None) else ''), what, figure)
    return 0 if code == 0 and overall >= args.target else 1


def run_swarm(args, workdir):
    """The swarm of benchmarks.swarm_speed in the node (agent.topics none, the wander
    controller in its worker, 10 Hz), recording MCAP; its real-time factor from a probe."""
    from benchmarks.swarm_speed import parameters as swarm_parameters
    ns = namespace()
    path = Path(workdir) / 'swarm.mcap'
    values = swarm_parameters(args.robots, 0.0)
    parameters = {name: (f"[{', '.join(str(v) for v in value)}]" if isinstance(value, list)
                         else value) for name, value in values.items()}
    if args.record:
        parameters['record.mcap'] = path
    started = time.monotonic()
    node = NodeProcess(workdir, ns, 'swarm', parameters)
    listener = Listener(ns, stats=True, dt=0.1)
    try:
        listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
        start_s = time.monotonic() - started
        listener.probe.spin_for(2.0)
        first_step, began = listener.last_step, time.monotonic()
        threads_before = thread_cpu(node.pid)
        while time.monotonic() < began + args.seconds:
            node.check_alive()
            listener.spin(0.05)
        elapsed = time.monotonic() - began
        steps = listener.last_step - first_step
        threads_after = thread_cpu(node.pid)
        stopping = time.monotonic()
        code = node.stop(signal.SIGINT)
        stop_s = time.monotonic() - stopping
    finally:
        node.kill()
        listener.close()
    parts = cpu_by_part(node.pid, threads_before, threads_after, elapsed)
    size = _size_mb(path)
    if path.exists() and not args.keep:
        path.unlink()
    overall = steps * 0.1 / elapsed
    what = (f'{args.robots:,} diff-drive robots, agent.topics none, 16-beam 2 m ring at 10 Hz, '
            f'wander at 10 Hz, rate_hz 10' + (f', recording MCAP ({size:,.0f} MB)'
                                              if args.record else '')
            + f'; first step heard {start_s:.1f} s after the start; {steps:,} steps in '
            f'{elapsed:.1f} s; SIGINT to exit {stop_s:.1f} s (exit {code}); CPU (share of one '
            'core): ' + ', '.join(f'{part} {share:.2f}' for part, share in sorted(parts.items()))
            + f'; load average {os.getloadavg()[0]:.1f} at the end')
    figure = (f'real-time factor {overall:.3f} over {elapsed:.0f} s (probe: steps heard x dt / '
              'wall time)')
    row(f'swarm --robots {args.robots}', what, figure)
    return 0 if code == 0 and overall >= args.target else 1


# startup --------------------------------------------------------------------------------------

def first_messages(workdir, label, backend, environment):
    """Seconds from starting the node process to the first two `balls` messages a probe hears
    (step 0, published once the world is built; step 1, the first step taken)."""
    ns = namespace()
    listener = Listener(ns)  # subscribed before the node starts: its start-up is not timed
    began = time.perf_counter()
    node = NodeProcess(workdir, ns, f'startup-{label}', {'physics.backend': backend},
                       env=environment)
    try:
        listener.spin_until(lambda: len(listener.first_arrivals) >= 2, 'step 1', node)
        code = node.stop(signal.SIGINT)
    finally:
        node.kill()
        listener.close()
    if code != 0:
        raise SoakError(f'the node ({label}) exited with {code}: {node.log()[-500:]}')
    return [arrival - began for arrival in listener.first_arrivals]


def run_startup(args, workdir):
    """The default world, process start to first messages: numba kernels cached (as `make
    setup` leaves them), numba with an empty cache (NUMBA_CACHE_DIR), and numpy."""
    cold_cache = Path(workdir) / 'empty_numba_cache'
    cold_cache.mkdir()
    cases = [('numba, kernels cached', 'numba', {}),
             ('numba, no kernel cache (first run ever)', 'numba',
              {'NUMBA_CACHE_DIR': str(cold_cache)}),
             ('numpy', 'numpy', {})]
    rows = []
    for label, backend, extra in cases:
        times = []
        # Only the first run with an empty cache is cold: it fills the cache.
        for attempt in range(1 if 'NUMBA_CACHE_DIR' in extra else args.repeats):
            if extra:
                shutil.rmtree(cold_cache)
                cold_cache.mkdir()
            times.append(first_messages(workdir, f'{backend}{attempt}', backend,
                                        {**os.environ, **extra}))
            progress(f'startup, {label}: step 0 heard after {times[-1][0]:.2f} s, step 1 after '
                     f'{times[-1][1]:.2f} s')
        rows.append((label, times))
    for label, times in rows:
        step0 = sorted(t[0] for t in times)
        step1 = sorted(t[1] for t in times)
        spread = (lambda values: f'{values[len(values) // 2]:.2f} s' + (
            f' (runs {values[0]:.2f}-{values[-1]:.2f})' if len(values) > 1 else ''))
        row(f'startup: {label}', f'default world (20 balls, 60 Hz), {len(times)} run(s); '
            'a probe subscribed before the node process starts',
            f'first `balls` (step 0) after {spread(step0)}; step 1 after {spread(step1)}')
    return 0


# fulldisk -------------------------------------------------------------------------------------

@contextlib.contextmanager
def small_disk(directory, size_mb):
    """A tmpfs of size_mb mounted at directory (needs root), unmounted at the end; yields
    None, or the file size limit to use instead when it cannot be mounted."""
    import subprocess
    directory.mkdir()
    size = f'size={round(size_mb * 1024)}k'
    done = subprocess.run(['mount', '-t', 'tmpfs', '-o', size, 'tmpfs', str(directory)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        progress(f'fulldisk: no tmpfs ({done.stderr.strip()}); using RLIMIT_FSIZE instead')
        yield int(size_mb * 2**20)
        return
    try:
        yield None
    finally:
        subprocess.run(['umount', str(directory)], check=True)


def mcap_findings(path, workdir):
    """What the tools make of an MCAP left by a full disk: as it is, then after repair."""
    from ball_world.recording.mcap_reader import Recording, RecordingError
    from ball_world.tools import repair
    findings = {}
    try:
        recording = Recording(path)
        steps = [step.step for step in recording.steps() if step.complete]
        findings['steps'] = (len(steps), steps == list(range(len(steps))))
        findings['summary'] = recording.has_summary
        findings['readers'] = check_readers(path, recording.topic_of('balls'))
    except RecordingError as error:
        findings['steps'] = f'ball_world cannot read it: {error}'
    repaired = Path(workdir) / f'{path.parent.name}-{path.stem}.repaired.mcap'
    try:
        repair.repair(str(path), str(repaired))
        recording = Recording(repaired)
        findings['repaired_readers'] = check_readers(repaired, recording.topic_of('balls'))
        findings['repaired_steps'] = sum(1 for step in recording.steps() if step.complete)
    except RecordingError as error:
        findings['repaired_readers'] = f'repair failed: {error}'
    return findings


def run_fulldisk_once(args, workdir, sig):
    name = signal.Signals(sig).name
    disk = Path(workdir) / f'disk-{name}'
    with small_disk(disk, args.size_mb) as size_limit:
        mcap, rrd = disk / 'full.mcap', disk / 'full.rrd'
        options = {} if size_limit is None else {'limit_file_size': size_limit}
        ns = namespace()
        node = NodeProcess(workdir, ns, f'fulldisk-{name}',
                           {**world_parameters(args), 'rate_hz': args.rate,
                            'record.mcap': mcap, 'record.rerun': rrd}, **options)
        listener = Listener(ns)
        failures = ('recording to McapSink stopped', 'recording to RerunSink stopped')
        try:
            listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
            listener.spin_until(lambda: all(f in node.log() for f in failures),
                                'both recorders to report the full disk', node)
            failed_at = listener.last_step
            listener.probe.spin_for(1.0)
            first_step, began = listener.last_step, time.monotonic()
            listener.probe.spin_for(args.seconds)
            rate = (listener.last_step - first_step) / (time.monotonic() - began)
            signalled = time.monotonic()
            code = node.stop(sig)
            exit_seconds = time.monotonic() - signalled
        finally:
            node.kill()
            listener.close()
        log = node.log()
        counts = [log.count(f) for f in failures]
        findings = mcap_findings(mcap, workdir)
        rrd_verify = rerun_cli('rrd', 'verify', rrd) if rrd.exists() else (None, 'no file')
        sizes = (_size_mb(mcap), _size_mb(rrd))
    how = 'RLIMIT_FSIZE' if size_limit else 'tmpfs'
    readable = (isinstance(findings['steps'], tuple) and findings['steps'][1]
                and all(isinstance(v, int) and v == findings['steps'][0]
                        for v in findings['readers'].values()))
    repaired = findings['repaired_readers']
    repaired_ok = isinstance(repaired, dict) and all(isinstance(v, int) for v in repaired.values())
    what = (f'{args.balls:,} balls at {args.rate:g} Hz recording MCAP and .rrd onto a '
            f'{args.size_mb:g} MB {how}: failures logged {counts[0]}x (MCAP) and {counts[1]}x '
            f'(.rrd), both by step {failed_at}; stepping went on at {rate:.1f} steps/s; '
            f'{name}: exit {code} after {exit_seconds:.1f} s; '
            f'{"Traceback in the log; " if "Traceback" in log else ""}'
            f'MCAP {sizes[0]:.2f} MB, summary {findings.get("summary")}, '
            + (f'{findings["steps"][0]} steps read by ball_world, as is mcap / mcap_ros2 / '
               f'rosbags read {findings["readers"]}'
               if isinstance(findings['steps'], tuple) else findings['steps'])
            + f'; after ball_world_repair {repaired}; .rrd {sizes[1]:.2f} MB, `rerun rrd '
            f'verify` exit {rrd_verify[0]}')
    fine = (counts == [1, 1] and code == 0 and exit_seconds < 10.0
            and rate >= 0.9 * args.rate and (readable or repaired_ok))
    return what, fine, rate, exit_seconds


def run_fulldisk(args, workdir):
    fine = True
    for sig in (signal.SIGINT, signal.SIGTERM):
        what, ok, rate, exit_seconds = run_fulldisk_once(args, workdir, sig)
        fine = fine and ok
        row(f'fulldisk --balls {args.balls} ({signal.Signals(sig).name})', what,
            f'{rate:.1f} steps/s after the failure; exit {exit_seconds:.1f} s after '
            f'{signal.Signals(sig).name}')
    return 0 if fine else 1


# viewer ---------------------------------------------------------------------------------------

#: A subscriber in a process of its own, taking `balls`, `state` and `markers` as rclpy
#: messages (reliable, as RViz and Foxglove subscribe), so that SIGSTOP freezes a real reader.
FROZEN_SUBSCRIBER = """
import sys
import rclpy
from geometry_msgs.msg import PoseArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from visualization_msgs.msg import MarkerArray
rclpy.init()
node = rclpy.create_node('soak_frozen_subscriber')
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
for kind, topic in ((PoseArray, 'balls'), (Float64MultiArray, 'state'),
                    (MarkerArray, 'markers')):
    node.create_subscription(kind, sys.argv[1] + '/' + topic, lambda message: None, qos)
rclpy.spin(node)
"""


def start_viewer(workdir):
    """`rerun --save` on a free port, which takes the stream as a viewer does: (process, url)."""
    import socket
    harness = _harness()
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        port = probe.getsockname()[1]
    viewer = harness.start([str(harness.RERUN), '--bind', '127.0.0.1', '--port', str(port),
                            '--save', str(Path(workdir) / 'viewer.rrd')],
                           log=Path(workdir) / 'viewer.log')
    deadline = time.monotonic() + DEADLINE
    while True:
        try:
            socket.create_connection(('127.0.0.1', port), timeout=1.0).close()
            return viewer, f'rerun+http://127.0.0.1:{port}/proxy'
        except OSError:
            if time.monotonic() > deadline or viewer.poll() is not None:
                raise SoakError('rerun --save did not listen')
            time.sleep(0.1)


#: A progress line of the node: its ROS time stamp (s) and the real-time factor of the 10 s
#: before it.
PROGRESS_LINE = re.compile(r'\[(\d+\.\d+)\] \[[^]]*\]: step \d+: [^,]*, real-time factor '
                           r'(\d+(?:\.\d*)?)')


def node_windows(log, began, ended):
    """The real-time factors of the node's progress lines whose 10 s lie within [began, ended]
    (seconds since the epoch): what the node itself did, whatever its subscribers heard."""
    return [float(rtf) for stamp, rtf in PROGRESS_LINE.findall(log)
            if began + 10.0 <= float(stamp) <= ended]


def run_viewer(args, workdir):
    """The node streaming to a live viewer beside a reliable subscriber, each phase for
    args.seconds: both taking the data, both frozen (SIGSTOP), both killed. Reports the
    node's own real-time factor in each phase (its 10 s progress lines) and how much of the
    stream a second, healthy subscriber (this process's probe) still received."""
    ns = namespace()
    harness = _harness()
    viewer, url = start_viewer(workdir)
    subscriber = harness.start([sys.executable, '-c', FROZEN_SUBSCRIBER, ns],
                               log=Path(workdir) / 'subscriber.log')
    node = NodeProcess(workdir, ns, 'viewer', {**world_parameters(args), 'rate_hz': 100.0,
                                               'markers.rate_hz': 10.0, 'view.rerun': url})
    listener = Listener(ns)
    phases = []  # (name, began, ended: time.time(), share of the steps the probe heard)
    try:
        listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
        listener.probe.spin_for(2.0)

        def phase(name):
            first_step, began = listener.last_step, time.time()
            while time.time() < began + args.seconds:
                node.check_alive()
                listener.spin(0.05)
            ended = time.time()
            heard = (listener.last_step - first_step) * DT / (ended - began)
            phases.append((name, began, ended, heard))
            progress(f'viewer: {name}: the probe heard {heard:.0%} of real time')

        phase('both taking the data')
        for process in (viewer, subscriber):
            process.send_signal(signal.SIGSTOP)
        phase('both frozen (SIGSTOP)')
        for process in (viewer, subscriber):
            harness.kill(process)
        phase('both killed')
        code = node.stop(signal.SIGINT)
    finally:
        node.kill()
        listener.close()
        for process in (viewer, subscriber):
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGCONT)
            harness.kill(process)
    log = node.log()
    told = sum('recording to RerunSink stopped: live view' in line for line in log.splitlines())
    windows = {name: node_windows(log, began, ended) for name, began, ended, _ in phases}
    what = (f'{args.balls:,} balls at 100 Hz streaming to `rerun --save` as a live viewer, '
            'a reliable rclpy subscriber to `balls`, `state` and `markers` in another process; '
            f'each phase {args.seconds:g} s; the node reported the view lost {told}x; '
            f'node exit {code}' + ('; Traceback in the log' if 'Traceback' in log else '')
            + '; a second subscriber (the probe) heard, of real time: '
            + ', '.join(f'{name} {heard:.0%}' for name, _, _, heard in phases))
    figure = 'node real-time factor, 10 s windows: ' + '; '.join(
        f'{name} {", ".join(f"{rtf:.3f}" for rtf in factors) or "none"}'
        for name, factors in windows.items())
    row(f'viewer --balls {args.balls}', what, figure)
    fine = (code == 0 and told == 1 and all(windows.values())
            and all(rtf >= args.target for factors in windows.values() for rtf in factors))
    return 0 if fine else 1


# liveview -------------------------------------------------------------------------------------

#: The node's start line and progress lines, with their ROS log stamps (s since the epoch).
START_LINE = re.compile(r'\[(\d+\.\d+)\] \[ball_world\]: world: .*?, dt ([0-9.e+-]+) s,')
STEP_LINE = re.compile(r'\[(\d+\.\d+)\] \[ball_world\]: step (\d+): ')
#: A screenshot line of scripts/screenshot_web.js: its file, when it was asked for and
#: when it was taken.
SHOT_LINE = re.compile(r'^(\S+\.png) (\d+\.\d+) (\d+\.\d+)$', re.MULTILINE)


def node_sim_time(log, when):
    """The node's simulated time at `when` (s since the epoch), from its log lines: the
    steps of the progress lines around it, interpolated (the start line is step 0)."""
    start = START_LINE.search(log)
    if start is None:
        raise SoakError('the node never logged its start line')
    dt = float(start.group(2))
    points = [(float(start.group(1)), 0)] + [(float(t), int(k)) for t, k in STEP_LINE.findall(log)]
    stamps, steps = zip(*points)
    if when > stamps[-1]:
        raise SoakError('a screenshot was taken after the last progress line of the node')
    return float(np.interp(when, stamps, steps)) * dt


def screenshot_tools():
    """(node, chromium, NODE_PATH) for scripts/screenshot_web.js, or SoakError saying what
    to install."""
    chromium = os.environ.get('CHROMIUM', '/usr/bin/chromium')
    node_path = os.environ.get('NODE_PATH', str(Path.home() / 'tools/puppeteer/node_modules'))
    node = shutil.which('node')
    if node is None or not Path(chromium).exists() or \
            not (Path(node_path) / 'puppeteer-core').is_dir():
        raise SoakError('liveview needs node, chromium (apt-get install chromium) and '
                        'puppeteer-core (npm install --prefix ~/tools/puppeteer puppeteer-core, '
                        'or NODE_PATH=...); see scripts/screenshot_web.js')
    return node, chromium, node_path


def run_liveview(args, workdir):
    """`make view` (scripts/view.sh) with pages in headless Chromium: one opened at the start,
    shot at args.early seconds after it loaded, and one opened args.late s into the run, shot
    at args.late_shots. Reports the node's simulated time at each shot, to set beside the time
    each page shows (read on the screenshots, kept in --dir)."""
    import socket
    import subprocess
    node, chromium, node_path = screenshot_tools()
    root = Path(__file__).resolve().parent.parent
    ports = []
    for _ in range(2):
        with socket.socket() as probe:
            probe.bind(('127.0.0.1', 0))
            ports.append(probe.getsockname()[1])
    environment = {**os.environ, 'VIEW_GRPC_PORT': str(ports[0]), 'VIEW_WEB_PORT': str(ports[1]),
                   'STEPS': '0', 'CHROMIUM': chromium, 'NODE_PATH': node_path}
    log_path = Path(workdir) / 'view.log'
    with open(log_path, 'w') as log_file:
        view = subprocess.Popen([str(root / 'scripts/view.sh')], cwd=root, env=environment,
                                stdout=log_file, stderr=subprocess.STDOUT,
                                start_new_session=True)
    url = (f'http://127.0.0.1:{ports[1]}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{ports[0]}'
           '%2Fproxy')
    pages = []
    try:
        deadline = time.monotonic() + DEADLINE
        while not START_LINE.search(log_path.read_text(errors='replace')):
            if view.poll() is not None or time.monotonic() > deadline:
                raise SoakError(f'make view did not start; see {log_path}')
            time.sleep(0.5)
        began = time.monotonic()

        def page(name, shots):
            output = open(Path(workdir) / f'{name}.out', 'w')
            process = subprocess.Popen(
                [node, str(root / 'scripts/screenshot_web.js'), url, str(Path(workdir) / name),
                 ','.join(f'{s:g}' for s in shots)],
                env=environment, stdout=output, stderr=subprocess.STDOUT)
            pages.append((name, process, output))
            progress(f'liveview: page {name} opened {time.monotonic() - began:.0f} s into the run')

        page('early', args.early)
        while time.monotonic() < began + args.late:
            if view.poll() is not None:
                raise SoakError(f'make view stopped; see {log_path}')
            time.sleep(1.0)
        page('late', args.late_shots)
        for _, process, output in pages:
            process.wait(timeout=max(args.early + args.late_shots) + DEADLINE)
            output.close()
        time.sleep(11.0)  # one more progress line of the node after the last shot
    finally:
        for _, process, _ in pages:
            if process.poll() is None:
                process.kill()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(view.pid, signal.SIGINT)
        try:
            view.wait(timeout=DEADLINE)
        except subprocess.TimeoutExpired:
            os.killpg(view.pid, signal.SIGKILL)
    log = log_path.read_text(errors='replace')
    findings = []
    for name, _, _ in pages:
        text = (Path(workdir) / f'{name}.out').read_text(errors='replace')
        loaded = re.search(r'^loaded (\d+\.\d+)$', text, re.MULTILINE)
        shots = SHOT_LINE.findall(text)
        if loaded is None or not shots:
            raise SoakError(f'page {name}: no screenshot ({text.strip()[-300:]})')
        opened = node_sim_time(log, float(loaded.group(1)))
        findings.append(f'{name} page (loaded at node t = {opened:.1f} s): ' + ', '.join(
            f'{Path(path).name} node t = {node_sim_time(log, float(asked)):.1f}-'
            f'{node_sim_time(log, float(taken)):.1f} s' for path, asked, taken in shots))
    what = (f'`make view` (the default world, trails 1 s) on ports {ports[0]}/{ports[1]}, '
            f'pages in headless Chromium (SwiftShader), load average '
            f'{os.getloadavg()[0]:.1f} at the end; screenshots in {workdir}')
    row('liveview', what, '; '.join(findings) + ' (compare with the sim_time each page shows)')
    return 0


# Command line ---------------------------------------------------------------------------------

def _seconds(text):
    """'10,40,70': a list of seconds."""
    return [float(part) for part in text.split(',')]


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog='python -m benchmarks.soak',
        description='Long reliability runs of the ball_world node. Each prints progress to '
                    'stderr and a Markdown table row (case | what happened | figure) to '
                    'stdout; exit 0 if its checks held, 1 if not, 2 if it could not run.')
    parser.add_argument('--dir', help="where to make the run's new directory for its "
                                      "recordings and node logs (default: the system's "
                                      'temporary directory); removed at the end unless --keep')
    parser.add_argument('--keep', action='store_true',
                        help='keep the recordings (and the temporary directory)')
    cases = parser.add_subparsers(dest='case')
    kill = cases.add_parser('kill', help='SIGKILL the recording node at random moments, '
                                         'repair each file, count the steps lost')
    kill.add_argument('--times', type=int, default=10)
    kill.add_argument('--balls', type=int, default=1000)
    kill.add_argument('--rate', type=float, default=100.0, help='rate_hz of the node')
    kill.add_argument('--seed', type=int, default=0, help='seed of the kill moments')
    kill.add_argument('--rerun', action='store_true',
                      help='also record a .rrd and report what Rerun reads of it after the kill')
    flood = cases.add_parser('flood', help='flood `impulse` and check every one is applied')
    flood.add_argument('--rate', type=float, default=20000.0, help='impulses per second asked')
    flood.add_argument('--seconds', type=float, default=10.0)
    flood.add_argument('--senders', type=int, default=1, help='sender processes')
    flood.add_argument('--balls', type=int, default=1000)
    steps = cases.add_parser('steps', help='the core alone at full speed for many steps')
    steps.add_argument('--count', type=int, default=1_000_000)
    steps.add_argument('--balls', type=int, default=1000)
    steps.add_argument('--seed', type=int, default=0)
    memory = cases.add_parser('memory', help='RSS of a recording node over minutes')
    recordings = cases.add_parser(
        'recordings', help='the long-run check (the default case): 20 min recording MCAP and '
                           '.rrd split every 60 s keeping 3 of each; the node and its children '
                           'flat from minute 5, every .rrd part verified, at most 3 kept')
    for case, minutes, split, kept in ((memory, 10.0, 0.0, 0), (recordings, 20.0, 60.0, 3)):
        case.add_argument('--minutes', type=float, default=minutes)
        case.add_argument('--every', type=float, default=10.0, help='seconds between samples')
        case.add_argument('--balls', type=int, default=1000)
        case.add_argument('--record', choices=('both', 'mcap', 'rrd', 'none'), default='both',
                          help='what the node records (default both), to tell whose memory '
                               'grows')
        case.add_argument('--split-seconds', type=float, default=split, metavar='S',
                          help='split the MCAP (a bag directory) and the .rrd (parts) every S '
                               f'simulated seconds (record.max_seconds; default {split:g}: '
                               + ('one file)' if not split else 'split)'))
        case.add_argument('--max-files', type=int, default=kept, metavar='K',
                          help='with --split-seconds: keep the newest K files of each '
                               f'(record.max_files; default {kept})')
        case.add_argument('--flat-after', type=float, default=5.0, metavar='MIN',
                          help='memory is judged from this minute on (default 5)')
        case.add_argument('--flat-slope', type=float, default=0.25, metavar='MB',
                          help='flat: the fitted growth of the node, and of the node and its '
                               'children together, at most this many MB a minute (default '
                               '0.25)')
    sinkmemory = cases.add_parser('sinkmemory', help='RSS of a Simulation writing through '
                                                     'one kind of sink, without ROS')
    sinkmemory.add_argument('--minutes', type=float, default=10.0,
                            help='simulated minutes at 100 Hz (default 10)')
    sinkmemory.add_argument('--balls', type=int, default=1000)
    sinkmemory.add_argument('--sinks', choices=('mcap', 'split', 'rrd', 'rrd-process'),
                            default='split')
    sinkmemory.add_argument('--split-seconds', type=float, default=10.0, metavar='S')
    sinkmemory.add_argument('--max-files', type=int, default=2, metavar='K')
    rtf = cases.add_parser('rtf', help='real-time factor of a 10,000-ball node at 100 Hz, '
                                       'publishing and recording MCAP')
    rtf.add_argument('--balls', type=int, default=10_000)
    rtf.add_argument('--speed', type=float, default=24.0,
                     help='random.speed: largest initial speed, m/s (default 24)')
    rtf.add_argument('--seconds', type=float, default=60.0)
    rtf.add_argument('--agents', type=int, default=0,
                     help='make ball_0... agents driven by cmd_vel at 10 Hz (issue 21: 100)')
    rtf.add_argument('--no-record', dest='record', action='store_false',
                     help='record nothing (default: record MCAP)')
    rtf.add_argument('--target', type=float, default=0.99,
                     help='least real-time factor that passes (default 0.99)')
    rtf.add_argument('--scanning-agents', type=int, default=0,
                     help='make ball_0 ... ball_<N-1> agents, each scanning 360 beams at 10 Hz '
                          '(issue 22: 10 in the 10,000-ball world; default 0)')
    rtf.add_argument('--map', metavar='YAML', help='a nav2 map the balls are placed in (radius '
                     '0.1-0.2 m), e.g. the warehouse `python -m benchmarks.warehouse DIR` '
                     'writes (issue 27: 1,000 balls, 100 scanning diff-drive agents)')
    rtf.add_argument('--drive', choices=('omni', 'diff'), help='agent.drive (default: omni)')
    rtf.add_argument('--odom-rate', type=float, default=0.0,
                     help='agent.odom.rate_hz of the --agents (default 0: every step)')
    rtf.add_argument('--listen', type=int, default=0,
                     help="subscribe to this many of the --agents' odom (issue 35: 100)")
    swarm = cases.add_parser('swarm', help='real-time factor of a swarm node: '
                                           'the world of benchmarks.swarm_speed at 10 Hz with '
                                           'its wander controller, recording MCAP')
    swarm.add_argument('--robots', type=int, default=10_000)
    swarm.add_argument('--seconds', type=float, default=60.0)
    swarm.add_argument('--no-record', dest='record', action='store_false')
    swarm.add_argument('--target', type=float, default=0.99)
    startup = cases.add_parser('startup', help='process start to the first `balls` message of '
                                               'the default world, numba cached and cold, numpy')
    startup.add_argument('--repeats', type=int, default=3)
    fulldisk = cases.add_parser('fulldisk', help='record MCAP and .rrd onto a tiny tmpfs (or '
                                                 'under RLIMIT_FSIZE), then SIGINT and SIGTERM')
    fulldisk.add_argument('--balls', type=int, default=3000)
    fulldisk.add_argument('--rate', type=float, default=100.0, help='rate_hz of the node')
    fulldisk.add_argument('--size-mb', type=float, default=2.0, help='size of the tmpfs, MB')
    fulldisk.add_argument('--seconds', type=float, default=5.0,
                          help='how long to count steps after the failure')
    viewer = cases.add_parser('viewer', help='real-time factor while a live Rerun viewer and '
                                             'a subscriber take the data, are frozen, are killed')
    viewer.add_argument('--balls', type=int, default=1000)
    viewer.add_argument('--seconds', type=float, default=30.0,
                        help='length of each phase (default 30: two 10 s progress windows '
                             'of the node)')
    viewer.add_argument('--target', type=float, default=0.99,
                        help='least real-time factor of every phase that passes (default 0.99)')
    liveview = cases.add_parser('liveview', help='make view in headless Chromium: the node '
                                                 'simulated time when a page opened at the '
                                                 'start and one opened late are shot')
    liveview.add_argument('--early', type=_seconds, default=[10.0, 40.0, 70.0, 100.0],
                          help='shots of the first page, s after it loaded (default '
                               '10,40,70,100)')
    liveview.add_argument('--late', type=float, default=300.0,
                          help='s into the run when the second page opens (default 300)')
    liveview.add_argument('--late-shots', type=_seconds, default=[10.0, 40.0],
                          help='shots of the late page, s after it loaded (default 10,40)')
    for case in (kill, flood, steps, memory, recordings, sinkmemory, rtf, fulldisk, viewer):
        case.add_argument('--backend', choices=('auto', 'numpy', 'numba'), default='auto',
                          help='physics.backend of the world (default auto, as the node)')
        case.add_argument('--mode', choices=('seed', 'exact'), default='seed',
                          help='physics.mode of the world (default seed, as the node)')
    argv = sys.argv[1:] if argv is None else argv
    args = parser.parse_args(argv if any(a in cases.choices for a in argv) or '-h' in argv
                             or '--help' in argv else [*argv, 'recordings'])
    # Started as a background job (nohup, `make soak &`), this process ignores SIGINT and its
    # children would inherit that: the node could then not be stopped as Ctrl-C stops it.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    for name in ('times', 'balls', 'count', 'senders', 'repeats'):
        if getattr(args, name, 1) < 1:
            parser.error(f'--{name} must be at least 1')
    runs = {'kill': run_kill, 'flood': run_flood, 'steps': run_steps, 'memory': run_memory,
            'recordings': run_memory,
            'sinkmemory': run_sink_memory, 'rtf': run_rtf, 'swarm': run_swarm,
            'startup': run_startup,
            'fulldisk': run_fulldisk, 'viewer': run_viewer, 'liveview': run_liveview}
    if args.dir:
        os.makedirs(args.dir, exist_ok=True)
    # A directory of its own, new (mkdtemp), even inside --dir: nothing planted in it
    # beforehand (a symlink at a recording's or log's name) can redirect a write.
    workdir = tempfile.mkdtemp(prefix='ball_world_soak_', dir=args.dir or None)
    try:
        return runs[args.case](args, workdir)
    except (SoakError, AssertionError) as error:  # AssertionError: the harness's HarnessError
        print(f'ball_world_soak {args.case}: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'ball_world_soak {args.case}: interrupted', file=sys.stderr)
        return 2
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
        else:
            progress(f'kept {workdir}')


if __name__ == '__main__':
    sys.exit(main())
