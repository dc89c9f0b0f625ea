"""Accuracy metrics (method.md §7).

* :func:`relative_errors` — per-pair errors ``δ_est ⊖ δ_ref`` of relative poses, the building
  block of Kümmerle et al.'s metric (Eqs. 22–23): translational norm (m), rotation (rad).
* :func:`pair_errors` — Eq. 24: mean absolute ``ex, ey, eθ`` over scan pairs.
* :func:`is_failure` — the matcher benchmark's failure rule.
"""

from __future__ import annotations

import numpy as np

from runtime.pose import between, wrap_angle


def relative_errors(estimated, reference):
    """Translational (m) and absolute rotational (rad) error of each estimated relative pose."""
    e = between(np.asarray(estimated, dtype=np.float64), np.asarray(reference, dtype=np.float64))
    return np.hypot(e[..., 0], e[..., 1]), np.abs(e[..., 2])


def pair_errors(estimated, reference) -> dict[str, float]:
    """Eq. 24: ``ex = 1/N Σ|x − x*|``, likewise ``ey`` and ``eθ`` (angle difference wrapped)."""
    est = np.asarray(estimated, dtype=np.float64).reshape(-1, 3)
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    d = est - ref
    d[:, 2] = wrap_angle(d[:, 2])
    return {
        "ex": float(np.mean(np.abs(d[:, 0]))),
        "ey": float(np.mean(np.abs(d[:, 1]))),
        "etheta": float(np.mean(np.abs(d[:, 2]))),
    }


def is_failure(e_trans, e_rot, max_trans: float = 0.3, max_rot: float = 0.1):
    """A match fails when it is off by more than 0.3 m or 0.1 rad."""
    return (np.asarray(e_trans) > max_trans) | (np.asarray(e_rot) > max_rot)
