"""Seek_Loop_Closure (Alg. 7; docs/method.md §5): candidates, outlier elimination, alignment, and
the consistency test that replaces the literal "error did not grow" rule.

1. Candidates: nodes near the new node's position, the most recent ones excluded (they are
   neighbours, not loops). A linear scan in compiled code over the node array stands in for
   the k-d tree: at the capacities used (≤ 10⁴ nodes) it costs microseconds, needs no
   rebuilding as nodes move under optimisation, and allocates nothing.
2. Outliers: keep candidates inside the 95% ellipse (χ²₂ = 5.991) of the relative position
   covariance, propagated along the chain of odometry edges.
3. For the closest remaining candidates: align the new node's scan with a local submap around
   the candidate (its scan and its neighbours', placed by the graph; Alg. 5, the search box
   centred on the graph's current estimate, its half-widths from :meth:`LoopCloser.window`),
   refuse a match at the box's edge, and accept it only if enough of its points lie on the
   submap's surfaces (the inlier fraction) or :func:`visibility` says the submap's scans saw
   enough of them on surfaces and few in their free space (λ itself is no test here, since
   scans metres apart always score worse than the keyframe pairs the rejection threshold was
   learnt on). Add the edge, re-optimise, and keep it only if its own
   error ``eᵀΩe`` stays under the χ²₃ gate (7.81) and the total error rose by no more than a
   consistent 3-dof constraint raises it (χ²₃ at 99.9%: 16.3); otherwise remove the edge and
   restore the poses. (Accepted loops raise χ² by a few hundredths at the median and a few
   units at the 99th percentile; a wrong closure that bends the map, by more than the gate.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from swarmslam.runtime.config import LoopClosureConfig
from swarmslam.runtime.node_scans import polar_image
from swarmslam.runtime.pose import between, compose, wrap_angle

POSITION_FLOOR = 0.1  # m: the least std of the relative position in the candidates' gate
# m, rad: how near two agreeing loops must place the node (agreement)
AGREEMENT_DISTANCE = 0.1
AGREEMENT_ANGLE = 0.02

CHI2_2D_95 = 5.991
# Loops refused for their own error judged together at most: the newest and those before it
# that it agrees with. Consecutive matches that agree are the evidence one match cannot give;
# two were too few to outweigh a long drift's chain, and each more adds an edge to one trial.
GROUP = 5


@njit(cache=True)
def nearby_nodes(poses, n_nodes, x, y, radius, exclude_from, out_idx, out_d2):
    """Indices of nodes ``< exclude_from`` within ``radius`` of ``(x, y)``, closest first."""
    count = 0
    r2 = radius * radius
    for k in range(min(n_nodes, exclude_from)):
        dx = poses[k, 0] - x
        dy = poses[k, 1] - y
        d2 = dx * dx + dy * dy
        if d2 > r2:
            continue
        # insertion into the sorted, capacity-bounded output
        pos = count if count < out_idx.shape[0] else out_idx.shape[0]
        while pos > 0 and out_d2[pos - 1] > d2:
            if pos < out_idx.shape[0]:
                out_idx[pos] = out_idx[pos - 1]
                out_d2[pos] = out_d2[pos - 1]
            pos -= 1
        if pos < out_idx.shape[0]:
            out_idx[pos] = k
            out_d2[pos] = d2
            if count < out_idx.shape[0]:
                count += 1
    return count


@njit(cache=True)
def visibility(points, counts, poses, members, n_members, frame, scan, n, x, y, t, tolerance,
               slope, image, state, out):
    """How the scans of nodes ``members[:n_members]`` saw the places where ``scan`` (at
    ``(x, y, t)`` in node ``frame``'s frame) puts its points: ``out[0]`` points on a surface
    one of them saw (within ``tolerance + slope·r``), ``out[1]`` points in space one of them
    saw through and none saw a surface at — evidence against the alignment. Points no scan
    saw (behind what they saw, or outside their view) count in neither (docs/method.md §5)."""
    for k in range(n):
        state[k] = 0
    cf, sf = math.cos(poses[frame, 2]), math.sin(poses[frame, 2])
    ct, st = math.cos(t), math.sin(t)
    bins = image.shape[0]
    for e in range(n_members):
        m = members[e]
        polar_image(points[m], counts[m], image)
        # node m's pose in the frame's frame, then the map from the frame into node m's
        dx, dy = poses[m, 0] - poses[frame, 0], poses[m, 1] - poses[frame, 1]
        mx, my = cf * dx + sf * dy, -sf * dx + cf * dy
        mt = poses[m, 2] - poses[frame, 2]
        cm, sm = math.cos(mt), math.sin(mt)
        for k in range(n):
            if state[k] == 1:
                continue
            qx = x + ct * scan[k, 0] - st * scan[k, 1] - mx
            qy = y + st * scan[k, 0] + ct * scan[k, 1] - my
            px, py = cm * qx + sm * qy, -sm * qx + cm * qy
            r = math.hypot(px, py)
            b = int((math.atan2(py, px) + math.pi) * bins / (2 * math.pi)) % bins
            seen = min(image[b], min(image[(b - 1) % bins], image[(b + 1) % bins]))
            if not seen < np.inf:
                continue
            margin = tolerance + slope * r
            if abs(r - seen) <= margin:
                state[k] = 1
            elif r < seen - margin:
                state[k] = 2
    out[0] = 0
    out[1] = 0
    for k in range(n):
        if state[k] == 1:
            out[0] += 1
        elif state[k] == 2:
            out[1] += 1


@dataclass
class LoopCounts:
    """The loop search's tallies, saved with a session and reported whole."""

    attempts: int = 0  # candidates aligned
    accepted: int = 0  # loop edges kept
    rejected_match: int = 0  # alignments refused (at the box's edge, or too few inliers)
    rejected_consistency: int = 0  # aligned loops the consistency test refused
    agreed: int = 0  # loops kept past the rise test by agreeing with one refused by it
    given_up: int = 0  # kept loops given up for two later ones that agree
    reanchored: int = 0  # loop edges tried from a steadier node than their candidate


class LoopCloser:
    """Buffers for candidate search (allocated once) and the closure statistics."""

    def __init__(self, config: LoopClosureConfig):
        self.config = config
        self._idx = np.zeros(config.max_candidates * 4, np.int64)
        self._d2 = np.zeros(config.max_candidates * 4)
        self.counts = LoopCounts()

    def candidates(self, graph, node_cov, node: int) -> list[int]:
        """Steps 1–2: nearby nodes inside the 95% ellipse of the relative position."""
        c = self.config
        p = graph.poses[node]
        n = nearby_nodes(graph.poses, graph.n_nodes, p[0], p[1], c.search_radius,
                         node - c.exclude_recent, self._idx, self._d2)
        gated = []
        floor = POSITION_FLOOR**2
        for k in self._idx[:n]:
            # Relative covariance along the chain from k to node (both from node 0).
            rel = node_cov[node, :2, :2] - node_cov[k, :2, :2]
            rel = 0.5 * (rel + rel.T) + floor * np.eye(2)
            d = graph.poses[node, :2] - graph.poses[k, :2]
            try:
                m2 = float(d @ np.linalg.solve(rel, d))
            except np.linalg.LinAlgError:
                continue
            if m2 <= CHI2_2D_95:
                gated.append(int(k))
            if len(gated) >= c.max_candidates:
                break
        return gated

    def window(self, graph, node_cov, candidate: int, node: int, out) -> np.ndarray:
        """The loop match's half-widths: 3σ of ``node``'s pose relative to ``candidate``'s (in
        the candidate's frame, propagated along the chain), between ``search_window`` and
        ``max_search_window``: a loop found after a long, weakly pinned stretch is searched as
        widely as the drift may be."""
        c = self.config
        rel = node_cov[node] - node_cov[candidate]
        rel = 0.5 * (rel + rel.T)
        co, si = math.cos(graph.poses[candidate, 2]), math.sin(graph.poses[candidate, 2])
        # variances of x and y in the candidate's frame (Rᵀ Σ R), and of the heading
        vx = co * co * rel[0, 0] + 2 * co * si * rel[0, 1] + si * si * rel[1, 1]
        vy = si * si * rel[0, 0] - 2 * co * si * rel[0, 1] + co * co * rel[1, 1]
        for d, v in enumerate((vx, vy, rel[2, 2])):
            out[d] = min(max(3.0 * math.sqrt(max(v, 0.0)), c.search_window[d]),
                         max(c.max_search_window[d], c.search_window[d]))
        return out

    def submap_span(self, candidate: int, node: int) -> tuple[int, int]:
        """The first and last node of the ordinary submap around ``candidate`` for a loop
        from ``node``: ``submap_nodes`` either side, none of ``node``'s neighbours."""
        c = self.config
        last = min(candidate + c.submap_nodes, node - c.exclude_recent)
        return max(candidate - c.submap_nodes, 0), max(last, candidate)

    def steadiest(self, graph, candidate: int, node: int) -> int:
        """The node a loop edge from ``node`` against ``candidate``'s submap is given to (step
        3): ``candidate`` itself unless its node turned faster than ``steady_turn_rate``,
        then the submap's nearest node turning no faster (``candidate`` if none is)."""
        rate = self.config.steady_turn_rate
        if rate <= 0 or turn_rate(graph, candidate, node) <= rate:
            return candidate
        first, last = self.submap_span(candidate, node)
        best, best_gap, best_rate = candidate, math.inf, math.inf
        for k in range(first, last + 1):
            r, gap = turn_rate(graph, k, node), abs(k - candidate)
            if r <= rate and (gap < best_gap or (gap == best_gap and r < best_rate)):
                best, best_gap, best_rate = k, gap, r
        return best

    def verdicts(self, graph, edge: int, total_before: float) -> tuple[bool, bool]:
        """Step 4's two tests, after optimising with the new edge: its own error is within
        ``chi2_gate`` (the graph absorbed it), and the total rose by at most ``total_gate``."""
        c = self.config
        chi2 = graph.edge_chi2()
        return (float(chi2[edge]) <= c.chi2_gate,
                float(np.sum(chi2)) - total_before <= c.total_gate)


class VerdictMemory:
    """What step 4 remembers of the loops it refused (docs/method.md §5, step 4): the last loop
    refused for the rise of the total alone (its own error passed), and the last ``GROUP − 1``
    refused for their own error (the graph could not absorb them), newest first, each with its
    information. Each is its candidate, its node and its measurement, the candidate −1 when
    there is none. A later loop that agrees with the first is judged by its own error; one
    that agrees with some of the others is tried with them as a group, which may take the
    place of the kept loops the group strains most."""

    def __init__(self, config: LoopClosureConfig):
        self.config = config
        self.rise_refused = np.array([-1.0, -1.0, 0.0, 0.0, 0.0])
        self.strained, self.strained_info = self.none_strained()
        self._agreeing = np.zeros(GROUP - 1, np.int64)

    @staticmethod
    def none_strained() -> tuple[np.ndarray, np.ndarray]:
        """:attr:`strained` and :attr:`strained_info` remembering no loop."""
        strained = np.zeros((GROUP - 1, 5))
        strained[:, :2] = -1.0
        return strained, np.zeros((GROUP - 1, 3, 3))

    def agrees(self, refused, graph, candidate: int, node: int, z) -> bool:
        """Whether the loop ``candidate`` → ``node`` (measurement ``z``) agrees with one
        refused before (``refused``: :attr:`rise_refused` or a row of :attr:`strained`): made
        from a node at most ``agreement.nodes`` before ``node``, and placing ``node`` within
        ``AGREEMENT_DISTANCE`` and ``AGREEMENT_ANGLE`` of where this one does, through the
        graph's short chains between the two nodes and between the two candidates. Two scans
        matched apart that put the robot in the same place of the old map are evidence that
        the drift the rise measures is real, or that a kept loop the two contradict is not."""
        c = self.config.agreement
        old, was = int(refused[0]), int(refused[1])
        if old < 0 or not c.enabled or not 0 < node - was <= c.nodes:
            return False
        p = graph.poses
        there = compose(compose(p[old], refused[2:]), between(p[node], p[was]))
        here = compose(p[candidate], z)
        return bool(math.hypot(here[0] - there[0], here[1] - there[1]) <= AGREEMENT_DISTANCE
                    and abs(wrap_angle(here[2] - there[2])) <= AGREEMENT_ANGLE)

    def agreeing(self, graph, candidate: int, node: int, z) -> np.ndarray:
        """The rows of :attr:`strained` the loop ``candidate`` → ``node`` agrees with
        (:meth:`agrees`), newest first: the group it is tried with."""
        count = 0
        for row in range(GROUP - 1):
            if self.agrees(self.strained[row], graph, candidate, node, z):
                self._agreeing[count] = row
                count += 1
        return self._agreeing[:count]

    def strain(self, candidate: int, node: int, z, info) -> None:
        """Remember a loop refused for its own error, the oldest remembered forgotten."""
        for row in range(GROUP - 2, 0, -1):  # row by row: a shifted slice would copy
            self.strained[row] = self.strained[row - 1]
            self.strained_info[row] = self.strained_info[row - 1]
        self.remember(self.strained[0], candidate, node, z)
        self.strained_info[0] = info

    def forget_strained(self) -> None:
        self.strained[:, :2] = -1.0

    @staticmethod
    def remember(refused, candidate: int, node: int, z) -> None:
        refused[:2] = candidate, node
        refused[2:] = z

    def state(self) -> dict:
        return {"rise_refused": self.rise_refused.copy(), "strained": self.strained.copy(),
                "strained_info": self.strained_info.copy()}

    def restore(self, state: dict, n_nodes: int) -> None:
        refused = np.asarray(state["rise_refused"], np.float64)
        if (refused.shape != (5,) or not np.all(np.isfinite(refused))
                or not -1 <= refused[0] < n_nodes or not -1 <= refused[1] < n_nodes):
            raise ValueError("the loop refused for its rise refers to nodes that do not exist")
        strained = np.asarray(state["strained"], np.float64)
        info = np.asarray(state["strained_info"], np.float64)
        if strained.shape != (GROUP - 1, 5) or info.shape != (GROUP - 1, 3, 3):
            raise ValueError(f"the loops refused for their own error are not {GROUP - 1} rows")
        if (not np.all(np.isfinite(strained)) or not np.all(np.isfinite(info))
                or not np.all((-1 <= strained[:, :2]) & (strained[:, :2] < n_nodes))):
            raise ValueError("the loops refused for their own error refer to nodes that do not "
                             "exist")
        self.rise_refused[:] = refused
        self.strained[:], self.strained_info[:] = strained, info


def turn_rate(graph, k: int, before: int) -> float:
    """How fast node ``k`` turned, by the graph: its largest turn to the node just before or
    after it (of those before node ``before``) over the time between them (rad/s)."""
    p, t = graph.poses, graph.stamps
    rate = 0.0
    for other in (k - 1, k + 1):
        if 0 <= other < before and t[other] != t[k]:
            rate = max(rate, abs(float(wrap_angle(p[other, 2] - p[k, 2]))) / abs(t[other] - t[k]))
    return rate


def relative_guess(graph, i: int, j: int) -> np.ndarray:
    """The graph's current estimate of node ``j`` in node ``i``'s frame."""
    return between(graph.poses[j], graph.poses[i])
