"""Pairing track messages with scans by their stamps, and saying what did not pair.

A tracker stamps its output with the stamp of the scan it came from (what tf2 and
message_filters expect). Each track message is paired with the scan of the same stamp, or,
with a tolerance, with the nearest scan within it. A message that pairs with no scan is
never dropped in silence: it is counted, and its offset to the nearest scan is kept, so a
report can say "your stamps are 1 ms late" (a tracker stamping with now(), or adding its
processing time). Two messages for one scan: the nearer is paired, the other counted.
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pairing:
    """Which message goes with which scan, and what was left over."""

    scan_of: np.ndarray  # per message: index of its scan, or -1
    offsets_ns: np.ndarray  # per message: its stamp minus the nearest scan's (0 if no scan)
    unpaired: np.ndarray  # indices of messages paired with no scan
    extra: np.ndarray  # indices of messages that lost their scan to a nearer one
    scans_without: int  # scans no message was paired with

    @property
    def paired(self):
        return int(np.sum(self.scan_of >= 0))

    def unpaired_offsets_ns(self):
        return self.offsets_ns[self.unpaired]


def pair(scan_stamps, message_stamps, tolerance_ns=0):
    """Pair messages with scans; both stamp lists in ns, scans sorted and distinct."""
    scans = np.asarray(scan_stamps, dtype=np.int64).reshape(-1)
    stamps = np.asarray(message_stamps, dtype=np.int64).reshape(-1)
    if len(scans) == 0:
        none = np.full(len(stamps), -1, dtype=np.int64)
        return Pairing(none, np.zeros(len(stamps), np.int64), np.arange(len(stamps)),
                       np.empty(0, np.int64), 0)
    after = np.searchsorted(scans, stamps).clip(1, len(scans) - 1)
    before = after - 1
    nearest = np.where(np.abs(stamps - scans[before]) <= np.abs(scans[after] - stamps),
                       before, after)
    if len(scans) == 1:
        nearest = np.zeros(len(stamps), dtype=np.int64)
    offsets = stamps - scans[nearest]
    within = np.abs(offsets) <= tolerance_ns
    scan_of = np.where(within, nearest, -1)
    # One message per scan: the nearest (the first of equals) keeps it.
    order = np.lexsort((np.arange(len(stamps)), np.abs(offsets), scan_of))
    extra = []
    taken = set()
    for index in order.tolist():
        scan = int(scan_of[index])
        if scan < 0:
            continue
        if scan in taken:
            extra.append(index)
            scan_of[index] = -1
        else:
            taken.add(scan)
    return Pairing(scan_of=scan_of, offsets_ns=offsets,
                   unpaired=np.flatnonzero(~within), extra=np.array(sorted(extra), np.int64),
                   scans_without=len(scans) - len(taken))


def describe(pairing, total, tolerance_ns):
    """One line on the messages that paired with no scan (None when all did)."""
    if len(pairing.unpaired) == 0 and len(pairing.extra) == 0:
        return None
    parts = []
    if len(pairing.unpaired):
        offsets = pairing.unpaired_offsets_ns()
        median = float(np.median(offsets))
        side = 'after' if median > 0 else 'before'
        within = (f'within the tolerance of {_ms(tolerance_ns)}' if tolerance_ns
                  else 'exactly')
        parts.append(
            f'{len(offsets)} of {total} track messages match no scan stamp {within}: '
            f'their stamps are {_ms(abs(median))} {side} the nearest scan '
            f'(median; from {_signed_ms(offsets.min())} to {_signed_ms(offsets.max())}); '
            "stamp tracks with their scan's header.stamp, or pair them with "
            f'--stamp-tolerance {_suggested(offsets)}')
    if len(pairing.extra):
        parts.append(f'{len(pairing.extra)} track messages found their scan taken by a '
                     'nearer one (two messages for one scan)')
    return '; '.join(parts)


def _ms(ns):
    return f'{ns / 1e6:.3f} ms'


def _signed_ms(ns):
    return f'{ns / 1e6:+.3f} ms'


def _suggested(offsets):
    """A tolerance (s) that pairs these offsets: the largest, rounded up to a round number."""
    largest = float(np.max(np.abs(offsets))) * 1e-9
    for step in (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0):
        if largest < 10 * step:
            return f'{np.ceil(largest / step + 1e-9) * step:.6g}'
    return f'{largest:.3g}'
