import math

import numpy as np
import pytest

from swarmslam.runtime.matching.scan import (PointScan, beam_directions, directions_to_points,
                                    ranges_to_points)


def test_invalid_readings_dropped():
    ranges = np.array([1.0, 0.0, np.nan, np.inf, 12.0, 2.0, -1.0])
    angles = np.linspace(-1, 1, 7)
    s = PointScan(16).set_ranges(ranges, angles, min_range=0.0, max_range=12.0)
    assert s.count == 2
    assert np.allclose(s.points[0], [math.cos(-1), math.sin(-1)])
    assert np.allclose(s.points[1], 2 * np.array([math.cos(angles[5]), math.sin(angles[5])]))


def test_uneven_angles_and_any_count():
    rng = np.random.default_rng(0)
    angles = np.sort(rng.uniform(-np.pi, np.pi, 333))  # an RPLidar rotation is never even
    ranges = rng.uniform(0.5, 5.0, 333)
    s = PointScan.from_ranges(ranges, angles)
    assert s.count == 333
    assert np.allclose(np.hypot(*s.points.T), ranges)
    assert np.allclose(np.arctan2(s.points[:, 1], s.points[:, 0]), angles)


def test_buffer_reused_without_reallocation():
    s = PointScan(100)
    buf = s.buffer
    s.set_ranges(np.ones(50), np.zeros(50))
    s.set_ranges(np.ones(10), np.zeros(10))
    assert s.buffer is buf and s.count == 10


@pytest.mark.parametrize(
    "ranges, angles, message",
    [
        ([], [], "empty scan"),
        ([0.0, np.nan, 99.0], [0.0, 0.1, 0.2], "all 3 readings are invalid"),
        ([1.0, 2.0], [0.0], "differ in length: 2 ranges, 1 angles"),
        ([[1.0]], [[0.0]], "must be 1-D"),
    ],
)
def test_bad_input_raises_clear_error(ranges, angles, message):
    with pytest.raises(ValueError, match=message):
        PointScan(8).set_ranges(ranges, angles, max_range=10.0)


def test_capacity_exceeded_is_named():
    with pytest.raises(ValueError, match="buffer holds 4"):
        PointScan(4).set_ranges(np.ones(5), np.zeros(5))


def test_fixed_directions_give_the_same_points_bit_for_bit():
    rng = np.random.default_rng(3)
    angles = np.r_[np.linspace(-math.pi, math.pi, 700, endpoint=False), np.nan]
    ranges = rng.uniform(-1.0, 14.0, angles.size)
    ranges[rng.random(angles.size) < 0.1] = np.inf
    ranges[5], ranges[6] = np.nan, 12.0  # unreadable; at the limit (no return)
    directions = np.zeros((angles.size, 2))
    beam_directions(angles, directions)
    for capacity in (1000, 300):  # and when the buffer fills
        a, b = np.zeros((capacity, 2)), np.zeros((capacity, 2))
        n = ranges_to_points(ranges, angles, 0.15, 12.0, a)
        assert directions_to_points(ranges, directions, 0.15, 12.0, b) == n
        assert 0 < n <= capacity and np.array_equal(a[:n], b[:n])
