"""A prior map for localization in the simulator: a saved session's, or one surveyed from the
world as a perfect mapping run would have left it."""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.localization.map_tracking import SavedMap
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.session import read_session
from swarmslam_sim.lidar import Lidar
from swarmslam_sim.mapping import wall_clearance, world_grid
from swarmslam_sim.world import World


def surveyed_map(world: World, lidar: Lidar, spacing: float = 1.0,
                 clearance: float = 0.4) -> SavedMap:
    """Exact scans (no noise) taken every ``spacing`` m over the reachable free space at least
    ``clearance`` m from any wall, each a node at its true pose (heading 0)."""
    grid = world_grid(world, 0.1)
    ok = (grid.region != 0) & (wall_clearance(world, grid) >= clearance)
    step = max(int(round(spacing / grid.resolution)), 1)
    rows, cols = np.nonzero(ok[::step, ::step])
    if len(rows) == 0:
        raise ValueError(f"world {world.name!r}: no free place {clearance} m from the walls "
                         f"to survey")
    res = grid.resolution
    poses = np.zeros((len(rows), 3))
    poses[:, 0] = grid.origin[0] + (cols * step + 0.5) * res
    poses[:, 1] = grid.origin[1] + (rows * step + 0.5) * res
    c = lidar.config
    nodes = NodeScans(len(poses), c.beams)
    scan = PointScan(c.beams)
    ranges = np.zeros(c.beams)
    for k, pose in enumerate(poses):
        lidar.cast(pose, ranges)
        scan.set_ranges(ranges, lidar.angles, c.min_range, c.max_range)
        nodes.store(k, scan)
    return SavedMap(poses, nodes, len(poses))


def session_map(path) -> SavedMap:
    """The map of a saved session file (``swarmslam replay`` / ``lidar`` write them)."""
    state = read_session(path)
    counts = np.asarray(state["slam"]["nodes"]["counts"])
    return SavedMap.from_state(state["slam"], max(int(counts.max(initial=0)), 1))
