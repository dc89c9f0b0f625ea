"""Odometry's translation scale, fitted to the matches that pin the motion (docs/method.md
§6.1, "Odometry's scale").

    >>> fit = OdometryScale(prior_travel=5.0, limits=(0.8, 1.25), dead_zone=0.005)
    >>> for _ in range(200):  # 20 m of steps the scans measured 2% longer than odometry
    ...     fit.observe([0.102, 0.0], [0.1, 0.0])
    >>> round(fit.scale, 4)
    1.011

A wheel a little larger or smaller than odometry assumes (a tyre worn, a load, a radius set by
hand) makes every translation odometry reports a few per cent off. Where the scans pin the
motion, the matches correct it; along a direction they do not pin (a plain corridor's axis)
odometry's prediction stands (:mod:`swarmslam.runtime.degeneracy`) and its error piles up,
1 cm a metre for a 1% wheel. The fit is what the matches that do pin the motion say of it:
``Σ m·o / Σ o·o`` over the steps observed (odometry's ``o``, the scans' ``m``), which weighs
each step by its length, with a prior of 1 worth ``prior_travel`` metres of travel at the
run's mean step, clipped to ``limits``. The scale used is the fit shrunk towards 1 by
``dead_zone`` (1 within it): the matches' own scale errs by a per-mille or two (the
simulator's scanners), which is no wheel's to correct; shrinking rather than cutting keeps the
scale continuous as the fit moves, so no optimisation sees every corridor edge jump at once.

The front end does not use the scale to predict; the pose graph holds each node edge's part
taken from odometry along a degenerate axis, and the back end brings those parts to this scale
inside its next loop closure's optimisation (:meth:`PoseGraph.rescale`), where the closure is
judged with it.
"""

from __future__ import annotations

import math

import numpy as np


class OdometryScale:
    """The fit so far (see the module's docstring)."""

    def __init__(self, prior_travel: float, limits: tuple[float, float], dead_zone: float):
        self.prior_travel = float(prior_travel)
        self.limits = (float(limits[0]), float(limits[1]))
        self.dead_zone = float(dead_zone)
        self.sums = np.zeros(3)  # Σ m·o, Σ o·o (m²), Σ |o| (m) over the steps observed

    @property
    def scale(self) -> float:
        """Odometry's translations times this are the scans' (see the module's docstring)."""
        matched, squared, travel = self.sums
        if travel <= 0.0:
            return 1.0
        prior = self.prior_travel * squared / travel  # prior_travel metres at the mean step
        fit = min(max((matched + prior) / (squared + prior), self.limits[0]), self.limits[1])
        return 1.0 + math.copysign(max(abs(fit - 1.0) - self.dead_zone, 0.0), fit - 1.0)

    def observe(self, matched, read) -> None:
        """One step: the translation two matches that pin the motion showed (``matched``) and
        odometry's over the same readings (``read``), in one frame. Non-finite steps are
        skipped."""
        mx, my, ox, oy = float(matched[0]), float(matched[1]), float(read[0]), float(read[1])
        squared = ox * ox + oy * oy
        if not (squared > 0.0 and math.isfinite(squared) and math.isfinite(mx)
                and math.isfinite(my)):
            return
        self.sums[0] += mx * ox + my * oy
        self.sums[1] += squared
        self.sums[2] += math.sqrt(squared)

    def restore(self, sums) -> None:
        """The sums a saved run had (Σ m·o, Σ o·o, Σ |o|); refused unless three finite
        numbers, the last two non-negative."""
        sums = np.asarray(sums, np.float64)
        if sums.shape != (3,) or not np.all(np.isfinite(sums)) or np.any(sums[1:] < 0):
            raise ValueError("odometry's scale sums are not three finite numbers, the last "
                             "two non-negative")
        self.sums[:] = sums
