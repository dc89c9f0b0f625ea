"""Odometry's scale, fitted to the matches, and the node edges that follow it (docs/method.md
§6.1, "Odometry's scale").

    scale = OdometryScale(prior_travel=5.0, limits=(0.8, 1.25), dead_zone=0.005,
                          significance=2.0)
    step = scale.apply(step)      # odometry's predicted motion, its translation scaled
    scale.observe(matched)        # the motion the scans then showed (a match that pins it)
    edges = ScaledEdges(max_edges)
    edges.note(axis, step_used, step_read)   # a match that took the prediction along ``axis``
    edges.close(edge)                        # the node edge that holds those scans' motion
    edges.rescale(graph, scale.scale)        # every such edge at the scale fitted now

A wheel a little larger or smaller than odometry assumes (a tyre worn, a load, a radius set by
hand) makes every translation odometry reports a few per cent off. Where the scans pin the
motion, the matches correct it; along a direction they do not pin (a plain corridor's axis)
odometry's prediction stands (swarmslam.runtime.degeneracy), and its error piles up: 1 cm a
metre for a 1% wheel. The scale is what the matches that do pin the motion say of it: the
least-squares fit of their translations to odometry's, ``Σ m·o / Σ o·o`` over the steps
observed, which weighs each step by its length (a turn in place, which moves a scanner
mounted off the axle, says nothing of the wheels). A prior of 1 counts as ``prior_travel``
metres of travel at the run's own mean step, so a short run keeps odometry as it reads; the
fit is clipped to ``limits``, and it is 1 unless it stands ``significance`` standard errors
(from the steps' own scatter about it) beyond ``dead_zone`` of 1: the matches' own scale errs
by a per-mille or two (the simulator's scanners), which is no wheel's to correct, and the first
metres' fit swings by more than that.

A scale learnt while the robot drives changes under a corridor's first pass: that pass took
odometry's distance at the scale of its time, a later pass at a later one, and a loop closed
in a plain corridor cannot say which is right along it. So each node edge keeps how much of
its translation it took from odometry's prediction along a degenerate axis — as read and as
used — and follows the scale as it changes: every pass is measured at the scale fitted now
(docs/experiments/2026-11-29-odometry-scale-again.md).
"""

from __future__ import annotations

import math

import numpy as np


class OdometryScale:
    """The fit so far, and the prediction scaled by it (see module doc)."""

    def __init__(self, prior_travel: float, limits: tuple[float, float], dead_zone: float,
                 significance: float):
        self.prior_travel = float(prior_travel)
        self.limits = (float(limits[0]), float(limits[1]))
        self.dead_zone = float(dead_zone)
        self.significance = float(significance)
        # Σ m·o, Σ o·o (m²), Σ |o| (m), Σ m·m (m²) and the count of the steps observed
        self.sums = np.zeros(5)
        self.raw = np.zeros(3)  # the step apply() was last given, as odometry read it
        self._scaled = np.zeros(3)

    @property
    def scale(self) -> float:
        """Odometry's translation times this is the scans' (1 until the fit stands clear of
        the dead zone)."""
        matched, squared, travel, matched_squared, count = self.sums
        if travel <= 0.0 or count < 2:
            return 1.0
        prior = self.prior_travel * squared / travel  # prior_travel m at the mean step
        value = min(max((matched + prior) / (squared + prior), self.limits[0]), self.limits[1])
        fit = matched / squared  # the steps' own, and their scatter about it (two axes each)
        scatter = max(matched_squared - 2.0 * fit * matched + fit * fit * squared, 0.0)
        error = math.sqrt(scatter / (2.0 * count - 1.0) / squared)
        if abs(value - 1.0) - self.dead_zone > self.significance * error:
            return value
        return 1.0

    def apply(self, step) -> np.ndarray:
        """``step`` (odometry's motion, x, y, θ) with its translation scaled; kept as read in
        :attr:`raw`. The array returned is this object's own, rewritten by the next call."""
        self.raw[:] = step
        self._scaled[:] = step
        self._scaled[:2] *= self.scale
        return self._scaled

    def observe(self, matched) -> None:
        """The motion a match that pins it showed over the step :meth:`apply` was last given
        (in the same frame: the pose that step was added to)."""
        o = self.raw[:2]
        squared = float(o @ o)
        if squared <= 0.0 or not (math.isfinite(matched[0]) and math.isfinite(matched[1])):
            return
        self.sums[0] += float(matched[0] * o[0] + matched[1] * o[1])
        self.sums[1] += squared
        self.sums[2] += math.sqrt(squared)
        self.sums[3] += float(matched[0] * matched[0] + matched[1] * matched[1])
        self.sums[4] += 1.0

    def restore(self, sums) -> None:
        """The sums a saved run had (Σ m·o, Σ o·o, Σ |o|, Σ m·m, count); refused unless five
        finite numbers, all but the first non-negative."""
        sums = np.asarray(sums, np.float64)
        if sums.shape != (5,) or not np.all(np.isfinite(sums)) or np.any(sums[1:] < 0):
            raise ValueError("odometry's scale sums are not five finite numbers, all but the "
                             "first non-negative")
        self.sums[:] = sums


class ScaledEdges:
    """Per node edge, the translation it took from odometry's prediction along a degenerate
    axis (in its first node's frame), as odometry read it (``raw``) and as the edge holds it
    now (``used``); and the same for the keyframe's interval so far (see module doc)."""

    def __init__(self, max_edges: int):
        self.raw = np.zeros((max_edges, 2))
        self.used = np.zeros((max_edges, 2))
        self.pending = np.zeros((2, 2))  # the interval's raw and used
        self.applied = 1.0  # the scale the edges' ``used`` parts are at
        self._change = np.zeros((max_edges, 2))

    def note(self, axis, used, raw) -> None:
        """A scan whose match took the prediction along ``axis``: the prediction's step from the
        last scan's pose as used (scaled) and as odometry read it; their parts along the axis
        are the motion odometry gave."""
        self.pending[0] += axis * float(axis[0] * raw[0] + axis[1] * raw[1])
        self.pending[1] += axis * float(axis[0] * used[0] + axis[1] * used[1])

    def close(self, edge: int, taken: bool = True) -> None:
        """The node edge ``edge`` holds the interval's motion (``taken``; else none of it came
        from odometry: an edge placed by localization); the next interval starts."""
        self.raw[edge] = self.pending[0] if taken else 0.0
        self.used[edge] = self.pending[1] if taken else 0.0
        self.pending[:] = 0.0

    def rescale(self, graph, scale: float) -> None:
        """Every edge's odometry part at ``scale``, where it changed since the last call."""
        if scale == self.applied:
            return
        n = graph.n_edges
        change = self._change[:n]
        np.multiply(self.raw[:n], scale, out=change)
        change -= self.used[:n]
        graph.z[:n, :2] += change
        self.used[:n] += change
        self.applied = scale

    def state(self, n_edges: int) -> dict:
        return {"raw": self.raw[:n_edges].copy(), "used": self.used[:n_edges].copy(),
                "pending": self.pending.copy(), "applied": self.applied}

    def restore(self, state: dict, n_edges: int) -> None:
        """What :meth:`state` gave, for a graph of ``n_edges`` edges; refused unless each part
        is finite and one per edge."""
        raw, used = (np.asarray(state[k], np.float64) for k in ("raw", "used"))
        pending = np.asarray(state["pending"], np.float64)
        applied = float(state["applied"])
        if (raw.shape != (n_edges, 2) or used.shape != (n_edges, 2) or pending.shape != (2, 2)
                or not all(np.all(np.isfinite(a)) for a in (raw, used, pending))
                or not math.isfinite(applied) or applied <= 0):
            raise ValueError("the edges' odometry parts are not two finite numbers per edge")
        self.raw[:] = 0.0
        self.used[:] = 0.0
        self.raw[:n_edges], self.used[:n_edges] = raw, used
        self.pending[:] = pending
        self.applied = applied
