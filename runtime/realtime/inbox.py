"""The newest-scan mailbox between a scanner (or simulator, or log) and the fixed-rate loop.

A producer — the serial driver's reader thread, a simulator step, a log replay — ``put``s each
complete scan; the loop ``take``s the newest one at its tick. A scan that is overwritten before
any tick took it is stale: it is dropped and counted, never queued (a queue would make the SLAM
fall further behind the robot the slower it runs). Both sides work on buffers allocated here,
once; a lock makes the hand-over safe across threads.

Records no robot produces are screened here, counted and never absorbed (docs/runtime.md §7):
a scan with no valid reading or a non-finite or backward timestamp is refused; odometry that is
non-finite, or jumps further than the robot can move between two readings (``InputConfig``), is
dropped from its scan — which is still matched — and the front end's odometry starts afresh at
the next good reading, so a re-based odometry (a 10 km jump) shifts nothing.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from swarmslam.runtime.config import InputConfig
from swarmslam.runtime.matching.scan import (PointScan, finite_points, ranges_to_points, usable_beams,
                                    usable_points)


# What a record may say (docs/runtime.md §7): stamps are seconds since 1970 or since the log
# began, up to the year 2286; a robot stays within 1,000 km of its odometry's origin; a heading
# wound beyond 10^4 rad has lost its precision (wrapped, it is noise).
MAX_STAMP = 1e10  # s
MAX_COORDINATE = 1e6  # m
MAX_HEADING = 1e4  # rad
# Allowed on top of input.max_speed and max_turn_rate × the time between two readings (m,
# rad): logs whose stamps were reordered put two readings metres or a radian apart within
# milliseconds; a garbage line is metres or kilometres off.
JUMP_SLACK = 1.0
TURN_SLACK = 1.0


def real_array(name: str, values, ndim: int) -> np.ndarray:
    """``values`` as a float64 array of ``ndim`` dimensions (``ndim`` 2: N × 2 points), or a
    ValueError naming the argument (a list is taken; complex, text or another shape is not)."""
    array = np.asarray(values)
    if array.dtype.kind not in "fiu" or array.dtype.kind == "b":
        raise ValueError(f"{name}: needs real numbers, got an array of {array.dtype}")
    if array.ndim != ndim or (ndim == 2 and array.shape[1] != 2):
        shape = "(N,)" if ndim == 1 else "(N, 2)"
        raise ValueError(f"{name}: needs shape {shape}, got {array.shape}")
    return np.ascontiguousarray(array, dtype=np.float64)


class ScanInbox:
    def __init__(self, max_points: int, min_range: float = 0.0, max_range: float = np.inf,
                 limits: InputConfig | None = None):
        """``min_range``/``max_range``: the sensor's; readings outside are dropped.
        ``limits``: what a robot's odometry can do between two readings."""
        self.min_range, self.max_range = float(min_range), float(max_range)
        self.limits = limits or InputConfig()
        self._pending = PointScan(max_points)
        self._odometry = np.zeros(3)
        self._has_odometry = False
        self._stamp = 0.0
        self._full = False
        self._lock = threading.Lock()
        self.received = 0  # scans put
        self.stale = 0  # scans overwritten before a tick took them
        self.empty = 0  # scans with no valid reading, refused
        self.bad_stamps = 0  # scans with a non-finite or backward timestamp, refused
        self.odometry_non_finite = 0  # readings dropped from their scan
        self.odometry_out_of_range = 0  # readings no robot gives (beyond the bounds below)
        self.odometry_jumps = 0  # readings further than the robot moves, dropped
        self.cut = 0  # scans with more usable points than max_points: the rest dropped
        self._last_stamp = -math.inf  # the newest scan's timestamp
        self._last_reading = np.zeros(3)  # the newest finite odometry reading, and its time
        self._reading_stamp = math.nan
        self._odometry_break = False  # a reading was dropped since the last take

    def put_ranges(self, *, angles, ranges, stamp: float, odometry=None) -> bool:
        """Hand over one scan as beam angles (rad, robot frame) and ranges (m), float64
        arrays, by keyword only (two arrays of one shape are easily swapped; a positional call
        fails instead). Readings outside the sensor's ranges, or not finite, are dropped here;
        a scan with none left is refused (False)."""
        angles, ranges = real_array("angles", angles, 1), real_array("ranges", ranges, 1)
        with self._lock:
            if ranges.shape[0] != angles.shape[0]:
                raise ValueError(f"{ranges.shape[0]} ranges but {angles.shape[0]} angles")
            n = ranges_to_points(ranges, angles, self.min_range, self.max_range,
                                 self._pending.buffer, self._pending.sweep)
            if n == self._pending.capacity and usable_beams(
                    ranges, angles, self.min_range, self.max_range) > n:
                self.cut += 1
            return self._accept(n, stamp, odometry)

    def put_points(self, points, count: int, stamp: float, odometry=None, sweep=None) -> bool:
        """Hand over ``points[:count]`` (robot frame, metres; an (N, 2) array) in the order the
        scanner took them; ``sweep``: each one's place in its sweep, 0 (first beam) to 1 (last),
        if known (else their order gives it). Points that are not finite, or whose place is not
        in [0, 1], are dropped; a scan with none left is refused (False)."""
        points = real_array("points", points, 2)
        if sweep is not None:
            sweep = real_array("sweep", sweep, 1)
            if sweep.shape[0] < min(int(count), points.shape[0]):
                raise ValueError(f"sweep: {sweep.shape[0]} places for {count} points")
        with self._lock:
            count = min(int(count), points.shape[0])
            n = finite_points(points, count, self._pending.buffer, sweep, self._pending.sweep)
            if n == self._pending.capacity and usable_points(points, count, sweep) > n:
                self.cut += 1
            return self._accept(n, stamp, odometry)

    def _accept(self, n, stamp, odometry) -> bool:
        self.received += 1
        try:
            stamp = float(stamp)
        except (TypeError, ValueError):
            raise ValueError(f"stamp: needs a number (seconds), got {stamp!r}") from None
        if odometry is not None and np.shape(odometry) != (3,):
            raise ValueError(f"odometry: needs (x, y, θ), got shape {np.shape(odometry)}")
        # not finite, beyond the year 2286 (or as far before 1970), or backwards
        if not (abs(stamp) <= MAX_STAMP and stamp >= self._last_stamp):
            self.bad_stamps += 1
            return False
        self._last_stamp = stamp
        usable = odometry is not None and self._odometry_usable(odometry, stamp)
        if n == 0:
            self.empty += 1
            return False
        if self._full:
            self.stale += 1
        self._pending.count = n
        self._stamp = stamp
        self._has_odometry = usable
        if usable:
            self._odometry[0] = odometry[0]
            self._odometry[1] = odometry[1]
            self._odometry[2] = odometry[2]
        self._full = True
        return True

    def _odometry_usable(self, odometry, stamp: float) -> bool:
        """A finite reading within what the robot can move since the previous reading; the
        reading becomes the previous one either way (a re-based odometry is then followed)."""
        x, y, theta = float(odometry[0]), float(odometry[1]), float(odometry[2])
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
            self.odometry_non_finite += 1
            self._odometry_break = True
            return False
        if not (abs(x) <= MAX_COORDINATE and abs(y) <= MAX_COORDINATE
                and abs(theta) <= MAX_HEADING):
            self.odometry_out_of_range += 1
            self._odometry_break = True
            return False
        last, lim = self._last_reading, self.limits
        first = math.isnan(self._reading_stamp)
        dt = 0.0 if first else max(stamp - self._reading_stamp, 0.0)
        turned = abs(math.remainder(theta - last[2], math.tau))
        jumped = not first and (
            math.hypot(x - last[0], y - last[1]) > JUMP_SLACK + lim.max_speed * dt
            or turned > TURN_SLACK + lim.max_turn_rate * dt)
        last[0], last[1], last[2] = x, y, theta
        self._reading_stamp = stamp
        if jumped:
            self.odometry_jumps += 1
            self._odometry_break = True
        return not jumped

    def take(self, scan: PointScan, odometry_out) -> tuple[bool, bool, float]:
        """Copy the newest scan into ``scan`` (and its odometry into ``odometry_out``).
        Returns (got a scan, it had odometry, its stamp)."""
        with self._lock:
            if not self._full:
                return False, False, 0.0
            n = self._pending.count
            scan.buffer[:n] = self._pending.buffer[:n]
            scan.sweep[:n] = self._pending.sweep[:n]
            scan.count = n
            odometry_out[:] = self._odometry
            self._full = False
            # After a dropped reading the scan taken goes without odometry, even if a good
            # reading overwrote the dropped one: the front end's odometry then starts afresh.
            has_odometry = self._has_odometry and not self._odometry_break
            self._odometry_break = False
            return True, has_odometry, self._stamp

    def waiting(self) -> bool:
        return self._full

    def counts(self) -> dict:
        """The records screened out so far, by kind (report and status line)."""
        return {"stale_scans": self.stale, "empty_scans": self.empty,
                "bad_stamp_scans": self.bad_stamps,
                "odometry_non_finite": self.odometry_non_finite,
                "odometry_out_of_range": self.odometry_out_of_range,
                "odometry_jumps": self.odometry_jumps, "cut_scans": self.cut}

    def skipped(self) -> str:
        """The records screened out, for a status line ('' when none were)."""
        return skipped_text(self.counts())

    def state(self) -> dict:
        return {"received": self.received, "stale": self.stale, "empty": self.empty,
                "bad_stamps": self.bad_stamps, "odometry_non_finite": self.odometry_non_finite,
                "odometry_out_of_range": self.odometry_out_of_range,
                "odometry_jumps": self.odometry_jumps, "cut": self.cut}

    def restore(self, state: dict) -> None:
        """The counts go on; the previous stamp and reading do not (a resumed session may
        start a new log, with its own clock and odometry)."""
        self.received, self.stale = int(state["received"]), int(state["stale"])
        self.empty = int(state["empty"])
        self.bad_stamps = int(state["bad_stamps"])
        self.odometry_non_finite = int(state["odometry_non_finite"])
        self.odometry_jumps = int(state["odometry_jumps"])
        self.odometry_out_of_range = int(state["odometry_out_of_range"])
        self.cut = int(state["cut"])


SKIPPED = {"empty_scans": "scans with no return", "bad_stamp_scans": "bad timestamps",
           "odometry_non_finite": "non-finite odometry",
           "odometry_out_of_range": "odometry out of range", "odometry_jumps": "odometry jumps",
           "cut_scans": "scans' points beyond sensor.max_points"}


def skipped_text(counts: dict) -> str:
    """'skipped 1 scans with no return, 2 odometry jumps' from a report's counts ('' if none)."""
    parts = [f"{counts[k]} {what}" for k, what in SKIPPED.items() if counts.get(k)]
    return "skipped " + ", ".join(parts) if parts else ""
