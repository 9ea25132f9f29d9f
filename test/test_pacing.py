"""The node's step schedule (core/pacing.py): missed ticks are made up, up to a bound.

Times are made-up numbers, never the clock: the rule is a pure function of due times.
"""
import math
import random

import pytest

from ball_world.core.pacing import MAX_BURST, MAX_LAG, steps_due

PERIOD = 0.01  # 100 Hz
TICK = PERIOD


def test_a_tick_on_time_takes_one_step_and_moves_the_due_time_one_period():
    assert steps_due(1.0, 1.0, PERIOD, TICK) == (1, 1.0 + PERIOD, 0)


def test_nothing_is_taken_before_the_tick_nearest_the_due_time():
    assert steps_due(0.994, 1.0, PERIOD, TICK) == (0, 1.0, 0)
    # Half a tick early is the nearest tick: taken now, not skipped to the next one.
    assert steps_due(0.996, 1.0, PERIOD, TICK)[0] == 1


def test_missed_ticks_are_made_up_in_bursts_without_dropping_time():
    # A 0.25 s hiccup: the steps due at 1.00, 1.01, ..., 1.25 are owed (26 of them).
    now, due, taken = 1.25, 1.0, 0
    while True:
        take, due, dropped = steps_due(now, due, PERIOD, TICK)
        assert dropped == 0 and take <= MAX_BURST
        if not take:
            break
        taken += take
    assert taken == 26
    assert due == pytest.approx(1.26)


def test_lag_beyond_the_bound_is_dropped_and_counted():
    # Two seconds late at 100 Hz: 201 steps owed, 50 (MAX_LAG of them) made up.
    now, due = 3.0, 1.0
    take, due, dropped = steps_due(now, due, PERIOD, TICK)
    allowed = math.floor(MAX_LAG / PERIOD)
    assert dropped == 201 - allowed
    assert take == MAX_BURST
    # What is left to make up after this tick is within the bound.
    assert now - due == pytest.approx(MAX_LAG - MAX_BURST * PERIOD - PERIOD)


def test_a_slow_rate_is_neither_early_nor_dropped_when_its_one_step_is_late():
    period, tick = 10.0, 0.1  # 0.1 Hz, checked every 0.1 s
    assert steps_due(19.9, 20.0, period, tick) == (0, 20.0, 0)
    assert steps_due(19.96, 20.0, period, tick) == (1, 30.0, 0)
    # A step owed 3 s late (more than MAX_LAG) is still one step: the bound never drops it.
    assert steps_due(23.0, 20.0, period, tick) == (1, 30.0, 0)


def test_rate_zero_takes_one_step_per_tick():
    assert steps_due(5.0, 1.0, 0.0, 0.0) == (1, 5.0, 0)


def test_a_timer_a_hair_faster_than_the_schedule_takes_exactly_one_step_per_tick():
    # rcl keeps the period in whole nanoseconds: 1/60 s becomes 16,666,666 ns.
    period = 1.0 / 60.0
    tick = 16_666_666e-9
    due = period
    for k in range(1, 100_000):
        take, due, dropped = steps_due(k * tick, due, period, tick)
        assert (take, dropped) == (1, 0)


def run_timer(seconds, period, stalls, cost):
    """Steps taken by a timer whose ticks come late by `stalls` (s, per tick index).

    The timer behaves as rcl's: a call sets the next tick to the first multiple of the period
    after the call's start, so the ticks missed before it are skipped, and a call that ran
    past that tick is followed at once. Each step costs `cost` s.
    """
    now, due, tick_time = 0.0, period, period
    steps = dropped = 0
    index = 0
    while tick_time < seconds:
        now = max(now, tick_time + stalls(index))
        tick_time = (math.floor(now / period) + 1) * period
        take, due, lost = steps_due(now, due, period, period)
        steps += take
        dropped += lost
        now += take * cost
        index += 1
    return steps, dropped


def test_hiccups_shorter_than_the_bound_keep_the_average_rate():
    # 60 s at 100 Hz, steps costing 3 ms, and every tick late by up to 4 ms with a 0.2 s
    # stall (a marker array, a collection) every 200 ticks: nothing is lost.
    rng = random.Random(7)

    def stalls(index):
        return 0.2 if index % 200 == 199 else rng.uniform(0.0, 0.004)

    steps, dropped = run_timer(60.0, PERIOD, stalls, cost=0.003)
    assert dropped == 0
    assert abs(steps - 6000) <= MAX_LAG / PERIOD  # at most the lag still being made up


def test_a_world_that_costs_more_than_its_rate_drops_time_rather_than_piling_it_up():
    # Steps of 15 ms at 100 Hz: about 2/3 of the steps can be taken, the rest is dropped.
    steps, dropped = run_timer(60.0, PERIOD, lambda index: 0.0, cost=0.015)
    assert steps == pytest.approx(60.0 / 0.015, rel=0.01)
    assert steps + dropped == pytest.approx(6000, abs=MAX_LAG / PERIOD + 1)
