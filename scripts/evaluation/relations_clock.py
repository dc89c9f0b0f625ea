"""On whose clock are a relations file's headings: the scans' or odometry's? (docs/method.md
§7.1, part of ``swarmslam relations audit``)

A scanner's reading and the odometry stamped with it are seldom taken at the same instant:
serial and USB latency put tens of milliseconds between them. A reference made by matching the
scans places each scan where its geometry says, a reference made from odometry-corrected poses
places it where odometry was at the stamp; while the robot turns at ω, the two differ in heading
by ω × the latency. A trajectory on the other clock then errs, on a relation from ``t1`` to
``t2``, by ``latency × (ω(t2) − ω(t1))`` — an error that is the reference's convention, not the
trajectory's.

Fitting each source's heading error against that change of odometry's turn rate tells the
clock: a source on the reference's clock has a slope near 0, one on the other clock a slope
of the latency. Where the trajectory has the slope, moving its poses by odometry's motion over
that time puts it on the reference's clock, and scoring it again shows how much of its heading
error was the clock.

    >>> import numpy as np
    >>> from swarmslam.formats.relations import Relations
    >>> t = np.arange(0.0, 20.0, 0.1)
    >>> omega = 0.5 * np.sin(t)                                   # turning one way, then back
    >>> heading = np.cumsum(omega) * 0.1
    >>> odometry = np.c_[np.zeros((len(t), 2)), heading]
    >>> late = heading + 0.03 * omega                             # scans 30 ms after the stamp
    >>> steps = np.c_[np.zeros((len(t) - 5, 2)), heading[5:] - heading[:-5]]
    >>> relations = Relations(t[:-5], t[5:], steps)                # the truth, on odometry's clock
    >>> rates = turn_rates(t, odometry)[:, 2]
    >>> round(heading_slope(t, rates, relations, late)[0] * 1000)      # ms
    30
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.pose import between, compose, wrap_angle
from swarmslam.evaluation.metrics import LOCAL_GAP, kummerle, match_relations, nearest_stamps

MAX_ERROR_DEG = 3.0  # a relation's heading error beyond this is a failure, not a clock: left out
AGREEMENT_DEG = 0.1  # a relation's heading within this of odometry's agrees with odometry


def turn_rates(stamps, odometry) -> np.ndarray:
    """Odometry's motion per second at each stamp (x, y, yaw in the robot's frame), over the
    readings either side."""
    n = len(stamps)
    after, before = np.minimum(np.arange(n) + 1, n - 1), np.maximum(np.arange(n) - 1, 0)
    dt = np.maximum(stamps[after] - stamps[before], 1e-3)
    return between(odometry[after], odometry[before]) / dt[:, None]


def heading_slope(stamps, rates, relations, headings) -> tuple[float, float, np.ndarray]:
    """``headings`` (one per stamp) against the local relations: the least-squares slope (s)
    of their heading error on the change of odometry's turn rate (``rates``, rad/s at each
    stamp: :func:`turn_rates`) between each relation's ends, the correlation, and each local
    relation's heading error (rad, NaN where not found)."""
    i, j, found = match_relations(stamps, relations)
    found &= np.abs(relations.t2 - relations.t1) < LOCAL_GAP
    error = np.full(len(relations), np.nan)
    error[found] = wrap_angle(headings[j[found]] - headings[i[found]]
                              - relations.delta[found, 2])
    change = rates[j] - rates[i]
    used = found & (np.abs(error) < np.radians(MAX_ERROR_DEG))
    if used.sum() < 3 or np.ptp(change[used]) == 0:
        return 0.0, 0.0, error
    x, y = change[used], error[used]
    slope = float(np.dot(x - x.mean(), y - y.mean()) / np.dot(x - x.mean(), x - x.mean()))
    correlation = float(np.corrcoef(x, y)[0, 1]) if np.ptp(y) > 0 else 0.0  # no error: none
    return slope, correlation, error


def _agreement(error) -> float:
    """The share of the local relations (``error`` not NaN) within ``AGREEMENT_DEG``."""
    local = ~np.isnan(error)
    if not np.any(local):
        return 0.0
    return float(np.mean(np.abs(error[local]) < np.radians(AGREEMENT_DEG)))


def reference_clock(stamps, odometry, relations, trajectory=None) -> dict:
    """Odometry's (and, with ``trajectory`` — ``(stamps, poses)`` — the trajectory's) heading
    slope against the relations (see the module's docstring), the share of local relations
    whose heading agrees with odometry's within ``AGREEMENT_DEG``, and the trajectory scored
    again on the reference's clock."""
    stamps = np.asarray(stamps, np.float64)
    odometry = np.asarray(odometry, np.float64)
    slope, corr, error = heading_slope(stamps, turn_rates(stamps, odometry)[:, 2], relations,
                                       odometry[:, 2])
    out = {"odometry_slope_ms": 1e3 * slope, "odometry_correlation": corr,
           "odometry_agreement": _agreement(error)}
    if trajectory is None:
        return out
    t_stamps, poses = trajectory
    at, on_log = nearest_stamps(stamps, t_stamps)
    if not np.all(on_log):
        raise ValueError(f"{int((~on_log).sum())} of the trajectory's stamps are not the log's "
                         "scans' (a trajectory of another log?)")
    rates = turn_rates(t_stamps, odometry[at])  # once: the fit's and the move's
    slope, corr, error = heading_slope(t_stamps, rates[:, 2], relations, poses[:, 2])
    out.update({"trajectory_slope_ms": 1e3 * slope, "trajectory_correlation": corr,
                "trajectory_agreement": _agreement(error),
                "on_reference_clock": kummerle(t_stamps, compose(poses, -slope * rates),
                                               relations)})
    return out
