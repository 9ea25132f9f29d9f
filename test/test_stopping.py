"""The spin loops' stop rule (ros/stopping.py): signals stop quietly, real errors go up."""
import threading

import pytest
import rclpy
from rclpy.executors import ExternalShutdownException

from ball_world.ros import stopping
from ball_world.ros.stopping import stopped_by_signal


@pytest.fixture
def context():
    rclpy.init(args=['test_stopping'])
    yield
    rclpy.try_shutdown()


@pytest.mark.parametrize('signal_error', [KeyboardInterrupt, ExternalShutdownException])
def test_a_signal_stops_quietly(context, signal_error):
    with stopped_by_signal():
        raise signal_error()


def test_an_error_with_the_context_valid_is_raised(context, monkeypatch):
    monkeypatch.setattr(stopping, 'SHUTDOWN_GRACE', 0.05)
    with pytest.raises(ValueError, match='a real bug'):
        with stopped_by_signal():
            raise ValueError('a real bug')


def test_an_error_while_rclpy_finishes_a_signals_shutdown_is_a_stop(context):
    # rclpy shuts the context down on its own thread, just after the interrupted call failed.
    threading.Timer(0.2, rclpy.try_shutdown).start()
    with stopped_by_signal():
        raise RuntimeError("Unable to convert call argument '0' to Python object")
    assert not rclpy.ok()


def test_ctrl_c_waits_for_rclpy_to_take_the_context_down(context):
    # Python raises KeyboardInterrupt in the main thread while rclpy's signal thread is still
    # shutting the context down: what runs after the loop must see it down, or a line logged
    # there goes to a /rosout publisher that is invalid by the time it publishes.
    threading.Timer(0.2, rclpy.try_shutdown).start()
    with stopped_by_signal():
        raise KeyboardInterrupt()
    assert not rclpy.ok()
