"""Planar transforms from recorded /tf and /tf_static: where a frame is in the world frame.

Tracks given in another frame than the world's (an agent's odom or base_link, or a frame of
the tracker's own that it broadcasts) are put in the world frame through the transforms of
the recording, as tf2 would: each link's transform at the stamp, interpolated between the
two recorded stamps around it (translation linearly, heading along the shorter arc), and
none beyond the first or last (tf2's extrapolation error). Only the planar part is used
(x, y and the rotation about z): the world is a plane.
"""
import bisect
import math

import numpy as np

#: Longest chain of frames followed up to the world frame.
MAX_DEPTH = 64


class TransformError(ValueError):
    """No transform between two frames at a stamp; the message says which link is missing."""


def yaw_of(qx, qy, qz, qw):
    """The heading (rotation about z) of a quaternion."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


class PlanarTransforms:
    """Links child -> parent, static or stamped, and lookups up a chain of them."""

    def __init__(self):
        self._static = {}  # child -> (parent, x, y, yaw)
        self._rows = {}  # child -> {stamp_ns: (parent, x, y, yaw)} while adding
        self._tables = {}  # child -> (parent, stamps list, array (n, 3)) once looked up

    def add(self, parent, child, stamp_ns, x, y, yaw, static=False):
        """One transform: `child`'s pose in `parent` (a later one at a stamp replaces)."""
        if static:
            self._static[child] = (parent, float(x), float(y), float(yaw))
            return
        rows = self._rows.setdefault(child, {})
        rows[int(stamp_ns)] = (parent, float(x), float(y), float(yaw))
        self._tables.pop(child, None)

    def frames(self):
        return sorted(set(self._static) | set(self._rows))

    def _table(self, child):
        table = self._tables.get(child)
        if table is None:
            rows = self._rows[child]
            stamps = sorted(rows)
            parents = {rows[s][0] for s in stamps}
            if len(parents) > 1:
                raise TransformError(f'frame {child!r} has more than one parent in /tf: '
                                     f'{", ".join(sorted(parents))}')
            values = np.array([rows[s][1:] for s in stamps], dtype=np.float64)
            table = (rows[stamps[0]][0], stamps, values)
            self._tables[child] = table
        return table

    def link(self, child, stamp_ns):
        """(parent, x, y, yaw) of `child` at stamp_ns, or TransformError."""
        if child in self._rows:
            parent, stamps, values = self._table(child)
            at = bisect.bisect_left(stamps, stamp_ns)
            if at < len(stamps) and stamps[at] == stamp_ns:
                return (parent, *values[at])
            if at == 0 or at == len(stamps):
                raise TransformError(
                    f'no transform of {child!r} at {stamp_ns * 1e-9:.9f} s: /tf has it from '
                    f'{stamps[0] * 1e-9:.9f} to {stamps[-1] * 1e-9:.9f} s')
            t0, t1 = stamps[at - 1], stamps[at]
            share = (stamp_ns - t0) / (t1 - t0)
            (x0, y0, a0), (x1, y1, a1) = values[at - 1], values[at]
            turn = math.remainder(a1 - a0, 2.0 * math.pi)
            return (parent, x0 + share * (x1 - x0), y0 + share * (y1 - y0),
                    math.remainder(a0 + share * turn, 2.0 * math.pi))
        if child in self._static:
            return self._static[child]
        raise TransformError(f'frame {child!r} is in neither /tf nor /tf_static')

    def lookup(self, target, source, stamp_ns):
        """(x, y, yaw) of frame `source` in frame `target` at stamp_ns (TransformError)."""
        x, y, yaw = 0.0, 0.0, 0.0
        frame = source
        for _ in range(MAX_DEPTH):
            if frame == target:
                return x, y, yaw
            try:
                parent, px, py, pyaw = self.link(frame, stamp_ns)
            except TransformError as error:
                raise TransformError(f'{source!r} -> {target!r}: {error}') from None
            c, s = math.cos(pyaw), math.sin(pyaw)
            x, y, yaw = px + c * x - s * y, py + s * x + c * y, pyaw + yaw
            frame = parent
        raise TransformError(f'{source!r} -> {target!r}: no chain of at most {MAX_DEPTH} '
                             'links (a loop in /tf?)')


def to_frame(points, x, y, yaw):
    """Points (N, 2) given in a frame at (x, y, yaw), in the frame that one is in."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.column_stack((x + c * points[:, 0] - s * points[:, 1],
                            y + s * points[:, 0] + c * points[:, 1]))
