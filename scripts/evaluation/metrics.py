"""Accuracy metrics (docs/method.md §7).

* :func:`relative_errors` — per-pair errors ``δ_est ⊖ δ_ref`` of relative poses, the building
  block of Kümmerle et al.'s metric (Eqs. 22–23): translational norm (m), rotation (rad).
* :func:`pair_errors` — Eq. 24: mean absolute ``ex, ey, eθ`` over scan pairs.
* :func:`is_failure` — the matcher benchmark's failure rule.
* :func:`kummerle` — Eqs. 22–23 over a relations file, as Cartographer's
  ``compute_relations_metrics``: mean ± std of ``|trans(δ_ij ⊖ δ*_ij)|`` (m) and
  ``|rot(δ_ij ⊖ δ*_ij)|`` (deg), with ``δ_ij = x_j ⊖ x_i`` from the estimated trajectory.
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.pose import between, wrap_angle


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


LOCAL_GAP = 300.0  # s: relations with endpoints closer in time are "local" (datasets README)
# s: relations with endpoints closer in time are "short": the front end's own accuracy, before
# the back end's closures join far ends; their tail (p99, max, count above OUTLIER_DEG) shows
# gross heading failures the mean hides.
SHORT_GAP = 10.0
OUTLIER_DEG = 5.0


def nearest_stamps(stamps, times, tolerance: float = 1e-4):
    """For each of ``times``, the index into ``stamps`` (in any order) of the nearest stamp,
    and whether it lies within ``tolerance`` s: ``(index, ok)``."""
    stamps = np.asarray(stamps, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if len(stamps) == 0:
        return np.zeros(len(times), np.int64), np.zeros(len(times), bool)
    order = np.argsort(stamps)
    sorted_stamps = stamps[order]
    k = np.clip(np.searchsorted(sorted_stamps, times), 1, max(len(sorted_stamps) - 1, 1))
    k = np.minimum(k, len(sorted_stamps) - 1)
    k = np.where(np.abs(sorted_stamps[k - 1] - times) < np.abs(sorted_stamps[k] - times),
                 k - 1, k)
    return order[k], np.abs(sorted_stamps[k] - times) <= tolerance


def match_relations(stamps, relations, tolerance: float = 1e-4):
    """For each relation, the indices into ``stamps`` of its two ends and whether both are
    there (within ``tolerance`` s): ``(i, j, ok)``."""
    n = len(relations.t1)
    k, ok = nearest_stamps(stamps, np.r_[relations.t1, relations.t2], tolerance)
    return k[:n], k[n:], ok[:n] & ok[n:]


def relation_errors(stamps, poses, relations, tolerance: float = 1e-4):
    """Each relation's errors (Eqs. 22–23 before averaging) for the relations whose two
    timestamps are both in the trajectory: ``(mask of the relations used, e_t m, e_r deg)``."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    i, j, ok = match_relations(stamps, relations, tolerance)
    if not np.any(ok):
        raise ValueError("no relation matches the trajectory's timestamps")
    estimated = between(poses[j[ok]], poses[i[ok]])  # δ_ij = x_j ⊖ x_i
    e_t, e_r = relative_errors(estimated, relations.delta[ok])
    return ok, e_t, np.degrees(e_r)


def kummerle(stamps, poses, relations, tolerance: float = 1e-4,
             local_gap: float = LOCAL_GAP, short_gap: float = SHORT_GAP) -> dict:
    """Eqs. 22–23 for the relations whose two timestamps are both in the trajectory, over all
    of them and apart for local (endpoints < ``local_gap`` s apart) and global ones
    (``eT_local``, ``eR_local_deg``, ``relations_local``, likewise ``_global``; NaN-free: a
    part with no relation is left out); and the short ones' (< ``short_gap`` s apart) mean and
    tail: ``eT_short``, ``eR_short_deg``, ``eR_short_median_deg``, ``eR_short_p99_deg``,
    ``eR_short_max_deg``, ``eR_short_over_5deg`` (a count), ``relations_short``.

    ``stamps`` and ``poses`` are the estimated trajectory (one pose per scan); a relation's
    timestamp matches a scan within ``tolerance`` seconds.
    """
    ok, e_t, e_r = relation_errors(stamps, poses, relations, tolerance)
    out = {
        "eT": float(np.mean(e_t)),
        "eT_std": float(np.std(e_t)),
        "eR_deg": float(np.mean(e_r)),
        "eR_std": float(np.std(e_r)),
        "relations_used": int(ok.sum()),
        "relations_total": int(len(relations)),
    }
    local = np.abs(relations.t2[ok] - relations.t1[ok]) < local_gap
    for name, part in (("local", local), ("global", ~local)):
        if np.any(part):
            out.update({f"eT_{name}": float(np.mean(e_t[part])),
                        f"eT_{name}_std": float(np.std(e_t[part])),
                        f"eR_{name}_deg": float(np.mean(e_r[part])),
                        f"eR_{name}_std": float(np.std(e_r[part])),
                        f"relations_{name}": int(part.sum())})
    short = np.abs(relations.t2[ok] - relations.t1[ok]) < short_gap
    if np.any(short):
        e = e_r[short]
        out.update({"eT_short": float(np.mean(e_t[short])), "eR_short_deg": float(np.mean(e)),
                    "eR_short_median_deg": float(np.median(e)),
                    "eR_short_p99_deg": float(np.percentile(e, 99)),
                    "eR_short_max_deg": float(np.max(e)),
                    f"eR_short_over_{OUTLIER_DEG:g}deg": int(np.sum(e > OUTLIER_DEG)),
                    "relations_short": int(short.sum())})
    return out
