"""The global occupancy grid (Alg. 4's Generate_Global_Map): log-odds over a fixed-capacity
grid, rays traced from each scan's optimised pose (Bresenham), in compiled code.

Output convention is ROS map_server's (see :mod:`swarmslam.formats.map_io`): probability of occupancy
from the log-odds, thresholds 0.65 / 0.196.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

L_OCC = 0.85  # log-odds added at a beam end  (p ≈ 0.70)
L_FREE = -0.4  # added along the beam         (p ≈ 0.40)
L_MIN, L_MAX = -4.0, 4.0


@njit(cache=True)
def integrate_scan(logodds, region, origin_x, origin_y, res, pose, pts, n, max_range):
    """Add one scan (sensor-frame points) seen from ``pose`` to the log-odds grid; returns how
    many cells of ``region`` (nonzero cells of a uint8 grid) it made known for the first time."""
    h, w = logodds.shape
    newly_known = 0
    if not (math.isfinite(pose[0]) and math.isfinite(pose[1]) and math.isfinite(pose[2])):
        return 0
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    fx0 = (pose[0] - origin_x) / res
    fy0 = (pose[1] - origin_y) / res
    if not (0.0 <= fx0 < w and 0.0 <= fy0 < h):
        return 0  # the sensor off the grid: no ray is traced (none would cross it reliably)
    x0 = int(math.floor(fx0))
    y0 = int(math.floor(fy0))
    for k in range(n):
        px = pts[k, 0]
        py = pts[k, 1]
        if not (math.isfinite(px) and math.isfinite(py)):
            continue
        if px * px + py * py > max_range * max_range:
            continue
        wx = pose[0] + c * px - s * py
        wy = pose[1] + s * px + c * py
        # Every loop is bounded (docs/runtime.md §7): an end point off the grid is drawn as
        # far as the grid's edge (the ray leaves it once and for all), never walked to.
        gx = min(max((wx - origin_x) / res, -1.0), float(w))
        gy = min(max((wy - origin_y) / res, -1.0), float(h))
        if gx != (wx - origin_x) / res or gy != (wy - origin_y) / res:
            # shorten the ray along its own direction to where it meets the clamped box
            tx = 1.0
            dxw = (wx - origin_x) / res - fx0
            dyw = (wy - origin_y) / res - fy0
            if dxw > 0.0:
                tx = min(tx, (w - fx0) / dxw)
            elif dxw < 0.0:
                tx = min(tx, (fx0 + 1.0) / -dxw)
            if dyw > 0.0:
                tx = min(tx, (h - fy0) / dyw)
            elif dyw < 0.0:
                tx = min(tx, (fy0 + 1.0) / -dyw)
            gx = fx0 + tx * dxw
            gy = fy0 + tx * dyw
        x1 = int(math.floor(gx))
        y1 = int(math.floor(gy))
        # Bresenham from the sensor to the end point; the end cell is occupied.
        dx = abs(x1 - x0)
        dy = -abs(y1 - y0)
        sx = 1 if x0 < x1 else -1
        sy = 1 if y0 < y1 else -1
        err = dx + dy
        x = x0
        y = y0
        while True:
            if x == x1 and y == y1:
                break
            if 0 <= x < w and 0 <= y < h:
                if logodds[y, x] == 0.0 and region[y, x]:
                    newly_known += 1
                logodds[y, x] = max(L_MIN, logodds[y, x] + L_FREE)
            e2 = 2 * err
            if e2 >= dy:
                err += dy
                x += sx
            if e2 <= dx:
                err += dx
                y += sy
        if 0 <= x1 < w and 0 <= y1 < h:
            if logodds[y1, x1] == 0.0 and region[y1, x1]:
                newly_known += 1
            logodds[y1, x1] = min(L_MAX, logodds[y1, x1] + L_OCC - L_FREE)
    return newly_known


def probability(logodds) -> np.ndarray:
    """Occupancy probabilities of log-odds cells (0.5 where nothing was seen)."""
    return 1.0 - 1.0 / (1.0 + np.exp(np.asarray(logodds).astype(np.float64)))


class OccupancyGrid:
    """A log-odds grid; row 0 is the lowest y (``origin`` is its lower-left corner, metres)."""

    def __init__(self, width: int, height: int, resolution: float, origin=(0.0, 0.0)):
        if width < 1 or height < 1 or not resolution > 0:
            raise ValueError(f"bad grid size {width}×{height} at {resolution} m")
        self.logodds = np.zeros((height, width), np.float32)
        # cells whose first observation integrate() counts (e.g. a simulator's reachable area)
        self.region = np.ones((height, width), np.uint8)
        self.resolution = float(resolution)
        self.origin = np.array(origin, dtype=np.float64)

    @classmethod
    def covering(cls, points_xy, resolution: float, margin: float = 1.0, max_cells: int = 4096):
        """A grid over the bounding box of ``points_xy``, at most ``max_cells`` per side (the
        resolution is coarsened rather than the map cropped)."""
        points_xy = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        if not len(points_xy):  # nothing mapped yet: a grid of unknown cells at the origin
            points_xy = np.zeros((1, 2))
        lo = np.min(points_xy, axis=0) - margin
        hi = np.max(points_xy, axis=0) + margin
        res = max(resolution, float(np.max(hi - lo)) / max_cells)
        size = np.ceil((hi - lo) / res).astype(int) + 1
        return cls(int(size[0]), int(size[1]), res, lo)

    @classmethod
    def covering_nodes(cls, poses, nodes, n_nodes: int, map_config) -> OccupancyGrid:
        """An empty grid over the first ``n_nodes`` node poses and their stored scans
        (a :class:`swarmslam.runtime.node_scans.NodeScans`) within ``map_config.max_range``."""
        m = map_config
        return cls.covering(nodes.extent_points(poses, n_nodes, m.max_range), m.resolution,
                            m.margin, m.max_cells)

    @classmethod
    def of_nodes(cls, poses, nodes, n_nodes: int, map_config) -> OccupancyGrid:
        """The map of the first ``n_nodes`` node scans drawn from ``poses``: a grid
        :meth:`covering_nodes` them, each scan drawn within ``map_config.max_range``."""
        grid = cls.covering_nodes(poses, nodes, n_nodes, map_config)
        return grid.draw_nodes(poses, nodes, n_nodes, map_config.max_range)

    def draw_nodes(self, poses, nodes, n_nodes: int, max_range: float) -> OccupancyGrid:
        """Draw the first ``n_nodes`` node scans (a :class:`swarmslam.runtime.node_scans.NodeScans`)
        from ``poses`` into the grid (added to what is in it); returns the grid."""
        for k in range(n_nodes):
            self.integrate(poses[k], nodes.scan_points(k), max_range)
        return self

    def integrate(self, pose, points, max_range: float = np.inf) -> int:
        """Add a scan; returns the number of ``region`` cells it observed for the first time."""
        pts = np.asarray(points, dtype=np.float64)
        return integrate_scan(self.logodds, self.region, self.origin[0], self.origin[1],
                              self.resolution, np.asarray(pose, dtype=np.float64), pts, len(pts),
                              max_range)

    def probability(self) -> np.ndarray:
        return probability(self.logodds)

    def known(self) -> np.ndarray:
        return self.logodds != 0.0
