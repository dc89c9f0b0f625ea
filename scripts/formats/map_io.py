"""Maps in ROS map_server format (PGM + YAML) and as PNG, written atomically.

map_server reads the PGM with row 0 at the top (highest y) and ``origin`` as the pose of the
lower-left pixel; map_saver's trinary values: 0 occupied, 254 free, 205 unknown.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarmslam.runtime.occupancy_grid import OccupancyGrid, probability
from swarmslam.runtime.realtime.writers import write_bytes_atomic, write_text_atomic
from swarmslam.formats.png import write_png

OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


def trinary_image(grid: OccupancyGrid) -> np.ndarray:
    """The grid in map_saver's trinary values, row 0 at the top."""
    return trinary_values(grid.logodds)[::-1]


def trinary_values(logodds) -> np.ndarray:
    """map_saver's trinary values of log-odds cells (any block of the grid's rows)."""
    p = probability(logodds)
    img = np.full(p.shape, 205, np.uint8)
    known = logodds != 0.0
    img[known & (p > OCCUPIED_THRESH)] = 0
    img[known & (p < FREE_THRESH)] = 254
    return img


def encode_pgm(image: np.ndarray) -> bytes:
    h, w = image.shape
    return f"P5\n{w} {h}\n255\n".encode("ascii") + np.ascontiguousarray(image).tobytes()


def write_map(stem, grid: OccupancyGrid) -> dict:
    """Write ``stem.pgm``, ``stem.yaml`` (map_server) and ``stem.png``; return the paths."""
    stem = Path(stem)
    img = trinary_image(grid)
    pgm = write_bytes_atomic(stem.with_suffix(".pgm"), encode_pgm(img))
    yaml = write_text_atomic(
        stem.with_suffix(".yaml"),
        f"image: {pgm.name}\n"
        f"mode: trinary\n"
        f"resolution: {grid.resolution:.6f}\n"
        f"origin: [{grid.origin[0]:.6f}, {grid.origin[1]:.6f}, 0.0]\n"
        f"negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n",
    )
    png = write_png(stem.with_suffix(".png"), img)
    return {"pgm": str(pgm), "yaml": str(yaml), "png": str(png)}


def read_pgm(path) -> np.ndarray:
    data = Path(path).read_bytes()
    parts = data.split(maxsplit=4)
    if parts[0] != b"P5":
        raise ValueError(f"{path}: not a binary PGM (P5)")
    w, h, maxval = int(parts[1]), int(parts[2]), int(parts[3])
    if maxval != 255:
        raise ValueError(f"{path}: only 8-bit PGM supported, maxval {maxval}")
    return np.frombuffer(parts[4][: w * h], np.uint8).reshape(h, w)
