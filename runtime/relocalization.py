"""Global relocalization: a scan's pose in a saved map with no prior, or "ambiguous"
(docs/method.md §8).

    relocalizer = Relocalizer(config, poses, nodes, n_nodes)
    answer = relocalizer.relocalize(scan)        # Located(pose, score) | Ambiguous

1. search: the exact best pose on the hit grid over every standable cell and heading
   (:func:`runtime.place_search.branch_and_bound`);
2. ambiguity: the same search keeps every distinct pose scoring at least ``ambiguity_ratio``
   of the best — any such rival is a different explanation about as good, and the answer is
   :class:`Ambiguous` (with every such pose, best first);
3. polish: the swarm (Alg. 5) aligns the scan with the nearest node scans in a small box around
   the grid's answer, as loop closure does.

Confirmation merges the scans of the next ``confirm_seconds`` — placed by the motion tracked
between them — into one query (:meth:`Relocalizer.relocalize_merged`), meant to tell apart
what one scan cannot; measured, it rarely does in corridors (README, ``bench localize``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from runtime.config import SlamConfig
from runtime.node_scans import NodeScans
from runtime.place_search import (
    HIT_MAX,
    PlaceMap,
    branch_and_bound,
    heading_step,
    rotate_query,
    select_query,
)
from runtime.pose import between, compose, wrap_angle
from runtime.scan import PointScan
from runtime.scan_matcher import ScanMatcher


@dataclass(frozen=True)
class Located:
    """The scan's pose in the map and its score (mean hit value of the query's points, 0–1);
    no distinct pose scored ``ambiguity_ratio`` of it."""

    pose: np.ndarray
    score: float


@dataclass(frozen=True)
class Ambiguous:
    """Distinct poses explaining the scan about equally well (best first), or none at all."""

    poses: tuple
    scores: tuple
    reason: str


class Relocalizer:
    """The global search over one saved map (read-only): its buffers are allocated here."""

    def __init__(self, config: SlamConfig, poses, nodes: NodeScans, n_nodes: int, seed: int = 0):
        rc = self.config = config.relocalization
        self.poses = poses[:n_nodes]
        self.nodes, self.n_nodes = nodes, n_nodes
        self.place = PlaceMap(poses, nodes, n_nodes, rc, config.matcher.max_gap)
        self.n_headings = int(math.ceil(2 * math.pi / heading_step(rc.resolution,
                                                                  rc.query_range)))
        ny, nx = self.place.shape
        top = 1 << rc.levels
        group = int(self.place.groups[-1])
        groups = -(-self.n_headings // group)
        roots = groups * (-(-ny // top)) * (-(-nx // top))
        self._query = np.zeros((config.sensor.max_points, 2))  # a larger scan gets its own
        # headings past the last (a group's middle may lie there) wrap around the circle
        self._offsets = np.zeros((groups * group, rc.query_points, 2), np.int64)
        self._roots = np.zeros((roots, 5), np.int64)
        self._stack = np.zeros((8 * (rc.levels + 2), 5), np.int64)
        self._found = np.zeros((rc.max_hypotheses, 4), np.int64)
        self.cell_radius = int(math.ceil(rc.distinct_distance / rc.resolution))
        self.matcher = ScanMatcher(replace(config.matcher, guess_window=rc.refine_window),
                                   seed=seed)
        self.reference = self.matcher.new_reference()
        self._submap = PointScan(config.sensor.max_points * rc.refine_nodes)
        self.blocks_scored = 0  # by the last search

    # ------------------------------------------------------------------ the answer
    def relocalize(self, scan: PointScan) -> Located | Ambiguous:
        """Where ``scan`` (robot frame) was taken in the map, or :class:`Ambiguous`."""
        return self._answer(scan)

    def relocalize_merged(self, scans, motions) -> Located | Ambiguous:
        """Confirmation: ``scans`` (robot frames) merged into the last one's frame by
        ``motions`` (each scan's pose in the last scan's frame), relocalized as one query."""
        merged = PointScan(sum(s.count for s in scans))
        n = 0
        for s, m in zip(scans, motions):
            pts = compose(np.asarray(m, np.float64), np.c_[s.points, np.zeros(s.count)])
            merged.buffer[n : n + s.count] = pts[:, :2]
            n += s.count
        merged.count = n
        return self._answer(merged)

    def _answer(self, scan: PointScan) -> Located | Ambiguous:
        rc = self.config
        query = self._query if scan.count <= len(self._query) else np.zeros((scan.count, 2))
        n = select_query(scan.buffer, scan.count, rc.query_range, rc.query_spacing,
                         rc.query_points, query)
        if n < 3:
            return Ambiguous((), (), f"only {n} usable points within {rc.query_range} m")
        found = self.search(query, n)
        if not found:
            return Ambiguous((), (), "no pose explains the scan (every score below min_score)")
        if len(found) > 1:
            return Ambiguous(tuple(p for p, _ in found), tuple(s for _, s in found),
                             f"{len(found)} distinct poses score within "
                             f"{rc.ambiguity_ratio:.0%} of the best")
        pose, score = found[0]
        polished = self.polish(scan, pose)
        if self.place.score(query, n, polished) >= score:
            pose = polished
        return Located(pose, score)

    # ------------------------------------------------------------------ steps
    def search(self, query, n: int) -> list[tuple[np.ndarray, float]]:
        """The best pose and every distinct pose scoring ``ambiguity_ratio`` of it (at most
        ``max_hypotheses``), as ``(pose, mean hit value)``, best first."""
        rc = self.config
        # the heading step moves the query's farthest point by one cell (fewer steps for a
        # scan of a small room than the allocation's query_range allows)
        reach = max(float(np.max(np.hypot(query[:n, 0], query[:n, 1]))), rc.resolution)
        n_headings = min(int(math.ceil(2 * math.pi / heading_step(rc.resolution, reach))),
                         self.n_headings)
        step = 2 * math.pi / n_headings
        rotate_query(query, n, rc.resolution, step, self._offsets.shape[0], self._offsets)
        heading_radius = int(math.ceil(rc.distinct_angle / step))
        full = HIT_MAX * n
        n_found, self.blocks_scored = branch_and_bound(
            self.place.bounds, self.place.shifts, self.place.groups, self.place.free,
            self._offsets, n, n_headings, int(math.ceil(rc.min_score * full)),
            rc.ambiguity_ratio, self.cell_radius, heading_radius, self._roots,
            self._stack, self._found)
        found = []
        for score, a, row, col in self._found[:n_found]:
            x, y = self.place.position_of(int(row), int(col))
            found.append((np.array([x, y, wrap_angle(int(a) * step)]), score / full))
        return found

    def polish(self, scan: PointScan, pose) -> np.ndarray:
        """The swarm's alignment of ``scan`` with the nearest node scans, in a small box around
        ``pose`` (the grid's answer)."""
        rc = self.config
        d2 = np.sum((self.poses[:, :2] - pose[:2]) ** 2, axis=1)
        near = np.argsort(d2, kind="stable")[: rc.refine_nodes]
        anchor = int(near[0])
        submap = self.nodes.place(self.poses, sorted(int(k) for k in near), anchor, self._submap)
        reference = self.matcher.build_reference(submap, self.reference)
        guess = between(pose, self.poses[anchor])
        match = self.matcher.align_scans(scan, reference, guess)
        return compose(self.poses[anchor], match.pose)
