"""The map a viewer shows, redrawn a few nodes per tick so that watching never costs a deadline.

Drawing the whole map takes ~90 ms for Intel's 1,284 nodes — a missed deadline at 10 Hz if done
in one tick. :class:`MapPainter` spreads it: each call draws at most ``nodes_per_tick`` node
scans into a grid sized for the nodes known when the pass began; the finished grid's cells are
then turned into what the viewers send (map_saver's trinary values, ROS occupancy percent) at
most ``cells_per_tick`` at a time — on fr-clinic's map (8.8 million cells at the end) it took
50–190 ms when done at once — and the :class:`PaintedMap` is handed over when all is done. The
next pass starts once the graph has changed (a node added, a loop closed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarmslam.runtime.occupancy_grid import OccupancyGrid, probability
from swarmslam.formats.map_io import trinary_values


def map_nodes(slam):
    """``(poses, node scans, count, version)`` of what a map is drawn from: the graph being
    built, or the saved map being localized in (which never changes)."""
    saved = getattr(slam, "saved", None)
    if saved is not None:
        return saved.poses, saved.nodes, saved.n_nodes, (saved.n_nodes, 0)
    g = slam.graph
    return g.poses, slam.nodes, g.n_nodes, (g.n_nodes, slam.revision)


@dataclass
class PaintedMap:
    """A finished redraw: the grid and its cells as viewers send them (row 0 the lowest y)."""

    grid: OccupancyGrid
    trinary: np.ndarray  # uint8: 0 occupied, 254 free, 205 unknown (map_saver's values)
    percent: np.ndarray  # int8: −1 unknown, else the occupancy probability in percent (ROS)


class MapPainter:
    """Incremental redraws of the occupancy map (see module doc)."""

    def __init__(self, map_config, nodes_per_tick: int = 40, cells_per_tick: int = 250_000):
        if nodes_per_tick < 1 or cells_per_tick < 1:
            raise ValueError(f"nodes_per_tick and cells_per_tick must be ≥ 1, got "
                             f"{nodes_per_tick} and {cells_per_tick}")
        self.config = map_config
        self.nodes_per_tick, self.cells_per_tick = nodes_per_tick, cells_per_tick
        self._grid: OccupancyGrid | None = None
        self._painted: PaintedMap | None = None  # the pass's cells, while they are converted
        self._next = 0  # the next node of the pass under way, then the next row to convert
        self._count = 0  # nodes the pass draws
        self._version = None  # of the graph the last pass began on

    @property
    def busy(self) -> bool:
        """A pass is under way."""
        return self._grid is not None

    def paint(self, slam) -> PaintedMap | None:
        """Go on with the pass: draw the next few node scans or convert the next rows; the
        finished map when the pass completes, else None."""
        poses, nodes, n, version = map_nodes(slam)
        if self._grid is None:
            if n == 0 or version == self._version:
                return None
            self._grid = OccupancyGrid.covering_nodes(poses, nodes, n, self.config)
            self._painted = None
            self._next, self._count, self._version = 0, n, version
        grid = self._grid
        if self._painted is None:  # drawing the node scans
            end = min(self._next + self.nodes_per_tick, self._count)
            for k in range(self._next, end):
                grid.integrate(poses[k], nodes.scan_points(k), self.config.max_range)
            self._next = end
            if end < self._count:
                return None
            shape = grid.logodds.shape
            self._painted = PaintedMap(grid, np.empty(shape, np.uint8), np.empty(shape, np.int8))
            self._next = 0
            return None
        painted, height, width = self._painted, *grid.logodds.shape
        first = self._next
        last = min(first + max(self.cells_per_tick // width, 1), height)
        rows = grid.logodds[first:last]
        painted.trinary[first:last] = trinary_values(rows)
        painted.percent[first:last] = occupancy_percent(rows)
        self._next = last
        if last < height:
            return None
        self._grid = self._painted = None
        return painted


def occupancy_percent(logodds) -> np.ndarray:
    """ROS ``OccupancyGrid`` values of log-odds cells (any block of the grid's rows): −1
    unknown, else the occupancy probability in percent."""
    out = np.rint(100.0 * probability(logodds)).astype(np.int8)
    out[logodds == 0.0] = -1
    return out
