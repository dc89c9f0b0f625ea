"""The sweep: a rotating scanner takes its beams one after another, and while the robot turns
each beam sees from the heading the robot had at that instant (docs/method.md §6.1, "The
sweep").

    sweep = SweepMotion(config.sensor, capacity)
    scan = sweep.undistort(scan, motion, interval)   # every point as seen at the stamp's heading
    match, scan = sweep.align(matcher, scan, reference, guess, turn, turn_interval,
                              previous, interval)    # Alg. 5 on the scan so undistorted

An RPLidar's sweep is its whole rotation (0.18 s at 5.5 Hz): turning at 1 rad/s the robot
turns 10° between its first beam and its last, and a straight wall comes out bent. The second
pass takes the turn at a rate changing evenly over the sweep, from the last interval's: a
pivot starts and ends within a sweep. A SICK LMS sweeps its 180° in 13 ms (27 ms for two
interlaced 0.5° sweeps), where the same turn is 1.5° at most; its presets leave the sweep at
0, which changes nothing. Only the turn is undone:
the translation over the sweep, undone too by the motion the scans showed, cost the
simulated logs' relations more than it gained.
"""

from __future__ import annotations

import math

from numba import njit

from swarmslam.runtime.config import SensorConfig
from swarmslam.runtime.pose import between
from swarmslam.runtime.matching.scan import PointScan


@njit(cache=True)
def undistort(points, places, count, w, seconds, stamp_place, out, w_last=math.nan):
    """Turn ``points[:count]`` (robot frame) into ``out`` as seen at the robot's heading at
    the stamp: point ``i`` was taken ``(places[i] − stamp_place)·seconds`` from the stamp,
    while the robot turned at ``w`` rad/s — or, given ``w_last``, at a rate changing evenly
    from ``w`` at the sweep's first beam to ``w_last`` at its last."""
    dw = 0.0 if math.isnan(w_last) else w_last - w
    s2 = stamp_place * stamp_place
    for i in range(count):
        p = places[i]
        a = (w * (p - stamp_place) + dw * (p * p - s2) * 0.5) * seconds
        c = math.cos(a)
        s = math.sin(a)
        x = points[i, 0]
        y = points[i, 1]
        out[i, 0] = c * x - s * y
        out[i, 1] = s * x + c * y


class SweepMotion:
    """Turns each scan's points to the heading at its stamp, by the robot's turn over the
    scans (a buffer of ``capacity`` points allocated here, once)."""

    def __init__(self, sensor: SensorConfig, capacity: int):
        self.seconds = sensor.sweep_seconds
        self.stamp_place = sensor.sweep_stamp
        self._out = PointScan(capacity)

    @property
    def moving(self) -> bool:
        """The scanner's beams are not simultaneous (a sweep is configured)."""
        return self.seconds > 0.0

    def rate(self, motion, interval: float) -> float:
        """The turn rate ``motion`` (its turn ``motion[2]``) shows over the ``interval`` s
        before a scan (rad/s): over the sweep's own length if that is longer (a stamp's
        jitter: a scanner takes one sweep per scan); NaN when the interval is unknown."""
        if not math.isfinite(interval) or interval <= 0.0:
            return math.nan
        return float(motion[2]) / max(interval, self.seconds)

    def undistort(self, scan: PointScan, motion, interval: float,
                  rate_before: float = math.nan) -> PointScan:
        """``scan`` as seen at the robot's heading at its stamp, given ``motion`` (the robot's,
        its turn ``motion[2]`` read) over the ``interval`` s before it; ``scan`` itself when
        the sweep is 0 or the interval unknown. The returned scan is this object's buffer,
        valid until the next call. The turn is taken at a steady rate (:meth:`rate`), or,
        given ``rate_before`` (rad/s, the rate of the interval before), at a rate changing
        evenly from that one at the sweep's first beam to the one that makes the same turn: a
        turn that starts or ends is not steady over a sweep."""
        rate = self.rate(motion, interval)
        if not self.moving or math.isnan(rate):
            return scan
        out = self._out
        # (a steady turn: the rate at the first beam is the one at the last, the change 0)
        first = rate_before if math.isfinite(rate_before) else rate
        undistort(scan.buffer, scan.sweep, scan.count, first, self.seconds, self.stamp_place,
                  out.buffer, 2.0 * rate - first)
        out.sweep[: scan.count] = scan.sweep[: scan.count]
        out.count = scan.count
        return out

    def align(self, matcher, scan: PointScan, reference, guess, turn, turn_interval: float,
              previous, interval: float, window=None):
        """Alg. 5 for ``scan`` (its points as taken) against ``reference`` from ``guess`` (the
        box's half-widths ``window``, None: the matcher's ``guess_window``), by ``matcher`` (a
        :class:`~swarmslam.runtime.matching.scan_matcher.ScanMatcher`), its sweep undone in two passes:
        by ``turn`` (the robot's last motion, over ``turn_interval`` s) for the swarm's match,
        then by the match's own turn from ``previous`` (the last scan's pose in the
        reference's frame, ``interval`` s before), the match settled again on the scan so
        turned (:meth:`~swarmslam.runtime.matching.scan_matcher.ScanMatcher.settle`). Returns the match
        and the scan as undistorted (this object's buffer, or ``scan`` itself with no sweep
        or no interval)."""
        if not self.moving:
            return matcher.align_scans(scan, reference, guess, window), scan
        match = matcher.align_scans(self.undistort(scan, turn, turn_interval), reference, guess,
                                    window)
        turned = self.undistort(scan, between(match.pose, previous), interval,
                                self.rate(turn, turn_interval))
        return matcher.settle(turned, reference, match), turned
