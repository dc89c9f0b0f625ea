"""The scans stored with the pose graph's nodes, and each node's propagated covariance.

Node ``k``'s scan (robot frame, at most ``max_points`` points) is kept so that the keyframe
reference, loop submaps and the map can be rebuilt from the optimised poses at any time; the
covariance of each node's pose, propagated along the odometry chain, gates loop candidates
(Alg. 7, step 2). Capacities are fixed at construction.
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.pose import compose, place_points_nb
from swarmslam.runtime.scan import PointScan


class NodeScans:
    def __init__(self, max_nodes: int, max_points: int):
        self.points = np.zeros((max_nodes, max_points, 2))
        self.counts = np.zeros(max_nodes, np.int64)
        self.cov = np.zeros((max_nodes, 3, 3))

    @property
    def max_points(self) -> int:
        return self.points.shape[1]

    def store(self, node: int, scan: PointScan) -> None:
        n = min(scan.count, self.max_points)
        self.points[node, :n] = scan.buffer[:n]
        self.counts[node] = n

    def load(self, node: int, scan: PointScan) -> PointScan:
        n = self.counts[node]
        scan.buffer[:n] = self.points[node, :n]
        scan.count = n
        return scan

    def scan_points(self, node: int) -> np.ndarray:
        """Node ``node``'s points (a view, robot frame)."""
        return self.points[node, : self.counts[node]]

    def place(self, poses, nodes, frame: int, out: PointScan, rows=None) -> PointScan:
        """The stored scans of ``nodes``, one after another, in the frame of ``poses[frame]``
        as ``poses`` place them (each scan's points stay together, so surfaces join within
        it). ``rows``: the row of ``poses`` placing each node (default: the node's own)."""
        n = 0
        for k, other in enumerate(nodes):
            row = other if rows is None else rows[k]
            n = place_points_nb(poses, row, frame, self.points[other], self.counts[other],
                                out.buffer, n)
        out.count = n
        return out

    def extent_points(self, poses, n_nodes: int, reach: float) -> np.ndarray:
        """The node positions and every stored point within ``reach`` of its node, in the
        map frame ``poses`` gives (``(M, 2)``): what a map of the nodes must cover."""
        out = [poses[:n_nodes, :2]]
        for k in range(n_nodes):
            pts = self.scan_points(k)
            near = pts[np.hypot(pts[:, 0], pts[:, 1]) <= reach]
            if len(near):
                out.append(compose(poses[k], np.c_[near, np.zeros(len(near))])[:, :2])
        return np.vstack(out)

    # ------------------------------------------------------------------ state
    def state(self, n_nodes: int) -> dict:
        counts = self.counts[:n_nodes]
        points = (np.concatenate([self.points[i, : counts[i]] for i in range(n_nodes)])
                  if n_nodes else np.zeros((0, 2)))
        return {"counts": counts.copy(), "points": points, "cov": self.cov[:n_nodes].copy()}

    def restore(self, state: dict) -> None:
        counts, points = state["counts"], state["points"]
        n = len(counts)
        if n > self.counts.shape[0]:
            raise ValueError(f"{n} node scans exceed the node capacity {self.counts.shape[0]}")
        if int(counts.sum()) != len(points) or (n and int(counts.max()) > self.max_points):
            raise ValueError("node scan counts do not match the stored points")
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        for i in range(n):
            self.points[i, : counts[i]] = points[offsets[i] : offsets[i + 1]]
        self.counts[:n] = counts
        self.cov[:n] = state["cov"]
