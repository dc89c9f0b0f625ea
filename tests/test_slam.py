"""Graph SLAM end to end on synthetic scans with known poses, loop closure, map, metric."""

import os
from pathlib import Path

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.front_end.odometry_gate import _unbeatable, scans_overrule
from swarmslam.runtime.pose import between, compose, wrap_angle
from swarmslam.runtime.pose_graph import LOOP
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.map_io import read_pgm, write_map
from swarmslam.metrics import kummerle
from swarmslam.relations import Relations, RelationsFormatError, read_relations

ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))


def run(steps=100, laps=1.25, odometry_noise=(0.02, 0.02, 0.01), seed=0, config=None,
        initial_pose=None):
    """Drive 1¼ laps of the demo loop: the second pass over the start closes a loop."""
    truth = loop_path(int(steps / laps))
    truth = np.vstack([truth] * 2)[:steps]
    world = room_world(seed, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=truth)
    rng = np.random.default_rng(seed)
    slam = GraphSlam(config or SlamConfig(), seed=seed, initial_pose=initial_pose)
    odom = truth[0].copy()
    scan = PointScan(len(ANGLES))
    for k in range(steps):
        if k:  # noisy wheel odometry, integrated
            odom = compose(odom, between(truth[k], truth[k - 1]) + rng.normal(0, odometry_noise))
        scan.set_ranges(scan_at(world, truth[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, odom, stamp=float(k))
    # The SLAM's world frame is the first scan's: express the truth in it.
    return slam, between(truth, truth[0]), odom


def test_loop_closes_and_optimised_trajectory_recovers_the_truth():
    slam, truth, _ = run()
    stamps, poses = slam.trajectory()
    err = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    assert slam.loops_closed >= 1
    assert np.sum(slam.graph.kind[: slam.graph.n_edges] == LOOP) == slam.loops_closed
    assert err.max() < 0.15 and err.mean() < 0.05, (err.max(), err.mean())
    assert np.allclose(stamps, np.arange(len(truth)))


def test_initial_pose_anchors_the_map_frame():
    slam, _, _ = run(steps=40)
    start = np.array([3.0, -2.0, 1.0])
    anchored, _, _ = run(steps=40, initial_pose=start)
    assert np.allclose(anchored.graph.poses[0], start)
    _, poses = slam.trajectory()
    _, placed = anchored.trajectory()
    # the same run, expressed in a frame where the first scan sits at ``start``
    assert np.allclose(placed, compose(start, poses), atol=1e-6)


def test_runs_on_scans_alone_as_in_the_paper():
    slam = GraphSlam(SlamConfig(), seed=0)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop_path(80))
    scan = PointScan(len(ANGLES))
    path = loop_path(80)[:40]
    for k in range(40):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, None, float(k))
    _, poses = slam.trajectory()
    err = np.hypot(*(poses[:, :2] - between(path, path[0])[:, :2]).T)
    assert err.max() < 0.15


def test_false_loop_candidate_is_rejected_and_graph_restored():
    slam, _, _ = run(steps=60, laps=0.7)  # no real loop yet
    g = slam.graph
    assert g.n_nodes > 12
    node = g.n_nodes - 1
    victim = 0
    # Make an old node a plausible candidate: place it beside the newest one, and give it the
    # scan of a different room, as a mistaken place recognition would.
    g.poses[victim] = compose(g.poses[node], [0.3, 0.0, 0.0])
    other = room_world(99, size=(7.0, 11.0), boxes=5, walls=2)
    wrong = PointScan(len(ANGLES)).set_ranges(scan_at(other, [3.0, 5.0, 1.0], ANGLES, 12.0),
                                              ANGLES, 0.05, 12.0)
    slam.nodes.store(victim, wrong)
    edges, poses = g.n_edges, g.poses[: g.n_nodes].copy()
    assert victim in slam.back_end.loops.candidates(g, slam.nodes.cov, node)
    assert slam.back_end.seek_loop_closure(node) is False
    assert g.n_edges == edges and np.array_equal(g.poses[: g.n_nodes], poses)
    assert slam.back_end.loops.counts.rejected_match + slam.back_end.loops.counts.rejected_consistency >= 1


def test_capacity_reached_keeps_localising():
    slam, _, _ = run(steps=40, config=override(SlamConfig(), {"capacity.max_nodes": 5, "capacity.max_edges": 8}))
    assert slam.graph.n_nodes == 5 and "capacity reached" in slam.status
    _, poses = slam.trajectory()
    assert len(poses) == 40 and np.all(np.isfinite(poses))


def test_global_map_ros_format(tmp_path):
    slam, _, _ = run(steps=30, laps=0.3)
    paths = write_map(tmp_path / "map", slam.global_map())
    img = read_pgm(paths["pgm"])
    assert set(np.unique(img)) <= {0, 205, 254} and {0, 254} <= set(np.unique(img))
    yaml = Path(paths["yaml"]).read_text()
    for key in ("image: map.pgm", "resolution: 0.05", "origin: [", "occupied_thresh: 0.65",
                "free_thresh: 0.196", "negate: 0"):
        assert key in yaml


def test_kummerle_metric_known_errors():
    stamps = np.arange(5.0)
    truth = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.1], [3, 1, 0.2], [3, 2, 0.3]], float)
    rel = Relations(stamps[:-1], stamps[1:], between(truth[1:], truth[:-1]))
    exact = kummerle(stamps, truth, rel)
    assert exact["eT"] < 1e-12 and exact["eR_deg"] < 1e-10 and exact["relations_used"] == 4
    moved = truth.copy()
    moved[4] = compose(truth[4], [0.1, 0.0, np.deg2rad(2.0)])  # only the last relation is off
    m = kummerle(stamps, moved, rel)
    assert np.isclose(m["eT"], 0.1 / 4) and np.isclose(m["eR_deg"], 2.0 / 4)
    with pytest.raises(ValueError, match="no relation"):
        kummerle(stamps + 100, truth, rel)


def test_kummerle_reports_the_short_relations_tail():
    """Relations under 10 s apart are scored apart with their tail: one relation 8° off among
    ninety-nine right ones moves the mean by 0.08° but is the maximum and the count above 5°;
    a long relation's error stays out of them."""
    stamps = np.arange(201.0)
    truth = np.c_[0.1 * stamps, np.zeros(201), np.zeros(201)]
    t1 = np.r_[np.arange(100.0), 0.0]
    t2 = np.r_[np.arange(100.0) + 2, 200.0]  # 100 short relations and one 200 s long
    rel = Relations(t1, t2, between(truth[t2.astype(int)], truth[t1.astype(int)]))
    moved = truth.copy()
    moved[51:] = compose(truth[51:], [0.0, 0.0, np.deg2rad(8.0)])  # turned 8° from scan 51 on
    m = kummerle(stamps, moved, rel)
    assert m["relations_short"] == 100
    assert np.isclose(m["eR_short_max_deg"], 8.0) and m["eR_short_over_5deg"] == 2
    assert m["eR_short_median_deg"] < 1e-9 and np.isclose(m["eR_short_deg"], 16.0 / 100)


def test_relations_reader_rejects_malformed_lines(tmp_path):
    p = tmp_path / "r.relations"
    p.write_text("1.0 2.0 0.1 0.2 0 0 0 0.3\n3.0 4.0 0.1 oops 0 0 0 0.3\n")
    with pytest.raises(RelationsFormatError) as info:
        read_relations(p)
    assert info.value.line == 2 and info.value.field == "y" and "r.relations:2:" in str(info.value)
    p.write_text("1.0 2.0 0.1\n")
    with pytest.raises(RelationsFormatError, match="expected 8 values"):
        read_relations(p)


DATA = Path(os.environ.get("SWARMSLAM_DATASETS", Path(__file__).parents[1] / ".." / "shared" / "datasets"))


@pytest.mark.skipif(not (DATA / "radish" / "intel.clf.gz").exists(),
                    reason=f"integration data absent: {DATA / 'radish' / 'intel.clf.gz'}")
def test_intel_first_scans_stay_bounded():
    from swarmslam.replay import replay

    m = replay(DATA / "radish" / "intel.clf.gz", DATA / "radish" / "intel.relations", limit=400)
    assert m["relations_used"] >= 20
    assert m["eT"] < 0.1 and m["eR_deg"] < 1.0, m


def test_scans_only_recovers_after_a_gap_in_the_stream():
    # Scans 20 to 23 are lost (a stalled driver): the next one is ~1.3 m and ~0.3 rad on,
    # beyond the ±0.3 box around the prediction but inside the ±2 m whole box, so the guided
    # match loses track and the swarm's search over the whole box has to find it again.
    path = loop_path(80)[:50]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    kept = [k for k in range(50) if not 20 <= k < 24]
    for k in kept:
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, None, float(k))
    _, poses = slam.trajectory()
    err = np.hypot(*(poses[:, :2] - between(path[kept], path[0])[:, :2]).T)
    assert slam.front_end.counts.lost_matches >= 1
    assert err.max() < 0.15, err.max()


def test_scans_between_two_nodes_share_the_graphs_correction_of_both():
    # the spread alone: the between-scan smoothing (test_between_scans.py) reads the
    # trajectory, so a bent graph would move what it takes from odometry too
    slam, _, _ = run(config=override(SlamConfig(), {"front_end.smooth_between_headings": False,
                                                    "front_end.smooth_between_positions": False}))
    fe, g = slam.front_end, slam.graph
    stamps, before = slam.trajectory()
    node = fe.scans.node[: fe.scans.n]
    m = int(np.argmax(np.bincount(node)[: g.n_nodes - 2]))  # the node that tracked most scans
    between_nodes = node == m
    assert between_nodes.sum() >= 3
    g.poses[m + 1 :, 0] += 0.3  # the graph bends the chain between nodes m and m + 1
    _, after = slam.trajectory()
    share = (stamps[between_nodes] - g.stamps[m]) / (g.stamps[m + 1] - g.stamps[m])
    assert share.min() == 0 and 0 < share[1] < share[2] < 1  # the node's own scan, then two
    moved = after - before
    assert np.allclose(moved[between_nodes, 0], 0.3 * share, atol=1e-12)
    assert np.allclose(moved[between_nodes, 1:], 0.0, atol=1e-12)
    assert np.allclose(moved[node < m], 0.0, atol=1e-12)
    assert np.allclose(moved[node > m, 0], 0.3, atol=1e-12)
    # Off, each scan moves with its tracking node alone.
    fe.scans.config = override(slam.config, {"front_end.spread_corrections": False}).front_end
    _, rigid = slam.trajectory()
    tracked = fe.scans.rel[: fe.scans.n][between_nodes]
    assert np.allclose(rigid[between_nodes], compose(g.poses[m], tracked))


def test_submap_reference_tracks_and_closes_the_loop():
    slam, truth, _ = run(config=override(SlamConfig(), {"front_end.submap_nodes": 4}))
    _, poses = slam.trajectory()
    err = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    assert slam.loops_closed >= 1
    assert err.max() < 0.15 and err.mean() < 0.05, (err.max(), err.mean())
    # The reference really holds several scans: more points than the newest scan alone.
    assert slam.front_end.submap.scan.count > slam.nodes.counts[slam.keyframe]


def _glitch_run(config, glitch_at=20, glitch_turn_deg=12.0):
    """Drive part of the demo loop with exact odometry; one scan is taken as if the robot had
    turned ``glitch_turn_deg`` more than it did (what a match that lost track reports)."""
    path = loop_path(80)[:30]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(config, seed=0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        seen = compose(path[k], [0.0, 0.0, np.radians(glitch_turn_deg)]) if k == glitch_at else path[k]
        scan.set_ranges(scan_at(world, seen, ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, path[k], float(k)).pose[2])
    truth = between(path, path[0])
    return slam, np.degrees(np.abs(wrap_angle(np.array(headings) - truth[:, 2])))


def test_match_contradicting_odometry_is_not_trusted_unless_the_scans_clearly_side_with_it():
    """A scan taken as if the robot had turned 12° more than odometry (right here) says. The
    front end cannot tell such a scan from odometry that erred: it fits the keyframe fully at
    the turned pose, far better than at odometry's prediction. With the scans never allowed to
    overrule odometry (``odometry_gate_fit`` and ``odometry_gate_explained`` 1), the gate
    keeps odometry's prediction for it and tracking goes on from there; by default the scans
    are believed (docs/method.md §6.1: real odometry lags fast turns by that much); with no
    gate at all, likewise."""
    refused = override(SlamConfig(), {"front_end.odometry_gate_fit": 1.0,
                                      "front_end.odometry_gate_explained": 1.0})
    slam, heading_error = _glitch_run(refused)
    # (the glitch scan became a node here, so the next scans match against it until the next
    # node: also gated)
    assert 1 <= slam.front_end.counts.lost_matches <= 3 and slam.front_end.counts.overruled_odometry == 0
    assert heading_error[20] < 1.5 and heading_error.max() < 1.5, heading_error
    trusted, heading_error = _glitch_run(SlamConfig())
    assert trusted.front_end.counts.overruled_odometry >= 1
    assert heading_error[20] > 8.0, heading_error[20]
    ungated, heading_error = _glitch_run(override(SlamConfig(), {"front_end.odometry_gate": None}))
    assert ungated.front_end.counts.lost_matches == 0 and ungated.front_end.counts.overruled_odometry == 0
    assert heading_error[20] > 8.0, heading_error[20]


def _heading_errors(config, world, path, reading, interval):
    """A run along ``path`` in ``world``, scans ``interval`` s apart, the odometry reading at
    scan k ``reading(k)``: the SLAM, and each scan's heading error (°) against the path's."""
    truth = between(path, path[0])
    slam = GraphSlam(config, seed=0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, reading(k), interval * k).pose[2])
    return slam, np.degrees(np.abs(wrap_angle(np.array(headings) - truth[:, 2])))


def test_a_rescued_match_within_the_gate_stands_when_it_fits_far_better():
    """A robot turning on the spot 30° a scan whose odometry reading jumps 18° ahead once:
    the match around its prediction is pressed against its box's edge (±17°), so it is
    sought again around the scans' own motion and found where the robot is. It corrects
    odometry by less than the gate allows over a 48° step, so it contradicts nothing, and it
    fits far better than the prediction: it stands (docs/method.md §6.1). When new readings
    are never overruled (``odometry_gate_explained`` 1) the prediction stands in, 18° off."""
    loop = loop_path(80)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop)
    turn, jump = np.radians(30.0), np.radians(18.0)
    path = np.array([[loop[0, 0], loop[0, 1], loop[0, 2] + k * turn] for k in range(10)])

    def reading(k):
        return compose(path[k], [0.0, 0.0, jump]) if k >= 6 else path[k]

    slam, errors = _heading_errors(SlamConfig(), world, path, reading, 1.0)
    assert slam.front_end.counts.rescued_matches >= 1, errors
    assert errors.max() < 1.0, errors
    refused = override(SlamConfig(), {"front_end.odometry_gate_explained": 1.0})
    slam, errors = _heading_errors(refused, world, path, reading, 1.0)
    assert slam.front_end.counts.rescued_matches == 0
    assert errors[6] > 15.0, errors


def test_the_scans_overrule_a_new_reading_by_the_share_of_its_misses_they_fit():
    """Against a new reading the match must fit much of what odometry's prediction misses:
    every point against nine in ten (a prediction a few degrees off in a turn) overrules it;
    two thirds against a half (a hall whose walls fit a slip either way) does not. Against a
    stale reading, which says nothing of the motion, a plain gain above ``odometry_gate_fit``
    suffices."""
    c = SlamConfig().front_end
    assert scans_overrule(1.0, 0.91, stale=False, config=c)
    assert not scans_overrule(0.66, 0.49, stale=False, config=c)
    assert not scans_overrule(1.0, 0.91, stale=True, config=c)  # a gain of 0.09 < 0.1
    assert scans_overrule(0.63, 0.46, stale=True, config=c)
    assert not scans_overrule(0.9, 0.9, stale=False, config=c)
    never = override(SlamConfig(), {"front_end.odometry_gate_explained": 1.0,
                                    "front_end.odometry_gate_fit": 1.0}).front_end
    assert not any(scans_overrule(1.0, p, stale, never) for p in (0.0, 0.5, 0.99)
                   for stale in (False, True))


def test_a_match_that_only_moves_odometrys_position_does_not_overrule_it():
    """The same glitch as a slide of 0.25 m sideways (odometry's heading right): a match that
    moves only odometry's position, from a prediction that still tracks (fits
    ``min_track_inliers`` of the points), may have slid along a corridor, so the gate's
    refusal stands however well it fits."""
    path = loop_path(80)[:30]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    for k in range(len(path)):
        seen = compose(path[k], [0.0, 0.25, 0.0]) if k == 20 else path[k]
        scan.set_ranges(scan_at(world, seen, ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k], float(k))
    assert slam.front_end.counts.lost_matches >= 1 and slam.front_end.counts.overruled_odometry == 0
    _, poses = slam.trajectory()
    truth = between(path, path[0])
    assert np.hypot(*(poses[:, :2] - truth[:, :2]).T).max() < 0.1


def test_a_stale_reading_is_not_counted_twice():
    """Odometry read every third scan (the same reading in between) while the robot turns:
    each new reading is applied from the scan that brought the last one, so the prediction
    lands where the robot is, not a stale stretch further on; no match falls back to the
    prediction. (A stale reading predicts no motion, and the robot moves 0.285 m a scan: the
    match lies at the guess box's edge margin, so it may be sought again; it must be found.)"""
    path = loop_path(80)[:30]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    fe = slam.front_end
    scan = PointScan(len(ANGLES))
    predicted = {}  # scan → its prediction in the map frame
    align = fe.matcher.align_scans

    def recording(scan_, reference, guess=None, window=None):
        predicted.setdefault(fe.scans.n, compose(slam.graph.poses[fe.keyframe], guess))
        return align(scan_, reference, guess, window)

    fe.matcher.align_scans = recording
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k - k % 3], float(k))
    truth = between(path, path[0])
    for k in range(3, len(path), 3):  # a new reading lands the prediction on the truth
        assert np.hypot(*(predicted[k][:2] - truth[k, :2])) < 0.05
        assert abs(wrap_angle(predicted[k][2] - truth[k, 2])) < np.radians(1.0)
    assert fe.counts.lost_matches == fe.counts.rescued_matches
    _, poses = slam.trajectory()
    assert np.hypot(*(poses[:, :2] - truth[:, :2]).T).max() < 0.05


def _hall_with_a_wall_held_twice(config, seed):
    """A hall 3 m wide with a door every 3 m, driven straight at 0.1 m a scan with exact
    odometry; once the third node is made, the node before it is turned 4.5° in the graph
    and the keyframe's submap rebuilt: it holds both walls twice, 4.5° apart (fr-clinic's
    halls after a node was placed off). The heading error of every later scan (°). The
    moved points' test is off: the copy's points in front of the walls the other node scans
    saw lie in their free space, and with them left out no seed goes more than 0.25° wrong
    even with both rules off (docs/method.md §6.1, "Moved points"). The rules tested here
    are for the copies nothing saw through."""
    walls = [[x, y, x + 2.2, y] for y in (-1.5, 1.5) for x in np.arange(-3.0, 30.0, 3.0)]
    world = np.array(walls + [[-3.0, -1.5, -3.0, 1.5]])
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(40)])
    slam = GraphSlam(override(config, {"front_end.drop_moved_points": False}), seed=seed)
    fe = slam.front_end
    rng = np.random.default_rng(seed)
    scan = PointScan(len(ANGLES))
    errors = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        heading = slam.step(scan, path[k], float(k)).pose[2]
        if errors or fe.keyframe >= 2:
            errors.append(abs(np.degrees(wrap_angle(heading))))
        if len(errors) == 1:
            slam.graph.poses[fe.keyframe - 1, 2] += np.radians(4.5)
            fe.submap.rebuild(fe.keyframe)
    return fe, np.array(errors[1:])


def _worst_without_and_with(without, with_rule, counter):
    """The hall with a wall held twice on seeds 0–3, under a configuration without a rule and
    one with it: each seed's worst heading error (°) under both, and how often the rule acted
    (the front end's ``counter``), which must be never without it."""
    worst_without, worst_with, acted = [], [], 0
    for seed in range(4):
        fe, errors = _hall_with_a_wall_held_twice(without, seed)
        assert getattr(fe.counts, counter) == 0
        worst_without.append(errors.max())
        fe, errors = _hall_with_a_wall_held_twice(with_rule, seed)
        acted += getattr(fe.counts, counter)
        worst_with.append(errors.max())
    return worst_without, worst_with, acted


def test_the_previous_scan_disowns_a_match_on_a_wall_the_submap_holds_twice():
    """Tracked against a submap that holds the hall's walls twice, a scan fits either copy
    about equally, and some seeds' matches take the copy 4.5° off, which odometry's gate (5°)
    lets pass. The previous scan holds each wall once: odometry's prediction fits it clearly
    better than such a match, so the match is lost and the prediction stands
    (docs/method.md §6.1). With the check off (``previous_scan_gain`` 1) they go wrong."""
    # (odometry's heading weighed too would hold those matches first: the next test)
    alone = override(SlamConfig(), {"front_end.odometry_heading_weight": 0.0})
    never = override(alone, {"front_end.previous_scan_gain": 1.0})
    worst_unchecked, worst_checked, disowned = _worst_without_and_with(never, alone,
                                                                       "disowned_matches")
    assert max(worst_unchecked) > 4.0, worst_unchecked
    assert max(worst_checked) < 0.5 and disowned >= 1, (worst_checked, disowned)


def test_of_two_copies_of_a_wall_the_match_nearer_odometry_stands():
    """The same submap with the wall held twice, the previous scan's check off: a match on
    the copy 4.5° off fits about as well as the optimum at odometry's heading (which saw no
    turn), so with odometry's heading weighed (``odometry_heading_weight``) the nearer optimum
    stands (docs/method.md §6.1); weighed at 0, some seeds take the far copy."""
    unweighed = override(SlamConfig(), {"front_end.previous_scan_gain": 1.0,
                                        "front_end.odometry_heading_weight": 0.0})
    weighed = override(SlamConfig(), {"front_end.previous_scan_gain": 1.0})
    worst_unweighed, worst_weighed, held = _worst_without_and_with(unweighed, weighed,
                                                                   "held_to_odometry")
    assert max(worst_unweighed) > 4.0, worst_unweighed
    assert max(worst_weighed) < 0.5 and held >= 1, (worst_weighed, held)


def test_loop_reference_is_a_submap_around_the_candidate():
    slam, _, _ = run()
    g, k = slam.graph, slam.config.loop_closure.submap_nodes
    node, candidate = g.n_nodes - 1, 5
    assert k >= 1
    slam.back_end.align_loop(candidate, node)  # builds the submap, whatever the match
    submap = slam.back_end.alignment.submap
    counts = slam.nodes.counts[candidate - k : candidate + k + 1]
    assert submap.count == counts.sum()
    # Each neighbour's scan sits where the graph puts it: back in the world, it lands on its
    # own node's points.
    start = 0
    for other in range(candidate - k, candidate + k + 1):
        m = slam.nodes.counts[other]
        placed = compose(g.poses[candidate], np.c_[submap.buffer[start : start + m], np.zeros(m)])
        own = compose(g.poses[other], np.c_[slam.nodes.points[other, :m], np.zeros(m)])
        assert np.allclose(placed[:, :2], own[:, :2], atol=1e-9)
        start += m
    # Near the new node the submap stops short of its neighbours (they are not a loop).
    recent = node - slam.config.loop_closure.exclude_recent
    slam.back_end.align_loop(recent, node)
    assert slam.back_end.alignment.submap.count == slam.nodes.counts[recent - k : recent + 1].sum()


def test_closure_spacing_skips_the_search_just_after_a_closure():
    spaced = override(SlamConfig(), {"loop_closure.closure_spacing": 2})
    closed_at = {}
    every = override(SlamConfig(), {"loop_closure.closure_spacing": 0})
    for name, config in (("every node", every), ("spaced", spaced)):
        slam, truth, _ = run(steps=160, laps=1.25, config=config)
        g = slam.graph
        loops = np.sort(g.ij[: g.n_edges][g.kind[: g.n_edges] == LOOP, 1])
        closed_at[name] = loops
        stamps, poses = slam.trajectory()
        err = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
        assert err.mean() < 0.05, (name, err.mean())
    assert np.min(np.diff(closed_at["every node"])) <= 2  # closures on close nodes, unspaced
    assert np.min(np.diff(closed_at["spaced"])) > 2
    assert 0 < len(closed_at["spaced"]) < len(closed_at["every node"])


def test_a_candidate_whose_match_failed_a_node_ago_is_passed_over_until_the_graph_changes(
        monkeypatch):
    """Alg. 7's attempts go to candidates not just tried in vain: a candidate whose match
    failed for node n − 1 is not tried for node n unless a closure changed the graph since;
    the next gated candidate takes its place."""
    from swarmslam.runtime.back_end.slices import BackEnd

    attempts = []  # (node, candidate, matched, graph revision)
    align = BackEnd.align_loop

    def recording(self, candidate, node, guess=None, window=None):
        z = align(self, candidate, node, guess, window)
        if guess is None:
            attempts.append((node, candidate, z is not None, self.revision))
        return z

    monkeypatch.setattr(BackEnd, "align_loop", recording)
    # a strict inlier test, the visibility test off, rougher odometry: some loop matches fail
    config = override(SlamConfig(), {"loop_closure.min_inliers": 0.99,
                                     "loop_closure.min_overlap": 1.0})
    slam, truth, _ = run(steps=160, laps=1.25, config=config, odometry_noise=(0.04, 0.04, 0.02))
    failed = {(n, c, r) for n, c, ok, r in attempts if not ok}
    assert failed, "no loop match failed: the rule is not exercised"
    passed_over = 0
    for n, c, ok, r in attempts:
        assert (n - 1, c, r) not in failed, (n, c)  # not retried, the graph unchanged
    for n, c, r in failed:  # ... while the next node's search did run
        passed_over += any(a[0] == n + 1 and a[3] == r for a in attempts)
    assert passed_over > 0
    restored = GraphSlam(config, seed=0)
    restored.restore(slam.state())
    assert np.array_equal(restored.back_end.failed[: restored.back_end.n_failed],
                          slam.back_end.failed[: slam.back_end.n_failed])
    assert restored.back_end.failed_node == slam.back_end.failed_node
    _, poses = slam.trajectory()
    assert np.hypot(*(poses[:, :2] - truth[:, :2]).T).mean() < 0.05


def _drifted_chain(config, n=60, step=0.5, stretch=1.05):
    """A GraphSlam whose graph is a straight chain of ``n`` nodes with odometry 5% long (1.5 m
    of drift), and its back end ready to close loops measured by the truth."""
    slam = GraphSlam(config, seed=0)
    g, back = slam.graph, slam.back_end
    info = slam.front_end.information()
    for k in range(n):
        g.add_node([k * step * stretch, 0.0, 0.0], float(k))
        if k:
            g.add_edge(k - 1, k, [step * stretch, 0.0, 0.0], info)
    back.z_info[:] = slam.front_end.information(loop=True)
    return slam, back, np.array([(n - 2) * step, 0.0, 0.0])


@pytest.mark.parametrize("moved, kept", [(0.0, True), (0.3, False)])
def test_a_loop_refused_for_the_drift_it_repairs_is_kept_when_the_next_agrees(moved, kept):
    """A true loop after a long drift is absorbed (its own χ² passes) but raises the total
    past ``total_gate``: refused. The next node's loop to the next old node, placing the robot
    where the first did, is judged by its own error and kept; one placing it 0.3 m away is
    refused as the first was (docs/method.md §5, step 4)."""
    slam, back, z = _drifted_chain(SlamConfig())
    loops, n = back.loops, slam.graph.n_nodes
    assert not back.close_loop(0, n - 2, z) and loops.counts.rejected_consistency == 1
    assert back.closure.memory.rise_refused[1] == n - 2
    assert back.close_loop(1, n - 1, z + [moved, 0.0, 0.0]) is kept
    assert loops.counts.agreed == int(kept) and loops.counts.rejected_consistency == 2 - int(kept)
    if kept:  # the drift repaired: the far end, 1.48 m long, pulled back near the truth
        assert abs(slam.graph.poses[n - 1, 0] - (n - 1) * 0.5) < 0.15
    slam, back, z = _drifted_chain(override(SlamConfig(), {"loop_closure.agreement_nodes": 0}))
    back.close_loop(0, n - 2, z)
    assert not back.close_loop(1, n - 1, z)  # without the rule, refused as before


@pytest.mark.parametrize("rate, given_to", [(0.5, 4), (0.0, 5)])
def test_a_loop_to_a_node_scanned_in_a_fast_turn_is_given_to_a_steady_neighbour(rate, given_to):
    """Node 5 was scanned as the robot turned 0.5 rad in 0.25 s: a scan swept in such a turn
    leaves its node's pose off the map its scan draws. A loop matched against its submap is
    given to node 4, its nearest node turning no faster than ``steady_turn_rate`` (node 6 ends
    the same turn), the measurement re-expressed in node 4's frame: the same place of the map.
    At 0 the loop stays with node 5 (docs/method.md §5, step 3)."""
    slam = GraphSlam(override(SlamConfig(), {"loop_closure.steady_turn_rate": rate}), seed=0)
    g, back = slam.graph, slam.back_end
    info = slam.front_end.information()
    pose, stamp = np.zeros(3), 0.0
    for k in range(30):
        if k:
            z = [0.0, 0.0, 0.5] if k == 6 else [0.5, 0.0, 0.0]
            pose, stamp = compose(pose, z), stamp + (0.25 if k == 6 else 1.0)
            g.add_edge(k - 1, g.add_node(pose, stamp), z, info)
        else:
            g.add_node(pose, stamp)
    back.z_info[:] = slam.front_end.information(loop=True)
    measured = compose(between(g.poses[29], g.poses[5]), [0.02, -0.01, 0.01])
    before = g.poses[:30].copy()
    there = compose(before[5], measured)  # where the match puts node 29
    assert back.close_loop(5, 29, measured)
    edge = g.n_edges - 1
    assert tuple(g.ij[edge]) == (given_to, 29) and g.kind[edge] == LOOP
    np.testing.assert_allclose(compose(before[given_to], g.z[edge]), there, atol=1e-12)
    assert back.loops.counts.reanchored == int(given_to != 5)


def _chain_with_wrong_loops(config, n=60, step=0.5, turn=0.003):
    """A GraphSlam whose graph is a chain of ``n`` nodes along a straight line, its odometry
    turning ``turn`` rad a step (2.2 m to the side after 55 nodes), and loops from nodes 0, 1
    and 2 to nodes 50, 51 and 52 kept where the drifted chain put them (a corner's L matched
    onto the other L, agreeing with the drift)."""
    slam = GraphSlam(config, seed=0)
    g, back = slam.graph, slam.back_end
    info = slam.front_end.information()
    z = np.array([step, 0.0, turn])
    g.add_node([0.0, 0.0, 0.0], 0.0)
    for k in range(1, n):
        g.add_node(compose(g.poses[k - 1], z), float(k))
        g.add_edge(k - 1, k, z, info)
    for k in range(3):
        g.add_edge(k, 50 + k, between(g.poses[50 + k], g.poses[k]),
                   slam.front_end.information(loop=True), LOOP)
    back.z_info[:] = slam.front_end.information(loop=True)
    return slam, back


@pytest.mark.parametrize("given_up", [3, 0])
def test_two_loops_that_agree_give_up_the_kept_loops_they_contradict(given_up):
    """Wrong loops kept (nodes 0–2 → 50–52, where drift put them) make the graph refuse the
    right loops of the place after them for their own error: the map holds the place twice.
    Two in a row that agree give up the kept loops they strain (at most ``max_given_up``) and
    are kept (docs/method.md §5, step 4)."""
    config = override(SlamConfig(), {"loop_closure.max_given_up": given_up})
    slam, back = _chain_with_wrong_loops(config)
    g, loops, z = slam.graph, back.loops, np.array([51 * 0.5, 0.0, 0.0])
    bent, edges = abs(g.poses[55, 1]), g.n_edges
    assert bent > 2.0  # the drift the wrong loops hold
    assert not back.close_loop(4, 55, z)  # right, refused: the graph cannot absorb it
    assert back.closure.memory.strained[1] == 55 and loops.counts.rejected_consistency == 1
    kept = back.close_loop(5, 56, z)  # the next agrees
    assert kept is (given_up > 0) and loops.counts.agreed == 0
    wrong = {(0, 50), (1, 51), (2, 52)}
    held = {tuple(int(v) for v in g.ij[k]) for k in range(g.n_edges) if g.kind[k] == LOOP}
    if kept:
        assert loops.counts.given_up == 3 and held == {(4, 55), (5, 56)}
        assert g.n_edges == edges - 3 + 2 and abs(g.poses[55, 1]) < 0.25 * bent
        restored = GraphSlam(config, seed=0)
        restored.restore(slam.state())
        assert restored.back_end.loops.counts.given_up == 3 and restored.graph.n_edges == g.n_edges
    else:
        assert held == wrong and g.n_edges == edges and abs(g.poses[55, 1]) == bent


def test_a_match_counted_until_it_cannot_be_disowned_gets_the_verdict_of_full_counts():
    # the previous-scan check stops counting the match's inliers at _unbeatable(n, gain):
    # from there no count of the prediction's (at most n) beats it by more than the gain, in
    # floating point as the check computes it, and below it one could
    for gain in (0.0, 0.05, 0.1, 0.3, 0.7, 0.999):
        for n in range(1, 160):
            k = _unbeatable(n, gain)
            assert 0 <= k <= n + 1
            for fit in range(n + 1):
                beatable = any(p / n - fit / n > gain for p in range(fit, n + 1))
                assert beatable == (fit < k), (gain, n, fit, k)


def _corridor_with_stale_odometry(config, period=4):
    """A plain corridor 2 m wide and 40 m long, driven straight at 0.1 m a scan with exact
    odometry read every ``period`` scans (the same reading in between, as a robot whose
    odometry comes less often than its scans logs it). The error (m) of each scan's motion
    from the one before, on the trajectory."""
    world = np.array([[-2.0, y, 38.0, y] for y in (-1.0, 1.0)])
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(60)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k - k % period], float(k))
    _, poses = slam.trajectory()
    steps = between(poses[1:], poses[:-1])  # each scan in the frame of the one before
    return slam.front_end, np.hypot(steps[:, 0] - 0.1, steps[:, 1])


def test_a_stale_reading_continues_the_last_readings_motion_along_a_corridor():
    """Along a plain corridor the scans cannot tell how far the robot went: the prediction's
    position stands in along the axis (the degeneracy test). With odometry read every fourth
    scan, a stale reading that predicted no motion held three scans in four still and put
    the whole motion into the fourth (the simulator's robot effects: 0.045 m of error a
    scan). A stale reading now continues the translation per scan the last new reading
    showed (``stale_motion``; docs/method.md §6.1), so every scan moves its 0.1 m."""
    fe, errors = _corridor_with_stale_odometry(
        override(SlamConfig(), {"front_end.stale_motion": False}))
    assert fe.counts.degenerate_matches > 20
    assert errors.max() > 0.15, errors
    fe, errors = _corridor_with_stale_odometry(SlamConfig())
    assert fe.counts.degenerate_matches > 20
    assert errors[4:].max() < 0.03 and errors[4:].mean() < 0.01, errors  # from the 1st reading on


def _corridor_with_people(config, n=60):
    """A plain corridor 2 m wide, its ends out of reach of a scanner that sees 180° ahead
    (a SICK's view), driven at 0.1 m a scan with exact odometry; a person 0.4 m wide walks
    towards the robot at 0.15 m a scan, 0.45 m to its left (another starts 8 m further on
    once one has passed). The error (m) of each scan's position along the corridor."""
    walls = np.array([[-20.0, y, 40.0, y] for y in (-1.0, 1.0)])
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(n)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    angles = np.deg2rad(np.arange(-90.0, 90.5, 1.0))
    scan = PointScan(len(angles))
    for k in range(n):
        x = 6.0 - 0.15 * k + (8.0 if 6.0 - 0.15 * k < path[k, 0] + 0.5 else 0.0)
        person = np.array([[x - 0.2, 0.25, x + 0.2, 0.25], [x + 0.2, 0.25, x + 0.2, 0.65],
                           [x + 0.2, 0.65, x - 0.2, 0.65], [x - 0.2, 0.65, x - 0.2, 0.25]])
        world = np.vstack([walls, person])
        scan.set_ranges(scan_at(world, path[k], angles, 12.0, 0.01, rng), angles, 0.05, 12.0)
        slam.step(scan, path[k], float(k))
    _, poses = slam.trajectory()
    return np.abs(poses[:, 0] - path[:, 0])


def test_a_person_walking_down_a_corridor_does_not_carry_the_match_along():
    """Along a plain corridor a walking person is the one thing the match can pin the axis
    to, and pins it to themselves: the keyframe reference held them where they were. Their
    returns there lie where another of its node scans saw through (docs/method.md §6.1,
    "Moved points"): left out, the axis stays degenerate and odometry holds it."""
    errors = _corridor_with_people(override(SlamConfig(), {"front_end.drop_moved_points": False}))
    assert errors.max() > 0.5, errors
    errors = _corridor_with_people(SlamConfig())
    assert errors.max() < 0.05, errors


def test_a_repeated_reading_at_rest_predicts_no_motion():
    """Odometry read at every scan repeats a reading only when the robot stands: the last new
    reading took one scan to come, so a repeat continues nothing and every prediction at
    rest is the last scan's pose."""
    world = np.array([[-2.0, y, 38.0, y] for y in (-1.0, 1.0)] + [[-2.0, -1.0, -2.0, 1.0]])
    slam = GraphSlam(SlamConfig(), seed=0)
    fe = slam.front_end
    guesses = {}
    align = fe.matcher.align_scans

    def recording(scan_, reference, guess=None, window=None):
        guesses.setdefault(fe.scans.n, (guess.copy(), fe.rel.copy()))
        return align(scan_, reference, guess, window)

    fe.matcher.align_scans = recording
    scan = PointScan(len(ANGLES))
    moving = [[0.1 * k, 0.0, 0.0] for k in range(10)]
    for k, pose in enumerate(moving + [moving[-1]] * 10):
        scan.set_ranges(scan_at(world, pose, ANGLES, 12.0, 0.0), ANGLES, 0.05, 12.0)
        slam.step(scan, np.array(pose), float(k))
    assert all(np.array_equal(*guesses[k]) for k in range(10, 20))
    assert not any(np.array_equal(*guesses[k]) for k in range(2, 10))


def test_a_match_pressed_against_its_box_is_sought_again_around_itself():
    """A robot that turns on the spot 25° a scan from rest, then stops, its odometry reading
    one scan late: as the turn starts, odometry and the scans' last motion both predict no
    turn, and as it stops both predict 25° more; the truth lies beyond the ±17° box either
    time. The match pressed against the box's edge is sought again around itself, found
    where the robot is, and stands (docs/method.md §6.1); without that second search the
    prediction stands in, 25° off."""
    loop = loop_path(80)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop)
    turn = np.radians(25.0)
    turns = np.r_[np.zeros(4), np.arange(1, 7), np.full(4, 6)] * turn
    path = np.c_[np.tile(loop[0, :2], (len(turns), 1)), loop[0, 2] + turns]
    truth = between(path, path[0])
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, path[max(k - 1, 0)], float(k)).pose[2])
    errors = np.degrees(np.abs(wrap_angle(np.array(headings) - truth[:, 2])))
    assert slam.front_end.counts.rescued_matches >= 2, errors
    assert errors.max() < 1.0, errors


def test_a_pivot_beyond_every_box_is_found_over_the_turn_the_robot_can_make():
    """Scans at 2 Hz of a robot that turns on the spot 75° a scan (2.6 rad/s) for three scans,
    its odometry (exact) read every second scan. The turn starts at a scan with a stale
    reading, which says nothing of it: the scans' last motion says no turn, the match pressed
    against the stale box (±34°) and sought again around itself reaches 68°. One more search,
    over every heading the robot can turn to in half a second (``pivot_search_rate`` 3 rad/s:
    ±86°), finds it (docs/method.md §6.1, "Recovery"); without it (``pivot_search_rate`` 0) the
    prediction stands in, 75° off, there and at the next stale scan."""
    loop = loop_path(80)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop)
    turns = np.r_[np.zeros(5), np.arange(1, 4), np.full(3, 3)] * np.radians(75.0)
    path = np.c_[np.tile(loop[0, :2], (len(turns), 1)), loop[0, 2] + turns]

    def every_second_scan(k):
        return path[k - k % 2]

    slam, errors = _heading_errors(SlamConfig(), world, path, every_second_scan, 0.5)
    assert slam.front_end.counts.rescued_matches >= 2 and errors.max() < 1.0, errors
    off = override(SlamConfig(), {"front_end.pivot_search_rate": 0.0})
    slam, errors = _heading_errors(off, world, path, every_second_scan, 0.5)
    assert errors[5] > 70.0 and errors[7] > 70.0, errors


def _pivot_facing_a_near_wall(config):
    """A corridor 2 m wide ending in a wall; the robot drives up to 0.6 m from it, then turns
    on the spot 8° a scan, its odometry (exact) read every fourth scan and stale in between.
    The heading error (°) of each scan."""
    world = np.array([[-2.0, -1.0, 38.0, -1.0], [-2.0, 1.0, 38.0, 1.0], [2.5, -1.0, 2.5, 1.0]])
    turn = np.radians(8.0)
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(20)]
                    + [[1.9, 0.0, turn * k] for k in range(1, 9)] + [[1.9, 0.0, 8 * turn]] * 6)
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, path[k - k % 4], float(k)).pose[2])
    return np.degrees(np.abs(wrap_angle(np.array(headings) - path[:, 2])))


def test_a_stale_reading_is_never_held_to_more_than_a_new_one():
    """Facing a wall 0.6 m off, a scan turned 8° still fits 0.9 of its points where a stale
    reading predicts no turn: no match can gain the 0.1 of ``odometry_gate_fit`` over it.
    Judged only so (``odometry_gate_explained`` 1: the test a new reading gets is off), the
    matches of the turn are refused and the prediction stands, 8° off; judged as against a
    new reading too — the share of the prediction's misses the match fits — they stand
    (docs/method.md §6.1)."""
    errors = _pivot_facing_a_near_wall(
        override(SlamConfig(), {"front_end.odometry_gate_explained": 1.0}))
    assert errors.max() > 5.0, errors
    errors = _pivot_facing_a_near_wall(SlamConfig())
    assert errors.max() < 1.0, errors


def test_a_match_that_turns_odometrys_heading_past_the_gates_own_part_is_not_a_slide():
    """A match that moves a new reading's position beyond the gate and turns its heading by
    12° — within the gate's share of a 60° turn, beyond its own 5° — is no slide along a
    corridor: odometry's heading is off, and its position with it. Fitting every point
    where the prediction fits few, it overrules odometry; moved 0.35 m with the heading
    right, it does not (docs/method.md §6.1)."""
    fe, scan, pose = _tracked_in_a_room()
    step = np.array([0.3, 0.0, np.radians(60.0)])
    turned = compose(pose, [0.35, 0.0, np.radians(12.0)])
    slid = compose(pose, [0.35, 0.0, 0.0])
    fit = fe.gate.fit(scan, pose)
    assert fit > 0.9
    assert fe.gate.overrules(scan, pose, fit, turned, step, True, False)
    assert not fe.gate.overrules(scan, pose, fit, slid, step, True, False)


def test_a_prediction_that_would_count_as_lost_is_no_place_to_slide_from():
    """The slide along a corridor is refused from a prediction that itself tracks: 0.35 m
    off, odometry's prediction still fits more than ``min_track_inliers`` of the points. At
    0.6 m it fits a tenth of them — odometry's catch-up after a turn put the scan where it
    cannot be (MIT-CSAIL) — and the match fitting them all stands (docs/method.md §6.1)."""
    fe, scan, pose = _tracked_in_a_room()
    step = np.array([0.3, 0.0, 0.0])
    fit = fe.gate.fit(scan, pose)
    near, far = compose(pose, [0.35, 0.0, 0.0]), compose(pose, [0.6, 0.0, 0.0])
    limit = fe.config.front_end.min_track_inliers
    assert fe.gate.fit(scan, near) >= limit > fe.gate.fit(scan, far)
    assert not fe.gate.overrules(scan, pose, fit, near, step, True, False)
    assert fe.gate.overrules(scan, pose, fit, far, step, True, False)


def _tracked_in_a_room():
    """A SLAM that tracked twelve scans of a room's loop with exact odometry: its front end,
    the last scan and that scan's pose in its keyframe's frame."""
    path = loop_path(80)[:12]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k], float(k))
    return slam.front_end, scan, slam.front_end.rel.copy()
