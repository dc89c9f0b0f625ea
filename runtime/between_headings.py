"""The headings of the scans between two nodes, smoothed with odometry's turns
(docs/method.md §6.2, "Between-scan headings").

A scan between nodes k and k + 1 is matched on its own, and its heading in node k's frame errs
by the match's noise, scan by scan. Odometry's turn between two scans errs too, but its error
adds up from reading to reading. Which of the two is worth more differs from robot to robot,
so the run's own record tells: the disagreement D = (trajectory heading − odometry heading) of
two scans with consecutive new readings varies as

    Var(D_q − D_p) = (scans between nodes among p, q) · a + (node scans among them) · c + L · b

with a the variance of a between-scan match's heading, c a node scan's, b odometry's turn over
one reading and L the readings from p to q (1 or 2). A weighted least-squares fit over the
pairs' robust variances gives a, b, c and their standard errors. Where ``a`` stands
``significance`` standard errors clear of 0 — the matches are measurably noisier, scan by scan,
than odometry makes them look — each interval's between-scan headings are re-estimated from
their matches (variance a), the two nodes' (c; the far one as the node edge places it, 2c),
and odometry's turns between them (b each; one that disagrees by more than ``gate`` σ is not
used). Otherwise nothing changes: odometry that drifts faster than the matches err (most
robots) or a run too short to tell leaves every heading as matched.

Nodes keep their graph poses: this changes only what the trajectory says of the scans between
them, never the map.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> truth = np.cumsum(rng.normal(0.0, 0.01, 3000))         # the robot's true heading
    >>> node = np.arange(3000) // 3                            # every third scan a node's
    >>> is_node = np.arange(3000) % 3 == 0
    >>> frame = truth[node * 3]                                # each scan's node's heading
    >>> odometry = truth + np.cumsum(rng.normal(0.0, 0.002, 3000))
    >>> rel = np.zeros((3000, 3))                              # matched: σ 0.004 rad between
    >>> rel[:, 2] = np.where(is_node, 0.0, truth - frame + rng.normal(0.0, 0.004, 3000))
    >>> step = np.full((1000, 3), np.nan)
    >>> step[:-1, 2] = truth[3::3] - truth[:-3:3]
    >>> kind = np.full(3000, NEW_READING)
    >>> smoothed, noise = smooth_between(node, rel, is_node, frame + rel[:, 2], odometry,
    ...                                  kind, step, BetweenSmoothing())
    >>> round(float(np.sqrt(noise.between)), 3), round(float(np.sqrt(noise.odometry)), 3)
    (0.004, 0.002)
    >>> error = lambda h: np.abs(h - (truth - frame))[~is_node].mean()
    >>> bool(error(smoothed) < 0.85 * error(rel[:, 2]))
    True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_banded

from swarmslam.runtime.pose import wrap_angle

# What a scan's odometry was, as the front end records it
NO_READING = 0  # none (scans alone, or a reading the inbox dropped): odometry's chain breaks
STALE_READING = 1  # the last reading again: it tells nothing of the turn since
NEW_READING = 2
FIRST_READING = 3  # odometry starts (again) here: no turn from the reading before

# A robust variance from the median absolute deviation: (1.4826 MAD)² for a normal spread;
# its sampling variance is about 2.7 v² / n (against 2 v² / n for the plain estimate).
_MAD_SCALE = 1.4826
_MAD_VARIANCE = 2.7


@dataclass(frozen=True)
class BetweenSmoothing:
    """What :func:`smooth_between` needs of the configuration (``FrontEndConfig``'s
    ``between_*`` fields)."""

    significance: float = 2.0
    gate: float = 4.0
    min_pairs: int = 30


@dataclass(frozen=True)
class HeadingNoise:
    """Variances (rad²) of a between-scan match's heading (``between``), a node scan's
    (``node``) and odometry's turn over one reading (``odometry``), each with its standard
    error."""

    between: float
    node: float
    odometry: float
    between_se: float
    node_se: float
    odometry_se: float

    def trusted(self, significance: float) -> bool:
        """The between-scan matches are measurably noisy and odometry's turns are not
        noise-free: smoothing has something to take from each."""
        return self.between - significance * self.between_se > 0 and self.odometry > 0


def linked(kind: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the scans with a new reading, and for each whether odometry's turn joins it
    to the one before in that list (no scan without a reading between them, and not odometry
    starting afresh)."""
    new = np.flatnonzero((kind == NEW_READING) | (kind == FIRST_READING))
    breaks = np.cumsum(kind == NO_READING)
    joined = np.zeros(len(new), bool)
    joined[1:] = (breaks[new[1:]] == breaks[new[:-1]]) & (kind[new[1:]] != FIRST_READING)
    return new, joined


def estimate_noise(disagreement: np.ndarray, is_node: np.ndarray, kind: np.ndarray,
                   min_pairs: int) -> HeadingNoise | None:
    """The three variances from the disagreement D (trajectory − odometry heading, rad) of
    every scan (see the module's docstring); None when fewer than three kinds of pair have
    ``min_pairs`` pairs each, or the pairs cannot tell the three apart."""
    new, joined = linked(kind)
    rows, values, weights = [], [], []
    for lag in (1, 2):
        if len(new) <= lag:
            continue
        ok = joined[lag:].copy()
        for back in range(1, lag):
            ok &= joined[lag - back: len(joined) - back]
        p, q = new[:-lag][ok], new[lag:][ok]
        nodes = is_node[p].astype(np.int64) + is_node[q].astype(np.int64)
        for count in (0, 1, 2):
            pick = nodes == count
            if pick.sum() < min_pairs:
                continue
            d = np.asarray(wrap_angle(disagreement[q[pick]] - disagreement[p[pick]]))
            v = (_MAD_SCALE * np.median(np.abs(d - np.median(d)))) ** 2
            if v <= 0:
                continue
            rows.append((2 - count, count, lag))
            values.append(v)
            weights.append(pick.sum() / (_MAD_VARIANCE * v * v))
    if len(rows) < 3:
        return None
    x, y, w = np.array(rows, np.float64), np.array(values), np.array(weights)
    normal = (x.T * w) @ x
    if np.linalg.cond(normal) > 1e12:  # e.g. no pair with a node scan: c not told from a
        return None
    covariance = np.linalg.inv(normal)
    a, c, b = covariance @ ((x.T * w) @ y)
    se = np.sqrt(np.diag(covariance))
    return HeadingNoise(float(a), float(c), float(b), float(se[0]), float(se[1]), float(se[2]))


def smooth_between(node, rel, is_node, headings, odometry, kind, step,
                   config: BetweenSmoothing) -> tuple[np.ndarray, HeadingNoise | None]:
    """Each scan's heading in its node's frame (``rel[:, 2]``), those between nodes smoothed
    with odometry's turns where the run shows it pays, and the noise estimated.

    ``node``: each scan's tracking node; ``rel``: its tracked pose in that node's frame;
    ``is_node``: the scan is its node's own; ``headings``: its heading in the trajectory
    (rad); ``odometry``: odometry's heading at it (rad, read where ``kind`` is a new or first
    reading); ``kind``: what its odometry reading was (``NO_READING`` ...); ``step``: per
    node k, the edge that made node k + 1 in k's frame (NaN where none)."""
    out = rel[:, 2].copy()
    noise = estimate_noise(np.asarray(wrap_angle(headings - odometry)), is_node, kind,
                           config.min_pairs)
    if noise is None or not noise.trusted(config.significance):
        return out, noise
    a = noise.between - config.significance * noise.between_se  # the lower bound: trust
    c = max(noise.node - config.significance * noise.node_se, 1e-12)  # odometry no further
    b = noise.odometry  # than the record shows
    n_nodes = int(node.max()) + 1
    first = np.full(n_nodes, -1)  # each node's own scan (-1: not recorded)
    first[node[is_node]] = np.flatnonzero(is_node)
    # The chain of points: per interval, node k's scan (its heading 0 in its own frame, σ² c),
    # the scans between with a new reading (their match, a), node k + 1's scan (the edge's
    # heading, 2c: both nodes' errors). Points with no reading keep their match.
    new, joined = linked(kind)
    joined_to_previous = np.zeros(len(node), bool)
    joined_to_previous[new] = joined
    has_reading = np.zeros(len(node), bool)
    has_reading[new] = True
    scans_between = np.flatnonzero(~is_node & has_reading)
    k = node[scans_between]  # (in recording order, so interval by interval)
    usable = (first[k] >= 0) & has_reading[first[k]]
    scans_between, k = scans_between[usable], k[usable]
    if len(scans_between) == 0:
        return out, noise
    starts = np.r_[True, k[1:] != k[:-1]]
    ends = np.r_[k[1:] != k[:-1], True]
    nxt = np.minimum(k + 1, n_nodes - 1)
    end_scan = first[nxt]
    has_end = (ends & (k + 1 < n_nodes) & (end_scan >= 0) & ~np.isnan(step[k, 2])
               & has_reading[np.maximum(end_scan, 0)])
    # point list: for each between scan, a start point before it when it opens an interval
    # and an end point after it when it closes one with a usable next node
    count = len(scans_between) + starts.sum() + has_end.sum()
    value = np.zeros(count)  # the measurement, in node k's frame
    variance = np.zeros(count)
    turn = np.zeros(count)  # odometry's heading relative to node k's scan
    link = np.zeros(count, bool)  # odometry's turn joins the point to the one before
    slot = np.cumsum(starts) + np.arange(len(scans_between)) + np.r_[0, np.cumsum(has_end)[:-1]]
    head = slot[starts] - 1
    value[head], variance[head], turn[head] = 0.0, c, 0.0
    base = odometry[first[k]]
    value[slot] = out[scans_between]
    variance[slot] = a
    turn[slot] = np.asarray(wrap_angle(odometry[scans_between] - base))
    # (an interval's scans are recorded one after another, so the point before a scan is the
    # scan with a new reading before it: the one odometry's turn is from)
    link[slot] = joined_to_previous[scans_between]
    tail = slot[has_end] + 1
    value[tail] = step[k[has_end], 2]
    variance[tail] = 2 * c
    turn[tail] = np.asarray(wrap_angle(odometry[end_scan[has_end]] - base[has_end]))
    link[tail] = joined_to_previous[end_scan[has_end]]
    # odometry's turns that disagree with the matches by more than the gate are not used
    expected = turn[1:] - turn[:-1]
    residual = np.asarray(wrap_angle(expected - (value[1:] - value[:-1])))
    sigma = np.sqrt(variance[1:] + variance[:-1] + b)
    use = link[1:] & (np.abs(residual) <= config.gate * sigma)
    w = np.where(use, 1.0 / b, 0.0)
    # minimise Σ (x − value)² / variance + Σ w (x_q − x_p − expected)²: tridiagonal
    banded = np.zeros((3, count))
    banded[1] = 1.0 / variance
    banded[1, :-1] += w
    banded[1, 1:] += w
    banded[0, 1:] = -w
    banded[2, :-1] = -w
    rhs = value / variance
    rhs[1:] += w * expected
    rhs[:-1] -= w * expected
    x = solve_banded((1, 1), banded, rhs)
    out[scans_between] = x[slot]
    return out, noise
