"""The trajectory the front end records: every scan's node, its pose in that node's frame, its
stamp and what odometry read at it; placed by the graph when asked (docs/method.md §6.2).

    scans = ScanTrajectory(config.front_end, capacity)
    scans.record(node, rel, stamp, reading, odometry)
    stamps, poses = scans.placed(graph)

A scan's pose is kept relative to its node, so a loop closure that moves the nodes moves the
scans with them; the scans between two nodes are smoothed with odometry's motion where the run
shows that pays (:mod:`swarmslam.runtime.front_end.between_scans`).
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.front_end.between_scans import (FIRST_READING, NO_READING, BetweenSmoothing,
                                             smooth_headings, smooth_positions)
from swarmslam.runtime.config import FrontEndConfig
from swarmslam.runtime.pose import between, compose, interpolate
from swarmslam.runtime.pose_graph import ODOMETRY, PoseGraph


class ScanTrajectory:
    """Fixed-capacity arrays, one row a scan: ``node``, ``rel`` (the pose in the node's frame),
    ``stamp``, ``reading`` (its kind, :mod:`swarmslam.runtime.front_end.between_scans`) and ``odometry``
    (odometry's pose at a new reading)."""

    def __init__(self, config: FrontEndConfig, capacity: int):
        self.config = config
        self.node = np.zeros(capacity, np.int64)
        self.rel = np.zeros((capacity, 3))
        self.stamp = np.zeros(capacity)
        self.reading = np.zeros(capacity, np.int8)
        self.odometry = np.zeros((capacity, 3))
        self.n = 0
        # the last placement's estimates (between_scans.BetweenNoise), heading and position
        self.heading_noise = self.position_noise = None

    @property
    def capacity(self) -> int:
        return self.node.shape[0]

    def record(self, node: int, rel, stamp: float, reading: int, odometry) -> bool:
        """One scan's row; False when the capacity is reached (nothing recorded)."""
        k = self.n
        if k >= self.capacity:
            return False
        self.node[k] = node
        self.rel[k] = rel
        self.stamp[k] = stamp
        self.reading[k] = reading
        self.odometry[k] = odometry
        self.n += 1
        return True

    def placed(self, graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and poses of every scan recorded, placed by the graph's optimised poses."""
        n = self.n
        node, rel, stamp = self.node[:n], self.rel[:n], self.stamp[:n]
        step = _node_steps(graph)
        poses = self._place(graph, node, rel, stamp, step)
        c = self.config
        if not n:
            return stamp.copy(), poses
        # the scans between nodes smoothed with odometry's motion, heading first (a position's
        # motion is read in the frame its heading gives), where the run shows it pays
        is_node = np.r_[True, node[1:] != node[:-1]]  # a node's first scan is its own
        smoothing = BetweenSmoothing(min_pairs=c.between_scans.min_pairs)
        odometry, kind = self.odometry[:n], self.reading[:n]
        rel = rel.copy()
        if c.between_scans.headings:
            headings, self.heading_noise = smooth_headings(node, rel, is_node, poses, odometry,
                                                           kind, step, smoothing)
            if headings is not None:
                rel[:, 2] = headings
                poses = self._place(graph, node, rel, stamp, step)
        if c.between_scans.positions:
            positions, self.position_noise = smooth_positions(node, rel, is_node, poses, odometry,
                                                              kind, step, smoothing, graph.scale)
            if positions is not None:
                rel[:, :2] = positions
                poses = self._place(graph, node, rel, stamp, step)
        return stamp.copy(), poses

    def _place(self, g: PoseGraph, node, rel, stamp, step):
        """Each scan placed by the graph: from its node by its pose in the node's frame and,
        with ``spread_corrections``, blended with its place from the next node: a scan
        tracked from node k before node k + 1 was made is placed from k + 1 by that pose taken
        back along the edge that made k + 1, and the two blended by the scan's share of the
        time between the nodes. When the graph bends the chain between k and k + 1, the scans
        between them follow the bend instead of moving with k alone."""
        poses = compose(g.poses[node], rel)
        if not self.config.spread_corrections:
            return poses
        nxt = np.minimum(node + 1, g.n_nodes - 1)
        gap = g.stamps[nxt] - g.stamps[node]
        ok = (node + 1 < g.n_nodes) & ~np.isnan(step[node, 0]) & (gap > 0)
        if not np.any(ok):
            return poses
        k = node[ok]
        from_next = compose(g.poses[k + 1], between(rel[ok], step[k]))  # z⁻¹ ⊕ rel, from k + 1
        share = np.clip((stamp[ok] - g.stamps[k]) / gap[ok], 0.0, 1.0)
        poses[ok] = interpolate(poses[ok], from_next, share)
        return poses

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        k = self.n
        return {"scan_node": self.node[:k].copy(), "scan_rel": self.rel[:k].copy(),
                "scan_stamp": self.stamp[:k].copy(), "scan_reading": self.reading[:k].copy(),
                "scan_odometry": self.odometry[:k].copy()}

    def restore(self, state: dict, n_nodes: int) -> None:
        """The rows :meth:`state` gave, checked against a graph of ``n_nodes`` nodes."""
        node = np.asarray(state["scan_node"])
        k = len(node)
        if k > self.capacity:
            raise ValueError(f"{k} scans exceed the trajectory capacity {self.capacity}")
        if k and (node.min() < 0 or node.max() >= n_nodes):
            raise ValueError("the trajectory refers to nodes that do not exist")
        reading = np.asarray(state["scan_reading"])
        odometry = np.asarray(state["scan_odometry"], np.float64)
        if (reading.shape != (k,) or odometry.shape != (k, 3) or not np.all(np.isfinite(odometry))
                or np.any((reading < NO_READING) | (reading > FIRST_READING))):
            raise ValueError("the trajectory's odometry readings are not one per scan, each "
                             "a known kind with a finite pose")
        self.node[:k], self.rel[:k], self.stamp[:k] = node, state["scan_rel"], state["scan_stamp"]
        self.reading[:k], self.odometry[:k] = reading, odometry
        self.n = k


def _node_steps(g: PoseGraph) -> np.ndarray:
    """Per node k, the edge that made node k + 1, in k's frame (NaN where none)."""
    ij, kind, z = g.ij[: g.n_edges], g.kind[: g.n_edges], g.z[: g.n_edges]
    made = (kind == ODOMETRY) & (ij[:, 1] == ij[:, 0] + 1)  # node k → k + 1 (Alg. 6)
    step = np.full((g.n_nodes, 3), np.nan)
    step[ij[made, 0]] = z[made]
    return step
