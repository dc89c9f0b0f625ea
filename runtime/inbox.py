"""The newest-scan mailbox between a scanner (or simulator, or log) and the fixed-rate loop.

A producer — the serial driver's reader thread, a simulator step, a log replay — ``put``s each
complete scan; the loop ``take``s the newest one at its tick. A scan that is overwritten before
any tick took it is stale: it is dropped and counted, never queued (a queue would make the SLAM
fall further behind the robot the slower it runs). Both sides work on buffers allocated here,
once; a lock makes the hand-over safe across threads.
"""

from __future__ import annotations

import threading

import numpy as np

from runtime.scan import PointScan, ranges_to_points


class ScanInbox:
    def __init__(self, max_points: int, min_range: float = 0.0, max_range: float = np.inf):
        """``min_range``/``max_range``: the sensor's; readings outside are dropped."""
        self.min_range, self.max_range = float(min_range), float(max_range)
        self._pending = PointScan(max_points)
        self._odometry = np.zeros(3)
        self._has_odometry = False
        self._stamp = 0.0
        self._full = False
        self._lock = threading.Lock()
        self.received = 0  # scans put
        self.stale = 0  # scans overwritten before a tick took them
        self.empty = 0  # scans with no valid reading, refused

    def put_ranges(self, *, angles, ranges, stamp: float, odometry=None) -> bool:
        """Hand over one scan as beam angles (rad, robot frame) and ranges (m), float64
        arrays, by keyword only (two arrays of one shape are easily swapped; a positional call
        fails instead). Readings outside the sensor's ranges are dropped here; a scan with none
        left is refused (False)."""
        with self._lock:
            if ranges.shape[0] != angles.shape[0]:
                raise ValueError(f"{ranges.shape[0]} ranges but {angles.shape[0]} angles")
            n = ranges_to_points(ranges, angles, self.min_range, self.max_range,
                                 self._pending.buffer)
            return self._accept(n, stamp, odometry)

    def put_points(self, points, count: int, stamp: float, odometry=None) -> bool:
        """Hand over ``points[:count]`` (robot frame, metres)."""
        with self._lock:
            n = min(count, self._pending.capacity)
            self._pending.buffer[:n] = points[:n]
            return self._accept(n, stamp, odometry)

    def _accept(self, n, stamp, odometry) -> bool:
        self.received += 1
        if n == 0:
            self.empty += 1
            return False
        if self._full:
            self.stale += 1
        self._pending.count = n
        self._stamp = float(stamp)
        self._has_odometry = odometry is not None
        if odometry is not None:
            self._odometry[0] = odometry[0]
            self._odometry[1] = odometry[1]
            self._odometry[2] = odometry[2]
        self._full = True
        return True

    def take(self, scan: PointScan, odometry_out) -> tuple[bool, bool, float]:
        """Copy the newest scan into ``scan`` (and its odometry into ``odometry_out``).
        Returns (got a scan, it had odometry, its stamp)."""
        with self._lock:
            if not self._full:
                return False, False, 0.0
            n = self._pending.count
            scan.buffer[:n] = self._pending.buffer[:n]
            scan.count = n
            odometry_out[:] = self._odometry
            self._full = False
            return True, self._has_odometry, self._stamp

    def waiting(self) -> bool:
        return self._full

    def state(self) -> dict:
        return {"received": self.received, "stale": self.stale, "empty": self.empty}

    def restore(self, state: dict) -> None:
        self.received, self.stale = int(state["received"]), int(state["stale"])
        self.empty = int(state["empty"])
