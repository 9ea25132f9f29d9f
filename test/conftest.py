"""Test isolation for ROS, and the harness's fixtures (ball_world_testing.harness).

Every pytest process gets its own DDS domain, on localhost only. Tests that start the node as
a subprocess inherit these variables, so two test runs on one machine (or a user's own nodes)
can never hear each other.
"""
import os
import signal

from ball_world_testing.harness import Children, Probe
import pytest

if 'BALL_WORLD_TEST_DOMAIN' not in os.environ:
    os.environ['BALL_WORLD_TEST_DOMAIN'] = str(1 + os.getpid() % 50 * 4)
# pytest-xdist's workers (gw0, gw1, ...) inherit the run's variables: each takes a domain of
# its own next to the run's (ids up to 232 are valid on Linux).
_worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw')
os.environ['ROS_DOMAIN_ID'] = str(
    int(os.environ['BALL_WORLD_TEST_DOMAIN']) + (int(_worker) % 4 if _worker.isdigit() else 0))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
# The Rerun SDK logs its own errors (a viewer a test left unreachable on purpose, retried
# until the process ends) after pytest's summary; ball_world reports such failures itself.
os.environ.setdefault('RUST_LOG', 'off')
# A test run started as a background job (`make test &`, nohup) ignores SIGINT, and children
# inherit an ignored signal: the nodes, viewers and tools that tests stop with SIGINT, as a
# user's Ctrl-C would, then never stop. Give them the default disposition back.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def processes():
    """Children (node, tools, scripts) of a test: killed if the test ends while they run."""
    with Children() as children:
        yield children


@pytest.fixture
def probes(processes):
    """Probe(name, ...) factory; every probe leaves the graph when the test ends, before the
    test's processes are killed (a probe outlives no peer killed while it wrote to it)."""
    made = []

    def make(name='probe', **options):
        made.append(Probe(name, **options))
        return made[-1]

    yield make
    for probe in made:
        probe.close()


@pytest.fixture
def probe(probes):
    """One probe named 'probe'."""
    return probes()
