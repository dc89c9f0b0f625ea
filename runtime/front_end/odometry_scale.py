"""Odometry's translation scale, fitted to the matches that pin the motion (docs/method.md
§6.1, "Odometry's scale").

    >>> fit = OdometryScale(prior_travel=5.0, limits=(0.8, 1.25), dead_zone=0.005)
    >>> for _ in range(200):  # 20 m of steps the scans measured 2% longer than odometry
    ...     fit.observe([0.102, 0.0], [0.1, 0.0])
    >>> round(fit.scale, 3)
    1.011

A wheel a little larger or smaller than odometry assumes (a tyre worn, a load, a radius set by
hand) makes every translation odometry reports a few per cent off. Where the scans pin the
motion, the matches correct it; along a direction they do not pin (a plain corridor's axis)
odometry's prediction stands (:mod:`swarmslam.runtime.matching.degeneracy`) and its error piles up,
1 cm a metre for a 1% wheel. The fit is what the matches that do pin the motion say of it:
each step's ratio ``m·o / o·o`` (odometry's translation ``o``, the scans' ``m``), and of those
the median, each step weighed by its length ``|o|`` (a turn in place, which moves a scanner
mounted off the axle, says nothing of the wheels). A median, not the least-squares ratio:
people walking beside the robot drag some pinned matches along with them, and on a simulated
corridor with three people and noisy wheels the least-squares ratio read 1.016 where the
wheels were true, the median 1.006. The ratios are kept as the travel in each of ``BINS``
bins across ``limits`` (a step beyond them counts in the end bin), so the memory is fixed;
the median is interpolated within its bin. It is then blended with a prior of 1 worth
``prior_travel`` metres, so a short run keeps odometry as it reads, and shrunk towards 1 by
``dead_zone`` (1 within it): the matches' own scale errs by a per-mille or two, which is no
wheel's to correct; shrinking rather than cutting keeps the scale continuous as the fit
moves, so no optimisation sees every corridor edge jump at once.

The front end does not use the scale to predict; the pose graph holds each node edge's part
taken from odometry along a degenerate axis, and the back end brings those parts to this scale
inside its next loop closure's optimisation (:meth:`PoseGraph.rescale`), where the closure is
judged with it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.pose import between

# m: the fit is blended with a scale of 1 worth this much travel (a short run keeps odometry as
# it reads)
PRIOR_TRAVEL = 5.0
# The fitted scale is shrunk towards 1 by this much (1 within it): the matches' own scale errs
# by a per-mille or two.
DEAD_ZONE = 0.005
BINS = 1000  # bins of the steps' ratios across the limits (0.00045 wide for 0.8–1.25)


@njit(cache=True)
def weighted_median(travel, low, high):
    """The median ratio of the travel binned in ``travel`` across ``low``–``high``,
    interpolated within its bin; NaN when there is none."""
    total = 0.0
    for k in range(travel.shape[0]):
        total += travel[k]
    if not total > 0.0:
        return math.nan
    width = (high - low) / travel.shape[0]
    half = 0.5 * total
    below = 0.0
    for k in range(travel.shape[0]):
        w = travel[k]
        if w > 0.0 and below + w >= half:
            return low + width * (k + (half - below) / w)
        below += w
    return high


class OdometryScale:
    """The fit so far (see the module's docstring)."""

    def __init__(self, prior_travel: float, limits: tuple[float, float], dead_zone: float):
        self.prior_travel = float(prior_travel)
        self.limits = (float(limits[0]), float(limits[1]))
        self.dead_zone = float(dead_zone)
        self.travel = np.zeros(BINS)  # m of odometry's travel per bin of the steps' ratios

    @property
    def scale(self) -> float:
        """Odometry's translations times this are the scans' (see the module's docstring)."""
        low, high = self.limits
        median = weighted_median(self.travel, low, high)
        if math.isnan(median):
            return 1.0
        travel = float(self.travel.sum())
        fit = (median * travel + self.prior_travel) / (travel + self.prior_travel)
        return 1.0 + math.copysign(max(abs(fit - 1.0) - self.dead_zone, 0.0), fit - 1.0)

    def observe(self, matched, read) -> None:
        """One step: the translation two matches that pin the motion showed (``matched``) and
        odometry's over the same readings (``read``), in one frame. Non-finite steps and
        steps odometry read as none are skipped."""
        mx, my, ox, oy = float(matched[0]), float(matched[1]), float(read[0]), float(read[1])
        squared = ox * ox + oy * oy
        if not (squared > 0.0 and math.isfinite(squared) and math.isfinite(mx)
                and math.isfinite(my)):
            return
        low, high = self.limits
        ratio = (mx * ox + my * oy) / squared
        if not math.isfinite(ratio):
            return
        k = min(max(int((ratio - low) / (high - low) * BINS), 0), BINS - 1)
        self.travel[k] += math.sqrt(squared)

    def restore(self, travel) -> None:
        """The binned travel a saved run had; refused unless ``BINS`` finite, non-negative
        numbers."""
        travel = np.asarray(travel, np.float64)
        if travel.shape != (BINS,) or not np.all(np.isfinite(travel)) or np.any(travel < 0):
            raise ValueError(f"odometry's scale is not {BINS} finite, non-negative travels")
        self.travel[:] = travel


class OdometryCalibration:
    """Odometry's scale as the front end observes it: the fit, the translation the keyframe's
    interval so far took from odometry along a degenerate axis (the next node edge's odometry
    part), and whether the match that brought odometry's last new reading pinned the motion,
    so that the motion from it can be observed."""

    def __init__(self, config):
        """``config``: the front end's section (its ``odometry_scale``)."""
        self.enabled = config.odometry_scale.enabled
        self.fit = OdometryScale(PRIOR_TRAVEL, config.odometry_scale.limits, DEAD_ZONE)
        self.part = np.zeros(2)
        self.pinned_base = False

    def note_part(self, axis, guess, last) -> None:
        """A match that took odometry's prediction ``guess`` along its degenerate ``axis``: the
        step from the last scan's pose ``last`` that the prediction gave there adds to the
        next node edge's odometry part."""
        if not self.enabled:
            return
        along = float(axis[0] * (guess[0] - last[0]) + axis[1] * (guess[1] - last[1]))
        self.part += along * axis

    def observe(self, pose, base, step, pinned: bool) -> None:
        """A new reading's scan: the motion from the scan that brought the last new reading
        (``base``) to ``pose`` against odometry's ``step`` over it, where both matches pinned
        the motion."""
        if pinned and self.pinned_base and self.enabled:
            self.fit.observe(between(pose, base), step)
        self.pinned_base = pinned

    def state(self) -> dict:
        return {"odometry_scale": self.fit.travel.copy(), "odometry_part": self.part.copy(),
                "pinned_base": self.pinned_base}

    def restore(self, state: dict) -> None:
        self.fit.restore(state["odometry_scale"])
        part = np.asarray(state["odometry_part"], np.float64)
        if part.shape != (2,) or not np.all(np.isfinite(part)):
            raise ValueError("the keyframe's odometry part is not two finite numbers")
        self.part[:] = part
        self.pinned_base = bool(state["pinned_base"])
