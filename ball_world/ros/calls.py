"""How the node's service calls run: every one answered, none stopping the world.

Why a module of its own: the node steps on the same executor thread that answers its
services, so a call that raises would end the node (rclpy re-raises a callback's exception
from spin), a call that computes for seconds would stop the world for seconds, and a call
that waits in a mutually exclusive group holds the whole group. Here:
- guarded(): any exception of a callback becomes the standard's RESULT_OPERATION_FAILED and
  one log line; the node never dies of a request.
- Calls.turn()/Slices: a long call works in slices of at most SLICE seconds and hands the
  executor back between them, so the stepping timer keeps its rate; calls in flight are
  counted, so that finish() can answer them before the node leaves (QUITTING, max_steps).
- BackgroundSender: rclpy converts a response to C in the thread that sends it, about 40 us
  per EntityState (4 s for 100,000 balls); large answers are sent from a worker thread, which
  shares the GIL with stepping instead of taking it for seconds.
- SERVICE_QOS: rclpy's default service depth of 10 drops the 11th of a burst of concurrent
  requests, unanswered; these keep 1,000.
"""
from concurrent.futures import ThreadPoolExecutor
import functools
import inspect
import time

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from simulation_interfaces.msg import Result

#: Requests (and responses) a service keeps before it would drop any.
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)
#: Shortest time a long call works before handing the executor back, s.
SLICE = 0.005
#: Longest, when the executor keeps control long (large worlds step slowly), s.
MAX_SLICE = 0.1
#: Longest the node waits, when its run ends, for calls in flight to be answered, s.
FINISH_TIMEOUT = 5.0
#: Extra time given to the answers of goals that just ended (result requests), s.
FINISH_GRACE = 0.3
#: Longest text of an exception quoted in an answer or log line, characters.
QUOTED = 160


class Quitting(Exception):
    """The run ended while a call was in flight: it is answered, unfinished."""


class _NextTurn:
    """Awaiting it hands control back to the executor once (a coroutine's yield)."""

    def __await__(self):
        yield


class Stranded:
    """Awaiting it never ends (each turn of the executor it yields again).

    For a goal whose node lost its context (Ctrl-C, SIGTERM, rclpy.shutdown) while it ran:
    feedback, the result and every change of the goal's state are published, and nothing can
    be published any more, so rclpy's own handling (abort, with a traceback) would fail too.
    The goal is left where it is and ends with the process; its client sees the server go.
    """

    def __await__(self):
        while True:
            yield


def describe(error):
    """One bounded line for an exception, even one whose str() itself fails."""
    try:
        text = str(error)
    except Exception:  # noqa: B902 - a message that cannot be made must not fail the answer
        text = ''
    text = text.splitlines()[0] if text else ''
    if len(text) > QUOTED:
        text = text[:QUOTED] + '...'
    return f'{type(error).__name__}: {text}' if text else type(error).__name__


class Calls:
    """The calls of one node: guards, slices and the count of calls in flight."""

    def __init__(self, node):
        self.node = node
        self.in_flight = 0
        self.sender = BackgroundSender(node.get_logger().error)

    async def turn(self):
        """Let the executor run everything else once (the stepping timer first of all)."""
        self.node.wake()
        await _NextTurn()
        if self.node.finished:
            raise Quitting()

    def slices(self):
        return Slices(self)

    def guarded(self, name, callback):
        """The callback, answering RESULT_OPERATION_FAILED (and logging one line) on any
        exception; a coroutine callback is counted in flight while it runs."""
        if inspect.iscoroutinefunction(callback):
            @functools.wraps(callback)
            async def answer(request, response):
                self.in_flight += 1
                try:
                    return await callback(request, response)
                except Quitting:
                    return self._failed(name, response, 'the simulation is quitting')
                except Exception as error:  # noqa: B902 - no request may end the node
                    return self._crashed(name, response, error)
                finally:
                    self.in_flight -= 1
            return answer

        @functools.wraps(callback)
        def answer(request, response):
            try:
                return callback(request, response)
            except Exception as error:  # noqa: B902 - no request may end the node
                return self._crashed(name, response, error)
        return answer

    def _crashed(self, name, response, error):
        line = f'{name}: the request failed with {describe(error)}'
        if self.node.context.ok():  # else it failed because the node is going: no answer
            self.node.get_logger().error(line)  # can be sent, and no log line published
        return self._failed(name, response, line)

    @staticmethod
    def _failed(name, response, message):
        fresh = type(response)()  # the one given may be half filled
        fresh.result = Result(result=Result.RESULT_OPERATION_FAILED, error_message=message)
        return fresh

    def finish(self, spin_once, timeout=FINISH_TIMEOUT):
        """Spin until the calls in flight have answered (they see the run end at their next
        turn) and large answers are sent, at most `timeout` s; then a short grace for the
        answers that follow them (an action's result)."""
        if not self.in_flight and not self.sender.busy:
            return
        deadline = time.monotonic() + timeout
        while (self.in_flight or self.sender.busy) and time.monotonic() < deadline:
            spin_once()
        grace = min(deadline, time.monotonic() + FINISH_GRACE)
        while time.monotonic() < grace:
            spin_once()
        self.sender.close()


class Slices:
    """give_way() hands the executor back once the current slice has lasted long enough.

    A slice lasts SLICE, or as long as the executor kept control the last time (at most
    MAX_SLICE): a world whose step takes 150 ms (100,000 balls) then shares the thread about
    equally with the call, instead of giving it 5 ms per step and the call taking minutes.
    """

    def __init__(self, calls):
        self._calls = calls
        self._start = time.monotonic()
        self._length = SLICE

    async def give_way(self):
        left = time.monotonic()
        if left - self._start < self._length:
            return
        await self._calls.turn()
        self._start = time.monotonic()
        self._length = min(MAX_SLICE, max(SLICE, self._start - left))


class BackgroundSender:
    """Sends large responses of a service from one worker thread, in order.

    send_response of a Service is replaced (wrap()): responses for which `large(response)`
    holds go to the worker; others are sent at once, as rclpy would.
    """

    def __init__(self, report):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='ball_world-send')
        self._futures = set()
        self._report = report

    @property
    def busy(self):
        return any(not future.done() for future in list(self._futures))

    def wrap(self, service, large):
        send_now = service.send_response

        def send_response(response, header):
            if not large(response):
                return send_now(response, header)
            future = self._pool.submit(send_now, response, header)
            self._futures.add(future)
            future.add_done_callback(self._sent)
        service.send_response = send_response
        return service

    def _sent(self, future):
        self._futures.discard(future)
        error = future.exception()
        if error is not None:
            # A client gone, or the node closing: nobody is left to tell but the log.
            self._report(f'a large answer could not be sent: {describe(error)}')

    def close(self):
        self._pool.shutdown(wait=True, cancel_futures=False)
