"""The swarm scan matcher on synthetic scans with known motion (the paper's tuning protocol)."""

from dataclasses import replace

import numpy as np
import pytest

from swarmslam.runtime.config import SwarmConfig
from swarmslam.runtime.matching.distance_field import R2, field_lookup
from swarmslam.runtime.matching.objectives import KERNELS, scan_to_scan_error
from swarmslam.runtime.pose import between
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import (POLISH_HALVINGS, POLISH_STEP, MatcherConfig,
                                                     ScanMatcher)
from swarmslam.runtime.realtime.warm_up import pose_after, room_world, scan_at

ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))  # a 360° RPLidar-like scanner
START = np.array([3.0, 3.0, 0.3])
MOTIONS = {
    "rotation": (0.0, 0.0, 0.9),
    "translation": (0.8, -0.4, 0.0),
    "roto-translation": (1.2, 0.5, -0.7),
}


def scans_for(motion, noise=0.0, seed=0):
    world = room_world(seed=seed)
    rng = np.random.default_rng(seed)
    a = scan_at(world, START, ANGLES, 12.0, noise, rng)
    b = scan_at(world, pose_after(START, motion), ANGLES, 12.0, noise, rng)
    ref = PointScan.from_ranges(a, ANGLES, 0.05, 12.0)
    cur = PointScan.from_ranges(b, ANGLES, 0.05, 12.0)
    return ref, cur


def match(optimizer, ref, cur, guess=None, **kw):
    m = ScanMatcher(MatcherConfig.for_optimizer(optimizer, **kw), seed=1)
    return m.align_scans(cur, m.build_reference(ref), guess)


@pytest.mark.parametrize("optimizer", ["pso", "abc", "fa"])
@pytest.mark.parametrize("motion", list(MOTIONS))
@pytest.mark.parametrize("noise", [0.0, 0.02])
def test_recovers_known_motion_without_guess(optimizer, motion, noise):
    ref, cur = scans_for(MOTIONS[motion], noise)
    r = match(optimizer, ref, cur)
    e = between(r.pose, np.array(MOTIONS[motion]))
    tol = 0.03 if noise == 0 else 0.06
    assert np.hypot(e[0], e[1]) < tol, r
    assert abs(e[2]) < tol / 2, r


def test_initial_guess_centres_the_box():
    motion = np.array([3.0, 1.0, 2.5])  # far outside the default box
    ref, cur = scans_for(motion)
    r = match("abc", ref, cur, guess=motion + [0.1, -0.1, 0.05])
    e = between(r.pose, motion)
    assert np.hypot(e[0], e[1]) < 0.03 and abs(e[2]) < 0.02
    assert np.all(np.abs(r.pose - motion) <= np.array([0.4, 0.4, 0.35]))


def test_robust_kernel_beats_paper_form_under_partial_overlap():
    # Points seeing space the reference did not see pull Eq. 14's summed squares; the
    # per-point Cauchy kernel caps their pull. Both must still find the motion.
    motion = np.array(MOTIONS["roto-translation"])
    ref, cur = scans_for(motion, 0.02)
    errors = {}
    for name, config in [("paper", MatcherConfig.paper("abc")), ("cauchy", MatcherConfig())]:
        m = ScanMatcher(config, seed=1)
        e = between(m.align_scans(cur, m.build_reference(ref)).pose, motion)
        errors[name] = np.hypot(e[0], e[1])
    assert errors["paper"] < 0.15
    assert errors["cauchy"] < errors["paper"] / 2, errors


def test_the_default_reference_joins_a_wall_seen_grazing_and_the_papers_form_does_not():
    # End points of beams 1° apart on a wall 1 m to the side, 9.6 m down to 1.03 m apart: every
    # pair is farther apart than max_gap, yet they are one surface (docs/method.md §3).
    bearing = np.radians(2.0 + np.arange(7))
    wall = PointScan.from_points(np.c_[1.0 / np.tan(bearing), np.ones(7)])
    between_ends = 0.5 * (wall.points[3] + wall.points[4])  # on the wall, the two 1.9 m apart
    share = {}  # of the cost of a place no surface is near
    for name, config in [("default", MatcherConfig()), ("paper", MatcherConfig.paper("abc"))]:
        m = ScanMatcher(config, seed=0)
        ref = m.build_reference(wall)
        share[name] = field_lookup(ref.field, ref.meta, *between_ends) / ref.meta[R2]
    assert share["default"] < 0.01
    assert share["paper"] > 0.8  # Eq. 14's d² to the nearest end point, 0.95 m away


def test_same_seed_same_match_bit_for_bit():
    ref, cur = scans_for(MOTIONS["roto-translation"], 0.02)
    a = match("pso", ref, cur)
    b = match("pso", ref, cur)
    assert a.pose.tobytes() == b.pose.tobytes() and a.error == b.error


def test_a_match_between_keep_and_rewind_leaves_no_trace():
    """Matches whose outcome is dropped (the front end's pivot search that keeps nothing)
    put the random stream and the rejection threshold back: the next match is the one a
    matcher that never made them gives, to the bit; without the rewind it is not."""
    ref, cur = scans_for(MOTIONS["roto-translation"], 0.02)
    plain = ScanMatcher(MatcherConfig.for_optimizer("abc"), seed=1)
    expected = plain.align_scans(cur, plain.build_reference(ref))
    m = ScanMatcher(MatcherConfig.for_optimizer("abc"), seed=1)
    reference = m.build_reference(ref)
    m.keep_stream()
    m.align_scans(cur, reference, np.array([0.5, 0.0, 0.2]))
    m.rewind_stream()
    after = m.align_scans(cur, reference)
    assert after.pose.tobytes() == expected.pose.tobytes() and after.error == expected.error
    assert m.threshold.state() == plain.threshold.state()
    m = ScanMatcher(MatcherConfig.for_optimizer("abc"), seed=1)
    reference = m.build_reference(ref)
    m.align_scans(cur, reference, np.array([0.5, 0.0, 0.2]))
    assert m.align_scans(cur, reference).pose.tobytes() != expected.pose.tobytes()


def test_threshold_tracks_mean_plus_std_and_triggers_fallback():
    ref, cur = scans_for(MOTIONS["translation"], 0.02)
    # Without the stall rule every stage spends its whole budget, so the count shows the
    # fallback ran.
    whole_budget = replace(MatcherConfig().swarm, stall_iterations=0)
    m = ScanMatcher(MatcherConfig(scan_to_map=True, swarm=whole_budget), seed=0)
    reference = m.build_reference(ref)
    errors = [m.align_scans(cur, reference).error for _ in range(5)]
    assert m.threshold.count == 5
    assert np.isclose(m.threshold.rejection_threshold, np.mean(errors) + np.std(errors, ddof=1))
    # An unrelated scan matches badly: λ above ε, so the scan-to-map stage is run.
    other, _ = scans_for(MOTIONS["translation"], 0.02, seed=5)
    r = m.align_scans(other, reference)
    assert r.scan_error > m.threshold.mean
    assert r.evaluations > 2 * m.config.swarm.max_evaluations  # both stages ran


def test_bad_input_raises_clear_errors():
    m = ScanMatcher()
    with pytest.raises(ValueError, match="reference maps were never built"):
        m.align_scans(PointScan.from_points([[1.0, 0.0]]), m.new_reference())
    with pytest.raises(ValueError, match="reference scan is empty"):
        m.build_reference(PointScan(4))
    ref = m.build_reference(PointScan.from_points([[1.0, 0.0], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="current scan is empty"):
        m.align_scans(PointScan(4), ref)
    with pytest.raises(ValueError, match="non-finite"):
        m.align_scans(PointScan.from_points([[1.0, 0.0]]), ref, guess=[0, np.nan, 0])
    with pytest.raises(ValueError, match="matcher.kernel: must be one of paper, cauchy"):
        MatcherConfig(kernel="huber")


def test_a_good_prediction_is_matched_by_the_local_stage_alone():
    """predict_first: with the guess near the truth the local stage's match stands (the
    global stage never runs); a guess it cannot mend still gets the global stage."""
    motion = np.array([0.4, -0.2, 0.15])
    ref, cur = scans_for(motion, noise=0.01)
    results = {}
    for first in (0.0, 1.5):
        m = ScanMatcher(MatcherConfig.for_optimizer("abc", predict_first=first), seed=1)
        reference = m.build_reference(ref)
        for _ in range(3):  # a running mean λ to judge by
            m.align_scans(cur, reference, motion + [0.02, -0.02, 0.01])
        near = m.align_scans(cur, reference, motion + [0.03, 0.02, -0.01])
        far = m.align_scans(cur, reference, motion + [0.25, -0.25, 0.2])
        results[first] = near, far
        for r in (near, far):
            e = between(r.pose, motion)
            assert np.hypot(e[0], e[1]) < 0.03 and abs(e[2]) < 0.015, (first, r)
    (near_full, _), (near_first, far_first) = results[0.0], results[1.5]
    c = MatcherConfig()
    # The local stage and the polish at most, the last colony iteration (21 bees) past its
    # budget: no global stage.
    local_only = c.refine_evaluations + c.polish_evaluations + 21
    assert near_first.evaluations <= local_only < near_full.evaluations
    # the local stage alone did not fit: the global stage ran too
    assert far_first.evaluations > local_only + c.refine_evaluations


def test_polish_settles_a_short_swarm_in_its_basin():
    """The compass search (matcher.polish_*) takes a swarm stopped early — its matches tens of
    millimetres apart from seed to seed — to the one minimum of the fine field, lower in λ,
    where no step of its finest size lowers λ further."""
    motion = np.array([0.4, -0.2, 0.15])
    ref, cur = scans_for(motion)
    guess = motion + [0.05, -0.05, 0.02]
    results = {}
    for budget in (0, 300):
        results[budget] = []
        for seed in range(4):
            config = MatcherConfig(swarm=SwarmConfig(max_evaluations=200), refine_evaluations=0,
                                   polish_evaluations=budget)
            m = ScanMatcher(config, seed=seed)
            results[budget].append(m.align_scans(cur, m.build_reference(ref), guess))
    rough, polished = results[0], results[300]

    def spread(matches):
        return max(np.hypot(*(a.pose - b.pose)[:2]) for a in matches for b in matches)

    assert spread(rough) > 0.005
    assert spread(polished) < 0.0005
    for r, p in zip(rough, polished):
        assert p.error <= r.error
        assert p.evaluations > r.evaluations  # the polish's evaluations are counted
        e = between(p.pose, motion)
        assert np.hypot(e[0], e[1]) < 0.005 and abs(e[2]) < 0.002
    # a polished match is a local minimum: no step of the finest size lowers λ
    m = ScanMatcher(MatcherConfig(), seed=0)
    reference = m.build_reference(ref)
    p = m.align_scans(cur, reference, guess)
    step_xy, step_t = (s / 2**POLISH_HALVINGS for s in POLISH_STEP)
    for d, step in ((0, step_xy), (1, step_xy), (2, step_t)):
        for sign in (1, -1):
            moved = p.pose.copy()
            moved[d] += sign * step
            assert scan_to_scan_error(reference.field, reference.meta, cur.buffer, cur.count, 1,
                                      *moved, KERNELS["cauchy"]) >= p.error


@pytest.mark.parametrize("turn", [-0.5, -0.2, 0.25, 0.5])
@pytest.mark.parametrize("step_deg", [1.0, 0.25])
def test_seek_headings_finds_the_turn_anywhere_in_the_box(turn, step_deg):
    """The compass search settled from headings 3° apart across the last box (a lost match
    sought again, docs/method.md §6.1 "Recovery") reaches the turn wherever it lies in a
    ±0.6 rad box, for a 1° scan and a 0.25° one (whose starts score a stride of the points);
    its λ is λ on every point, where no step of the finest size lowers it."""
    angles = np.deg2rad(np.arange(-180, 180, step_deg))
    world = room_world(seed=0)
    rng = np.random.default_rng(0)
    motion = np.array([0.3, -0.1, turn])
    ref, cur = (PointScan.from_ranges(scan_at(world, pose, angles, 12.0, 0.02, rng), angles,
                                      0.05, 12.0) for pose in (START, pose_after(START, motion)))
    m = ScanMatcher(MatcherConfig(), seed=0)
    reference = m.build_reference(ref)
    m.set_search_box(np.array([0.3, -0.1, 0.0]), np.array([0.3, 0.3, 0.6]))
    sought = m.seek_headings(cur, reference, np.radians(3.0))
    e = between(sought.pose, motion)
    assert np.hypot(e[0], e[1]) < 0.005 and abs(e[2]) < np.radians(0.15), sought
    assert sought.evaluations > 23 * 10  # 23 starts, each settled by steps
    kernel = KERNELS["cauchy"]
    assert sought.error == scan_to_scan_error(reference.field, reference.meta, cur.buffer,
                                              cur.count, 1, *sought.pose, kernel)
    step_xy, step_t = (s / 2**POLISH_HALVINGS for s in POLISH_STEP)
    for d, step in ((0, step_xy), (1, step_xy), (2, step_t)):
        for sign in (1, -1):
            moved = sought.pose.copy()
            moved[d] += sign * step
            assert scan_to_scan_error(reference.field, reference.meta, cur.buffer, cur.count,
                                      1, *moved, kernel) >= sought.error
    for step in (0.0, 0.001, np.nan):  # (its starts are bounded)
        with pytest.raises(ValueError, match="step must be at least"):
            m.seek_headings(cur, reference, step)
    with pytest.raises(ValueError, match="empty"):
        m.seek_headings(PointScan(8), reference, np.radians(3.0))
    with pytest.raises(ValueError, match="never built"):
        m.seek_headings(cur, m.new_reference(), np.radians(3.0))


def test_a_dense_scan_is_scored_on_a_bounded_share_of_its_points():
    """matcher.global_points / refine_points: a 0.25° scan (1,440 beams) is matched on about
    as many points per stage as a 1° one, as accurately; a scan within the bounds is matched
    exactly as with the bounds off (the stride the configuration sets)."""
    from swarmslam.runtime.matching.scan_matcher import _stride

    assert _stride(180, 2, 96) == 2 and _stride(192, 2, 96) == 2  # a 1° scan: the stride
    assert _stride(361, 2, 96) == 4 and _stride(1440, 2, 96) == 15
    assert _stride(361, 1, 192) == 2 and _stride(361, 1, 0) == 1 and _stride(5, 3, 96) == 3
    dense = np.deg2rad(np.arange(-180, 180, 0.25))
    motion = np.array([0.4, -0.2, 0.15])
    world = room_world(seed=3)
    rng = np.random.default_rng(3)
    ref = PointScan.from_ranges(scan_at(world, START, dense, 12.0, 0.01, rng), dense, 0.05, 12.0)
    cur = PointScan.from_ranges(scan_at(world, pose_after(START, motion), dense, 12.0, 0.01,
                                        rng), dense, 0.05, 12.0)
    assert cur.count > 1000
    guess = motion + [0.1, -0.1, 0.05]
    for bounds in ({}, {"global_points": 0, "refine_points": 0}):
        r = match("abc", ref, cur, guess, **bounds)
        e = between(r.pose, motion)
        assert np.hypot(e[0], e[1]) < 0.01 and abs(e[2]) < 0.005, (bounds, r)
    ref, cur = scans_for(tuple(motion))  # 360 beams, every one returned: 4 × 96 ≥ 360
    wide = dict(global_points=90, refine_points=360, stride=4)
    assert np.array_equal(match("abc", ref, cur, guess, **wide).pose,
                          match("abc", ref, cur, guess, stride=4, global_points=0,
                                refine_points=0).pose)


def test_the_default_reference_holds_returns_far_beyond_a_small_grid():
    # A SICK-class scanner in an open hall: a near wall and the far wall 60 m ahead, which
    # pins the heading best. The default grid (2,048 cells at 5 cm: 102 m) keeps the far
    # wall's surface; a grid of 1,024 (51 m, centred on the sensor) would leave it out.
    near = np.c_[np.linspace(1.0, 20.0, 200), np.full(200, -3.0)]
    far = np.c_[np.full(200, 60.0), np.linspace(-10.0, 10.0, 200)]
    ref = PointScan.from_points(np.concatenate([near, far]))
    for cells, kept in ((MatcherConfig().grid_cells, True), (1024, False)):
        m = ScanMatcher(MatcherConfig(grid_cells=cells), seed=0)
        reference = m.build_reference(ref)
        cost = field_lookup(reference.field, reference.meta, 60.0, 2.0)
        assert (cost < 0.01 * reference.meta[R2]) == kept, cells
        assert field_lookup(reference.field, reference.meta, 10.0, -3.0) < 0.01


def test_align_inside_is_the_match_or_none_at_the_box_edge_without_the_fine_field(monkeypatch):
    """A loop attempt's alignment (``align_inside``) renders the fine field only after a global
    stage that ended inside the box: there its match is :meth:`align_scans`' to the bit (the
    same seed, the same swarm); a box that ends short of the true motion leaves the global
    stage's best at its edge, and the answer is None with no fine field built."""
    motion = np.array([0.8, -0.4, 0.3])
    ref, cur = scans_for(motion, 0.01)
    window = np.array([0.3, 0.3, 0.2])
    whole = ScanMatcher(MatcherConfig(), seed=3)
    expected = whole.align_scans(cur, whole.build_reference(ref), motion + 0.05, window)
    split = ScanMatcher(MatcherConfig(), seed=3)
    out = split.new_reference()
    got = split.align_inside(cur, ref, out, motion + 0.05, window, 0.05)
    assert got.pose.tobytes() == expected.pose.tobytes() and got.error == expected.error
    assert out.ready

    fine_builds = []
    build_field = ScanMatcher.build_field
    monkeypatch.setattr(ScanMatcher, "build_field",
                        lambda self, scan, o: (fine_builds.append(1), build_field(self, scan, o)))
    short = ScanMatcher(MatcherConfig(), seed=3)
    out = short.new_reference()
    # the box around a guess 0.4 m short along x ends 0.1 m before the true motion
    assert short.align_inside(cur, ref, out, motion - [0.4, 0.0, 0.0], window, 0.05) is None
    assert fine_builds == [] and not out.ready
    assert short.align_inside(cur, ref, out, motion, window, 0.05) is not None
    assert fine_builds == [1]
    # a trusted prediction's local stage comes first: Alg. 5 runs whole, never None
    trusting = ScanMatcher(MatcherConfig(predict_first=1.5), seed=3)
    out = trusting.new_reference()
    short_guess = motion - [0.4, 0.0, 0.0]
    assert trusting.align_inside(cur, ref, out, short_guess, window, 0.05) is not None
    assert fine_builds == [1, 1] and out.ready
