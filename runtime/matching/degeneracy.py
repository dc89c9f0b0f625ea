"""Degenerate matches: the direction a scan match does not pin (a plain corridor's axis), the
prediction standing in along it, and an edge information weak along it (docs/method.md §6.1,
§5 step 3).

The curvature (Hessian) of the summed per-point cost at the match is reduced to translation
with the heading at its best (the Schur complement ``H_tt − H_tθ H_θθ⁻¹ H_θt``): walls pin
the heading even where they do not pin the position along them. If the weaker translation
eigenvalue is below ``ratio`` of the stronger, its direction is degenerate: the match's
correction of the prediction is dropped along it (the solution remapping of Zhang, Kaess &
Singh, ICRA 2016), and an edge built on the match keeps along it only the share of its
information the curvature supports (at least ``floor``).
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam.runtime.matching.scan_matcher import CURVATURE_STEP


class Degeneracy:
    """The decomposition of one match's curvature, and what follows from it."""

    def __init__(self, hessian, ratio: float, floor: float = 0.01):
        h = np.asarray(hessian, float)
        tt = h[:2, :2]
        if h[2, 2] > 0:
            tt = tt - np.outer(h[:2, 2], h[2, :2]) / h[2, 2]
        values, vectors = np.linalg.eigh(tt)
        self.ratio = float(values[0] / values[1]) if values[1] > 0 else 0.0
        self.axis = vectors[:, 0]  # the translation direction pinned least
        self.share = (min(max(self.ratio / ratio, floor), 1.0) if ratio > 0 else 1.0)
        self.degenerate = self.share < 1.0

    def remap(self, pose, prediction) -> np.ndarray:
        """``pose``, but at ``prediction``'s position along the degenerate axis."""
        if not self.degenerate:
            return pose
        out = np.array(pose, dtype=float)
        slide = float(self.axis @ (out[:2] - prediction[:2]))
        out[:2] -= slide * self.axis
        return out

    def information(self, base, share: float | None = None) -> np.ndarray:
        """``base`` with its information along the degenerate axis cut to ``share`` (default:
        the share the curvature supports)."""
        if not self.degenerate:
            return base
        share = self.share if share is None else share
        a = np.zeros(3)
        a[:2] = self.axis
        scale = np.eye(3) - (1.0 - math.sqrt(share)) * np.outer(a, a)
        return scale @ base @ scale


class DegeneracyCheck:
    """The match where the scan pins it, the prediction where it does not (the front end's
    ``reference``); :attr:`last` is the last match's :class:`Degeneracy`, for the next node's
    edge, which is weak along its axis."""

    def __init__(self, config, matcher, reference, counts):
        """``config``: the front end's section (``degeneracy_ratio``,
        ``degenerate_information``); ``counts``: tallies ``degenerate_matches``."""
        self.config, self.matcher, self.reference, self.counts = config, matcher, reference, counts
        self.last: Degeneracy | None = None

    def constrain(self, scan, pose, guess) -> np.ndarray:
        """``pose`` (a match of ``scan``), but at the prediction ``guess``'s position along the
        axis the scan does not pin."""
        c = self.config
        h = self.matcher.curvature(scan, self.reference, pose, CURVATURE_STEP)
        self.last = Degeneracy(h, c.degeneracy_ratio, c.degenerate_information)
        if self.last.degenerate:
            self.counts.degenerate_matches += 1
        return self.last.remap(pose, guess)
