"""ball_world_soak: long reliability runs of the node, each ending in one result table row.

The test suite checks each failure mode once, quickly; these runs repeat them long enough to
give figures: how much a SIGKILL loses over many kills, whether an impulse flood is applied
in full, whether the core stays exact over a million steps, whether memory grows over
minutes of recording. Every case prints progress to stderr and one Markdown table row
(case | what happened | figure) to stdout, and exits 0 when its checks held, 1 when one
failed, 2 when it could not run.

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


# The node as a subprocess ---------------------------------------------------------------------

def _harness():
    """The test harness, imported by the cases that use it: with it come ROS and Rerun."""
    from ball_world_testing import harness
    return harness


class NodeProcess:
    """The node in a subprocess, with its output in a log file (a pipe could fill and block)."""

    def __init__(self, workdir, namespace, name, parameters):
        self.log_path = Path(workdir) / f'{name}.log'
        self.process = _harness().start_node(
            *(f'{key}:={value}' for key, value in parameters.items()),
            ros_args=['-r', f'__ns:={namespace}'], log=self.log_path)
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
        factors = []
        for line in self.log().splitlines():
            if 'real-time factor' in line:
                try:
                    factors.append(float(line.split('real-time factor ')[1].split(',')[0]))
                except (IndexError, ValueError):
                    pass
        return factors


def world_parameters(args, seed=0):
    """Node parameters of a world of args.balls random balls, loosely packed (~8% of a box)."""
    side = arena_side(args.balls)
    return {'random.count': args.balls, 'random.seed': seed,
            'arena': f'[0.0, 0.0, {side}, {side}]', 'markers.rate_hz': 0.0, 'dt': DT,
            'physics.backend': args.backend}


def arena_side(balls):
    """Side of a square arena that random balls (mean area ~0.13 m^2) fill to about 8%."""
    return float(max(10, math.ceil(math.sqrt(balls * 0.13 / 0.08))))


class Listener:
    """A probe (a node in its own context) that hears the soaked node's `balls` and `stats`.

    It takes the messages as CDR bytes and decodes only what it needs with ball_world.msgs.cdr:
    rclpy's conversion of a 1,000-pose PoseArray would cost this process a whole core at
    100 Hz, taken from the node it measures.
    """

    def __init__(self, namespace, stats=False):
        from geometry_msgs.msg import PoseArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64MultiArray
        self.probe = _harness().Probe('soak_listener')
        self.last_step = -1
        self.heard = 0
        self.real_time_factor = math.nan
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.probe.node.create_subscription(PoseArray, f'{namespace}/balls', self._on_balls,
                                            qos, raw=True)
        if stats:
            self.probe.node.create_subscription(Float64MultiArray, f'{namespace}/stats',
                                                self._on_stats, qos, raw=True)

    def _on_balls(self, data):
        stamp_ns = decode_pose_array(data)[0]
        self.last_step = max(self.last_step, round(stamp_ns / (DT * 1e9)))
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
    row(f'flood --rate {args.rate:g} --senders {args.senders}', what, figure)
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
                             'physics.backend': args.backend})
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
    what = (f'Simulation ({args.backend}), {args.balls} balls in a {side:g} m box, '
            f'{simulation.step_index:,} steps in {elapsed:.0f} s '
            f'({simulation.step_index / elapsed:,.0f} steps/s): '
            + (bad or 'no NaN, every centre inside the arena'))
    row(f'steps --count {args.count:,}', what,
        f'energy drift {drift:.2e} (largest at the 10% marks '
        f'{max(worst_drift, abs(drift)):.2e}); RSS '
        f'{rss_start:.0f} -> {rss_end:.0f} MB')
    return 0 if bad is None and abs(drift) < 1e-9 else 1


# memory ---------------------------------------------------------------------------------------

def run_memory(args, workdir):
    from ball_world.recording.mcap_reader import Recording
    ns = namespace()
    mcap_path, rrd_path = Path(workdir) / 'memory.mcap', Path(workdir) / 'memory.rrd'
    recordings = {}
    if args.record in ('mcap', 'both'):
        recordings['record.mcap'] = mcap_path
    if args.record in ('rrd', 'both'):
        recordings['record.rerun'] = rrd_path
    node = NodeProcess(workdir, ns, 'memory', {**world_parameters(args), 'rate_hz': 100.0,
                                               **recordings})
    listener = Listener(ns)
    samples = []
    try:
        listener.spin_until(lambda: listener.heard > 0, 'the first step', node)
        began = time.monotonic()
        end = began + args.minutes * 60.0
        next_sample = began + args.every
        while time.monotonic() < end:
            node.check_alive()
            listener.spin(0.1)
            if time.monotonic() >= next_sample:
                samples.append((time.monotonic() - began, rss_mb(node.pid)))
                next_sample += args.every
                progress(f'memory: {samples[-1][0]:.0f} s, RSS {samples[-1][1]:.1f} MB, '
                         f'step {listener.last_step}, MCAP {_size_mb(mcap_path):.0f} MB, '
                         f'.rrd {_size_mb(rrd_path):.0f} MB')
        steps = listener.last_step
        code = node.stop(signal.SIGINT)
    finally:
        node.kill()
        listener.close()
    if len(samples) < 2:
        raise SoakError('fewer than two RSS samples: give --minutes more than --every')
    times = np.array([t for t, _ in samples])
    rss = np.array([r for _, r in samples])
    growth = (rss[-1] - rss[0]) / rss[0] * 100.0
    warm = min(60.0, times[-1] / 2)  # the first minute (or half) is warm-up
    later = times >= warm
    slope = np.polyfit(times[later] / 60.0, rss[later], 1)[0] if later.sum() >= 2 else 0.0
    checks = [f'SIGINT exit {code}']
    fine = code == 0
    if 'record.mcap' in recordings:
        finished = Recording(mcap_path).has_summary
        fine = fine and finished
        checks.append(f'MCAP {_size_mb(mcap_path):,.0f} MB, summary {finished}')
    if 'record.rerun' in recordings:
        verify = rerun_cli('rrd', 'verify', rrd_path)
        fine = fine and verify[0] == 0
        checks.append(f'.rrd {_size_mb(rrd_path):,.0f} MB, `rerun rrd verify` '
                      + ('passes' if verify[0] == 0 else f'FAILS: {verify[1][-200:]}'))
    if not args.keep:
        for path in (mcap_path, rrd_path):
            if path.exists():
                path.unlink()
    rtf = node.real_time_factors()
    recorded = {'both': 'MCAP and .rrd', 'mcap': 'MCAP', 'rrd': '.rrd', 'none': 'nothing'}
    what = (f'{args.balls} balls at 100 Hz recording {recorded[args.record]} for '
            f'{args.minutes:g} min ({steps:,} steps); real-time factor '
            + (f'{min(rtf):.2f}-{max(rtf):.2f}' if rtf else 'n/a') + '; ' + ', '.join(checks))
    row(f'memory --minutes {args.minutes:g} --record {args.record}', what,
        f'RSS {rss[0]:.0f} MB at {times[0]:.0f} s -> {rss[-1]:.0f} MB at {times[-1]:.0f} s: '
        f'{growth:+.1f}% ({slope:+.2f} MB/min fitted from {warm:.0f} s on)')
    return 0 if fine else 1


def _size_mb(path):
    return path.stat().st_size / 2**20 if path.exists() else 0.0


# Command line ---------------------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(
        prog='python -m benchmarks.soak',
        description='Long reliability runs of the ball_world node. Each prints progress to '
                    'stderr and a Markdown table row (case | what happened | figure) to '
                    'stdout; exit 0 if its checks held, 1 if not, 2 if it could not run.')
    parser.add_argument('--dir', help='where to write recordings and node logs (default: a '
                                      'new temporary directory, removed at the end)')
    parser.add_argument('--keep', action='store_true',
                        help='keep the recordings (and the temporary directory)')
    cases = parser.add_subparsers(dest='case', required=True)
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
    memory.add_argument('--minutes', type=float, default=10.0)
    memory.add_argument('--every', type=float, default=10.0, help='seconds between samples')
    memory.add_argument('--balls', type=int, default=1000)
    memory.add_argument('--record', choices=('both', 'mcap', 'rrd', 'none'), default='both',
                        help='what the node records (default both), to tell whose memory grows')
    for case in (kill, flood, steps, memory):
        case.add_argument('--backend', choices=('numpy', 'numba'), default='numpy',
                          help='physics.backend of the world (default numpy)')
    args = parser.parse_args(argv)
    for name in ('times', 'balls', 'count', 'senders'):
        if getattr(args, name, 1) < 1:
            parser.error(f'--{name} must be at least 1')
    runs = {'kill': run_kill, 'flood': run_flood, 'steps': run_steps, 'memory': run_memory}
    workdir = args.dir or tempfile.mkdtemp(prefix='ball_world_soak_')
    os.makedirs(workdir, exist_ok=True)
    try:
        return runs[args.case](args, workdir)
    except (SoakError, AssertionError) as error:  # AssertionError: the harness's HarnessError
        print(f'ball_world_soak {args.case}: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'ball_world_soak {args.case}: interrupted', file=sys.stderr)
        return 2
    finally:
        if not args.dir and not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
        elif args.keep:
            progress(f'kept {workdir}')


if __name__ == '__main__':
    sys.exit(main())
