"""Odometry's heading noise and bias, learnt from the log itself, and each node edge's heading
fused with odometry's by them (docs/method.md §6.1, "Odometry's heading, weighed by what it has
shown"; opt-in: ``front_end.odometry_noise_window``).

Wheel odometry differs from robot to robot by more than an order of magnitude: over one node
step the match and odometry disagree in heading by a robust σ of 0.17° on fr-clinic, 0.61° on
ACES3 and 1.0° on Intel (straight steps; on Intel about a bias of −1.8° a step as well). A fixed
weight would either waste a good odometry or let a bad one bend the map. So each node step
whose match held (not replaced by odometry) leaves its heading residual ``θ_odometry −
θ_match`` in a fixed-capacity ring, one for straight steps and one for each way of turning:
odometry errs most, and one-sidedly, in turns. A ring's median is odometry's bias (one wheel
larger than assumed), taken out of its heading; its spread (1.4826 × the median absolute
deviation) is the two's disagreement, ``σ_d² = σ_match² + σ_odometry²``.

Residuals of two sources cannot tell whose noise is whose, so the match's share is a prior,
``match_sigma`` (straight, turning: in a turn the overlap with the submap shrinks and the
match errs more), and ``σ_odometry² = max(σ_d² − σ_match², floor²)``.

The edge's heading is then the information-weighted mean of the match's and odometry's
(Eq. 21's least squares over two measurements of one step, in closed form): odometry weighs
``σ_match² / (σ_match² + σ_odometry²)``, the edge's heading information grows by the same
factor, and its position stays the match's. The graph, the scans placed between nodes and the
loop search's propagated covariance all see the one edge.

    >>> import numpy as np
    >>> noise = OdometryNoise(window=8, min_steps=3, turn_split=0.25, floor=1e-3,
    ...                       match_sigma=(0.002, 0.008))
    >>> for r in (0.003, -0.004, 0.002):
    ...     noise.add(np.array([0.5, 0.0, 0.0]), np.array([0.5, 0.0, r]))
    >>> [round(v, 4) for v in noise.bias_and_spread(0.0)]
    [0.002, 0.0015]
    >>> round(noise.sigma(0.0), 4)  # odometry's share, at least the floor
    0.001
    >>> noise.sigma(0.5) is None  # no left turn seen yet
    True
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam.runtime.pose import between, compose

MAD_TO_SIGMA = 1.4826  # σ of a normal distribution over its median absolute deviation


def median_and_spread(values) -> tuple[float, float]:
    """The median of ``values`` and their robust σ about it (1.4826 × the median absolute
    deviation): a few wild samples move neither."""
    median = float(np.median(values))
    return median, MAD_TO_SIGMA * float(np.median(np.abs(values - median)))


class OdometryNoise:
    """Odometry's heading bias and σ over a node step, from the last ``window`` steps of each
    kind (straight, or turning more than ``turn_split`` rad left or right); σ at least
    ``floor`` rad; the match's own σ over a step ``match_sigma`` (straight, turning)."""

    def __init__(self, window: int, min_steps: int, turn_split: float, floor: float,
                 match_sigma: tuple[float, float]):
        self.window, self.min_steps = window, min_steps
        self.turn_split, self.floor, self.match_sigma = turn_split, floor, match_sigma
        self.residuals = np.zeros((3, max(window, 1)))  # rings: straight, left, right
        self.counts = np.zeros(3, np.int64)  # residuals ever added, per ring

    def _ring(self, turn: float) -> int:
        if abs(turn) <= self.turn_split:
            return 0
        return 1 if turn > 0 else 2

    def add(self, z_match, z_odometry) -> None:
        """One node step's match and odometry (each the new node in the old one's frame)."""
        if self.window <= 0:
            return
        k = self._ring(z_odometry[2])
        self.residuals[k, self.counts[k] % self.window] = math.remainder(
            z_odometry[2] - z_match[2], 2 * math.pi)
        self.counts[k] += 1

    def bias_and_spread(self, turn: float) -> tuple[float, float] | None:
        """The median (rad) of the heading residuals of steps turning like ``turn``, and
        their robust σ about it (1.4826 × the median absolute deviation); None until
        ``min_steps`` such steps were seen."""
        k = self._ring(turn)
        n = min(int(self.counts[k]), self.window)
        if self.window <= 0 or n < self.min_steps:
            return None
        return median_and_spread(self.residuals[k, :n])

    def match_share(self, turn: float) -> float:
        """The match's own heading σ (rad) over a step turning ``turn`` (the prior)."""
        return self.match_sigma[self._ring(turn) > 0]

    def sigma(self, turn: float) -> float | None:
        """Odometry's heading σ (rad) over a step turning ``turn`` rad, its bias taken out:
        the spread less the match's own share, at least ``floor``; None while unknown."""
        known = self._bias_and_sigma(turn)
        return None if known is None else known[1]

    def _bias_and_sigma(self, turn: float) -> tuple[float, float] | None:
        known = self.bias_and_spread(turn)
        if known is None:
            return None
        m = self.match_share(turn)
        return known[0], math.sqrt(max(known[1] ** 2 - m * m, self.floor**2))

    def fuse(self, z_match, info, z_odometry):
        """The step's edge ``(z, information)``: the match's heading and odometry's weighed
        by their information (the match's from ``info``); ``(z_match, info)`` while odometry's
        σ is not known yet."""
        turn = z_odometry[2]
        known = self._bias_and_sigma(turn)
        if known is None:
            return np.asarray(z_match, np.float64), info
        bias, sigma = known
        # in the graph's units: the match's heading information stands for its own σ
        odometry_info = np.zeros((3, 3))
        odometry_info[2, 2] = info[2, 2] * (self.match_share(turn) / sigma) ** 2
        delta = between(np.asarray(z_odometry, np.float64), np.asarray(z_match, np.float64))
        delta[:2] = 0.0  # heading only: the positions stay the match's
        delta[2] = math.remainder(delta[2] - bias, 2 * math.pi)  # odometry's bias taken out
        fused = info + odometry_info
        step = np.linalg.solve(fused, odometry_info @ delta)
        return compose(np.asarray(z_match, np.float64), step), fused

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {"residuals": self.residuals.copy(), "counts": self.counts.copy()}

    def restore(self, state: dict) -> None:
        residuals = np.asarray(state["residuals"], np.float64)
        if residuals.shape != self.residuals.shape:
            raise ValueError("the odometry noise ring is not this configuration's "
                             "(another front_end.odometry_noise_window?)")
        self.residuals[:] = residuals
        self.counts[:] = state["counts"]
