"""The poses of the scans between two nodes, smoothed with odometry's motion (docs/method.md
§6.2, "Between-scan poses").

A scan between nodes k and k + 1 is matched on its own, and its pose in node k's frame errs
by the match's noise, scan by scan. Odometry's motion between two scans errs too, but its error
adds up from reading to reading. Which of the two is worth more differs from robot to robot,
so the run's own record tells. For two scans p, q with consecutive new readings, the
disagreement between the trajectory's motion from p to q and odometry's (in heading, and in
position in p's frame, per axis) varies as

    Var = (scans between nodes among p, q) · a + (node scans among them) · c + L · b

with a the variance of a between-scan match, c a node scan's, b odometry's over one reading
and L the readings from p to q (1 or 2). A weighted least-squares fit over the pairs' robust
variances gives a, b, c and their standard errors, for the heading and for the position apart.
Where ``a`` stands ``significance`` standard errors clear of 0 — the matches are measurably
noisier, scan by scan, than odometry makes them look — each interval's between scans are
re-estimated from their matches (variance a), the two nodes' (c; the far one as the node edge
places it, 2c), and odometry's motion between them (b each; one that disagrees by more than
``gate`` σ is not used). Otherwise nothing changes: odometry that drifts faster than the
matches err (most robots' heading) or a run too short to tell leaves every pose as matched.

Nodes keep their graph poses: this changes only what the trajectory says of the scans between
them, never the map.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> truth = np.cumsum(rng.normal(0.0, 0.01, 3000))         # the robot's true heading
    >>> node = np.arange(3000) // 3                            # every third scan a node's
    >>> is_node = np.arange(3000) % 3 == 0
    >>> frame = truth[node * 3]                                # each scan's node's heading
    >>> odometry = np.zeros((3000, 3))
    >>> odometry[:, 2] = truth + np.cumsum(rng.normal(0.0, 0.002, 3000))
    >>> rel = np.zeros((3000, 3))                              # matched: σ 0.004 rad between
    >>> rel[:, 2] = np.where(is_node, 0.0, truth - frame + rng.normal(0.0, 0.004, 3000))
    >>> step = np.full((1000, 3), np.nan)
    >>> step[:-1, 2] = truth[3::3] - truth[:-3:3]
    >>> kind = np.full(3000, NEW_READING)
    >>> trajectory = np.zeros((3000, 3))
    >>> trajectory[:, 2] = frame + rel[:, 2]
    >>> smoothed, noise = smooth_headings(node, rel, is_node, trajectory, odometry, kind, step,
    ...                                   BetweenSmoothing())
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

from swarmslam.runtime.pose import between, wrap_angle

# What a scan's odometry was, as the front end records it
NO_READING = 0  # none (scans alone, or a reading the inbox dropped): odometry's chain breaks
STALE_READING = 1  # the last reading again: it tells nothing of the motion since
NEW_READING = 2
FIRST_READING = 3  # odometry's first (or first again after a restart): no motion to it

# A robust variance from the median absolute deviation: (1.4826 MAD)² for a normal spread;
# its sampling variance is about 2.7 v² / n (against 2 v² / n for the plain estimate).
_MAD_SCALE = 1.4826
_MAD_VARIANCE = 2.7


@dataclass(frozen=True)
class BetweenSmoothing:
    """The smoothing's rules: ``min_pairs`` is ``front_end.between_scans.min_pairs``; the
    others are fixed here."""

    # standard errors by which a between-scan match's estimated noise must exceed 0 before
    # odometry's motion is taken in (its lower bound is what is used)
    significance: float = 2.0
    # σ: odometry's motion between two scans that disagrees with their matches by more is not
    # taken in (a slipping wheel, a stamp out of step in a turn)
    gate: float = 4.0
    min_pairs: int = 30  # pairs of scans each kind of pair needs before its noise is estimated


@dataclass(frozen=True)
class BetweenNoise:
    """Variances of a between-scan match (``between``), a node scan (``node``) and odometry's
    motion over one reading (``odometry``), each with its standard error: rad² for the
    heading, m² per axis for the position."""

    between: float
    node: float
    odometry: float
    between_se: float
    node_se: float
    odometry_se: float

    def trusted(self, significance: float) -> bool:
        """The between-scan matches are measurably noisy and odometry's motion is not
        noise-free: smoothing has something to take from each."""
        return self.between - significance * self.between_se > 0 and self.odometry > 0


def linked(kind: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the scans with a new reading, and for each whether odometry's motion joins
    it to the one before in that list (no scan without a reading between them, and not
    odometry starting afresh)."""
    new = np.flatnonzero((kind == NEW_READING) | (kind == FIRST_READING))
    breaks = np.cumsum(kind == NO_READING)
    joined = np.zeros(len(new), bool)
    joined[1:] = (breaks[new[1:]] == breaks[new[:-1]]) & (kind[new[1:]] != FIRST_READING)
    return new, joined


def estimate_noise(disagreement, is_node: np.ndarray, kind: np.ndarray,
                   min_pairs: int) -> BetweenNoise | None:
    """The three variances from ``disagreement(p, q)``: for scans p, q (index arrays), how far
    the trajectory's motion from p to q is from odometry's ((m,) or (m, axes); see the
    module's docstring). None when fewer than three kinds of pair have ``min_pairs`` pairs
    each, or the pairs cannot tell the three apart."""
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
            d = np.asarray(disagreement(p[pick], q[pick])).reshape(int(pick.sum()), -1)
            v = float(np.mean((_MAD_SCALE * np.median(np.abs(d - np.median(d, axis=0)),
                                                      axis=0)) ** 2))  # per axis, pooled
            if v <= 0:
                continue
            rows.append((2 - count, count, lag))
            values.append(v)
            weights.append(d.size / (_MAD_VARIANCE * v * v))
    if len(rows) < 3:
        return None
    x, y, w = np.array(rows, np.float64), np.array(values), np.array(weights)
    normal = (x.T * w) @ x
    if np.linalg.cond(normal) > 1e12:  # e.g. no pair with a node scan: c not told from a
        return None
    covariance = np.linalg.inv(normal)
    a, c, b = covariance @ ((x.T * w) @ y)
    se = np.sqrt(np.diag(covariance))
    return BetweenNoise(float(a), float(c), float(b), float(se[0]), float(se[1]), float(se[2]))


def smooth_headings(node, rel, is_node, trajectory, odometry, kind, step,
                    config: BetweenSmoothing) -> tuple[np.ndarray | None, BetweenNoise | None]:
    """Each scan's heading in its node's frame (``rel[:, 2]``) with those between nodes
    smoothed with odometry's turns, or None where the run shows it does not pay; and the
    noise estimated. The arguments are as :func:`smooth_positions` takes them."""
    d = np.asarray(wrap_angle(trajectory[:, 2] - odometry[:, 2]))
    # odometry's heading relative to node k's scan: what its turns put each point at
    relative = lambda scans, base: np.asarray(
        wrap_angle(odometry[scans, 2:] - odometry[base, 2:]))
    out, noise = _smoothed(lambda p, q: wrap_angle(d[q] - d[p]), relative, rel[:, 2:],
                           step[:, 2:], node, is_node, kind, step, config, angular=True)
    return (None if out is None else out[:, 0]), noise


def smooth_positions(node, rel, is_node, trajectory, odometry, kind, step,
                     config: BetweenSmoothing,
                     scale: float = 1.0) -> tuple[np.ndarray | None, BetweenNoise | None]:
    """Each scan's position in its node's frame (``rel[:, :2]``) with those between nodes
    smoothed with odometry's motion, or None where the run shows it does not pay; and the
    noise estimated.

    ``node``: each scan's tracking node; ``rel``: its tracked pose in that node's frame;
    ``is_node``: the scan is its node's own; ``trajectory``: its pose in the map; ``odometry``:
    odometry's pose at it (read where ``kind`` is a new or first reading); ``kind``: what its
    odometry reading was (``NO_READING`` ...); ``step``: per node k, the edge that made node
    k + 1 in k's frame (NaN where none); ``scale``: odometry's translations times this are the
    scans' (:mod:`swarmslam.runtime.front_end.odometry_scale`)."""
    def disagreement(p, q):
        return (between(trajectory[q], trajectory[p])[:, :2]
                - scale * between(odometry[q], odometry[p])[:, :2])

    # odometry's position in node k's scan's frame (its robot frame there, as node k's is)
    relative = lambda scans, base: scale * between(odometry[scans], odometry[base])[:, :2]
    return _smoothed(disagreement, relative, rel[:, :2], step[:, :2], node, is_node, kind, step,
                     config, angular=False)


def _smoothed(disagreement, relative, matched, edge, node, is_node, kind, step,
              config: BetweenSmoothing, angular: bool):
    """The noise fitted from ``disagreement`` and, where it is trusted and some scan between
    nodes can be re-estimated, ``matched`` smoothed (:meth:`_Chain.solve`); else None."""
    noise = estimate_noise(disagreement, is_node, kind, config.min_pairs)
    if noise is None or not noise.trusted(config.significance):
        return None, noise
    chain = _Chain(node, is_node, kind, step)
    if chain.count == 0:
        return None, noise
    return chain.solve(matched, edge, relative, noise, config, angular), noise


class _Chain:
    """The points each interval between nodes k and k + 1 is solved over, in node k's frame:
    node k's scan (at 0, variance c), the scans between with a new reading (their match, a)
    and node k + 1's scan (the edge's value, 2c: both nodes' errors); scans with no new
    reading keep their match."""

    def __init__(self, node, is_node, kind, step):
        n_nodes = int(node.max()) + 1
        first = np.full(n_nodes, -1)  # each node's own scan (-1: not recorded)
        first[node[is_node]] = np.flatnonzero(is_node)
        new, joined = linked(kind)
        joined_to_previous = np.zeros(len(node), bool)
        joined_to_previous[new] = joined
        has_reading = np.zeros(len(node), bool)
        has_reading[new] = True
        scans = np.flatnonzero(~is_node & has_reading)
        k = node[scans]  # (in recording order, so interval by interval)
        usable = (first[k] >= 0) & has_reading[first[k]]
        scans, k = scans[usable], k[usable]
        self.count = 0
        if len(scans) == 0:
            return
        starts = np.r_[True, k[1:] != k[:-1]]
        ends = np.r_[k[1:] != k[:-1], True]
        end_scan = first[np.minimum(k + 1, n_nodes - 1)]
        has_end = (ends & (k + 1 < n_nodes) & (end_scan >= 0) & ~np.isnan(step[k, 0])
                   & has_reading[np.maximum(end_scan, 0)])
        # per between scan a point; a start point before it when it opens an interval and an
        # end point after it when it closes one with a usable next node
        self.count = len(scans) + int(starts.sum()) + int(has_end.sum())
        self.slot = np.cumsum(starts) + np.arange(len(scans)) + np.r_[0, np.cumsum(has_end)[:-1]]
        self.head = self.slot[starts] - 1
        self.tail = self.slot[has_end] + 1
        self.scans, self.k, self.has_end = scans, k, has_end
        self.base = first[k]  # node k's own scan, per between scan
        self.end_scan = end_scan[has_end]
        # odometry's motion joins a point to the one before (an interval's scans are recorded
        # one after another, so the point before a scan is the scan with a new reading before
        # it: the one odometry's motion is from)
        self.link = np.zeros(self.count, bool)
        self.link[self.slot] = joined_to_previous[scans]
        self.link[self.tail] = joined_to_previous[self.end_scan]

    def solve(self, matched, edge, relative, noise: BetweenNoise, config: BetweenSmoothing,
              angular: bool) -> np.ndarray:
        """``matched`` ((scans, axes): each scan's matched value in its node's frame) with the
        between scans re-estimated; ``edge``: per node, the node edge's value; ``relative``:
        (scans, node scans) → odometry's value at the scans in the node scans' frame."""
        a = noise.between - config.significance * noise.between_se  # the lower bound: trust
        c = max(noise.node - config.significance * noise.node_se, 1e-12)  # odometry no further
        b = noise.odometry  # than the record shows
        out = matched.copy()
        axes = matched.shape[1]
        value = np.zeros((self.count, axes))
        variance = np.zeros(self.count)
        odometry = np.zeros((self.count, axes))
        variance[self.head] = c  # (node k's scan: value 0, odometry's 0)
        value[self.slot], variance[self.slot] = matched[self.scans], a
        odometry[self.slot] = relative(self.scans, self.base)
        value[self.tail], variance[self.tail] = edge[self.k[self.has_end]], 2 * c
        odometry[self.tail] = relative(self.end_scan, self.base[self.has_end])
        # odometry's motions that disagree with the matches by more than the gate are not used
        expected = odometry[1:] - odometry[:-1]
        residual = expected - (value[1:] - value[:-1])
        if angular:  # (odometry's values are already relative to node k's scan, within a turn)
            residual = np.asarray(wrap_angle(residual))
        sigma = np.sqrt(variance[1:] + variance[:-1] + b)
        use = self.link[1:] & (np.sqrt((residual**2).sum(axis=1)) <= config.gate * sigma)
        w = np.where(use, 1.0 / b, 0.0)
        # minimise Σ |x − value|² / variance + Σ w |x_q − x_p − expected|²: tridiagonal, per axis
        banded = np.zeros((3, self.count))
        banded[1] = 1.0 / variance
        banded[1, :-1] += w
        banded[1, 1:] += w
        banded[0, 1:] = -w
        banded[2, :-1] = -w
        rhs = value / variance[:, None]
        rhs[1:] += w[:, None] * expected
        rhs[:-1] -= w[:, None] * expected
        out[self.scans] = solve_banded((1, 1), banded, rhs)[self.slot]
        return out
