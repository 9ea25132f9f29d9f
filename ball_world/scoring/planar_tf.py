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
    """Links child -> parent, static or stamped, and lookups up a chain of them.

    Stamped links are kept per child in stamp order; a recording adds them in order, so
    adding is an append and a lookup a binary search, however long the run.
    """

    def __init__(self):
        self._static = {}  # child -> (parent, x, y, yaw)
        self._stamps = {}  # child -> [stamp_ns] in order
        self._values = {}  # child -> [(parent, x, y, yaw)] in the same order

    def add(self, parent, child, stamp_ns, x, y, yaw, static=False):
        """One transform: `child`'s pose in `parent` (a later one at a stamp replaces)."""
        value = (parent, float(x), float(y), float(yaw))
        if static:
            self._static[child] = value
            return
        stamp_ns = int(stamp_ns)
        stamps = self._stamps.setdefault(child, [])
        values = self._values.setdefault(child, [])
        if stamps and stamps[-1] >= stamp_ns:
            at = bisect.bisect_left(stamps, stamp_ns)
            if at < len(stamps) and stamps[at] == stamp_ns:
                values[at] = value
                return
            stamps.insert(at, stamp_ns)
            values.insert(at, value)
            return
        stamps.append(stamp_ns)
        values.append(value)

    def frames(self):
        return sorted(set(self._static) | set(self._stamps))

    def link(self, child, stamp_ns):
        """(parent, x, y, yaw) of `child` at stamp_ns, or TransformError."""
        stamps = self._stamps.get(child)
        if stamps:
            values = self._values[child]
            at = bisect.bisect_left(stamps, stamp_ns)
            if at < len(stamps) and stamps[at] == stamp_ns:
                return values[at]
            if at == 0 or at == len(stamps):
                raise TransformError(
                    f'no transform of {child!r} at {stamp_ns * 1e-9:.9f} s: /tf has it from '
                    f'{stamps[0] * 1e-9:.9f} to {stamps[-1] * 1e-9:.9f} s')
            (p0, x0, y0, a0), (p1, x1, y1, a1) = values[at - 1], values[at]
            if p0 != p1:
                raise TransformError(f'frame {child!r} changes parent ({p0!r}, {p1!r}) '
                                     f'around {stamp_ns * 1e-9:.9f} s')
            t0, t1 = stamps[at - 1], stamps[at]
            share = (stamp_ns - t0) / (t1 - t0)
            turn = math.remainder(a1 - a0, 2.0 * math.pi)
            return (p0, x0 + share * (x1 - x0), y0 + share * (y1 - y0),
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
