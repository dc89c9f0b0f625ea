"""Recovery: a lost match sought again (docs/method.md §6.1, "Recovery").

    pose, weak = recovery.recover(scan, pose, predicted, inside)

With odometry, the match is sought again around the motion the scans showed last, continued
(after a stale reading, over a heading window as wide as ``recovery.stale_turn_window``), and, when the
lost match pressed against its box's edge, around that match itself: the optimum lay beyond
the box. Odometry that lags the scans and then catches up in a burst predicts tens of degrees
off, and so may the scans' last motion when a turn starts or stops. The better fitting of the
matches that fit the scans, and clearly better than odometry's prediction
(:meth:`OdometryGate.overrules`), stands; otherwise the prediction stands in, and the next
node's edge is weakened: a match that merely fits as well may be shifted along a corridor.
When none stands and the reading lags its scan, one more match spans every heading the robot
can have turned to (the pivot search). On scans alone, the whole box is searched without a
guess, the swarm's strength, and the better fitting of the two is kept.
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.matching.degeneracy import DegeneracyCheck
from swarmslam.runtime.front_end.odometry_gate import OdometryGate, Prediction, TrackingCounts
from swarmslam.runtime.front_end.odometry_readings import OdometryReadings
from swarmslam.runtime.pose import compose, wrap_angle
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import BOX_MARGIN, ScanMatcher

# The compass search's match replaces the swarm's where its λ is below this share of the
# swarm's: a basin the swarm missed, not the same one polished.
SEEK_RATIO = 0.9


def stale_turn_box(config: SlamConfig) -> np.ndarray:
    """The half-widths of a match's box after a stale reading: the guess window's, the
    heading's widened to ``recovery.stale_turn_window`` (a turn in place since the reading is not
    known)."""
    g = config.matcher.guess_window
    return np.array([g[0], g[1], max(g[2], config.front_end.recovery.stale_turn_window)])


class Recovery:
    """The searches that find a lost match again, judged by the front end's ``gate``."""

    def __init__(self, config: SlamConfig, matcher: ScanMatcher, reference, gate: OdometryGate,
                 degeneracy: DegeneracyCheck, readings: OdometryReadings,
                 counts: TrackingCounts):
        self.config, self.matcher, self.reference = config, matcher, reference
        self.gate, self.degeneracy, self.readings, self.counts = gate, degeneracy, readings, counts
        self._turn_window = stale_turn_box(config)  # a lost match's box after a stale reading

    def recover(self, scan: PointScan, pose, predicted: Prediction, inside: bool):
        """The pose that stands for the lost match ``pose`` (``inside``: an optimum inside its
        box), and whether it is odometry's prediction standing in (the next node's edge is
        then weak)."""
        self.counts.lost_matches += 1
        guess, step = predicted.guess, predicted.step
        if not predicted.odometry:
            wide = self.matcher.align_scans(scan, self.reference, None).pose
            return max((pose, wide), key=lambda p: self.gate.fit(scan, p)), False
        # (a stale reading says nothing of a turn in place since; the scans' last motion may
        # not show it either)
        window = self._turn_window if predicted.stale else None
        # around the lost match too when it pressed against its box: the optimum lay beyond
        priors = (compose(predicted.last, predicted.motion),) + (() if inside else (pose,))
        best, degeneracy = self._best_overruling(scan, priors, window, guess, step,
                                                 predicted.stale)
        # (a reading taken some time before its scan says nothing of a pivot since)
        if best is None and (predicted.stale or self.readings.reading_scans > 1
                             or self.readings.period() > 0):
            best, degeneracy = self._pivot_search(scan, predicted, priors, window)
        if best is not None:
            self.degeneracy.last = degeneracy  # (the next node's edge is weak where it slid)
            self.counts.rescued_matches += 1
            return best, False
        return guess, True

    def _pivot_search(self, scan, predicted: Prediction, searched, window):
        """One match over every heading the robot can have turned to since the last scan, at
        ``recovery.pivot_search_rate`` for the interval since it, either side of that scan's heading, at
        the prediction's position. It stands if it overrules the prediction as after a stale
        reading and turns beyond every box searched before (around the prediction and each of
        ``searched``, their half-widths ``window``, None: the guess window's): within them,
        the searches there found the scans' optimum, and a wider box finds a poorer one in a
        scan of few surfaces. At a low scan rate a pivot turns tens of degrees a scan: its
        first scan lies beyond the box around every prediction when the reading lags the
        turn."""
        c = self.config.front_end
        interval, guess, last = predicted.interval, predicted.guess, predicted.last
        if c.recovery.pivot_search_rate <= 0 or not math.isfinite(interval) or interval <= 0:
            return None, None
        prior = np.array(guess, dtype=np.float64)
        prior[2] = last[2]
        g = self.config.matcher.guess_window
        # (wide enough to hold the prediction's own box too)
        half = max(min(c.recovery.pivot_search_rate * interval, math.pi),
                   abs(float(wrap_angle(guess[2] - last[2]))) + g[2])
        self.matcher.keep_stream()
        kept = self.degeneracy.last, self.counts.degenerate_matches
        # (no heading search here: over every heading a building's right angles offer wrong
        # basins the fine field scores lower)
        found = self._best_overruling(scan, (prior,), np.array([g[0], g[1], half]), guess,
                                      predicted.step, stale=True, seek=False)
        turn = float((g if window is None else window)[2])
        if found[0] is None or any(abs(float(wrap_angle(found[0][2] - p[2]))) <= turn
                                   for p in (guess, *searched)):
            # nothing kept: the run goes on as without the search
            self.matcher.rewind_stream()
            self.degeneracy.last, self.counts.degenerate_matches = kept
            return None, None
        return found

    def _sought_match(self, scan, prior, window, seek: bool = True) -> np.ndarray:
        """A lost match sought again around ``prior`` (a box of half-widths ``window``, None:
        the guess window): Alg. 5's, or the compass search's settled from headings
        ``recovery.heading_step`` apart across the same box where it fits clearly better (λ
        below ``SEEK_RATIO`` of Alg. 5's). The swarm finds its basin on the coarse
        field, which people crowding a pivot can mislead; the fine field tells the turn.
        ``seek`` False: Alg. 5's alone."""
        c = self.config.front_end
        match = self.matcher.align_scans(scan, self.reference, prior, window)
        if seek and c.recovery.heading_step > 0:
            sought = self.matcher.seek_headings(scan, self.reference, c.recovery.heading_step)
            if sought.error < SEEK_RATIO * match.error:
                self.counts.sought_matches += 1
                return sought.pose
        return match.pose

    def _best_overruling(self, scan, priors, window, guess, step, stale: bool, seek=True):
        """Of the matches sought around each of ``priors`` (boxes of half-widths ``window``,
        None: the guess window; :meth:`_sought_match`, by ``seek``), the best fitting that
        overrules odometry's prediction ``guess`` (:meth:`OdometryGate.overrules`, judged as
        after a ``stale`` reading or a new one): ``(match, degeneracy)``, the match None when
        none does."""
        c = self.config.front_end
        best, best_fit, degeneracy = None, -1.0, None
        for prior in priors:
            match = self._sought_match(scan, prior, window, seek)
            inside_box = not self.matcher.at_box_edge(match, BOX_MARGIN)
            if c.degeneracy_ratio > 0:  # along a degenerate axis, odometry's position stands
                match = self.degeneracy.constrain(scan, match, guess)
                inside_box = not self.matcher.at_box_edge(
                    self.degeneracy.last.remap(match, prior), BOX_MARGIN)
            fit = self.gate.fit(scan, match)
            if fit > best_fit and self.gate.overrules(scan, match, fit, guess, step, inside_box,
                                                      stale):
                best, best_fit, degeneracy = match, fit, self.degeneracy.last
        return best, degeneracy
