"""When the node steps: a due-time schedule on the wall clock that makes up a bounded lag.

A step costs the node 2-4 ms of its 10 ms at 10,000 balls and 100 Hz, yet a tick of its
timer comes late whenever something else held the process (a marker array, a garbage
collection, another thread holding the GIL, another process on the core). A timer alone
skips the ticks it missed, so every such hiccup was lost for good and the real-time factor
stayed below 1 with time to spare. Here step k is due at `due + k * period` whatever the
ticks did: a tick takes every step due by then, several at once after a hiccup, so the
average rate holds whenever the average cost fits.

Making up lag has a bound. A world that costs more than its period can never catch up, and
a machine suspended for an hour must not answer with an hour of steps: lag beyond
`max_lag` seconds (at least one step) is dropped, and said so by the caller. At most
`max_burst` steps are taken per tick, so the node still answers its services and takes its
impulses while it catches up (the next tick comes at once when it is late).

Pure arithmetic on times in seconds, so the rule is tested without a clock.
"""
import math

#: Seconds of lag the schedule makes up by stepping more than once per tick.
MAX_LAG = 0.5
#: Most steps one tick takes while catching up.
MAX_BURST = 10


def steps_due(now, due, period, tick, max_lag=MAX_LAG, max_burst=MAX_BURST):
    """(steps to take now, the next step's due time, steps dropped) at wall time `now`.

    due: when the next step is due. period: seconds per step (0: as fast as possible, one
    step per tick). tick: the timer's period; a step is taken at the tick nearest its due
    time, so one due up to half a tick after `now` is taken now (a timer whose ticks run a
    hair ahead of the schedule must not alternate between no step and two).
    """
    if period <= 0.0:
        return 1, now, 0
    ahead = min(tick, period) / 2.0
    if now + ahead < due:
        return 0, due, 0
    owed = math.floor((now + ahead - due) / period) + 1
    allowed = max(1, math.floor(max_lag / period))
    dropped = max(0, owed - allowed)
    take = min(owed - dropped, max_burst)
    return take, due + (dropped + take) * period, dropped
