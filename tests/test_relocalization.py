"""Global relocalization (swarmslam.runtime.matching.place_search, swarmslam.runtime.localization.relocalization): the branch-and-bound
search is exact, a kidnapped robot is found with no prior, and a symmetric world is called
ambiguous rather than answered wrongly."""

import math
import tracemalloc

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.matching.place_search import (
    HIT_MAX,
    SEARCH_STATE,
    UNLIMITED,
    PlaceMap,
    _score,
    _score_children,
    bound_shift,
    branch_and_bound,
    pool_bounds,
    pool_level,
    pool_pyramid,
    refine_candidates,
    rotate_query,
    select_query,
)
from swarmslam.runtime.pose import between
from swarmslam.runtime.localization.relocalization import Ambiguous, Located, Relocalizer
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at

ANGLES = np.linspace(-np.pi, np.pi, 360, endpoint=False)
# the test worlds are small enough for the exact search: this searches them coarse to fine
COARSE_TO_FINE = override(SlamConfig(), {"relocalization.exact_max_cells": 0})


def map_from(world, poses, max_range=12.0):
    """Node scans taken at known poses: the map a perfect mapping run would have saved."""
    nodes = NodeScans(len(poses), len(ANGLES))
    scan = PointScan(len(ANGLES))
    for k, p in enumerate(poses):
        scan.set_ranges(scan_at(world, p, ANGLES, max_range), ANGLES, 0.05, max_range)
        nodes.store(k, scan)
    return np.asarray(poses, np.float64), nodes


def query(world, pose, rng, max_range=12.0):
    ranges = scan_at(world, pose, ANGLES, max_range, noise=0.01, rng=rng)
    return PointScan.from_ranges(ranges, ANGLES, 0.05, max_range)


def close(a, b, distance=0.3, angle=math.radians(5)):
    e = between(a, b)
    return math.hypot(e[0], e[1]) <= distance and abs(e[2]) <= angle


def random_search(rng, ny, nx, groups, hit_share, free_box, free_share, reach, n_headings, n):
    """A random hit grid with its bounds, a box of standable cells, a query of ``n`` points
    within ``reach`` m (0.1 m cells) rotated to ``n_headings`` headings, and brute force's score
    of every pose (heading, row, column; 0 where the robot cannot stand)."""
    levels = len(groups) - 1
    shifts = np.array([bound_shift(int(g)) for g in groups], np.int64)
    pyramid = np.zeros((levels + 2, ny, nx), np.uint8)
    pyramid[0] = rng.integers(0, 256, size=(ny, nx)) * (rng.random((ny, nx)) < hit_share)
    pool_pyramid(pyramid)
    bounds = np.zeros((levels + 1, ny, nx), np.uint8)
    pool_bounds(pyramid, shifts, bounds)
    free = np.zeros((levels + 1, ny, nx), np.uint8)
    rows, cols = free_box
    free[0, rows, cols] = rng.random((rows.stop - rows.start, cols.stop - cols.start)) < free_share
    pool_pyramid(free)
    points = rng.uniform(-reach, reach, size=(n, 2))
    offsets = np.zeros((n_headings, n, 2), np.int64)
    extent = np.zeros((n_headings, 4), np.int64)
    rotate_query(points, n, 0.1, 2 * math.pi / n_headings, n_headings, offsets, extent)
    brute = np.zeros((n_headings, ny, nx), np.int64)
    for a in range(n_headings):
        for i, j in zip(*np.nonzero(free[0])):
            r, q = i + offsets[a, :, 0], j + offsets[a, :, 1]
            ok = (r >= 0) & (r < ny) & (q >= 0) & (q < nx)
            brute[a, i, j] = int(pyramid[0][r[ok], q[ok]].astype(np.int64).sum())
    return bounds, shifts, free, offsets, extent, brute


def test_branch_and_bound_finds_the_exact_best_pose():
    """Against brute force over every standable cell and heading of a random map."""
    n_headings, n = 24, 12
    groups = np.array([1, 1, 2, 4], np.int64)
    bounds, shifts, free, offsets, extent, brute = random_search(
        np.random.default_rng(4), 40, 52, groups, 0.3, (slice(8, 32), slice(10, 44)), 0.5,
        0.6, n_headings, n)  # points within 6 cells
    roots = np.zeros((n_headings * 64, 5), np.int64)
    stack = np.zeros((64, 5), np.int64)
    found = np.zeros((4, 4), np.int64)
    state = np.zeros(SEARCH_STATE, np.int64)
    n_found, scored, done = branch_and_bound(bounds, shifts, groups, free, offsets, extent,
                                             n, n_headings, 1, 1.0, 0, 0, roots, stack, found,
                                             state, UNLIMITED)
    assert done and n_found == 1
    assert found[0, 0] == brute.max()
    assert brute[found[0, 1], found[0, 2], found[0, 3]] == brute.max()
    assert scored < brute.size  # and it scored fewer blocks than there are poses
    # sliced, 7 blocks at a time: the same blocks in the same order, so the same answer
    whole = found.copy()
    found[:], state[:], slices = 0, 0, 0
    while True:
        n_sliced, scored_sliced, done = branch_and_bound(
            bounds, shifts, groups, free, offsets, extent, n, n_headings, 1, 1.0, 0, 0, roots,
            stack, found, state, 7)
        slices += 1
        if done:
            break
    assert (n_sliced, scored_sliced) == (n_found, scored) and np.array_equal(found, whole)
    assert slices >= scored // 15  # a slice scores its budget and one block's children at most


def test_a_headings_box_holds_every_offset():
    rng = np.random.default_rng(3)
    points = rng.uniform(-2.0, 2.0, size=(30, 2))
    offsets = np.zeros((12, 40, 2), np.int64)
    extent = np.full((12, 4), 99, np.int64)
    rotate_query(points, 30, 0.1, 2 * math.pi / 12, 12, offsets, extent)
    rows, cols = offsets[:, :30, 0], offsets[:, :30, 1]
    assert np.array_equal(extent, np.c_[rows.min(1), rows.max(1), cols.min(1), cols.max(1)])


def test_four_blocks_scored_together_score_as_one_at_a_time():
    """Each block's exact score where it reaches the floor, below the floor where it does not
    (as one at a time: every caller drops those), a block left out below it; blocks whose
    points fall off the grid (its edges) included."""
    n_headings, n = 8, 15
    bounds, shifts, free, offsets, extent, brute = random_search(
        np.random.default_rng(11), 30, 34, np.ones(4, np.int64), 0.6, (slice(0, 30),
                                                                       slice(0, 34)),
        1.0, 0.8, n_headings, n)
    rng = np.random.default_rng(12)
    reached = short = inside = 0
    for _ in range(3000):
        h = int(rng.integers(0, 3))
        half = 1 << h
        i, j = int(rng.integers(0, 30 - half)), int(rng.integers(0, 34 - half))
        a = int(rng.integers(0, n_headings))
        floor = int(rng.integers(1, n * HIT_MAX))
        on = rng.random(4) < 0.8
        inside += (i + extent[a, 0] >= 0 and i + half + extent[a, 1] < 30
                   and j + extent[a, 2] >= 0 and j + half + extent[a, 3] < 34)
        together = _score_children(bounds, h, 0, offsets, extent, a, n, i, j, half, floor,
                                   *on)
        for c, (ii, jj) in enumerate(((i, j), (i, j + half), (i + half, j),
                                      (i + half, j + half))):
            alone = _score(bounds, h, 0, offsets, a, n, ii, jj, floor)
            if not on[c]:
                assert together[c] < floor
            elif alone >= floor:
                assert together[c] == alone
                reached += 1
            else:
                assert together[c] < floor
                short += 1
    assert reached > 100 and short > 100  # both kinds of score seen often,
    assert 300 < inside < 2700  # and both blocks wholly on the grid and blocks at its edges


def test_a_full_list_of_poses_is_the_top_of_brute_force():
    """With room for K poses the search keeps the K best (the floor rises to the K-th once the
    list is full, which prunes without changing the answer)."""
    n_headings, n, k = 16, 10, 6
    groups = np.ones(4, np.int64)
    # standable cells within the points' reach of the edges: bounds stay exact
    bounds, shifts, free, offsets, extent, brute = random_search(
        np.random.default_rng(8), 32, 36, groups, 0.4, (slice(8, 24), slice(8, 28)), 1.0,
        0.5, n_headings, n)
    found = np.zeros((k, 4), np.int64)
    n_found, _, _ = branch_and_bound(bounds, shifts, groups, free, offsets, extent, n,
                                     n_headings, 1, 0.01, 0, 0,
                                     np.zeros((n_headings * 64, 5), np.int64),
                                     np.zeros((64, 5), np.int64), found,
                                     np.zeros(SEARCH_STATE, np.int64), UNLIMITED)
    assert n_found == k
    standable = brute[:, free[0] == 1]
    assert found[:, 0].tolist() == sorted(standable.ravel().tolist(), reverse=True)[:k]


def test_the_coarse_to_fine_search_answers_as_the_exhaustive_one(room):
    """Two passes (coarse to fine) and one exact branch and bound on the fine grid give the same
    kind of answer, and the same pose within a cell and a heading step, on kidnapped scans."""
    world, path, relocalizer = room
    poses, nodes = relocalizer.poses, relocalizer.nodes
    exact = Relocalizer(SlamConfig(), poses, nodes, len(poses))
    assert exact.coarse is None and relocalizer.coarse is not None
    rng = np.random.default_rng(9)
    for _ in range(12):
        k = rng.integers(len(path))
        truth = path[k] + [rng.normal(0, 0.3), rng.normal(0, 0.3), rng.uniform(-np.pi, np.pi)]
        q = query(world, truth, rng)
        pts = np.zeros((q.count, 2))
        n = select_query(q.buffer, q.count, 20.0, 0.2, 96, pts)
        two, one = relocalizer.search(pts, n), exact.search(pts, n)
        assert len(two) == len(one), (truth, two, one)
        for (p, s), (pe, se) in zip(two, one):
            assert close(p, pe, 0.11, 0.02) and s == pytest.approx(se, abs=0.02), (p, pe)


@pytest.fixture(scope="module")
def room():
    path = loop_path(60)
    world = room_world(3, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    poses, nodes = map_from(world, path)
    return world, path, Relocalizer(COARSE_TO_FINE, poses, nodes, len(poses))


def test_a_kidnapped_robot_is_found_with_no_prior(room):
    world, path, relocalizer = room
    rng = np.random.default_rng(1)
    answers = []
    for _ in range(20):
        k = rng.integers(len(path))
        truth = path[k] + [rng.normal(0, 0.2), rng.normal(0, 0.2), rng.uniform(-np.pi, np.pi)]
        answer = relocalizer.relocalize(query(world, truth, rng))
        assert not isinstance(answer, Located) or close(answer.pose, truth), (truth, answer)
        answers.append(answer)
    found = sum(isinstance(a, Located) for a in answers)
    assert found >= 18, f"found {found} of 20"


@pytest.mark.parametrize("config", [SlamConfig(), COARSE_TO_FINE], ids=["exact", "coarse"])
def test_two_identical_rooms_are_ambiguous_not_wrong(config):
    room = room_world(5, size=(6.0, 5.0), boxes=4, walls=1)
    twin = room + [8.0, 0.0, 8.0, 0.0]  # the same room, 8 m to the right, walls apart
    world = np.vstack([room, twin])
    poses = [(x + dx, y, t) for dx in (0.0, 8.0)
             for x, y, t in ((1.5, 1.5, 0.0), (4.5, 1.5, 1.6), (4.5, 3.5, 3.1), (1.5, 3.5, -1.6),
                             (3.0, 2.5, 0.8))]
    poses, nodes = map_from(world, poses)
    relocalizer = Relocalizer(config, poses, nodes, len(poses))
    assert (relocalizer.coarse is None) == (config is not COARSE_TO_FINE)
    rng = np.random.default_rng(2)
    for truth in ((2.5, 2.0, 0.4), (10.8, 3.0, -2.0)):
        answer = relocalizer.relocalize(query(world, truth, rng))
        assert isinstance(answer, Ambiguous), answer
        assert len(answer.poses) >= 2
        # both rooms are among the explanations, each at the matching place in its room
        assert any(close(p, truth) for p in answer.poses)
        mirror = (truth[0] + (8.0 if truth[0] < 8 else -8.0), truth[1], truth[2])
        assert any(close(p, mirror) for p in answer.poses)


def test_a_search_spread_over_slices_answers_as_one_call(room):
    """Relocalizer.begin / Search.advance (a runtime spreading the search over ticks): both
    passes sliced give the answer of one call, bit for bit, coarse to fine and exact."""
    world, path, relocalizer = room
    poses, nodes = relocalizer.poses, relocalizer.nodes
    rng = np.random.default_rng(10)
    for config in (COARSE_TO_FINE, SlamConfig()):
        searcher = Relocalizer(override(config, {"relocalization.slice_blocks": 50}), poses,
                               nodes, len(poses))
        for _ in range(4):
            truth = path[rng.integers(len(path))] + [0.0, 0.0, rng.uniform(-np.pi, np.pi)]
            scan = query(world, truth, rng)
            searcher.matcher.optimizer.reseed(3)  # the polish's swarm draws the same
            whole = searcher.relocalize(scan)
            searcher.matcher.optimizer.reseed(3)
            search, ticks = searcher.begin(scan), 1
            while not search.advance(clock=lambda: 1.0, until=0.0):  # one slice per call
                ticks += 1
            sliced = search.answer
            assert ticks > 10 and type(sliced) is type(whole), (ticks, whole, sliced)
            if isinstance(whole, Located):
                assert np.array_equal(sliced.pose, whole.pose) and sliced.score == whole.score
            else:
                assert all(np.array_equal(a, b) for a, b in zip(sliced.poses, whole.poses))
                assert sliced.scores == whole.scores


def test_a_scan_from_elsewhere_is_not_placed(room):
    _, _, relocalizer = room
    other = room_world(11, size=(7.0, 14.0), boxes=3, walls=2)
    answer = relocalizer.relocalize(query(other, (3.5, 7.0, 0.2), np.random.default_rng(3)))
    assert isinstance(answer, Ambiguous) and not answer.poses, answer
    # points beyond every wall of the map: the coarse pass keeps no candidate at all
    far = PointScan(64)
    far.set_points(np.c_[np.linspace(16.0, 19.5, 64), np.zeros(64)])  # (within query_range)
    answer = relocalizer.relocalize(far)
    assert isinstance(answer, Ambiguous) and not answer.poses, answer


def test_confirmation_merges_scans_by_their_motion(room):
    world, path, relocalizer = room
    rng = np.random.default_rng(5)
    window = path[10:16]
    scans = [query(world, p, rng) for p in window]
    motions = [between(p, window[-1]) for p in window]
    answer = relocalizer.relocalize_merged(scans, motions)
    assert isinstance(answer, Located) and close(answer.pose, window[-1], 0.1), answer


def test_the_map_must_fit_its_cell_capacity(room):
    world, path, _ = room
    poses, nodes = map_from(world, path[:5])
    config = override(SlamConfig(), {"relocalization.max_cells": 1000})
    with pytest.raises(ValueError, match="relocalization.max_cells"):
        Relocalizer(config, poses, nodes, len(poses))


def test_the_search_allocates_nothing_after_warm_up(room):
    """Both compiled passes: the coarse branch and bound and the fine windows."""
    world, path, relocalizer = room
    coarse, place = relocalizer.coarse, relocalizer.place
    rng = np.random.default_rng(6)
    q = query(world, path[3], rng)
    n = 64
    pts = np.ascontiguousarray(q.points[:: max(q.count // n, 1)][:n])
    n = len(pts)
    n_coarse = relocalizer._coarse_offsets.shape[0]
    offsets = np.zeros((n_coarse, n, 2), np.int64)
    extent = np.zeros((n_coarse, 4), np.int64)
    rotate_query(pts, n, coarse.resolution, 2 * math.pi / n_coarse, n_coarse, offsets, extent)
    coarse_args = (coarse.bounds, coarse.shifts, coarse.groups, coarse.free, offsets, extent, n,
                   n_coarse, int(0.5 * HIT_MAX * n), 0.8, 1, 4, relocalizer._roots,
                   relocalizer._stack, relocalizer._coarse_found, relocalizer._state, UNLIMITED)
    relocalizer._state[:] = 0
    n_candidates, _, _ = branch_and_bound(*coarse_args)
    assert n_candidates > 0
    rotate_query(pts, n, place.resolution, 2 * math.pi / relocalizer.n_headings,
                 relocalizer.n_headings, relocalizer._offsets, relocalizer._offset_box)
    candidates = relocalizer._candidates
    candidates[:n_candidates] = relocalizer._coarse_found[:n_candidates, 1:] * [1, 5, 5]
    fine_args = (place.bounds, place.free, relocalizer._offsets, n, relocalizer.n_headings,
                 candidates, n_candidates, 10, 20, 6, 6, 3, int(0.5 * HIT_MAX * n), 0.9,
                 relocalizer._found)
    refine_candidates(*fine_args)
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        for _ in range(20):
            relocalizer._state[0] = 0  # a new search each time
            branch_and_bound(*coarse_args)
            refine_candidates(*fine_args)
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after - before <= 256 and peak - before < 4096, (after - before, peak - before)


def test_place_map_scores_the_true_pose_near_one(room):
    world, path, relocalizer = room
    q = query(world, path[7], np.random.default_rng(7))
    place: PlaceMap = relocalizer.place
    assert place.score(q.points, q.count, path[7]) > 0.8
    assert place.score(q.points, q.count, path[7] + [1.0, 0.0, 0.5]) < 0.5


def test_bench_localize_maps_again_when_the_mapping_defaults_or_code_changed(tmp_path):
    from swarmslam.bench.localize import MADE_BY, MADE_BY_CODE, mapping_code, mapping_session
    from swarmslam.simlog import write_simlog

    log = tmp_path / "hall.clf"
    write_simlog(log, "hall", seed=2, lidar="rplidar-a1", rate_hz=4.0, seconds=15)
    said = []
    session = mapping_session("hall", log, tmp_path / "maps", echo=said.append)
    made = session.stat().st_mtime_ns
    assert mapping_session("hall", log, tmp_path / "maps", echo=said.append) == session
    assert session.stat().st_mtime_ns == made and len(said) == 1  # kept: the same defaults
    # other search defaults change no map: kept (the queries run with today's)
    (session.parent / MADE_BY).write_text("[relocalization]\ndistinct_distance = 1.0\n"
                                          "[localization]\nconfirm_misses = 2.0\n")
    assert mapping_session("hall", log, tmp_path / "maps", echo=said.append) == session
    assert session.stat().st_mtime_ns == made and len(said) == 1
    (session.parent / MADE_BY).write_text("[front_end]\nsubmap_nodes = 1\n")  # other defaults
    mapping_session("hall", log, tmp_path / "maps", echo=said.append)
    assert "other defaults" in said[-1] and session.stat().st_mtime_ns != made
    # today's defaults, other code (a field added since reads as today's default): made again
    made, heard = session.stat().st_mtime_ns, len(said)
    assert mapping_session("hall", log, tmp_path / "maps", echo=said.append) == session
    assert session.stat().st_mtime_ns == made and len(said) == heard
    (session.parent / MADE_BY_CODE).write_text("0" * 64 + "\n")
    mapping_session("hall", log, tmp_path / "maps", echo=said.append)
    assert "other defaults or code" in said[-1] and session.stat().st_mtime_ns != made
    assert (session.parent / MADE_BY_CODE).read_text().strip() == mapping_code()


def test_bench_localize_maps_a_log_and_scores_its_queries(tmp_path):
    """The benchmark's pipeline on a short simulated survey: the mapping replay leaves a
    session, the queries are judged against its trajectory, every figure is reported."""
    from swarmslam.bench.localize import bench_log, judge, mapping_session
    from swarmslam.simlog import write_simlog

    log = tmp_path / "hall.clf"
    write_simlog(log, "hall", seed=2, lidar="rplidar-a1", rate_hz=4.0, seconds=60)
    session = mapping_session("hall", log, tmp_path / "maps", echo=lambda *_: None)
    assert session.exists()
    # 12 queries: with 6, one scan more or less found in the open hall swings the rate by 17%
    row = bench_log("hall", log, session, queries=12, seed=0, echo=lambda *_: None)
    rates = ("success_rate", "wrong_rate", "ambiguous_rate")
    assert abs(sum(row[k] for k in rates) - 1.0) < 1e-9
    assert row["wrong_rate"] == 0.0 and row["success_rate"] > 0.5, row
    assert 0 < row["ms_median"] <= row["ms_p99"]
    assert judge(Ambiguous((), (), "none"), np.zeros(3)) == "ambiguous"
    assert judge(Located(np.array([0.31, 0.0, 0.0]), 1.0), np.zeros(3)) == "wrong"
    assert judge(Located(np.array([0.2, 0.1, 0.05]), 1.0), np.zeros(3)) == "success"


def test_pooling_takes_each_blocks_largest_value():
    """Against numpy over every block: the pyramid (in two parts of rows, as the wide loop
    search pools it, and whole) and the bounds, on a grid whose sides are no power of two."""
    rng = np.random.default_rng(21)
    ny, nx, top = 23, 37, 4
    grid = rng.integers(0, 256, size=(ny, nx)).astype(np.uint8)
    pyramid = np.zeros((top + 1, ny, nx), np.uint8)
    pyramid[0] = grid
    parts = pyramid.copy()
    pool_pyramid(pyramid)
    for h in range(1, top + 1):
        pool_level(parts, h, 0, 10)
        pool_level(parts, h, 10, ny)
        side = 1 << h
        expected = [[grid[i:i + side, j:j + side].max() for j in range(nx)] for i in range(ny)]
        assert np.array_equal(pyramid[h], expected) and np.array_equal(parts[h], expected)
    shifts = np.array([0, 0, 3, 2], np.int64)
    bounds = np.zeros((len(shifts), ny, nx), np.uint8)
    pool_bounds(pyramid, shifts, bounds)
    for h, shift in enumerate(shifts):
        side = (1 << h) + 2 * shift
        expected = [[grid[i:i + side, j:j + side].max() for j in range(nx)] for i in range(ny)]
        assert np.array_equal(bounds[h], expected)
