"""The LiDAR model: the compiled caster against pymunk, geometry, noise, dropout, presets."""

import math

import numpy as np
import pytest

from swarmslam_sim.catalog import get_world
from swarmslam_sim.lidar import PRESETS, Lidar, LidarConfig, lidar_config
from swarmslam_sim.physics import build_space, pymunk_scan
from swarmslam_sim.raycast import hit_capsule, point_segment_distance
from swarmslam_sim.world import World

SQUARE = World("square", np.array([[0, 0, 4, 0], [4, 0, 4, 4], [4, 4, 0, 4], [0, 4, 0, 0]], float),
               (-0.5, -0.5, 4.5, 4.5), (1.0, 2.0, 0.0))


def free_poses(world, count, seed=0, clearance=0.2):
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = world.bounds
    out = []
    while len(out) < count:
        p = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1), rng.uniform(-math.pi, math.pi)])
        if min(point_segment_distance(p[None, :2], s)[0] for s in world.segments) > clearance:
            out.append(p)
    return out


@pytest.mark.parametrize("name", ["office", "maze", "clutter", "rooms"])
def test_compiled_caster_agrees_with_pymunk(name):
    world = get_world(name, seed=2)
    lidar = Lidar(world, PRESETS["rplidar-a1"])
    space = build_space(world)
    for pose in free_poses(world, 25):
        ours = lidar.cast(pose)
        reference = pymunk_scan(space, pose, lidar.angles, lidar.config.max_range)
        assert np.array_equal(np.isfinite(ours), np.isfinite(reference))
        hit = np.isfinite(ours)
        assert hit.sum() > 100
        assert np.max(np.abs(ours[hit] - reference[hit])) < 1e-9


def test_walls_are_seen_at_the_distance_geometry_gives():
    lidar = Lidar(SQUARE, LidarConfig(beams=4, noise_std=0.0))  # beams at -π, -π/2, 0, π/2
    ranges = lidar.scan((1.0, 2.0, 0.0), np.random.default_rng(0))
    assert np.allclose(ranges, [1.0, 2.0, 3.0, 2.0])
    turned = lidar.scan((1.0, 1.5, math.pi / 2), np.random.default_rng(0))
    assert np.allclose(turned, [1.5, 3.0, 2.5, 1.0])  # south, east, north, west
    far = Lidar(SQUARE, LidarConfig(beams=4, noise_std=0.0, max_range=2.2))
    assert np.allclose(far.scan((1.0, 2.0, 0.0), np.random.default_rng(0)), [1.0, 2.0, 2.2, 2.0])


def test_thick_walls_are_capsules():
    seg = np.array([0.0, 1.0, 2.0, 1.0])
    assert hit_capsule(1.0, 0.0, 0.0, 1.0, seg, 0.1) == pytest.approx(0.9)  # the flat side
    assert hit_capsule(-1.0, 1.0, 1.0, 0.0, seg, 0.1) == pytest.approx(0.9)  # the end cap
    assert hit_capsule(1.0, 0.0, 0.0, -1.0, seg, 0.1) == math.inf  # facing away


def test_noise_and_dropout_follow_the_config():
    config = LidarConfig(beams=2000, noise_std=0.02, dropout=0.1, max_range=12.0)
    lidar = Lidar(SQUARE, config)
    exact = lidar.cast((2.0, 2.0, 0.3)).copy()
    ranges = lidar.scan((2.0, 2.0, 0.3), np.random.default_rng(1))
    dropped = ranges == config.max_range
    assert 0.07 < dropped.mean() < 0.13
    assert np.std(ranges[~dropped] - exact[~dropped]) == pytest.approx(0.02, rel=0.15)
    again = lidar.scan((2.0, 2.0, 0.3), np.random.default_rng(1)).copy()
    assert np.array_equal(again, ranges)  # the generator decides everything


def test_one_pass_of_noise_dropout_and_no_return_is_the_array_operations_bit_for_bit():
    """Noise, dropouts and the no-return rule are applied in one compiled pass: the same ranges
    as the array operations they replace, from the same draws."""
    config = LidarConfig(beams=720, noise_std=0.03, dropout=0.05, max_range=6.0)
    lidar = Lidar(get_world("office"), config)
    for seed, pose in enumerate(free_poses(get_world("office"), 5)):
        exact = lidar.cast(pose).copy()
        ranges = lidar.scan(pose, np.random.default_rng(seed))
        rng = np.random.default_rng(seed)
        expected = exact + rng.standard_normal(720) * 0.03
        expected[rng.random(720) < 0.05] = np.inf
        expected[(expected < config.min_range) | ~(expected < config.max_range)] = 6.0
        assert np.array_equal(ranges, expected)
        assert (ranges == 6.0).any() and (ranges < 6.0).any()


def test_presets_and_configs():
    a1, lms = PRESETS["rplidar-a1"], PRESETS["lms200"]
    assert a1.beams == 360 and a1.max_range == 12.0
    assert np.allclose(np.diff(a1.angles()), math.radians(1.0)) and a1.angles()[0] == -math.pi
    assert np.allclose(lms.angles()[[0, -1]], [-math.pi / 2, math.pi / 2])
    assert lidar_config({"preset": "rplidar-a2", "beams": 100}).beams == 100
    with pytest.raises(ValueError, match="unknown LiDAR preset 'velodyne'"):
        lidar_config("velodyne")
    with pytest.raises(ValueError, match="min_range < max_range"):
        LidarConfig(min_range=5.0, max_range=4.0)
