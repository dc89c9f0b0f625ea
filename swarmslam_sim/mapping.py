"""The environment's view of the map: the area there is to map, and the robot-centred crop.

The *mappable area* of a world is every grid cell whose centre lies at least one cell from any
wall and that the robot can reach from its start (a flood fill from the start cell). Coverage
is the share of it that the SLAM map has observed.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy import ndimage

from swarmslam.runtime.occupancy_grid import OccupancyGrid
from swarmslam_sim.raycast import point_segment_distance
from swarmslam_sim.world import World


MIN_MAPPABLE_AREA = 2.0  # m² reachable from the start: less is a start inside an obstacle
MAX_MAP_CELLS = 25_000_000  # a 500 m square at 0.1 m: 200 MB of log-odds


def world_grid(world: World, resolution: float) -> OccupancyGrid:
    """An empty grid over the world's bounds, its ``region`` set to the mappable area."""
    x0, y0, x1, y1 = world.bounds
    w, h = int(math.ceil((x1 - x0) / resolution)), int(math.ceil((y1 - y0) / resolution))
    if w * h > MAX_MAP_CELLS:
        raise ValueError(f"map_resolution {resolution:g} m is too fine for world "
                         f"{world.name!r} ({x1 - x0:g} × {y1 - y0:g} m): {w * h:,} cells, at "
                         f"most {MAX_MAP_CELLS:,}")
    grid = OccupancyGrid(w, h, resolution, (x0, y0))
    grid.region[:] = mappable_area(world, grid)
    return grid


def wall_clearance(world: World, grid: OccupancyGrid) -> np.ndarray:
    """Distance from each cell centre to the nearest wall (m), shape of the grid."""
    h, w = grid.logodds.shape
    xs = grid.origin[0] + (np.arange(w) + 0.5) * grid.resolution
    ys = grid.origin[1] + (np.arange(h) + 0.5) * grid.resolution
    centres = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    best = np.full(len(centres), np.inf)
    for seg in world.segments:
        np.minimum(best, point_segment_distance(centres, seg), out=best)
    return best.reshape(h, w)


def mappable_area(world: World, grid: OccupancyGrid) -> np.ndarray:
    free = wall_clearance(world, grid) >= grid.resolution
    labels, _ = ndimage.label(free)
    sx, sy = grid_cell(grid, world.start)
    if not (0 <= sy < free.shape[0] and 0 <= sx < free.shape[1]) or labels[sy, sx] == 0:
        raise ValueError(f"world {world.name!r}: the start {world.start[:2]} is not in free space")
    region = labels == labels[sy, sx]
    if region[0].any() or region[-1].any() or region[:, 0].any() or region[:, -1].any():
        raise ValueError(f"world {world.name!r}: the free space around the start "
                         f"{world.start[:2]} reaches the bounds — the start lies outside the "
                         f"walls, or the walls leave a gap")
    area = float(region.sum()) * grid.resolution**2
    if area < MIN_MAPPABLE_AREA:
        raise ValueError(f"world {world.name!r}: the start {world.start[:2]} is enclosed in "
                         f"{area:.2g} m² (inside a box?); at least {MIN_MAPPABLE_AREA:g} m² "
                         f"must be reachable")
    return region.astype(np.uint8)


def grid_cell(grid: OccupancyGrid, xy) -> tuple[int, int]:
    return (int(math.floor((xy[0] - grid.origin[0]) / grid.resolution)),
            int(math.floor((xy[1] - grid.origin[1]) / grid.resolution)))


@njit(cache=True)
def crop_probability(logodds, origin_x, origin_y, res, x, y, out):
    """Occupancy probability on a ``out``-sized window centred on (x, y), axis-aligned with the
    world, row 0 the lowest y; 0.5 (unknown) outside the grid."""
    h, w = logodds.shape
    size_y, size_x = out.shape
    cx = int(math.floor((x - origin_x) / res)) - size_x // 2
    cy = int(math.floor((y - origin_y) / res)) - size_y // 2
    for i in range(size_y):
        gy = cy + i
        for j in range(size_x):
            gx = cx + j
            if 0 <= gy < h and 0 <= gx < w and logodds[gy, gx] != 0.0:
                out[i, j] = 1.0 - 1.0 / (1.0 + math.exp(logodds[gy, gx]))
            else:
                out[i, j] = 0.5  # (what the formula gives at log-odds 0: unknown)


def map_error(world: World, poses, nodes, n_nodes: int, max_range: float = np.inf) -> float:
    """Mean distance (m) from the SLAM map's points — every node scan within ``max_range``,
    placed at its node's optimised pose — to the nearest wall of the world."""
    placed = []
    for k in range(n_nodes):
        pts = nodes.scan_points(k)
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= max_range]
        c, s = math.cos(poses[k, 2]), math.sin(poses[k, 2])
        placed.append(pts @ np.array([[c, s], [-s, c]]) + poses[k, :2])
    points = np.vstack(placed)
    best = np.full(len(points), np.inf)
    for seg in world.segments:
        np.minimum(best, point_segment_distance(points, seg), out=best)
    return float(best.mean())
