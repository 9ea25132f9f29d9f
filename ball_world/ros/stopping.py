"""One rule for every spin loop of the package: a signal is a normal way to stop.

Ctrl-C or SIGTERM reaches a spinning rclpy program as KeyboardInterrupt or
ExternalShutdownException, but also as whatever the call in progress raises: a publish fails
with RCLError once the context is gone, and a message being taken fails with pybind11's
RuntimeError ("Unable to convert call argument '0'") when the interrupt lands inside the
message's Python constructor. rclpy shuts its contexts down on a thread of its own after the
signal, so at that instant `rclpy.ok()` may still say True: such an error counts as a stop if
the context goes down within a short grace; with the context still valid after it, it is a
real error and goes on up. KeyboardInterrupt itself can come first, too: the loop waits for
the shutdown before it lets the program go on, so that what runs after it (closing the
recordings, a last word logged) sees the context as it will be and never logs through a
/rosout publisher that goes invalid mid-call.
"""
import contextlib
import time

import rclpy
from rclpy.executors import ExternalShutdownException

#: Seconds an error waits for rclpy to finish a signal's shutdown before it counts as real.
SHUTDOWN_GRACE = 1.0


@contextlib.contextmanager
def stopped_by_signal():
    """Run the spin loop inside this: a stop by signal ends it quietly."""
    try:
        yield
    except KeyboardInterrupt:
        _shutting_down(SHUTDOWN_GRACE)  # rclpy's own thread may not have finished yet
    except ExternalShutdownException:
        pass
    except Exception:  # noqa: B902 - whatever the interrupted call raises
        if not _shutting_down(SHUTDOWN_GRACE):
            raise


def _shutting_down(grace):
    """Whether rclpy's context is down, or goes down within `grace` seconds."""
    deadline = time.monotonic() + grace
    while rclpy.ok():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True
