"""Frames of the environment: the SLAM map, the true walls, both trajectories, the scan.

``rgb_array`` frames are plain numpy (uint8 H×W×3, drawn with the runtime's
:class:`~swarmslam_sim.canvas.Canvas`); ``human`` shows them in a pygame window (the optional ``human``
extra: ``pip install swarmslam[human]``).
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.occupancy_grid import OccupancyGrid
from swarmslam.runtime.pose import transform_points
from swarmslam_sim.canvas import Canvas

PIXELS_PER_METRE = 40
WALL = (40, 40, 40)
TRUE_PATH = (30, 160, 60)
ESTIMATED_PATH = (220, 40, 40)
SCAN = (50, 90, 230)


def map_shades(grid: OccupancyGrid) -> np.ndarray:
    """Grey level per cell: free white, occupied black, unknown light grey (map_server's look)."""
    p = grid.probability()
    shade = (255 * (1.0 - p)).astype(np.uint8)
    shade[grid.logodds == 0] = 205
    return shade


class Renderer:
    def __init__(self, world, grid: OccupancyGrid, mode: str, fps: int):
        self.world, self.grid, self.mode, self.fps = world, grid, mode, fps
        x0, y0, x1, y1 = world.bounds
        self.canvas = Canvas((x0, y0), (x1, y1), PIXELS_PER_METRE)
        h, w = self.canvas.image.shape[:2]
        m, s = self.canvas.margin, self.canvas.scale
        # each pixel's map cell, found once
        cols = (x0 + (np.arange(w) - m + 0.5) / s - grid.origin[0]) / grid.resolution
        rows = (y0 + (h - 1 - np.arange(h) - m + 0.5) / s - grid.origin[1]) / grid.resolution
        gh, gw = grid.logodds.shape
        self.cell_x = np.floor(cols).astype(int)
        self.cell_y = np.floor(rows).astype(int)
        self.inside = ((self.cell_y >= 0) & (self.cell_y < gh))[:, None] & \
                      ((self.cell_x >= 0) & (self.cell_x < gw))[None, :]
        self.cell_x = np.clip(self.cell_x, 0, gw - 1)
        self.cell_y = np.clip(self.cell_y, 0, gh - 1)
        self.window = self.clock = None

    def draw(self, env):
        img = self.canvas.image
        shade = map_shades(self.grid)[self.cell_y[:, None], self.cell_x[None, :]]
        img[:] = 255
        img[self.inside] = shade[self.inside][:, None]
        for x0, y0, x1, y1 in self.world.segments:
            self.canvas.polyline([(x0, y0), (x1, y1)], WALL)
        self.canvas.polyline(np.array(env.true_path)[:, :2], TRUE_PATH, radius=1)
        self.canvas.polyline(np.array(env.estimated_path)[:, :2], ESTIMATED_PATH, radius=1)
        self.canvas.points(transform_points(env.estimated_pose, env._scan.points), SCAN, radius=1)
        self._robot(env.true_pose, env.robot_radius, TRUE_PATH)
        self._robot(env.estimated_pose, env.robot_radius, ESTIMATED_PATH)
        if self.mode == "rgb_array":
            return img.copy()
        self._show(img)
        return None

    def _robot(self, pose, radius, colour):
        a = np.linspace(0, 2 * np.pi, 24)
        ring = np.c_[pose[0] + radius * np.cos(a), pose[1] + radius * np.sin(a)]
        self.canvas.polyline(ring, colour)
        self.canvas.polyline([pose[:2], pose[:2] + 1.5 * radius * np.array([np.cos(pose[2]), np.sin(pose[2])])],
                             colour)

    def _show(self, img):
        try:
            import pygame
        except ImportError as e:
            from gymnasium.error import DependencyNotInstalled

            raise DependencyNotInstalled(
                "render_mode='human' needs pygame: pip install 'swarmslam[human]'") from e
        if self.window is None:
            pygame.init()
            pygame.display.init()
            self.window = pygame.display.set_mode((img.shape[1], img.shape[0]))
            pygame.display.set_caption("SwarmSlam-v0")
            self.clock = pygame.time.Clock()
        pygame.event.pump()
        self.window.blit(pygame.surfarray.make_surface(np.ascontiguousarray(img.transpose(1, 0, 2))), (0, 0))
        pygame.display.flip()
        self.clock.tick(self.fps)

    def close(self):
        if self.window is not None:
            import pygame

            pygame.display.quit()
            pygame.quit()
            self.window = None
