"""ball_world as its users meet it, for the tests and the soak runs.

- Executables: the console scripts of the installed ball_world, found where its installation
  put them: `<prefix>/lib/ball_world` of the package the ament index names (colcon, and what
  `ros2 run` runs), beside the running Python (pip into a virtual environment, `make test`),
  or else on PATH.
- Child processes: started with their output kept (pipes, or a log file for long runs),
  finished within a deadline, and killed when the test or run that started them ends.
- Probe: a node in an rclpy context of its own, so that it meets the node under test as
  another process would; it listens, calls services, sets parameters, and waits with
  deadlines that fail naming what they waited for.
- Recordings: the messages of an MCAP as mcap, mcap-ros2-support and rosbags each read them;
  a sink keeping the truth a recording is compared with; an MCAP rewritten with edits.
- Rerun: the CLI binary that rerun-sdk ships, and an .rrd read by Rerun's own reader.

Whatever goes wrong here raises HarnessError, an AssertionError: a test fails with its
message, and a soak run reports it as a run that could not be carried out.
"""
import contextlib
import dataclasses
import os
from pathlib import Path
import resource
import shutil
import subprocess
import sys
import time
import warnings

from ament_index_python.packages import get_package_prefix, PackageNotFoundError
from geometry_msgs.msg import PoseArray, Vector3Stamped
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
import rerun as rr
import rerun_cli
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import get_typestore, Stores
from std_msgs.msg import Float64MultiArray

from ball_world.recording.mcap_reader import Scan
from ball_world.recording.rerun_log import BALLS, STEP
from ball_world.ros.rcl_init import creating_node

PACKAGE = 'ball_world'
#: Seconds to wait for anything that must happen (discovery, an answer, an exit): generous,
#: since two noisy shared cores may be slow; only a hang takes this long.
DEADLINE = 120.0
#: How a probe subscribes unless told otherwise: reliable and deep, so that it misses nothing.
RECEIVE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
#: The Rerun CLI itself. The `rerun` console script only runs this binary as its child, and a
#: viewer killed through the script would live on.
RERUN = Path(rerun_cli.__file__).parent / 'rerun'
#: How much of a child's output a failure message quotes (its end).
QUOTED = 2000


class HarnessError(AssertionError):
    """A deadline passed, a child exited when it should not have, or something is missing."""


# Executables ----------------------------------------------------------------------------------

def executable(name):
    """The path of ball_world's console script `name`, as installed."""
    places = _install_places()
    for place in places:
        path = place / name
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
    found = shutil.which(name)
    if found is None:
        raise HarnessError(
            f'{name} is installed neither in {", ".join(map(str, places))} nor on PATH: '
            'install ball_world (make setup, or colcon build, then source install/setup.bash)')
    return found


def _install_places():
    """Folders that may hold the console scripts, the one `ros2 run` would use first.

    The ament index names the prefix of the ball_world it knows (AMENT_PREFIX_PATH, set by
    sourcing a workspace and by colcon test): colcon puts the scripts in its lib/ball_world,
    pip in its bin. Without an index, the scripts are those of the environment this Python
    belongs to.
    """
    places = []
    if os.environ.get('AMENT_PREFIX_PATH'):
        try:
            prefix = Path(get_package_prefix(PACKAGE))
        except PackageNotFoundError:
            pass
        else:
            places += [prefix / 'lib' / PACKAGE, prefix / 'bin']
    return places + [Path(sys.executable).parent]


# Child processes ------------------------------------------------------------------------------

class Child(subprocess.Popen):
    """A child process started by start(), which can quote the end of its output."""

    #: The file its stdout and stderr go to, or None when they are pipes.
    log = None

    def tail(self, piped=''):
        """The end of what it wrote: its log file, or else `piped` (text read from a pipe)."""
        text = self.log.read_text(errors='replace') if self.log is not None else piped or ''
        return text[-QUOTED:]


def start(command, log=None, limit_file_size=None, **options):
    """Start a child with its output kept as text; Popen options override the defaults.

    The output goes to pipes, read when it ends (finish), or with `log` to that file, stdout
    and stderr together: a long run's pipes, which nobody reads, would fill and block it.
    limit_file_size caps every file the child writes (RLIMIT_FSIZE), to fill a disk on purpose.
    """
    settings = {'stdout': subprocess.PIPE, 'stderr': subprocess.PIPE, 'text': True}
    if limit_file_size is not None:
        settings['preexec_fn'] = lambda: resource.setrlimit(
            resource.RLIMIT_FSIZE, (limit_file_size, limit_file_size))
    settings.update(options)
    if log is None:
        return Child([str(part) for part in command], **settings)
    with open(log, 'w') as stream:
        child = Child([str(part) for part in command],
                      **{**settings, 'stdout': stream, 'stderr': subprocess.STDOUT})
    child.log = Path(log)
    return child


def node_command(*parameters, ros_args=()):
    """The node's command line: `-p` before each 'name:=value', then other ROS arguments."""
    command = [executable(PACKAGE), '--ros-args']
    for parameter in parameters:
        command += ['-p', parameter]
    return command + list(ros_args)


def start_node(*parameters, ros_args=(), **options):
    """The installed node in a child process (see node_command and start)."""
    return start(node_command(*parameters, ros_args=ros_args), **options)


def run_tool(name, *args, timeout=DEADLINE):
    """(exit code, stdout, stderr) of ball_world's console script `name` run to its end."""
    return finish(start([executable(name), *args]), timeout)


def finish(process, timeout=DEADLINE):
    """(exit code, stdout, stderr) once the child has exited on its own; killed if it hangs."""
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate()
        raise HarnessError(f'{_name(process)} did not exit within {timeout:g} s: '
                           f'{process.tail(err)}')
    return process.returncode, out, err


def check_running(process):
    """Fail if the child has exited, quoting its exit code and the end of its output."""
    if process.poll() is not None:
        out, err = process.communicate()
        raise HarnessError(f'{_name(process)} exited early with code {process.returncode}: '
                           f'{process.tail(err or out)}')


def kill(process):
    """Kill the child unless it has exited, wait for it and close its pipes (again: no harm)."""
    if process.poll() is None:
        process.kill()
    process.wait()
    for stream in (process.stdin, process.stdout, process.stderr):
        if stream is not None:
            stream.close()


def _name(process):
    return Path(process.args[0]).name


class Children:
    """The children of one test or run: close() kills those still running."""

    def __init__(self):
        self.started = []

    def start(self, command, **options):
        self.started.append(start(command, **options))
        return self.started[-1]

    def start_node(self, *parameters, ros_args=(), **options):
        return self.start(node_command(*parameters, ros_args=ros_args), **options)

    def close(self):
        for child in self.started:
            kill(child)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()


# Probe ----------------------------------------------------------------------------------------

#: A probe's participant: Fast DDS's UDP transport alone (see Probe). rmw_fastrtps adds
#: shared memory to a LOCALHOST discovery range of its own, so a probe's rcl context takes
#: the SUBNET range; the test's own domain keeps it apart, and the nodes a test starts,
#: LOCALHOST, announce themselves on the loopback, where it hears them.
PROBE_SETTINGS = {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}


@contextlib.contextmanager
def udp_only():
    """Fast DDS reads FASTDDS_BUILTIN_TRANSPORTS when it makes a participant (a context's
    first node): set for that moment only, so that the nodes a test starts keep the
    transports a user's have."""
    settings = PROBE_SETTINGS
    before = {name: os.environ.get(name) for name in settings}
    os.environ.update(settings)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                del os.environ[name]
            else:
                os.environ[name] = value


class Heard(list):
    """What a probe's subscription received, in order; `subscription` is the subscription."""

    subscription = None


class Probe:
    """A node in an rclpy context of its own, spun only while the probe waits.

    Its own context gives it its own DDS participant: it discovers the node under test and is
    discovered by it as a separate process would be. add_node() spins another node of the
    same context along with it (a node under test in this process). `timeout` is how long it
    waits for anything unless told otherwise.

    The participant talks over UDP only (PROBE_TRANSPORTS), never Fast DDS's shared memory:
    a peer that dies (SIGKILL) while it writes into a shared-memory port leaves that port's
    interprocess mutex locked, Fast DDS then gives the port up, and deleting the
    participant later locks the mutex in memory no longer mapped: the SIGSEGV in
    `destroy_node` that ended test workers (docs/reliability.md has the native backtrace).
    Tests kill nodes on purpose, and the fixtures kill what a test left running.
    """

    def __init__(self, name='probe', namespace=None, domain_id=None, timeout=DEADLINE):
        self.timeout = timeout
        self.context = rclpy.Context()
        with udp_only():
            rclpy.init(context=self.context, domain_id=domain_id)
        # No /rosout publisher: rcl keeps those in one table per process, keyed by node name
        # and not thread-safe, and a test worker makes hundreds of nodes named alike, each in
        # a context of its own; a probe logs nothing a test reads from /rosout.
        with creating_node(keep=True), udp_only():  # a test that cannot join says why
            self.node = rclpy.create_node(name, namespace=namespace, context=self.context,
                                          enable_rosout=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._nodes = [self.node]

    def add_node(self, node):
        """Spin `node` (created in self.context) too; close() destroys it."""
        self.executor.add_node(node)
        self._nodes.append(node)
        return node

    def listen(self, msg_type, topic, keep=None, qos=RECEIVE_QOS, raw=False):
        """Subscribe; returns the Heard list the messages (or keep(message)) arrive in."""
        heard = Heard()
        heard.subscription = self.node.create_subscription(
            msg_type, topic, lambda msg: heard.append(msg if keep is None else keep(msg)),
            qos, raw=raw)
        return heard

    def wait_for(self, predicate, timeout=None):
        """Spin until predicate() holds or the timeout passes; returns predicate()."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while not predicate() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def spin_until(self, predicate, what='the condition', timeout=None, process=None):
        """Spin until predicate() holds; fail if the timeout passes or `process` exits first."""
        timeout = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise HarnessError(f'timed out after {timeout:g} s waiting for {what}')
            if process is not None:
                check_running(process)
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds):
        """Spin for this long, whatever arrives: to see that something does not happen."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def drain(self, heard):
        """Spin until a pass takes nothing more (`heard()` counts what arrived so far): the
        messages a node sent just before it exited, still queued here."""
        before = None
        while before != heard():
            before = heard()
            self.executor.spin_once(timeout_sec=0.1)

    def result(self, future, what='the answer', timeout=None):
        """The result of a future (a service call, an action goal) once it is done."""
        self.spin_until(future.done, what, timeout)
        return future.result()

    def call(self, srv_type, name, request, timeout=None):
        """The response of service `name` to `request`, once it is offered and has answered."""
        client = self.node.create_client(srv_type, name)
        try:
            self.spin_until(client.service_is_ready, f'the service {name}', timeout)
            return self.result(client.call_async(request), f'the answer of {name}', timeout)
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node_name, values, timeout=None):
        """Set parameters of node `node_name` through its parameter service; all must succeed."""
        client = AsyncParameterClient(self.node, node_name)
        self.spin_until(client.services_are_ready, f'the parameter services of {node_name}',
                        timeout)
        future = client.set_parameters([Parameter(name, value=value)
                                        for name, value in values.items()])
        results = self.result(future, f'{node_name} to set its parameters', timeout).results
        if not all(result.successful for result in results):
            raise HarnessError(f'{node_name} refused parameters {values}: {results}')

    def close(self):
        """Leave the graph, destroying every node spun here (a second call does nothing)."""
        if self.context.ok():
            self.executor.shutdown()
            for node in reversed(self._nodes):
                node.destroy_node()
            rclpy.try_shutdown(context=self.context)


class InProcessWorld:
    """A BallWorld node in this process, spun by a Probe of the same context.

    Faster than a node process and lets a test look inside (`node.simulation`), while its
    topics and services are still reached over DDS, as a client would. `balls` and `states`
    hold what the probe heard on `balls` and `state`.
    """

    def __init__(self, **parameters):
        from ball_world.ros.node import BallWorld  # the harness itself needs no node
        self.probe = Probe()
        overrides = [Parameter(name, value=value) for name, value in parameters.items()]
        self.node = self.probe.add_node(BallWorld(context=self.probe.context,
                                                  parameter_overrides=overrides,
                                                  enable_rosout=False))  # as a probe's
        self.executor = self.probe.executor
        self.balls = self.probe.listen(PoseArray, 'balls')
        self.states = self.probe.listen(Float64MultiArray, 'state')
        self.impulses = self.probe.node.create_publisher(Vector3Stamped, 'impulse',
                                                         RECEIVE_QOS)

    @property
    def simulation(self):
        return self.node.simulation

    def spin_until(self, predicate, what='the condition', timeout=None):
        self.probe.spin_until(predicate, what, timeout=timeout)

    def call(self, srv_type, name, request):
        """Call one of the node's services by its name relative to the node (`reset`)."""
        return self.probe.call(srv_type, f'/ball_world/{name}', request)

    def impulse(self, frame_id, x, y, z=0.0):
        msg = Vector3Stamped()
        msg.header.frame_id = frame_id
        msg.vector.x, msg.vector.y, msg.vector.z = x, y, z
        self.spin_until(lambda: self.impulses.get_subscription_count() > 0,
                        'the node to hear impulses')
        self.impulses.publish(msg)

    def close(self):
        self.node.close()
        self.probe.close()


# Recordings -----------------------------------------------------------------------------------

#: The message types `ros2 bag` knows on Jazzy, as rosbags has them.
ROSBAGS_TYPES = get_typestore(Stores.ROS2_JAZZY)


def read_mcap(path, topics=None):
    """(topic, log time, CDR bytes) of each message, as mcap's reader gives them.

    A file without its summary fails: a finished or repaired recording has one.
    """
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        if reader.get_summary() is None:
            raise HarnessError(f'{path}: mcap finds no summary')
        return [(channel.topic, message.log_time, message.data)
                for _, channel, message in reader.iter_messages(topics=topics)]


def read_mcap_ros2(path, topics=None):
    """(topic, log time, ROS message) of each message, decoded by mcap-ros2-support from the
    schemas in the file (what Foxglove reads)."""
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(item.channel.topic, item.message.log_time, item.decoded_message)
                for item in reader.iter_decoded_messages(topics=topics)]


def read_rosbags(path, topics=None):
    """(topic, log time, ROS message) of each message, read and decoded by rosbags as a
    rosbag2 storage of Jazzy types (what `ros2 bag` reads)."""
    with RosbagsReader(path) as reader:
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        if not connections:
            return []  # rosbags reads every connection when given none
        return [(connection.topic, log_time,
                 ROSBAGS_TYPES.deserialize_cdr(data, connection.msgtype))
                for connection, log_time, data in reader.messages(connections=connections)]


#: Each reader by the name a report gives it.
READERS = {'mcap': read_mcap, 'mcap_ros2': read_mcap_ros2, 'rosbags': read_rosbags}


class Truth:
    """A Sink keeping every segment and step record it is given: what a recording of the
    same run must hold."""

    def __init__(self):
        self.segments = []  # (WorldSnapshot, RunInfo)
        self.records = []
        self.flushes = 0
        self.closed = False

    def start_segment(self, world, info):
        self.segments.append((world, info))

    def write_step(self, record):
        self.records.append(record)

    def flush(self):
        self.flushes += 1

    def close(self):
        self.closed = True


def rewrite_recording(source, target, metadata=None, data=None, edit=None):
    """Copy an MCAP record by record through mcap's Writer (zstd), changing it on the way: how
    a test makes a bad recording from a good one. Returns target.

    metadata(values) gives each metadata record's new values, data(topic, log_time, data) each
    message's new bytes; edit(record), for any other change, the record to write in place of
    any record (dataclasses.replace of it), or None to leave the record out.
    """
    with open(source, 'rb') as stream, open(target, 'wb') as out:
        writer = Writer(out, compression=CompressionType.ZSTD)
        topics = {}
        for item in Scan(stream, os.path.getsize(source)).records():
            kind = type(item).__name__
            if kind == 'Channel':
                topics[item.id] = item.topic
            elif kind == 'Metadata' and metadata is not None:
                item = dataclasses.replace(item, metadata=metadata(dict(item.metadata)))
            elif kind == 'Message' and data is not None:
                item = dataclasses.replace(
                    item, data=data(topics[item.channel_id], item.log_time, item.data))
            if edit is not None:
                item = edit(item)
            _write_record(writer, item)
        writer.finish()
    return target


def without_messages(source, target, dropped):
    """A copy of an MCAP (rewrite_recording) without the messages of every topic for which
    dropped(topic) holds; their channels stay, as in a recording that published nothing there
    (an older one, or a filtered copy). Returns target."""
    topics = {}

    def edit(item):
        kind = type(item).__name__
        if kind == 'Channel':
            topics[item.id] = item.topic
        elif kind == 'Message' and dropped(topics[item.channel_id]):
            return None
        return item

    return rewrite_recording(source, target, edit=edit)


def _write_record(writer, item):
    kind = type(item).__name__
    if kind == 'Header':
        writer.start(item.profile, item.library)
    elif kind == 'Schema':
        writer.register_schema(item.name, item.encoding, item.data)
    elif kind == 'Channel':
        writer.register_channel(item.topic, item.message_encoding, item.schema_id,
                                item.metadata)
    elif kind == 'Metadata':
        writer.add_metadata(item.name, item.metadata)
    elif kind == 'Message':
        writer.add_message(item.channel_id, item.log_time, item.data, item.publish_time,
                           item.sequence)


# Rerun ----------------------------------------------------------------------------------------

def run_rerun(*args, timeout=DEADLINE):
    """Run the Rerun CLI; the CompletedProcess, with its output as text."""
    return subprocess.run([str(RERUN), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def open_rrd(path):
    """Rerun's reader on an .rrd. A file without a footer (what `rerun --save` and a killed
    node leave) is read by a scan of the whole file, without the SDK's warning about it."""
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', 'RRD file has no footer')
        return rr.chunk.RrdReader(path)


def rrd_ball_steps(path):
    """For each recording in an .rrd, the sorted steps at which it holds ball positions."""
    reader = open_rrd(path)
    found = []
    for store in reader.recordings():
        steps = []
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if chunk.entity_path == f'/{BALLS}' and 'Points2D:positions' in batch.schema.names:
                steps += batch.column(STEP).to_pylist()
        found.append(sorted(steps))
    return found
