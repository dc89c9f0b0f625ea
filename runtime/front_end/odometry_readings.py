"""What each scan's odometry reading predicts (docs/method.md §6.1, "A stale reading").

    readings = OdometryReadings(stale_motion=True, periodic_ratio=1.5)
    step, news, first = readings.read(odometry, stamp)  # the reading at a scan (or None)

Odometry is often read less often than the scans: the same reading comes with several scans,
then a new one catches up at once. A new reading (``news``) predicts odometry's motion since
its last new one, to be added to the pose of the scan that brought that one — not to the last
scan's, which the scans in between have already moved (the catch-up would count their motion
twice). The same reading again predicts the translation per scan the last new reading showed,
while fewer scans have passed than that reading took to come (``stale_motion``), else no
motion: a reading that came at every scan repeats only at rest. The front end and the
localization's trackers keep the pose a new reading starts from; this keeps the readings.

Odometry read at its own period, slower than the scans (new readings on average more than
``periodic_ratio`` scan intervals apart), was taken some time before the scan that brings it:
up to a scan interval, a different time for each reading. The motion between two readings is
then not the motion between the scans that brought them; along a plain corridor, where the
prediction stands in for the match, the difference stays in the map (a simulated robot reading
odometry every 0.8 s: 4 cm a relation). The readings are taken as periodic: the lag of each one
behind its scan is the last lag plus how much longer than the period the scans took to bring
it, kept within one scan interval, and the motion at the rate the reading showed covers the
change of lag. The lags' changes sum to at most a scan interval over any run, so an error in
the period estimated from the readings so far never becomes a scale error (docs/method.md §6.1,
"Odometry at its own period").
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam.runtime.pose import between

# This many gaps in a row between new readings, each longer than twice the fewest scans one
# took, start the period's count again: the fewest was a stray (a reading one scan after
# another where scans were refused now and then).
RESTART_GAPS = 3


class OdometryReadings:
    """The readings so far, and what the next one predicts (see module doc)."""

    def __init__(self, stale_motion: bool, periodic_ratio: float = 0.0,
                 restart_gaps: int = RESTART_GAPS):
        self.stale_motion = stale_motion
        self.periodic_ratio = periodic_ratio
        self.restart_gaps = restart_gaps
        self.last = np.zeros(3)  # the last new reading (a copy)
        self.have = False  # a reading came at the last scan: the next one is a motion from it
        self.stale_scans = 0  # scans since the last new reading
        self.reading_scans = 0  # scans the last new reading took to come
        self.reading_step = np.zeros(3)  # its translation per scan (the turn stays 0)
        # odometry at its own period (see the module doc)
        self.stamp = math.nan  # the last scan's
        self.arrival = math.nan  # the scan's that brought the last new reading
        self.scan_time, self.scan_intervals = 0.0, 0  # the scans' intervals: their sum, count
        # the gaps between new readings that count: their sum in s and in scans, their count,
        # and the fewest scans one took
        self.period_time, self.period_scans, self.periods, self.fewest = 0.0, 0, 0, 0
        self.long_gaps = 0  # gaps in a row longer than twice the fewest
        self.lag = 0.0  # the last new reading's lag behind its scan (up to a constant)
        self.rate = np.zeros(3)  # translation per second it showed (the turn stays 0)

    def read(self, odometry, stamp: float = math.nan):
        """``(step, news, first)`` for the reading at a scan taken at ``stamp``: the motion it
        predicts (None without a reading: a scan alone, or a reading the inbox dropped, after
        which the next starts odometry afresh, docs/runtime.md §7), whether it is new (then
        ``step`` is added to the pose of the scan that brought the last new one, else to the
        last scan's), and whether it is the first (odometry starts here: its ``step`` is
        zero)."""
        interval = stamp - self.stamp if stamp > self.stamp else math.nan  # (NaN: none)
        if interval > 0:
            self.scan_time += interval
            self.scan_intervals += 1
        self.stamp = stamp
        if odometry is None:
            self.have = False
            return None, False, False
        odometry = np.asarray(odometry, np.float64)
        period = self.period()
        if self.have and np.array_equal(odometry, self.last):
            self.stale_scans += 1
            if self.stale_motion and period > 0:  # at the rate it showed, for a period
                if stamp - self.arrival < period and interval > 0:
                    return self.rate * interval, False, False
                return np.zeros(3), False, False
            if self.stale_motion and self.stale_scans < self.reading_scans:
                return self.reading_step, False, False
            return np.zeros(3), False, False
        first = not self.have
        if first:
            self.stale_scans = 0
        delta = np.zeros(3) if first else between(odometry, self.last)
        gap = stamp - self.arrival if not first else math.nan
        scans = self.stale_scans + 1  # the scans this reading took to come
        if gap > 0:
            # Readings the same at rest are not new, so a gap may span several periods: only
            # gaps of at most twice the fewest scans count, and one of fewer than half of
            # them starts the count again (those before held a rest: a log's first gap may be
            # tens of scans, then its odometry comes with every scan). At most, not fewer: a
            # period of 1.6 scans comes one scan or two apart (0.8 s at 2 Hz)
            # ``restart_gaps`` in a row longer than that start the count again too: the
            # fewest was a stray (a reading one scan after the one before it, in a survey
            # whose scans were refused now and then, no beam returned)
            self.long_gaps = self.long_gaps + 1 if scans > 2 * self.fewest else 0
            if (not self.periods or 2 * scans < self.fewest
                    or self.long_gaps >= self.restart_gaps):
                self.period_time, self.period_scans, self.periods = gap, scans, 1
                self.fewest, self.long_gaps = scans, 0
            elif scans <= 2 * self.fewest:
                self.period_time += gap
                self.period_scans += scans
                self.periods += 1
                self.fewest = min(self.fewest, scans)
        if period > 0 and gap > 0:
            self.rate[:2] = delta[:2] / period
            missed = max(round(gap / period), 1)  # (readings the same at rest: not new)
            lag = min(max(self.lag + gap - missed * period, 0.0), self.scan_interval())
            delta[:2] += self.rate[:2] * (lag - self.lag)
            self.lag = lag
        else:
            self.lag = 0.5 * self.scan_interval()
            if self.periods and gap > 0:
                self.rate[:2] = delta[:2] * (self.periods / self.period_time)
        self.arrival = stamp
        self.last[:] = odometry  # (a copy: callers may reuse their array)
        self.reading_scans = scans
        self.reading_step[:2] = delta[:2] / scans
        self.stale_scans = 0
        self.have = True
        return delta, True, first

    def scan_interval(self) -> float:
        """The mean interval between the scans so far (s; 0 before two scans)."""
        return self.scan_time / self.scan_intervals if self.scan_intervals else 0.0

    def period(self) -> float:
        """Odometry's own period as the readings so far show it (s), when new readings come on
        average more than ``periodic_ratio`` scan intervals apart; else 0 (read with the
        scans, or not yet known)."""
        if self.periodic_ratio <= 0 or self.periods < 2:  # (one gap may be a rest)
            return 0.0
        periodic = self.period_scans > self.periodic_ratio * self.periods
        return self.period_time / self.periods if periodic else 0.0

    _STATE = ("stamp", "arrival", "scan_time", "scan_intervals", "period_time", "period_scans",
              "periods", "fewest", "long_gaps", "lag")

    def state(self) -> dict:
        """The readings as a saved session keeps them (the front end's)."""
        return {"last_odometry": self.last.copy(), "have_odometry": self.have,
                "stale_scans": self.stale_scans, "reading_scans": self.reading_scans,
                "reading_step": self.reading_step.copy(),
                **{f"readings_{k}": getattr(self, k) for k in self._STATE},
                "readings_rate": self.rate.copy()}

    def restore(self, state: dict) -> None:
        """:meth:`state`'s values."""
        self.last[:] = state["last_odometry"]
        self.have = bool(state["have_odometry"])
        self.stale_scans = int(state["stale_scans"])
        self.reading_scans = int(state["reading_scans"])
        step = np.asarray(state["reading_step"], np.float64)
        if step.shape != (3,) or not np.all(np.isfinite(step)) or min(
                self.stale_scans, self.reading_scans) < 0:
            raise ValueError("the stale readings' motion is not one this front end keeps")
        self.reading_step[:] = step
        for k in self._STATE:
            setattr(self, k, type(getattr(self, k))(state[f"readings_{k}"]))
        rate = np.asarray(state["readings_rate"], np.float64)
        if (rate.shape != (3,) or not np.all(np.isfinite(rate)) or min(
                self.scan_intervals, self.period_scans, self.periods, self.fewest,
                self.long_gaps) < 0 or not all(
                math.isfinite(getattr(self, k)) and getattr(self, k) >= 0
                for k in ("scan_time", "period_time", "lag"))):
            raise ValueError("odometry's period is not one these readings keep")
        self.rate[:] = rate
