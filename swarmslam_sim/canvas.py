"""A raster canvas with a metric frame: the simulator's frames and the demos' figures are drawn
on it in metres (plain numpy, so ``rgb_array`` rendering needs no plotting library)."""

from __future__ import annotations

import numpy as np


class Canvas:
    """An RGB raster with a metric frame: draw points and polylines in metres."""

    def __init__(self, lo, hi, pixels_per_metre: float = 50.0, margin: int = 10,
                 background=(255, 255, 255)):
        self.lo = np.asarray(lo, dtype=np.float64)
        self.scale = float(pixels_per_metre)
        size = np.ceil((np.asarray(hi) - self.lo) * self.scale).astype(int) + 1 + 2 * margin
        self.margin = margin
        self.image = np.empty((size[1], size[0], 3), np.uint8)
        self.image[:] = background

    def _pixels(self, xy):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = np.round((xy[:, 0] - self.lo[0]) * self.scale).astype(int) + self.margin
        row = self.image.shape[0] - 1 - (
            np.round((xy[:, 1] - self.lo[1]) * self.scale).astype(int) + self.margin
        )
        ok = (row >= 0) & (row < self.image.shape[0]) & (col >= 0) & (col < self.image.shape[1])
        return row[ok], col[ok]

    def points(self, xy, colour, radius: int = 0):
        row, col = self._pixels(xy)
        for dr in range(-radius, radius + 1):
            for dc in range(-radius, radius + 1):
                r = np.clip(row + dr, 0, self.image.shape[0] - 1)
                c = np.clip(col + dc, 0, self.image.shape[1] - 1)
                self.image[r, c] = colour

    def polyline(self, xy, colour, radius: int = 0):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if len(xy) < 2:
            return self.points(xy, colour, radius)
        seg = np.diff(xy, axis=0)
        steps = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) * self.scale * 2), 1).astype(int)
        dense = [xy[k] + seg[k] * (np.arange(steps[k])[:, None] / steps[k]) for k in range(len(seg))]
        self.points(np.vstack(dense + [xy[-1:]]), colour, radius)
