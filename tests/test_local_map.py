import numpy as np
import pytest

from swarmslam.runtime.matching.distance_field import N_META, OX, OY, RES, build_distance_field
from swarmslam.runtime.matching.local_map import UNKNOWN, build_local_map, robot_square


def test_eq17_robot_square():
    # The spec's example: 0.05 m cells and a 0.15 m robot give (ρ+2)² = 25 cells.
    assert robot_square(0.15, 0.05) == 3
    assert robot_square(0.2, 0.05) == 5  # ⌈d/c⌉ = 4 is even → +1
    assert robot_square(0.35, 0.05) == 7
    with pytest.raises(ValueError):
        robot_square(0.0, 0.05)


def test_beams_free_ends_occupied_rest_unknown():
    angles = np.linspace(-0.5, 0.5, 41)
    pts = np.c_[2.0 * np.cos(angles), 2.0 * np.sin(angles)]
    field = np.zeros((256, 256), np.float32)
    grid = np.zeros((256, 256), np.uint8)
    meta = np.zeros(N_META)
    build_distance_field(pts, len(pts), 0.05, 0.5, 0.5, 0.0, field, meta, np.zeros(256),
                         np.zeros((256, 2), np.int64))
    build_local_map(pts, len(pts), field, meta, 0.0, 0.1, grid)

    def cell(x, y):
        return grid[int(round((y - meta[OY]) / meta[RES])), int(round((x - meta[OX]) / meta[RES]))]

    assert cell(2.0, 0.0) < 30  # beam end: occupied (0 at the point)
    assert cell(1.0, 0.0) == 255  # along the beam: free
    assert cell(1.0, 0.0) == 255 and cell(0.5, 0.1) == 255
    assert cell(-0.5, 0.9) == UNKNOWN  # behind the sensor: never seen
