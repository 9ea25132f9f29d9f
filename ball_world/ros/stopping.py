"""One rule for every spin loop of the package: a signal is a normal way to stop.

Ctrl-C or SIGTERM reaches a spinning rclpy program as KeyboardInterrupt or
ExternalShutdownException, but also as whatever the call in progress raises once the context
is gone: a publish fails with RCLError, a message being taken with a RuntimeError from its
conversion. Those are stops too, once rclpy says the context is down; with the context still
valid they are real errors and go on up.
"""
import contextlib

import rclpy
from rclpy.executors import ExternalShutdownException


@contextlib.contextmanager
def stopped_by_signal():
    """Run the spin loop inside this: a stop by signal ends it quietly."""
    try:
        yield
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: B902 - whatever the interrupted call raises
        if rclpy.ok():
            raise
