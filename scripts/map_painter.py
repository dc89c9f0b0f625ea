"""The map a viewer shows, redrawn a few nodes per tick so that watching never costs a deadline.

Drawing the whole map takes ~90 ms for Intel's 1,284 nodes — a missed deadline at 10 Hz if done
in one tick. :class:`MapPainter` spreads it: each call draws at most ``nodes_per_tick`` node
scans into a grid sized for the nodes known when the pass began, and hands the grid over when the
pass is complete; the next pass starts once the graph has changed (a node added, a loop closed).
"""

from __future__ import annotations

import numpy as np

from runtime.occupancy_grid import OccupancyGrid


def map_nodes(slam):
    """``(poses, node scans, count, version)`` of what a map is drawn from: the graph being
    built, or the saved map being localized in (which never changes)."""
    saved = getattr(slam, "saved", None)
    if saved is not None:
        return saved.poses, saved.nodes, saved.n_nodes, (saved.n_nodes, 0)
    g = slam.graph
    return g.poses, slam.nodes, g.n_nodes, (g.n_nodes, slam.revision)


class MapPainter:
    """Incremental redraws of the occupancy map (see module doc)."""

    def __init__(self, map_config, nodes_per_tick: int = 40):
        if nodes_per_tick < 1:
            raise ValueError(f"nodes_per_tick must be ≥ 1, got {nodes_per_tick}")
        self.config = map_config
        self.nodes_per_tick = nodes_per_tick
        self._grid: OccupancyGrid | None = None
        self._next = 0  # the next node of the pass under way
        self._count = 0  # nodes the pass draws
        self._version = None  # of the graph the last pass began on

    @property
    def busy(self) -> bool:
        """A pass is under way."""
        return self._grid is not None

    def paint(self, slam) -> OccupancyGrid | None:
        """Draw the next few node scans; the finished grid when a pass completes, else None."""
        poses, nodes, n, version = map_nodes(slam)
        if self._grid is None:
            if n == 0 or version == self._version:
                return None
            self._grid = OccupancyGrid.covering_nodes(poses, nodes, n, self.config)
            self._next, self._count, self._version = 0, n, version
        grid, end = self._grid, min(self._next + self.nodes_per_tick, self._count)
        for k in range(self._next, end):
            grid.integrate(poses[k], nodes.scan_points(k), self.config.max_range)
        self._next = end
        if end < self._count:
            return None
        self._grid = None
        return grid


def occupancy_percent(grid: OccupancyGrid) -> np.ndarray:
    """ROS ``OccupancyGrid`` values: −1 unknown, else the occupancy probability in percent
    (row 0 the lowest y, as in the grid)."""
    out = np.rint(100.0 * grid.probability()).astype(np.int8)
    out[~grid.known()] = -1
    return out
