"""A frontier-based exploration policy (Yamauchi 1997) on the SLAM map.

Every few steps: cells the map knows to be free and that leave the robot room (its radius plus
a margin from every occupied cell) are searched outward from the robot by Dijkstra, paths near
obstacles costing more; the nearest *frontier* — a free cell beside unknown ones — is the goal.
Between plans the robot steers at a point a little way along the path (pure pursuit). It uses
only what a real robot has: the estimated pose and the SLAM map.
"""

from __future__ import annotations

import heapq
import math

import numpy as np
from numba import njit
from scipy import ndimage

from swarmslam.runtime.occupancy_grid import OccupancyGrid
from swarmslam_sim.mapping import grid_cell

NO_GOAL = -1


@njit(cache=True)
def plan_to_frontier(passable, frontier, cost_extra, start, dist, parent):
    """Dijkstra over 8-connected ``passable`` cells from cell index ``start``; returns the
    index of the nearest ``frontier`` cell (``NO_GOAL`` if none is reachable). ``dist`` and
    ``parent`` (flat, one per cell) are filled for the path back."""
    h, w = passable.shape
    dist[:] = np.inf
    parent[:] = -1
    dist[start] = 0.0
    heap = [(0.0, start)]
    while len(heap) > 0:
        d, c = heapq.heappop(heap)
        if d > dist[c]:
            continue
        y, x = c // w, c % w
        if frontier[y, x] and c != start:
            return c
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if dx == 0 and dy == 0:
                    continue
                ny, nx = y + dy, x + dx
                if ny < 0 or ny >= h or nx < 0 or nx >= w or not passable[ny, nx]:
                    continue
                n = ny * w + nx
                nd = d + (1.4142135623730951 if dx != 0 and dy != 0 else 1.0) + cost_extra[ny, nx]
                if nd < dist[n]:
                    dist[n] = nd
                    parent[n] = c
                    heapq.heappush(heap, (nd, n))
    return NO_GOAL


class FrontierExplorer:
    """``act(pose, grid, in_contact)`` → action in [-1, 1]² for ``SwarmSlam-v0``."""

    def __init__(self, robot_radius: float = 0.17, margin: float = 0.08, comfort: float = 0.45,
                 max_angular: float = 1.5, replan_every: int = 4, lookahead: float = 0.5):
        self.robot_radius, self.margin, self.comfort = robot_radius, margin, comfort
        self.max_angular = max_angular
        self.replan_every, self.lookahead = replan_every, lookahead
        self.path = np.zeros((0, 2))
        self.steps_since_plan = replan_every
        self.backing_up = 0
        self.done = False  # no reachable frontier left

    @classmethod
    def for_env(cls, env, **kwargs) -> "FrontierExplorer":
        u = env.unwrapped
        return cls(robot_radius=u.robot_radius, max_angular=u.max_angular, **kwargs)

    def act(self, pose, grid: OccupancyGrid, in_contact: bool = False) -> np.ndarray:
        if in_contact or self.backing_up:  # bumped: back off, then plan afresh
            self.backing_up = 2 if in_contact else self.backing_up - 1
            self.steps_since_plan = self.replan_every
            return np.array([-0.6, 0.0], np.float32)
        if self.steps_since_plan >= self.replan_every or len(self.path) == 0:
            self.path = self.plan(pose, grid)
            self.steps_since_plan = 0
        self.steps_since_plan += 1
        if len(self.path) == 0:
            return np.array([0.0, 0.0], np.float32)
        return self.follow(pose)

    def plan(self, pose, grid: OccupancyGrid) -> np.ndarray:
        """Path (cell centres, metres) from the robot to the nearest frontier; empty if none."""
        lo, res = grid.logodds, grid.resolution
        occupied = lo > 0
        unknown = lo == 0
        free = lo < 0
        clearance = ndimage.distance_transform_edt(~occupied) * res
        passable = free & (clearance >= self.robot_radius + self.margin)
        near_unknown = ndimage.binary_dilation(unknown, structure=np.ones((3, 3), bool))
        frontier = passable & near_unknown
        # isolated one-cell frontiers are noise: keep those with frontier neighbours
        frontier &= ndimage.convolve(frontier.astype(np.uint8), np.ones((3, 3), np.uint8),
                                     mode="constant") >= 3
        cost_extra = np.clip(self.comfort - clearance, 0.0, None) * (8.0 / res)
        h, w = lo.shape
        sx, sy = grid_cell(grid, pose)
        sx, sy = min(max(sx, 0), w - 1), min(max(sy, 0), h - 1)
        passable[sy, sx] = True  # the robot's own cell, even when it hugs a wall
        start = sy * w + sx
        dist = np.empty(h * w)
        parent = np.empty(h * w, np.int64)
        goal = plan_to_frontier(passable, frontier, cost_extra, start, dist, parent)
        if goal == NO_GOAL:
            self.done = True
            return np.zeros((0, 2))
        self.done = False
        cells = [goal]
        while parent[cells[-1]] >= 0:
            cells.append(parent[cells[-1]])
        cells = np.array(cells[::-1])
        return np.c_[grid.origin[0] + (cells % w + 0.5) * res, grid.origin[1] + (cells // w + 0.5) * res]

    def follow(self, pose) -> np.ndarray:
        d = np.hypot(self.path[:, 0] - pose[0], self.path[:, 1] - pose[1])
        nearest = int(np.argmin(d))
        self.path = self.path[nearest:]
        ahead = np.nonzero(d[nearest:] >= self.lookahead)[0]
        target = self.path[ahead[0]] if len(ahead) else self.path[-1]
        if len(ahead) == 0 and d[-1] < 0.15:
            self.path = np.zeros((0, 2))  # reached: plan again next step
        error = math.atan2(target[1] - pose[1], target[0] - pose[0]) - pose[2]
        error = (error + math.pi) % (2 * math.pi) - math.pi
        angular = np.clip(2.0 * error / self.max_angular, -1.0, 1.0)
        linear = max(0.0, math.cos(error)) ** 3 if abs(error) < 1.0 else 0.0
        return np.array([linear, angular], np.float32)
