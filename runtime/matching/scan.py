"""Scans: ranges and beam angles into a fixed-capacity buffer of points in the sensor frame.

Real scanners give any number of beams at uneven angles (an RPLidar rotation) and invalid
readings (0, at or beyond the maximum range, NaN, inf). These are dropped here, once, so every
later stage sees only valid points.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def valid_reading(r, min_range, max_range):
    """A reading is valid when finite and ``min_range < r < max_range``."""
    return math.isfinite(r) and not (r <= min_range or r >= max_range)


@njit(cache=True, inline="always")
def sweep_place(i, beams):
    """Beam ``i``'s place in a sweep of ``beams`` beams taken in order: 0 the first, 1 the
    last."""
    return i / (beams - 1) if beams > 1 else 1.0


@njit(cache=True, inline="always")
def usable_beam(r, a, min_range, max_range):
    """A beam makes a point when its reading is valid and its angle a number."""
    return valid_reading(r, min_range, max_range) and math.isfinite(a)


@njit(cache=True, inline="always")
def usable_point(points, i, sweep):
    """Point ``i`` is kept when both its coordinates are finite and its place in the sweep,
    if given, is a number in [0, 1]."""
    if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])):
        return False
    if sweep is not None:
        return 0.0 <= sweep[i] <= 1.0  # (NaN fails too)
    return True


@njit(cache=True)
def ranges_to_points(ranges, angles, min_range, max_range, out, sweep=None):
    """Write the valid beams' end points into ``out`` (capacity × 2); return how many.

    A reading is valid when finite and ``min_range < r < max_range``. Beams beyond the
    buffer's capacity are ignored (the caller sized the buffer for its scanner). ``sweep``
    (capacity long), if given, gets each point's place in the sweep (:func:`sweep_place`):
    the beams are in the order the scanner took them.
    """
    n = 0
    cap = out.shape[0]
    beams = ranges.shape[0]
    for i in range(beams):
        r = ranges[i]
        a = angles[i]
        if not usable_beam(r, a, min_range, max_range):
            continue
        if n >= cap:
            break
        out[n, 0] = r * math.cos(a)
        out[n, 1] = r * math.sin(a)
        if sweep is not None:
            sweep[n] = sweep_place(i, beams)
        n += 1
    return n


@njit(cache=True)
def beam_directions(angles, out):
    """Each beam's unit vector ``(cos a, sin a)`` into ``out`` (beams × 2): for a scanner
    whose beams keep their angles, computed once for :func:`directions_to_points`."""
    for i in range(angles.shape[0]):
        out[i, 0] = math.cos(angles[i])
        out[i, 1] = math.sin(angles[i])


@njit(cache=True)
def directions_to_points(ranges, directions, min_range, max_range, out, sweep=None):
    """:func:`ranges_to_points` for beams along ``directions`` (:func:`beam_directions`):
    the same points, bit for bit, without a cosine and a sine per beam (a simulated scan's
    360 beams: a tenth of a step's time)."""
    n = 0
    cap = out.shape[0]
    beams = ranges.shape[0]
    for i in range(beams):
        r = ranges[i]
        c = directions[i, 0]
        s = directions[i, 1]
        if not (valid_reading(r, min_range, max_range) and math.isfinite(c)
                and math.isfinite(s)):
            continue
        if n >= cap:
            break
        out[n, 0] = r * c
        out[n, 1] = r * s
        if sweep is not None:
            sweep[n] = sweep_place(i, beams)
        n += 1
    return n


@njit(cache=True)
def usable_beams(ranges, angles, min_range, max_range):
    """How many beams :func:`ranges_to_points` would make points of, its capacity aside."""
    n = 0
    for i in range(ranges.shape[0]):
        if usable_beam(ranges[i], angles[i], min_range, max_range):
            n += 1
    return n


@njit(cache=True)
def usable_points(points, count, sweep=None):
    """How many of ``points[:count]`` :func:`finite_points` would keep, its capacity aside."""
    n = 0
    for i in range(min(count, points.shape[0])):
        if usable_point(points, i, sweep):
            n += 1
    return n


@njit(cache=True)
def finite_points(points, count, out, sweep=None, sweep_out=None):
    """Copy the finite ones among ``points[:count]`` into ``out`` (at most its capacity, in
    order); return how many. ``sweep_out``, if given, gets each point's place in its sweep:
    ``sweep[i]`` when given (a point whose place is not a number in [0, 1] is dropped), else
    the point's own place among ``points[:count]`` (:func:`sweep_place`)."""
    n = 0
    cap = out.shape[0]
    total = min(count, points.shape[0])
    for i in range(total):
        if not usable_point(points, i, sweep):
            continue
        if n >= cap:
            break
        out[n, 0] = points[i, 0]
        out[n, 1] = points[i, 1]
        if sweep_out is not None:
            sweep_out[n] = sweep_place(i, total) if sweep is None else sweep[i]
        n += 1
    return n


class PointScan:
    """A scan's valid points in its sensor frame, in a buffer allocated once.

    ``points[:count]`` are valid; the rest of the buffer is scratch.
    """

    def __init__(self, capacity: int = 2048):
        if capacity < 1:
            raise ValueError(f"scan capacity must be >= 1, got {capacity}")
        self.buffer = np.zeros((capacity, 2), dtype=np.float64)
        # Each point's place in its sweep, 0 (the first beam) to 1 (the last), when it came
        # from a scanner's beams; what turns it to the stamp's heading (runtime/matching/sweep_motion.py).
        self.sweep = np.ones(capacity, dtype=np.float64)
        self.count = 0

    @property
    def capacity(self) -> int:
        return self.buffer.shape[0]

    @property
    def points(self) -> np.ndarray:
        return self.buffer[: self.count]

    def set_ranges(self, ranges, angles, min_range: float = 0.0, max_range: float = np.inf):
        """Fill from ranges (m) and beam angles (rad); raises on input no scanner would send."""
        ranges = np.asarray(ranges, dtype=np.float64)
        angles = np.asarray(angles, dtype=np.float64)
        if ranges.ndim != 1 or angles.ndim != 1:
            raise ValueError(
                f"ranges and angles must be 1-D; got shapes {ranges.shape} and {angles.shape}"
            )
        if ranges.shape[0] != angles.shape[0]:
            raise ValueError(
                f"ranges and angles differ in length: {ranges.shape[0]} ranges, "
                f"{angles.shape[0]} angles"
            )
        if ranges.shape[0] == 0:
            raise ValueError("empty scan: no beams")
        if ranges.shape[0] > self.capacity:
            raise ValueError(
                f"scan has {ranges.shape[0]} beams but the buffer holds {self.capacity}; "
                "raise the scan capacity"
            )
        self.count = ranges_to_points(ranges, angles, min_range, max_range, self.buffer,
                                      self.sweep)
        if self.count == 0:
            raise ValueError(
                f"all {ranges.shape[0]} readings are invalid "
                f"(need finite ranges in ({min_range}, {max_range}))"
            )
        return self

    def set_points(self, points):
        """Fill from points ``(N, 2)`` already in the sensor frame, in the order the scanner
        took them (their places in the sweep)."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2:
            raise ValueError(f"points must have shape (N, 2); got {points.shape}")
        finite = np.all(np.isfinite(points), axis=1)
        n = int(finite.sum())
        if n == 0:
            raise ValueError("empty scan: no finite points")
        if n > self.capacity:
            raise ValueError(f"{n} points exceed the scan capacity {self.capacity}")
        self.count = finite_points(points, points.shape[0], self.buffer, None, self.sweep)
        return self

    @classmethod
    def from_ranges(cls, ranges, angles, min_range=0.0, max_range=np.inf, capacity=None):
        cap = capacity if capacity is not None else max(len(ranges), 1)
        return cls(cap).set_ranges(ranges, angles, min_range, max_range)

    @classmethod
    def from_points(cls, points, capacity=None):
        cap = capacity if capacity is not None else max(len(points), 1)
        return cls(cap).set_points(points)


def beam_angles(count: int, first: float, last: float) -> np.ndarray:
    """Evenly spaced beam angles from ``first`` to ``last`` inclusive (rad)."""
    return np.linspace(first, last, count)


def binned_ranges(angles, ranges, bins: int, no_return: float) -> np.ndarray:
    """Ranges in ``bins`` equal angle bins over a full turn, bin ``k`` centred on
    −π + 2πk/bins (a LaserScan's beams): of several in one bin the nearest, ``no_return``
    where none."""
    out = np.full(bins, no_return, np.float64)
    if len(ranges) == 0:
        return out
    k = np.floor((np.asarray(angles) + math.pi) / (2 * math.pi) * bins
                 + 0.5).astype(np.int64) % bins
    order = np.argsort(-np.asarray(ranges), kind="stable")  # nearest written last: it wins
    out[k[order]] = np.asarray(ranges)[order]
    return out
