"""The distance field must give the nearest-surface distance Eq. 14 needs."""

import numpy as np
from scipy.spatial import cKDTree

from runtime.distance_field import N_META, NX, NY, build_distance_field, field_lookup


def build(points, res=0.05, radius=0.5, gap=0.0, cells=512, inv_c2=0.0):
    field = np.zeros((cells, cells), np.float32)
    meta = np.zeros(N_META)
    build_distance_field(points, len(points), res, radius, gap, inv_c2, field, meta)
    return field, meta


def test_point_field_matches_kdtree_within_interpolation_error():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-4, 4, size=(150, 2))
    field, meta = build(pts, radius=1.0)
    q = rng.uniform(-4, 4, size=(2000, 2))
    exact = np.minimum(cKDTree(pts).query(q)[0], 1.0)
    got = np.sqrt([field_lookup(field, meta, x, y) for x, y in q])
    # Bilinear interpolation of d² on 5 cm nodes: error of order the cell size.
    assert np.max(np.abs(got - exact)) < 0.05
    assert np.median(np.abs(got - exact)) < 0.01


def test_truncated_at_radius_and_outside_window():
    pts = np.array([[0.0, 0.0], [1.0, 0.0]])
    field, meta = build(pts, radius=0.3)
    assert field_lookup(field, meta, 0.5, 0.0) == np.float32(0.09)
    assert field_lookup(field, meta, 100.0, 100.0) == meta[5]  # R2 outside the grid


def test_surface_joins_close_neighbours_only():
    wall = np.c_[np.linspace(0, 2, 5), np.zeros(5)]  # 0.5 m apart
    q = (0.25, 0.0)  # midway between two end points, on the wall
    f0, m0 = build(wall, gap=0.0)
    f1, m1 = build(wall, gap=0.6)
    assert field_lookup(f0, m0, *q) > 0.05  # 0.25² away from either point
    assert field_lookup(f1, m1, *q) < 1e-3  # on the joined surface
    f2, m2 = build(wall, gap=0.4)  # gap too small to join
    assert field_lookup(f2, m2, *q) > 0.05


def test_window_is_capped_at_capacity():
    pts = np.array([[-100.0, 0.0], [0.5, 0.5], [100.0, 0.0]])
    field, meta = build(pts, cells=64)
    assert meta[NX] == 64 and meta[NY] <= 64
    # The near point is kept (the window centres on the sensor); bilinear d² is off by ~res²/4.
    assert field_lookup(field, meta, 0.5, 0.5) < 0.002


def test_cauchy_kernel_baked_into_field():
    pts = np.array([[0.0, 0.0], [3.0, 0.0]])
    plain, m0 = build(pts, radius=0.5)
    cauchy, m1 = build(pts, radius=0.5, inv_c2=100.0)  # c = 0.1 m
    for q in [(0.2, 0.0), (0.0, 0.35), (1.5, 0.0), (50.0, 0.0)]:
        d2 = field_lookup(plain, m0, *q)
        assert np.isclose(field_lookup(cauchy, m1, *q), np.log1p(100.0 * d2), rtol=0.05)
