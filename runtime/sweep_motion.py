"""The sweep: a rotating scanner takes its beams one after another, and while the robot moves
each beam sees from where the robot was at that instant (docs/method.md §6.1, "The sweep").

    sweep = SweepMotion(config.sensor, capacity)
    scan = sweep.undistort(scan, motion, interval)   # every point as seen from the stamp's pose

An RPLidar's sweep is its whole rotation (0.18 s at 5.5 Hz): turning at 1 rad/s the robot
turns 10° between its first beam and its last, and a straight wall comes out bent. A SICK LMS
sweeps its 180° in 13 ms (27 ms for two interlaced 0.5° sweeps), where the same turn is 1.5°
at most; its presets leave the sweep at 0, which changes nothing.
"""

from __future__ import annotations

import math

from numba import njit

from swarmslam.runtime.config import SensorConfig
from swarmslam.runtime.scan import PointScan


@njit(cache=True)
def undistort(points, places, count, vx, vy, w, seconds, stamp_place, out):
    """Move ``points[:count]`` (robot frame) into ``out`` as seen from the robot's pose at the
    stamp: point ``i`` was taken ``(places[i] − stamp_place)·seconds`` from the stamp, while the
    robot moved at ``(vx, vy)`` m/s and turned at ``w`` rad/s (its frame at the stamp). A
    constant motion over one sweep, to first order in its translation: over 0.2 s a robot at
    1 m/s turning 2 rad/s is off the exact arc by 2 cm at the sweep's far end."""
    for i in range(count):
        tau = (places[i] - stamp_place) * seconds
        a = w * tau
        c = math.cos(a)
        s = math.sin(a)
        x = points[i, 0]
        y = points[i, 1]
        out[i, 0] = c * x - s * y + vx * tau
        out[i, 1] = s * x + c * y + vy * tau


class SweepMotion:
    """Moves each scan's points to the pose at its stamp, by the robot's motion over the scans
    (a buffer of ``capacity`` points allocated here, once)."""

    def __init__(self, sensor: SensorConfig, capacity: int):
        self.seconds = sensor.sweep_seconds
        self.stamp_place = sensor.sweep_stamp
        self._out = PointScan(capacity)

    @property
    def moving(self) -> bool:
        """The scanner's beams are not simultaneous (a sweep is configured)."""
        return self.seconds > 0.0

    def undistort(self, scan: PointScan, motion, interval: float) -> PointScan:
        """``scan`` as seen from the robot's pose at its stamp, given ``motion`` (the robot's,
        in its own frame) over the ``interval`` s before it; ``scan`` itself when the sweep
        is 0 or the interval unknown. The returned scan is this object's buffer, valid until
        the next call. An interval shorter than the sweep is a stamp's jitter (a scanner takes
        one sweep per scan): the sweep's own length is used."""
        if not self.moving or not math.isfinite(interval) or interval <= 0.0:
            return scan
        interval = max(interval, self.seconds)
        # ``motion`` is the stamp's pose in the frame before it: its translation turned into
        # the stamp's own frame.
        c, s = math.cos(float(motion[2])), math.sin(float(motion[2]))
        mx, my = float(motion[0]), float(motion[1])
        out = self._out
        undistort(scan.buffer, scan.sweep, scan.count, (c * mx + s * my) / interval,
                  (c * my - s * mx) / interval, float(motion[2]) / interval, self.seconds,
                  self.stamp_place, out.buffer)
        out.sweep[: scan.count] = scan.sweep[: scan.count]
        out.count = scan.count
        return out
