"""Odometry's distance scale, learnt from the log itself, where the match cannot see
(docs/method.md §6.1, "Odometry's distance scale").

Along a plain corridor the match is degenerate and odometry's prediction stands in
(swarmslam.runtime.degeneracy): the map there is as long as odometry says. A wheel 1% larger than the
robot believes makes every such stretch 1% short, and no loop can tell — a ring of corridors
scaled down is still closed. What tells is the node steps whose match pinned every direction:
over a straight one the matched translation against odometry's is the scale of this robot's
odometry. Their median over the last ``window`` such steps is the scale; while it stays within
``dead_zone`` of 1 — the matches' own spread of scale from place to place — plus
``confidence`` standard errors of the median, odometry is taken as it is.

The scale acts twice: on odometry's prediction of each scan, and on the node edges it already
shaped. Each degenerate edge keeps the along-axis part of odometry's step and the scale it was
made with; when the scale changes, every such edge is moved along its axis to the new one, so
a corridor driven before the scale was known and one driven after agree
(:func:`rescale_edges`; without it the two passes disagree along the corridor by the scale's
change, and loops between them land wrong).

Opt-in (``front_end.odometry_scale_window``): where few straight steps are pinned, the matches'
own ±0.5% rides on the estimate, and on one real log the matches, not the wheels, were off
(docs/method.md §6.1 has the figures).

    >>> import numpy as np
    >>> scale = OdometryScale(window=8, min_steps=3, min_step=0.2, max_turn=0.02,
    ...                       dead_zone=0.005, confidence=2.0, max_edges=4)
    >>> for matched in (0.505, 0.506, 0.504):  # odometry counted 0.5 m each time
    ...     scale.add_step(np.array([matched, 0.0, 0.0]), np.array([0.5, 0.0, 0.0]))
    >>> round(scale.scale, 3)
    1.01
    >>> z = np.zeros((4, 3))
    >>> scale.mark_edge(0, np.array([1.0, 0.0]), np.array([0.5, 0.0, 0.0]), applied=1.0)
    >>> scale.rescale(z, 1)  # the edge's 0.5 m along the axis become 0.505 m
    >>> float(round(z[0, 0], 4))
    0.005
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.odometry_noise import median_and_spread


@njit(cache=True)
def rescale_edges(z, along, made_with, marked, n_edges, scale):
    """Move every marked edge ``k < n_edges`` along its axis from the scale it was made with
    to ``scale``: ``z[k, :2] += (scale − made_with[k]) · along[k]`` (``along``: the axis part
    of odometry's step, unscaled)."""
    for k in range(n_edges):
        if marked[k]:
            d = scale - made_with[k]
            z[k, 0] += d * along[k, 0]
            z[k, 1] += d * along[k, 1]
            made_with[k] = scale


class OdometryScale:
    """The scale of odometry's translation (true over counted) from the last ``window``
    straight node steps (turning at most ``max_turn`` rad, at least ``min_step`` m long) whose
    match pinned every direction; 1 until ``min_steps`` were seen or while within
    ``dead_zone`` plus ``confidence`` standard errors of 1. ``max_edges``: the graph's edge
    capacity (one mark each, kept only when on: ``window`` > 0)."""

    def __init__(self, window: int, min_steps: int, min_step: float, max_turn: float,
                 dead_zone: float, confidence: float, max_edges: int):
        self.window, self.min_steps = window, min_steps
        self.min_step, self.max_turn, self.dead_zone = min_step, max_turn, dead_zone
        self.confidence = confidence
        self.ratios = np.zeros(max(window, 1))  # a ring
        self.count = 0  # ratios ever added
        self.scale = 1.0
        max_edges = max_edges if window > 0 else 0
        self.along = np.zeros((max_edges, 2))
        self.made_with = np.ones(max_edges)
        self.marked = np.zeros(max_edges, np.bool_)
        self.applied = 1.0  # the scale the marked edges were last moved to

    @property
    def enabled(self) -> bool:
        return self.window > 0

    def add_step(self, z_match, z_odometry) -> None:
        """One node step whose match pinned every direction (each the new node in the old
        one's frame): a straight one long enough adds its matched over counted translation."""
        if not self.enabled:
            return
        counted = math.hypot(z_odometry[0], z_odometry[1])
        if counted < self.min_step or abs(z_odometry[2]) > self.max_turn:
            return
        # the matched step projected on odometry's: a sideways error is not a scale
        ratio = (z_match[0] * z_odometry[0] + z_match[1] * z_odometry[1]) / (counted * counted)
        self.ratios[self.count % self.window] = ratio
        self.count += 1
        n = min(self.count, self.window)
        if n >= self.min_steps:
            median, spread = median_and_spread(self.ratios[:n])
            doubt = self.dead_zone + self.confidence * spread / math.sqrt(n)
            self.scale = median if abs(median - 1.0) > doubt else 1.0

    def mark_edge(self, edge: int, axis, z_odometry, applied: float) -> None:
        """Edge ``edge`` took odometry's step along ``axis`` (a degenerate match), scaled by
        ``applied``."""
        along = axis[0] * z_odometry[0] + axis[1] * z_odometry[1]
        self.along[edge, 0] = axis[0] * along
        self.along[edge, 1] = axis[1] * along
        self.made_with[edge] = applied
        self.marked[edge] = True

    def rescale(self, z, n_edges: int) -> None:
        """Move the marked edges of ``z[:n_edges]`` to the current scale, if it changed."""
        if self.scale != self.applied:
            rescale_edges(z, self.along, self.made_with, self.marked, n_edges, self.scale)
            self.applied = self.scale

    def scale_step(self, step) -> None:
        """Odometry's ``step`` (between two scans), its translation scaled in place."""
        if self.scale != 1.0:
            step[0] *= self.scale
            step[1] *= self.scale

    # ------------------------------------------------------------------ state
    def state(self, n_edges: int) -> dict:
        """What :meth:`restore` needs, the marks of the first ``n_edges`` edges."""
        return {"ratios": self.ratios.copy(), "count": self.count, "scale": self.scale,
                "along": self.along[:n_edges].copy(), "made_with": self.made_with[:n_edges].copy(),
                "marked": self.marked[:n_edges].copy(), "applied": self.applied}

    def restore(self, state: dict) -> None:
        ratios = np.asarray(state["ratios"], np.float64)
        m = len(state["marked"])
        if ratios.shape != self.ratios.shape or m > len(self.marked):
            raise ValueError("the odometry scale's ring or edge marks do not fit this "
                             "configuration (another front_end.odometry_scale_window or a "
                             "smaller capacity.max_edges?)")
        self.ratios[:] = ratios
        self.count = int(state["count"])
        self.scale = float(state["scale"])
        self.along[:m] = state["along"]
        self.made_with[:m] = state["made_with"]
        self.marked[:m] = state["marked"]
        self.applied = float(state["applied"])
