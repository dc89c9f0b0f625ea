"""The odometry gate and its exceptions: whether a scan's match has lost track (docs/method.md
§6.1).

    gate = OdometryGate(config.front_end, matcher, reference, counts)
    if gate.lost(scan, pose, predicted, inside):
        ...  # recovery (swarmslam.runtime.front_end.recovery)

A match has lost track when it is pressed against its search box's edge, when too few of its
points land on the keyframe's surfaces, when it corrects odometry's prediction by more than
odometry errs over the motion (the gate) and the scans do not overrule odometry, or when the
previous scan, which holds each wall once, fits the prediction clearly better (the previous-scan
check). The heading prior weighs a match that turns a new reading's heading against the
optimum nearer odometry's. Each rule reads only the scan, the keyframe's reference, the match
and the prediction (:class:`Prediction`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarmslam.runtime.config import FrontEndConfig
from swarmslam.runtime.pose import between, wrap_angle
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import INLIER_SLOPE, MatchResult, ScanMatcher

# m: against a new reading, a match's fit and odometry's prediction's count the points this
# near a surface: narrower than track_inlier_distance, which tells a lost match, it tells two
# poses a few degrees apart.
OVERRULE_DISTANCE = 0.15
# The previous-scan check applies only where odometry's prediction fits at least this share of
# the points on the previous scan's surfaces: the previous scan vouches for the prediction
# where the two overlap.
PREVIOUS_SCAN_FIT = 0.75
# A match that moves a new reading's position alone is taken for a slide along a corridor
# unless it fits all but this share of its points and odometry's prediction fits this share
# fewer (within OVERRULE_DISTANCE): a slide fits the corridor's walls but not what ends it, and
# leaves the prediction fitting as the walls do; a match fitting nearly every point, and
# clearly better, says odometry's position is what errs (a wheel reading that lost its sign as
# the robot backed up). Half of it lets slides in; twice it refuses too many right matches.
SLIDE_GAIN = 0.1
# rad, σ of odometry's heading over a step (plus the gate's heading share of its turn): the
# heading prior's unit.
HEADING_SIGMA = math.radians(1.0)


@dataclass
class Prediction:
    """What the front end predicted for the scan being tracked, in the keyframe's frame."""

    guess: np.ndarray  # the predicted pose
    step: np.ndarray  # the motion it was predicted over
    last: np.ndarray  # the previous scan's pose
    motion: np.ndarray  # the last motion the scans showed
    odometry: bool  # odometry gave a reading, new or stale
    stale: bool  # the reading is odometry's previous one again
    interval: float  # s since the previous scan


@dataclass
class TrackingCounts:
    """The front end's tallies of its rules, saved with a session and reported whole."""

    lost_matches: int = 0  # matches that lost track (each went to recovery)
    overruled_odometry: int = 0  # matches the gate refused that the scans upheld
    rescued_matches: int = 0  # lost matches found again by recovery
    sought_matches: int = 0  # of those sought again, the compass search's from headings
    degenerate_matches: int = 0  # matches held to the prediction along a direction
    disowned_matches: int = 0  # matches the previous-scan check called lost
    held_to_odometry: int = 0  # matches that gave way to the optimum nearer odometry (prior)


def contradicts_odometry(pose, guess, step, config: FrontEndConfig,
                         heading: bool = True, position: bool = True) -> bool:
    """The odometry gate: ``pose`` (a match) corrects ``guess`` (odometry's prediction, in the
    same frame; ``step`` the motion it predicted over) by more than odometry errs over that
    motion; ``heading``, ``position``: which of the two are judged."""
    if not config.odometry_gate.enabled:
        return False
    gate, share = config.odometry_gate.tolerance, config.odometry_gate.share
    correction = between(pose, guess)
    allowed = gate[0] + share[0] * math.hypot(step[0], step[1])
    return bool((position and math.hypot(correction[0], correction[1]) > allowed)
                or (heading and abs(correction[2]) > gate[1] + share[1] * abs(step[2])))


def scans_overrule(fit: float, predicted: float, stale: bool, config: FrontEndConfig) -> bool:
    """Whether a match fitting ``fit`` of its points on the keyframe's surfaces fits clearly
    better than odometry's prediction, which fits ``predicted``. Against a ``stale`` reading,
    which says nothing of the motion since, a gain above ``odometry_gate.fit`` suffices. A new
    reading is a measurement: the match must fit more than ``odometry_gate.explained`` of the
    points the prediction misses (both fits counted within ``OVERRULE_DISTANCE``). A fixed
    gain cannot tell a match that fits every point where the prediction misses a tenth from one
    that fits two thirds where it fits half (a hall whose walls fit a slip either way)."""
    if stale:
        return fit - predicted > config.odometry_gate.fit
    return fit - predicted > config.odometry_gate.explained * (1.0 - predicted)


def _unbeatable(n: int, gain: float) -> int:
    """The least count ``k`` of ``n`` points whose share leaves no room for a share above it
    by more than ``gain``: ``1 − k/n > gain`` fails, as floating point computes it (``n + 1``
    when no count does). Shares only grow with counts, so any count from ``k`` on fails too."""
    k = max(int((1.0 - gain) * n) - 1, 0)
    while k <= n and 1.0 - k / n > gain:
        k += 1
    return k


class PreviousScan:
    """The scan tracked last, and its surfaces listed once a match is checked against it: it
    holds each wall once where the keyframe's submap may hold one twice. Listed, not rendered:
    two matches are read against it, and rendering its field costs more than both reads."""

    def __init__(self, config: FrontEndConfig, matcher: ScanMatcher, points: int,
                 counts: TrackingCounts):
        self.config, self.matcher, self.counts = config, matcher, counts
        self.scan = PointScan(points)
        self._surfaces = matcher.new_surfaces(points)
        self._listed = False

    def remember(self, scan: PointScan) -> None:
        """Keep ``scan`` (at most ``sensor.max_points`` of it, as a node keeps); its surfaces
        are listed when first needed."""
        n = min(scan.count, self.scan.capacity)
        self.scan.buffer[:n] = scan.buffer[:n]
        self.scan.count = n
        self._listed = False

    def disowns(self, scan: PointScan, pose, predicted: Prediction) -> bool:
        """The previous-scan check: the previous scan fits odometry's prediction (a new
        reading) clearly better than the match ``pose``: more than ``previous_scan_check.gain``
        of the points better, the prediction fitting at least ``PREVIOUS_SCAN_FIT`` of them. A
        keyframe's submap whose node scans were placed a few degrees apart holds a wall twice,
        and a scan tracked against it fits either copy; the previous scan, moments old, holds
        the wall once."""
        c, check = self.config, self.config.previous_scan_check
        n = scan.count
        if (predicted.stale or not check.enabled or check.gain >= 1 or self.scan.count == 0
                or n == 0):
            return False  # a stale reading predicts nothing to vouch for
        if not self._listed:
            self.matcher.list_surfaces(self.scan, self._surfaces)
            self._listed = True
        # The match first: the prediction fits at most every point, so a match fitting
        # ``unbeatable`` of them cannot be disowned and its count stops there. The verdict is
        # the one both counts in full give, in about half the reads (most matches fit 0.9+).
        unbeatable = _unbeatable(n, check.gain)
        matched = self.matcher.surface_inliers(
            scan, self._surfaces, between(pose, predicted.last), c.track_inlier_distance,
            INLIER_SLOPE, stop=unbeatable)
        if matched >= unbeatable:
            return False
        fit = matched / n
        fits = self.matcher.surface_inliers(
            scan, self._surfaces, between(predicted.guess, predicted.last),
            c.track_inlier_distance, INLIER_SLOPE) / n
        if fits >= PREVIOUS_SCAN_FIT and fits - fit > check.gain:
            self.counts.disowned_matches += 1
            return True
        return False

    def state(self) -> np.ndarray:
        return self.scan.points.copy()

    def restore(self, points) -> None:
        if (points.ndim != 2 or points.shape[1] != 2 or len(points) > self.scan.capacity
                or not np.all(np.isfinite(points))):
            raise ValueError("the previous scan's points do not fit this front end")
        self.scan.buffer[: len(points)] = points
        self.scan.count, self._listed = len(points), False


class OdometryGate:
    """The judge of a scan's match against odometry's prediction and the keyframe's surfaces
    (``reference``, the front end's, rebuilt in place at every node)."""

    def __init__(self, config: FrontEndConfig, matcher: ScanMatcher, reference, points: int,
                 counts: TrackingCounts):
        self.config, self.matcher, self.reference, self.counts = config, matcher, reference, counts
        self.previous = PreviousScan(config, matcher, points, counts)

    def fit(self, scan: PointScan, pose, distance: float | None = None) -> float:
        """The share of ``scan``'s points at ``pose`` within ``distance`` (default
        ``track_inlier_distance``), plus ``INLIER_SLOPE`` per m of range, of the
        keyframe's surfaces."""
        c = self.config
        if distance is None:
            distance = c.track_inlier_distance
        return self.matcher.inlier_fraction(scan, self.reference, pose, distance, INLIER_SLOPE)

    def lost(self, scan: PointScan, pose, predicted: Prediction, inside: bool) -> bool:
        """The match has lost track: it is pressed against its search box's edge (not
        ``inside``: the optimum lies beyond), too few of its points land on the keyframe's
        surfaces, it contradicts odometry (the gate) without :meth:`overrules` odometry, or the
        previous scan disowns it (:meth:`PreviousScan.disowns`)."""
        c = self.config
        if not inside:
            return True
        fit = self.fit(scan, pose)
        if fit < c.min_track_inliers:
            return True
        guess, step = predicted.guess, predicted.step
        if predicted.odometry and contradicts_odometry(pose, guess, step, c):
            if not self.overrules(scan, pose, fit, guess, step, inside, predicted.stale):
                return True
            self.counts.overruled_odometry += 1
        return predicted.odometry and self.previous.disowns(scan, pose, predicted)

    def overrules(self, scan: PointScan, pose, fit: float, guess, step, inside: bool,
                  stale: bool) -> bool:
        """A match (``fit``: its share of points on the keyframe's surfaces) is trusted over
        odometry's prediction ``guess`` (over the motion ``step``) when it is an optimum inside
        its search box, fits, and fits clearly better than the prediction does
        (:func:`scans_overrule`), unless it moves a new reading's position alone, its heading
        within the gate's fixed part, from a prediction that itself tracks (fits
        ``min_track_inliers``), unless the match fits all but ``SLIDE_GAIN`` of the points and
        the prediction that much fewer: that match may have slid along a corridor, and
        odometry's position errs little between scans unless its heading does; a prediction
        that would count as lost is no place to slide from, and one the scans fit clearly worse
        than a match fitting nearly every point is no corridor's. A ``stale`` reading is never
        held to more than a new one: a match the plain gain refuses is judged as against a new
        reading (a turn started facing a near wall: the prediction fits nearly every point, so
        no fixed gain can be reached)."""
        c = self.config
        if not inside or fit < c.min_track_inliers:
            return False
        if stale and scans_overrule(fit, self.fit(scan, guess), True, c):
            return True
        # "alone": the heading within the gate's own part, not its share of the turn: a match
        # turning a fast turn's prediction far is no slide along a corridor, and odometry's
        # position, composed along its heading, is off with it
        slide = (contradicts_odometry(pose, guess, step, c, heading=False)
                 and abs(float(between(pose, guess)[2])) <= c.odometry_gate.tolerance[1]
                 and self.fit(scan, guess) >= c.min_track_inliers)
        if slide and fit < 1.0 - SLIDE_GAIN:  # (refused before the narrow band is counted)
            return False
        # a narrower band than a lost match's tells two poses a few degrees apart
        narrow, narrow_guess = (self.fit(scan, p, OVERRULE_DISTANCE) for p in (pose, guess))
        if slide and narrow - narrow_guess <= SLIDE_GAIN:
            return False
        return scans_overrule(narrow, narrow_guess, False, c)

    def heading_prior(self, scan: PointScan, match: MatchResult, predicted: Prediction):
        """Of two optima of the scan cost, the one nearer odometry's heading: a ``match``
        turning the prediction (a new reading) by more than σ (``HEADING_SIGMA`` plus
        ``odometry_gate.share``'s heading share of the predicted turn) is weighed against the
        optimum the compass search settles in from the prediction, each by its λ plus
        ``heading_prior.weight``·(its turn from the prediction / σ)². A submap holding a wall
        twice fits a scan at either copy about equally; odometry, which saw no such turn, tells
        them apart. A match that fits clearly better, odometry's lag in a fast turn, outweighs
        the prior. Returns the pose that stands."""
        c = self.config
        guess = predicted.guess
        turn = float(wrap_angle(match.pose[2] - guess[2]))
        sigma = HEADING_SIGMA + c.odometry_gate.share[1] * abs(float(predicted.step[2]))
        if not c.heading_prior.enabled or abs(turn) <= sigma:
            return match.pose
        settled = self.matcher.settle(scan, self.reference, at_prediction(guess))
        held = float(wrap_angle(settled.pose[2] - guess[2]))
        weight = c.heading_prior.weight
        if settled.error + weight * (held / sigma) ** 2 < match.error + weight * (turn / sigma) ** 2:
            self.counts.held_to_odometry += 1
            return settled.pose
        return match.pose


def at_prediction(guess) -> MatchResult:
    """Odometry's prediction as a match to settle from (its λ is the settling's to find)."""
    return MatchResult(pose=np.asarray(guess, dtype=np.float64), error=math.inf,
                       scan_error=math.inf, used_map=False, iterations=0, evaluations=0)
