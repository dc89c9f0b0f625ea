"""Samples → whole rotations, in buffers allocated once, handed on as scans.

The scanner reports angles in degrees, clockwise, 0 at its front; the runtime wants radians,
counter-clockwise, in the robot frame. ``mount_yaw`` is the scanner's heading on the robot
(rad, counter-clockwise; 0 when its front faces the robot's). A rotation ends where the next
sample carries the new-rotation flag; the partial rotation before the first flag is dropped.
Angles need not be even — a real rotation's are not — and zero distances stay in the scan as
range 0, which the runtime counts invalid.
"""

from __future__ import annotations

import math
import time

import numpy as np

DEG_Q6 = 1.0 / 64.0


class Rotations:
    def __init__(self, on_rotation=None, capacity: int = 8192, min_samples: int = 16,
                 mount_yaw: float = 0.0, clock=time.monotonic):
        self.on_rotation = on_rotation  # f(angles_rad, ranges_m, stamp) with array views
        self.angles = np.zeros(capacity)
        self.ranges = np.zeros(capacity)
        self.quality = np.zeros(capacity, np.int64)
        self.count = 0
        self.min_samples = min_samples
        self.mount_yaw = mount_yaw
        self.clock = clock
        self.started = False
        self.rotations = 0
        self.short = 0  # rotations dropped for having fewer than min_samples
        self.overflows = 0  # samples beyond the capacity, dropped
        self.callback_errors = 0  # on_rotation raised: counted, the stream goes on
        self.last_error = ""

    def add(self, start: bool, quality: int, angle_q6: int, distance_q2: int) -> None:
        if start:
            if self.started and self.count >= self.min_samples:
                self._emit()
            elif self.started:
                self.short += 1
            self.started = True
            self.count = 0
        if not self.started:
            return
        k = self.count
        if k >= self.angles.shape[0]:
            self.overflows += 1
            return
        # clockwise degrees → counter-clockwise radians, wrapped to (−π, π]
        a = self.mount_yaw - math.radians(angle_q6 * DEG_Q6)
        self.angles[k] = math.atan2(math.sin(a), math.cos(a))
        self.ranges[k] = distance_q2 / 4000.0
        self.quality[k] = quality
        self.count = k + 1

    def reset(self) -> None:
        """Forget the rotation under way (after a gap in the stream)."""
        self.started = False
        self.count = 0

    def _emit(self) -> None:
        self.rotations += 1
        if self.on_rotation is not None:
            n = self.count
            try:
                self.on_rotation(self.angles[:n], self.ranges[:n], self.clock())
            except Exception as exc:  # the consumer's fault must not stop the reader thread
                self.callback_errors += 1
                self.last_error = f"{type(exc).__name__}: {exc}"
