"""The distance field must give the nearest-surface distance Eq. 14 needs."""

import numpy as np
from scipy.spatial import cKDTree

from swarmslam.runtime.matching.distance_field import (INDEXED, N_META, N_SURFACE, NX, NY,
                                               build_distance_field, cell_costs, column_centres,
                                               field_lookup, list_surfaces, splat_segment)
from swarmslam.runtime.matching.objectives import inlier_fraction, surface_inliers


def build(points, res=0.05, radius=0.5, gap=0.0, cells=512, inv_c2=0.0, bend=0.0,
          gap_ratio=2.0):
    field = np.zeros((cells, cells), np.float32)
    meta = np.zeros(N_META)
    build_distance_field(points, len(points), res, radius, gap, inv_c2, field, meta,
                         np.zeros(cells), np.zeros((cells, 2), np.int64), bend, gap_ratio)
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


def test_a_segment_lowers_every_node_within_its_radius_to_its_exact_squared_distance():
    # against every node of the window, by the same arithmetic: points, axis-parallel and
    # slanted segments, ones reaching past the window's edges
    rng = np.random.default_rng(4)
    ny, nx = 40, 50
    for trial in range(400):
        res, radius = rng.choice([0.05, 0.1, 0.037]), rng.choice([0.5, 0.3, 0.05])
        ox, oy = rng.uniform(-1.0, 1.0, 2)
        a = rng.uniform(-1.0, 3.0, 2)
        b = [a, a + [rng.uniform(-2, 2), 0.0], a + [0.0, rng.uniform(-2, 2)],
             a + rng.uniform(-0.1, 0.1, 2), rng.uniform(-2.0, 4.0, 2)][trial % 5]
        field = np.full((ny, nx), radius * radius)
        columns = np.zeros(nx)
        column_centres(ox, res, nx, columns)
        splat_segment(a[0], a[1], b[0], b[1], ox, oy, res, radius, nx, ny, field, columns)
        cx = ox + np.arange(nx)[None, :] * res
        cy = oy + np.arange(ny)[:, None] * res
        ux, uy = b[0] - a[0], b[1] - a[1]
        uu = ux * ux + uy * uy
        t = np.clip(((cx - a[0]) * ux + (cy - a[1]) * uy) / uu, 0.0, 1.0) if uu > 0 else 0.0
        d2 = (a[0] + t * ux - cx) ** 2 + (a[1] + t * uy - cy) ** 2
        assert np.array_equal(field, np.where(d2 < radius * radius, d2, radius * radius)), trial


def test_the_splat_stores_every_lane_rather_than_masking_the_lowered_ones():
    # Written as ``d2 if d2 < f else f``, the store-back select compiled to a masked store
    # (vmaskmovps), microcoded on AMD Zen: each build took 1.4 times as long. Compiled afresh
    # (a cached kernel cannot show its code), for both fields it lowers: the matcher's float32
    # and the place search's float64. (On a CPU without such stores, nothing to find.)
    from numba import njit

    kernel = njit(splat_segment.py_func)
    for dtype in (np.float32, np.float64):
        kernel(1.0, 1.0, 1.02, 1.01, 0.0, 0.0, 0.05, 0.5, 64, 64, np.zeros((64, 64), dtype),
               np.arange(64) * 0.05)
    code = "".join(kernel.inspect_asm().values())
    assert "maskmov" not in code


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


def grazing_wall(beams=7):
    """The end points of beams 1° apart from 2° on a wall 1 m to the side: seen grazing, they
    lie 9.6 m down to 1.03 m apart."""
    bearing = np.radians(2.0 + np.arange(beams))
    return np.c_[1.0 / np.tan(bearing), np.ones(beams)]


def test_a_wall_seen_grazing_is_one_surface_though_its_points_lie_metres_apart():
    wall = grazing_wall()
    gaps = np.hypot(*np.diff(wall, axis=0).T)
    assert gaps.min() > 1.0  # every pair beyond max_gap
    inner = 0.5 * (wall[3] + wall[4])  # on the wall between two end points, 1.9 m apart
    f0, m0 = build(wall, gap=1.0, cells=1024)
    f1, m1 = build(wall, gap=1.0, cells=1024, bend=np.radians(3.0))
    assert field_lookup(f0, m0, *inner) > 0.2  # bare points: the radius² far
    assert field_lookup(f1, m1, *inner) < 1e-3  # joined
    # the two end pairs have no pair beyond them to continue: they stay apart
    outer = 0.5 * (wall[0] + wall[1])
    assert field_lookup(f1, m1, *outer) > 0.2


def test_a_jump_in_depth_or_a_doorway_is_not_joined():
    bend = np.radians(3.0)
    # from a wall 1 m to the side to one 3 m to the side: the pair across turns off both lines
    jump = np.array([[12.0, 1.0], [10.0, 1.0], [7.0, 3.0], [5.0, 3.0]])
    f, m = build(jump, gap=1.0, bend=bend)
    assert field_lookup(f, m, 8.5, 2.0) > 0.2
    f, m = build(jump, gap=1.0, bend=np.radians(89.0))  # any bend allowed: joined
    assert field_lookup(f, m, 8.5, 2.0) < 1e-3
    # a doorway in a wall seen square on: the line continues, the spacing does not
    wall = np.c_[[0.0, 0.3, 0.6, 2.6, 2.9, 3.2], np.full(6, 2.0)]
    f, m = build(wall, gap=1.0, bend=bend)
    assert field_lookup(f, m, 1.6, 2.0) > 0.2
    f, m = build(wall, gap=1.0, bend=bend, gap_ratio=10.0)  # evenly enough at 10×: joined
    assert field_lookup(f, m, 1.6, 2.0) < 1e-3


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


def test_every_node_of_a_wide_window_takes_the_kernel_of_its_plain_distance():
    # The kernel is taken only over the columns each band of rows' segments reached, the
    # rest of a row set to the constant: every node must still hold exactly log1p(d²/c²), or the
    # constant beyond the radius, whether its row was reached or not.
    rng = np.random.default_rng(7)
    wall = np.c_[np.linspace(-3.0, 3.0, 40), np.full(40, 2.0)]
    far = rng.uniform(-20.0, 20.0, size=(12, 2))  # isolated returns: most rows meet none
    pts = np.concatenate([wall, far])
    for inv_c2 in (100.0, 204.08):
        plain, _ = build(pts, radius=0.5, gap=0.5, cells=1024)
        cauchy, meta = build(pts, radius=0.5, gap=0.5, cells=1024, inv_c2=inv_c2)
        nx, ny = int(meta[NX]), int(meta[NY])
        v = plain[:ny, :nx].astype(np.float64)
        want = np.where(v < 0.25, np.log1p(v * inv_c2), np.log1p(0.25 * inv_c2))
        assert nx > 700 and ny > 700
        np.testing.assert_array_equal(cauchy[:ny, :nx], want.astype(np.float32))


def listed(points, res=0.05, radius=0.5, gap=1.0, cells=512, inv_c2=0.0, bend=0.0,
           side=10, links=None):
    surfaces = np.zeros((len(points), N_SURFACE))
    tiling = np.array([side, 0, 0])
    heads = np.zeros((-(-cells // side)) ** 2, np.int64)
    links = np.zeros((100 * len(points) if links is None else links, 2), np.int64)
    meta = np.zeros(N_META)
    count = list_surfaces(points, len(points), res, radius, gap, inv_c2, cells, cells, meta,
                          surfaces, tiling, heads, links, bend, 2.0)
    return (surfaces, count, tiling, heads, links, meta)


def cells_read_wrong(surface_list, radius, inv_c2, field):
    """How many cells' four nodes, read from the list, differ from the built field's."""
    surfaces, count, tiling, heads, links, meta = surface_list
    nx, ny = int(meta[NX]), int(meta[NY])
    wrong = 0
    for i in range(ny - 1):
        for j in range(nx - 1):
            got = cell_costs(surfaces, count, tiling, heads, links, meta, radius, inv_c2, i, j)
            wrong += not np.array_equal(np.reshape(got, (2, 2)), field[i:i + 2, j:j + 2])
    return wrong


def test_a_listed_field_reads_every_node_as_the_built_field_holds_it():
    # to the bit: a room and clutter, both kernels, a window cut to its capacity, tiles of
    # several sides and an index too small to hold every segment (every segment read)
    rng = np.random.default_rng(11)
    cases = [dict(), dict(inv_c2=1 / 0.07 ** 2), dict(cells=64, inv_c2=1 / 0.07 ** 2),
             dict(side=3, bend=np.radians(3.0)), dict(links=5, inv_c2=1 / 0.07 ** 2),
             dict(radius=0.3, res=0.037, side=7)]
    for case in cases:
        pts = np.r_[noisy_room(rng, beams=300), rng.uniform(-3, 3, (40, 2))]
        field, meta = build(pts, gap=1.0, cells=case.get("cells", 512),
                            inv_c2=case.get("inv_c2", 0.0), bend=case.get("bend", 0.0),
                            res=case.get("res", 0.05), radius=case.get("radius", 0.5))
        surface_list = listed(pts, **case)
        assert np.array_equal(surface_list[-1], meta), case
        assert surface_list[2][INDEXED] == (0 if case.get("links") else 1), case
        assert cells_read_wrong(surface_list, case.get("radius", 0.5), case.get("inv_c2", 0.0),
                                field) == 0, case


def noisy_room(rng, beams=720, noise=0.01):
    """A scan of a 6 × 4 m room around the sensor, with range noise, in beam order."""
    bearing = np.linspace(-np.pi, np.pi, beams, endpoint=False)
    c, s = np.cos(bearing), np.sin(bearing)
    with np.errstate(divide="ignore"):
        r = np.minimum(np.abs(3.0 / c), np.abs(2.0 / s))
    r = r + rng.normal(0.0, noise, beams)
    return np.c_[r * c, r * s]


def test_listed_inliers_count_as_the_built_field_does_and_stop_where_asked():
    # the previous-scan check counts a match's inliers on a listed field and stops early: the
    # full count must be the built field's, and a count told to stop at k gives min(full, k)
    rng = np.random.default_rng(5)
    inv_c2, radius = 1 / 0.07 ** 2, 0.5
    ref = noisy_room(rng, beams=360)
    field, meta = build(ref, gap=1.0, inv_c2=inv_c2)
    surface_list = listed(ref, inv_c2=inv_c2, side=5)
    scan = noisy_room(rng, beams=360)
    n = len(scan)
    seen = set()
    for x, y, t in rng.normal(0.0, [0.15, 0.15, 0.08], (40, 3)):
        share = inlier_fraction(field, meta, scan, n, x, y, t, 0.2, 0.01, inv_c2)
        full = surface_inliers(*surface_list, radius, scan, n, x, y, t, 0.2, 0.01, inv_c2,
                               n + 1)
        assert full / n == share
        seen.add(full)
        for stop in {1, max(full - 1, 1), max(full, 1), full + 1, n}:
            got = surface_inliers(*surface_list, radius, scan, n, x, y, t, 0.2, 0.01, inv_c2,
                                  stop)
            assert got == min(full, stop), (stop, full, got)
    assert len(seen) > 10  # poses that fit well and poorly
