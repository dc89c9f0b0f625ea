"""The scans stored with the pose graph's nodes, and each node's propagated covariance.

Node ``k``'s scan (robot frame, at most ``max_points`` points) is kept so that the keyframe
reference, loop submaps and the map can be rebuilt from the optimised poses at any time; the
covariance of each node's pose, propagated along the odometry chain, gates loop candidates
(Alg. 7, step 2). Capacities are fixed at construction.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.pose import between_nb, compose, place_points_nb
from swarmslam.runtime.matching.scan import PointScan


NO_EVIDENCE, SURFACE, THROUGH = 0, 1, 2  # what one scan saw of a place (_seen_by)
BEARING_BINS = 720  # bearing bins of a node scan's range image (polar_image): 0.5° each


@njit(cache=True)
def polar_image(points, count, image):
    """The nearest range per bearing bin of a scan in its own frame (``inf``: no return)."""
    bins = image.shape[0]
    image[:] = np.inf
    for k in range(count):
        r = math.hypot(points[k, 0], points[k, 1])
        b = int((math.atan2(points[k, 1], points[k, 0]) + math.pi) * bins / (2 * math.pi)) % bins
        if r < image[b]:
            image[b] = r
    return image


@njit(cache=True)
def _seen_by(placed, f, qx, qy, images, tolerance, slope):
    """What scan ``f`` saw of the place ``(qx, qy)`` (in the frame ``placed`` places the scans
    in): SURFACE there, THROUGH it (every ray of f passing within ``tolerance + slope·r`` of
    it went on beyond it by more than that; the point's own bearing alone would call a wall
    seen at a grazing angle seen through), or NO_EVIDENCE (no return of f at that bearing:
    out of its view or reach; or a nearer one: the place hidden)."""
    bins = images.shape[1]
    dx, dy = qx - placed[f, 0], qy - placed[f, 1]  # into scan f's frame
    ux = placed[f, 2] * dx + placed[f, 3] * dy
    uy = -placed[f, 3] * dx + placed[f, 2] * dy
    d = math.hypot(ux, uy)
    b = int((math.atan2(uy, ux) + math.pi) * bins / (2 * math.pi)) % bins
    if not min(images[f, b], images[f, (b - 1) % bins], images[f, (b + 1) % bins]) < np.inf:
        return NO_EVIDENCE  # no return of scan f at that bearing
    margin = tolerance + slope * d
    half = min(int(math.atan2(margin, d) * bins / (2 * math.pi)) + 1, bins // 4)
    seen = np.inf
    for j in range(b - half, b + half + 1):
        seen = min(seen, images[f, j % bins])
    if abs(d - seen) <= margin:
        return SURFACE
    return THROUGH if d < seen - margin else NO_EVIDENCE


@njit(cache=True)
def place_unmoved_nb(poses, nodes, m, frame, points, counts, tolerance, slope, images, placed,
                     out):
    """The points of the scans of ``nodes[:m]`` (placed by ``poses[:m]``, row for row) in the
    frame of ``poses[frame]``, but those that another of the scans saw through
    (:func:`_seen_by`) and none saw a surface at: what stood there moved, a person walking
    (docs/method.md §6.1, "Moved points"). ``images`` (a range image per scan) and ``placed``
    (each scan's pose in the frame, its cosine and sine) are work buffers. Returns how many
    points were written."""
    for e in range(m):
        polar_image(points[nodes[e]], counts[nodes[e]], images[e])
        x, y, t = between_nb(poses[e, 0], poses[e, 1], poses[e, 2],
                             poses[frame, 0], poses[frame, 1], poses[frame, 2])
        placed[e, 0], placed[e, 1] = x, y
        placed[e, 2], placed[e, 3] = math.cos(t), math.sin(t)
    n = 0
    for e in range(m):
        node = nodes[e]
        x, y, c, s = placed[e, 0], placed[e, 1], placed[e, 2], placed[e, 3]
        for k in range(counts[node]):
            px, py = points[node, k, 0], points[node, k, 1]
            qx = x + c * px - s * py
            qy = y + s * px + c * py
            moved = False
            for f in range(m):
                if f == e:
                    continue
                seen = _seen_by(placed, f, qx, qy, images, tolerance, slope)
                if seen == SURFACE:
                    moved = False  # a surface another scan saw there too
                    break
                moved = moved or seen == THROUGH
            if not moved:
                out[n, 0], out[n, 1] = qx, qy
                n += 1
    return n


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

    def place_unmoved(self, poses, nodes, frame: int, out: PointScan, tolerance: float,
                      slope: float, images, placed) -> PointScan:
        """As :meth:`place` with ``poses`` a row per node, without the points another of the
        scans saw through (:func:`place_unmoved_nb`); ``images`` and ``placed`` are its work
        buffers, a row per scan."""
        out.count = place_unmoved_nb(poses, nodes, len(nodes), frame, self.points,
                                     self.counts, tolerance, slope, images, placed, out.buffer)
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
