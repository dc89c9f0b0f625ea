"""What each scan's odometry reading predicts (docs/method.md §6.1, "A stale reading").

    readings = OdometryReadings(stale_motion=True)
    step, news, first = readings.read(odometry)   # odometry: the reading at this scan, or None

Odometry is often read less often than the scans: the same reading comes with several scans,
then a new one catches up at once. A new reading (``news``) predicts odometry's motion since
its last new one, to be added to the pose of the scan that brought that one — not to the last
scan's, which the scans in between have already moved (the catch-up would count their motion
twice). The same reading again predicts the translation per scan the last new reading showed,
while fewer scans have passed than that reading took to come (``stale_motion``), else no
motion: a reading that came at every scan repeats only at rest. The front end and the
localization's trackers keep the pose a new reading starts from; this keeps the readings.
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.pose import between


class OdometryReadings:
    """The readings so far, and what the next one predicts (see module doc)."""

    def __init__(self, stale_motion: bool):
        self.stale_motion = stale_motion
        self.last = np.zeros(3)  # the last new reading (a copy)
        self.have = False  # a reading came at the last scan: the next one is a motion from it
        self.stale_scans = 0  # scans since the last new reading
        self.reading_scans = 0  # scans the last new reading took to come
        self.reading_step = np.zeros(3)  # its translation per scan (the turn stays 0)

    def read(self, odometry):
        """``(step, news, first)`` for the reading at a scan: the motion it predicts (None
        without a reading: a scan alone, or a reading the inbox dropped, after which the next
        starts odometry afresh, docs/runtime.md §7), whether it is new (then ``step`` is
        added to the pose of the scan that brought the last new one, else to the last scan's),
        and whether it is the first (odometry starts here: its ``step`` is zero)."""
        if odometry is None:
            self.have = False
            return None, False, False
        odometry = np.asarray(odometry, np.float64)
        if self.have and np.array_equal(odometry, self.last):
            self.stale_scans += 1
            if self.stale_motion and self.stale_scans < self.reading_scans:
                return self.reading_step, False, False
            return np.zeros(3), False, False
        first = not self.have
        if first:
            self.stale_scans = 0
        delta = np.zeros(3) if first else between(odometry, self.last)
        self.last[:] = odometry  # (a copy: callers may reuse their array)
        self.reading_scans = self.stale_scans + 1
        self.reading_step[:2] = delta[:2] / self.reading_scans
        self.stale_scans = 0
        self.have = True
        return delta, True, first
