"""Minimal PNG encoding (8-bit grey or RGB) and a raster canvas for plots and maps.

The runtime must deploy with numpy/scipy/numba only, so it writes its own figures: PNG is a
zlib stream of filtered rows in CRC-checked chunks (RFC 2083), a few lines of code.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from runtime.writers import write_bytes_atomic


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of a uint8 image, ``H×W`` (grey) or ``H×W×3`` (RGB)."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"need uint8 H×W or H×W×3, got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    colour = 0 if img.ndim == 2 else 2
    rows = img.reshape(h, -1)
    raw = np.zeros((h, rows.shape[1] + 1), np.uint8)  # filter byte 0 (None) per row
    raw[:, 1:] = rows

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data) & 0xFFFFFFFF
        )

    header = struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6)) + chunk(b"IEND", b""))


def write_png(path, image: np.ndarray):
    return write_bytes_atomic(path, encode_png(image))


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
