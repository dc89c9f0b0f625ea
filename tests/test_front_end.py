"""The front end's rules (runtime/front_end/; docs/method.md §6.1). First each judged on its
own: a matcher, a reference built from one scan of a room, a scan moved from it by a known
motion, and a prediction, no GraphSlam. Then the scenarios each rule is for, tracked by a
GraphSlam: gaps, glitches, stale and periodic odometry, walls held twice, people, pivots."""

import math

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.front_end.odometry_gate import (OVERRULE_DISTANCE, SLIDE_GAIN,
                                                       OdometryGate, Prediction,
                                                       TrackingCounts, _unbeatable,
                                                       contradicts_odometry, scans_overrule)
from swarmslam.runtime.front_end.odometry_readings import OdometryReadings
from swarmslam.runtime.front_end.recovery import Recovery
from swarmslam.runtime.matching.degeneracy import DegeneracyCheck
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import MatchResult, ScanMatcher
from swarmslam.runtime.pose import compose
from swarmslam.runtime.pose import between, wrap_angle
from swarmslam.runtime.realtime.warm_up import loop_path, pose_after, room_world, scan_at
from swarmslam.runtime.slam import GraphSlam

from slam_scenes import (ANGLES, corridor_with_people, corridor_with_stale_odometry,
                         glitch_run, heading_errors, pivot_facing_a_near_wall, run,
                         tracked_in_a_corridor, tracked_in_a_room, worst_without_and_with)

START = np.array([4.0, 3.5, 0.3])
MOTION = np.array([0.3, 0.05, 0.04])  # the scan's true pose in the reference's frame


class Scene:
    """A reference scan of a furnished room and the scan taken after ``MOTION``."""

    def __init__(self, config: SlamConfig | None = None, seed: int = 0):
        self.config = config or SlamConfig()
        world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=[START])
        self.matcher = ScanMatcher(self.config.matcher, seed=seed)
        self.reference = self.matcher.new_reference()
        first = PointScan.from_ranges(scan_at(world, START, ANGLES, 12.0, 0.005,
                                              np.random.default_rng(1)), ANGLES, 0.05, 12.0)
        self.matcher.build_reference(first, self.reference)
        self.first = first
        self.scan = PointScan.from_ranges(
            scan_at(world, pose_after(START, MOTION), ANGLES, 12.0, 0.005,
                    np.random.default_rng(2)), ANGLES, 0.05, 12.0)
        self.counts = TrackingCounts()
        c = self.config.front_end
        self.gate = OdometryGate(c, self.matcher, self.reference, self.config.sensor.max_points,
                                 self.counts)
        self.degeneracy = DegeneracyCheck(c, self.matcher, self.reference, self.counts)
        self.readings = OdometryReadings(c.stale_motion, c.periodic_odometry_ratio)
        self.recovery = Recovery(self.config, self.matcher, self.reference, self.gate,
                                 self.degeneracy, self.readings, self.counts)

    def predicted(self, guess, odometry=True, stale=False, step=MOTION) -> Prediction:
        return Prediction(np.asarray(guess, np.float64), np.asarray(step, np.float64),
                          np.zeros(3), np.zeros(3), odometry, stale, 0.1)


@pytest.fixture(scope="module")
def scene():
    return Scene()


def test_the_gate_allows_a_fixed_part_and_a_share_of_the_motion():
    c = SlamConfig().front_end  # (0.15 m, 5°) plus (0.2, 0.35) of the motion
    step = np.array([1.0, 0.0, math.radians(20.0)])
    pose = np.zeros(3)
    assert not contradicts_odometry(pose, [0.34, 0.0, 0.0], step, c)
    assert contradicts_odometry(pose, [0.36, 0.0, 0.0], step, c)
    allowed = c.odometry_gate.tolerance[1] + c.odometry_gate.share[1] * step[2]
    assert not contradicts_odometry(pose, [0.0, 0.0, 0.99 * allowed], step, c)
    assert contradicts_odometry(pose, [0.0, 0.0, 1.01 * allowed], step, c)
    assert not contradicts_odometry(pose, [0.0, 0.0, 1.01 * allowed], step, c, heading=False)
    off = override(SlamConfig(), {"front_end.odometry_gate.enabled": False}).front_end
    assert not contradicts_odometry(pose, [9.0, 9.0, 3.0], step, off)


def test_the_overrule_rule_weighs_a_new_reading_by_its_misses_and_a_stale_one_by_a_gain():
    c = SlamConfig().front_end  # odometry_gate.explained 0.45, odometry_gate.fit 0.1
    assert scans_overrule(1.0, 0.9, False, c)  # fits every point the prediction misses
    assert not scans_overrule(0.67, 0.5, False, c)  # two thirds where it fits half
    assert scans_overrule(0.67, 0.5, True, c)  # a stale reading: the plain gain suffices
    assert not scans_overrule(0.95, 0.9, True, c)


@pytest.mark.parametrize("gain", [0.0, 0.05, 0.1, 0.3, 0.999, 1.0])
def test_unbeatable_is_the_least_count_no_share_can_beat_by_the_gain(gain):
    for n in (1, 7, 100, 361):
        k = _unbeatable(n, gain)
        assert all(1.0 - j / n <= gain for j in range(k, n + 1))
        assert k == 0 or 1.0 - (k - 1) / n > gain


def test_a_match_at_its_box_edge_or_off_the_surfaces_has_lost_track(scene):
    at_truth = scene.predicted(MOTION)
    assert scene.gate.fit(scene.scan, MOTION) > 0.9
    assert not scene.gate.lost(scene.scan, MOTION, at_truth, inside=True)
    assert scene.gate.lost(scene.scan, MOTION, at_truth, inside=False)
    off = compose(MOTION, [0.0, 0.0, math.radians(25.0)])
    assert scene.gate.fit(scene.scan, off) < SlamConfig().front_end.min_track_inliers
    assert scene.gate.lost(scene.scan, off, scene.predicted(off), inside=True)


def test_a_match_the_gate_refuses_stands_where_the_scans_overrule_odometry():
    """Odometry's prediction 0.6 m off fits few points: the match at the truth contradicts it
    (the gate) and overrules it, counted; with the rule that a match must explain the
    prediction's misses made impossible, the same match has lost track."""
    s = Scene()
    far = compose(MOTION, [0.6, 0.0, 0.0])
    assert s.gate.fit(s.scan, far) < s.config.front_end.min_track_inliers
    assert not s.gate.lost(s.scan, MOTION, s.predicted(far), inside=True)
    assert s.counts.overruled_odometry == 1
    strict = Scene(override(SlamConfig(), {"front_end.odometry_gate.explained": 1.0}))
    assert strict.gate.lost(strict.scan, MOTION, strict.predicted(far), inside=True)


def test_a_match_that_slides_a_tracking_prediction_is_refused_but_not_one_that_turns_it():
    """Down a corridor, a match moving a new reading's position beyond the gate along it, its
    heading within the gate's own part, from a prediction that tracks and fits as well, may
    have slid: refused. Turning the prediction by 12° (within the share of a 60° turn) it is
    no slide: it overrules odometry as any match that fits where the prediction does not."""
    fe, scan, pose = tracked_in_a_corridor()
    step = np.array([0.3, 0.0, math.radians(60.0)])
    fit = fe.gate.fit(scan, pose)
    slid = compose(pose, [0.25, 0.0, 0.0])
    turned = compose(pose, [0.25, 0.0, math.radians(12.0)])
    assert fe.gate.fit(scan, slid) >= SlamConfig().front_end.min_track_inliers
    assert not fe.gate.overrules(scan, pose, fit, slid, step, True, False)
    assert fe.gate.overrules(scan, pose, fit, turned, step, True, False)
    assert not fe.gate.overrules(scan, pose, fit, turned, step, False, False)  # at the box edge


def test_a_match_the_scans_fit_clearly_better_than_a_slid_prediction_overrules_it(scene):
    """In a furnished room the same slide leaves the prediction fitting ``min_track_inliers``
    but clearly worse than the match (by more than ``SLIDE_GAIN`` of the points): no
    corridor's slide, odometry's position is what errs, and the match stands."""
    gate, scan = scene.gate, scene.scan
    step = np.array([0.3, 0.0, math.radians(60.0)])
    slid = compose(MOTION, [0.25, 0.0, 0.0])
    assert gate.fit(scan, slid) >= SlamConfig().front_end.min_track_inliers
    assert (gate.fit(scan, MOTION, OVERRULE_DISTANCE) - gate.fit(scan, slid, OVERRULE_DISTANCE)
            > SLIDE_GAIN)
    assert gate.overrules(scan, MOTION, gate.fit(scan, MOTION), slid, step, True, False)


def test_the_previous_scan_disowns_a_match_it_fits_clearly_worse_than_the_prediction():
    s = Scene()
    previous = s.gate.previous
    previous.remember(s.first)  # the previous scan at the reference's own pose
    wrong = compose(MOTION, [0.0, 0.0, math.radians(8.0)])
    assert previous.disowns(s.scan, wrong, s.predicted(MOTION))
    assert s.counts.disowned_matches == 1
    assert not previous.disowns(s.scan, MOTION, s.predicted(wrong))  # the match fits better
    assert not previous.disowns(s.scan, wrong, s.predicted(MOTION, stale=True))
    state = previous.state()
    assert np.array_equal(state, s.first.points)
    state[0, 0] = np.nan
    with pytest.raises(ValueError, match="previous scan"):
        previous.restore(state)


def test_the_heading_prior_holds_a_turned_match_to_odometrys_heading(scene):
    """A match turning a new reading's heading by more than σ is weighed against the optimum
    settled from the prediction, each by its λ and its turn: at equal λ the one nearer
    odometry's heading stands. Within σ, or with the prior off, the match stands as it is."""
    s = Scene()
    settled = s.matcher.settle(s.scan, s.reference,
                               MatchResult(MOTION.copy(), math.inf, math.inf, False, 0, 0))
    turned = compose(settled.pose, [0.0, 0.0, math.radians(3.0)])
    match = MatchResult(turned, settled.error, settled.error, False, 0, 0)
    step = np.zeros(3)
    held = s.gate.heading_prior(s.scan, match, s.predicted(MOTION, step=step))
    assert abs(held[2] - MOTION[2]) < math.radians(0.5) and s.counts.held_to_odometry == 1
    near = MatchResult(compose(MOTION, [0.0, 0.0, math.radians(0.5)]), 1.0, 1.0, False, 0, 0)
    assert s.gate.heading_prior(s.scan, near, s.predicted(MOTION, step=step)) is near.pose
    off = Scene(override(SlamConfig(), {"front_end.heading_prior.enabled": False}))
    assert off.gate.heading_prior(off.scan, match, off.predicted(MOTION, step=step)) is turned


def test_recovery_on_scans_alone_keeps_the_better_of_the_lost_match_and_a_free_search():
    s = Scene()
    lost = compose(MOTION, [0.0, 0.0, math.radians(25.0)])
    pose, weak = s.recovery.recover(s.scan, lost, s.predicted(lost, odometry=False), True)
    assert not weak and s.counts.lost_matches == 1
    assert s.gate.fit(s.scan, pose) > 0.9 > s.gate.fit(s.scan, lost)


def test_recovery_with_odometry_finds_a_match_that_overrules_or_lets_the_prediction_stand():
    """Sought again around the scans' last motion, a match that fits where odometry's
    prediction, 0.6 m off, does not overrules it (rescued); when the prediction itself is
    right nothing fits clearly better, and the prediction stands in (the next edge weak)."""
    s = Scene()
    far = compose(MOTION, [0.6, 0.0, 0.0])
    lost = compose(MOTION, [0.0, 0.0, math.radians(25.0)])
    predicted = s.predicted(far)
    predicted.motion = MOTION.copy()  # the scans' last motion, continued: near the truth
    pose, weak = s.recovery.recover(s.scan, lost, predicted, True)
    assert not weak and s.counts.rescued_matches == 1
    assert np.hypot(*(pose[:2] - MOTION[:2])) < 0.05
    right = Scene()
    pose, weak = right.recovery.recover(right.scan, lost, right.predicted(MOTION), True)
    assert weak and np.array_equal(pose, MOTION) and right.counts.rescued_matches == 0


# ------------------------------------------------------------------ scenarios

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


def test_on_scans_alone_the_motion_is_continued_over_the_time_that_passed():
    """After a 2 s gap the match spans the whole gap's motion; the scans after it, 0.1 s
    apart again, are predicted with that motion scaled to their interval, not repeated whole
    (which carried a live pose away at metres a second), and tracked."""
    path = loop_path(400)[:80]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    kept = [k for k in range(80) if not 20 <= k < 40]  # 2 s without scans
    steps = []
    for k in kept:
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, None, 0.1 * k)
        steps.append(float(np.hypot(*slam.front_end._predicted.step[:2])))
    gap = kept.index(40)
    spanned = float(np.hypot(*between(path[40], path[19])[:2]))
    assert spanned > 0.5
    assert steps[gap + 1] < 0.25 * spanned  # the scan after the gap: a tenth of it
    _, poses = slam.trajectory()
    err = np.hypot(*(poses[:, :2] - between(path[kept], path[0])[:, :2]).T)
    assert err.max() < 0.15, err.max()


def test_scans_between_two_nodes_share_the_graphs_correction_of_both():
    # the spread alone: the between-scan smoothing (test_between_scans.py) reads the
    # trajectory, so a bent graph would move what it takes from odometry too
    slam, _, _ = run(config=override(SlamConfig(), {"front_end.between_scans.headings": False,
                                                    "front_end.between_scans.positions": False}))
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


def test_match_contradicting_odometry_is_not_trusted_unless_the_scans_clearly_side_with_it():
    """A scan taken as if the robot had turned 12° more than odometry (right here) says. The
    front end cannot tell such a scan from odometry that erred: it fits the keyframe fully at
    the turned pose, far better than at odometry's prediction. With the scans never allowed to
    overrule odometry (``odometry_gate.fit`` and ``odometry_gate.explained`` 1), the gate
    keeps odometry's prediction for it and tracking goes on from there; by default the scans
    are believed (docs/method.md §6.1: real odometry lags fast turns by that much); with no
    gate at all, likewise."""
    refused = override(SlamConfig(), {"front_end.odometry_gate.fit": 1.0,
                                      "front_end.odometry_gate.explained": 1.0})
    slam, heading_error = glitch_run(refused)
    # (the glitch scan became a node here, so the next scans match against it until the next
    # node: also gated)
    assert 1 <= slam.front_end.counts.lost_matches <= 3 and slam.front_end.counts.overruled_odometry == 0
    assert heading_error[20] < 1.5 and heading_error.max() < 1.5, heading_error
    trusted, heading_error = glitch_run(SlamConfig())
    assert trusted.front_end.counts.overruled_odometry >= 1
    assert heading_error[20] > 8.0, heading_error[20]
    ungated, heading_error = glitch_run(override(SlamConfig(), {"front_end.odometry_gate.enabled": False}))
    assert ungated.front_end.counts.lost_matches == 0 and ungated.front_end.counts.overruled_odometry == 0
    assert heading_error[20] > 8.0, heading_error[20]


def test_a_rescued_match_within_the_gate_stands_when_it_fits_far_better():
    """A robot turning on the spot 30° a scan whose odometry reading jumps 18° ahead once:
    the match around its prediction is pressed against its box's edge (±17°), so it is
    sought again around the scans' own motion and found where the robot is. It corrects
    odometry by less than the gate allows over a 48° step, so it contradicts nothing, and it
    fits far better than the prediction: it stands (docs/method.md §6.1). When new readings
    are never overruled (``odometry_gate.explained`` 1) the prediction stands in, 18° off."""
    loop = loop_path(80)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop)
    turn, jump = np.radians(30.0), np.radians(18.0)
    path = np.array([[loop[0, 0], loop[0, 1], loop[0, 2] + k * turn] for k in range(10)])

    def reading(k):
        return compose(path[k], [0.0, 0.0, jump]) if k >= 6 else path[k]

    slam, errors = heading_errors(SlamConfig(), world, path, reading, 1.0)
    assert slam.front_end.counts.rescued_matches >= 1, errors
    assert errors.max() < 1.0, errors
    refused = override(SlamConfig(), {"front_end.odometry_gate.explained": 1.0})
    slam, errors = heading_errors(refused, world, path, reading, 1.0)
    assert slam.front_end.counts.rescued_matches == 0
    assert errors[6] > 15.0, errors


def test_the_scans_overrule_a_new_reading_by_the_share_of_its_misses_they_fit():
    """Against a new reading the match must fit much of what odometry's prediction misses:
    every point against nine in ten (a prediction a few degrees off in a turn) overrules it;
    two thirds against a half (a hall whose walls fit a slip either way) does not. Against a
    stale reading, which says nothing of the motion, a plain gain above ``odometry_gate.fit``
    suffices."""
    c = SlamConfig().front_end
    assert scans_overrule(1.0, 0.91, stale=False, config=c)
    assert not scans_overrule(0.66, 0.49, stale=False, config=c)
    assert not scans_overrule(1.0, 0.91, stale=True, config=c)  # a gain of 0.09 < 0.1
    assert scans_overrule(0.63, 0.46, stale=True, config=c)
    assert not scans_overrule(0.9, 0.9, stale=False, config=c)
    never = override(SlamConfig(), {"front_end.odometry_gate.explained": 1.0,
                                    "front_end.odometry_gate.fit": 1.0}).front_end
    assert not any(scans_overrule(1.0, p, stale, never) for p in (0.0, 0.5, 0.99)
                   for stale in (False, True))


def test_a_match_that_only_moves_odometrys_position_stands_where_the_scans_place_it():
    """The same glitch as a slide of 0.25 m sideways (odometry's heading right), in a
    furnished room: the scan taken there fits the match and clearly not odometry's
    prediction, so the match overrules it and the pose is where the scan was taken."""
    path = loop_path(80)[:30]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    seen = [compose(path[k], [0.0, 0.25, 0.0]) if k == 20 else path[k] for k in range(30)]
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, seen[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k], float(k))
    assert slam.front_end.counts.overruled_odometry >= 1
    _, poses = slam.trajectory()
    truth = between(np.array(seen), path[0])
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


def test_the_previous_scan_disowns_a_match_on_a_wall_the_submap_holds_twice():
    """Tracked against a submap that holds the hall's walls twice, a scan fits either copy
    about equally, and some seeds' matches take the copy 4.5° off, which odometry's gate (5°)
    lets pass. The previous scan holds each wall once: odometry's prediction fits it clearly
    better than such a match, so the match is lost and the prediction stands
    (docs/method.md §6.1). With the check off (``previous_scan_check.enabled`` false) they go wrong."""
    # (odometry's heading weighed too would hold those matches first: the next test)
    alone = override(SlamConfig(), {"front_end.heading_prior.enabled": False})
    never = override(alone, {"front_end.previous_scan_check.enabled": False})
    worst_unchecked, worst_checked, disowned = worst_without_and_with(never, alone,
                                                                       "disowned_matches")
    assert max(worst_unchecked) > 4.0, worst_unchecked
    assert max(worst_checked) < 0.5 and disowned >= 1, (worst_checked, disowned)


def test_of_two_copies_of_a_wall_the_match_nearer_odometry_stands():
    """The same submap with the wall held twice, the previous scan's check off: a match on
    the copy 4.5° off fits about as well as the optimum at odometry's heading (which saw no
    turn), so with odometry's heading weighed (``heading_prior.weight``) the nearer optimum
    stands (docs/method.md §6.1); weighed at 0, some seeds take the far copy."""
    unweighed = override(SlamConfig(), {"front_end.previous_scan_check.enabled": False,
                                        "front_end.heading_prior.enabled": False})
    weighed = override(SlamConfig(), {"front_end.previous_scan_check.enabled": False})
    worst_unweighed, worst_weighed, held = worst_without_and_with(unweighed, weighed,
                                                                   "held_to_odometry")
    assert max(worst_unweighed) > 4.0, worst_unweighed
    assert max(worst_weighed) < 0.5 and held >= 1, (worst_weighed, held)


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


def test_a_stale_reading_continues_the_last_readings_motion_along_a_corridor():
    """Along a plain corridor the scans cannot tell how far the robot went: the prediction's
    position stands in along the axis (the degeneracy test). With odometry read every fourth
    scan, a stale reading that predicted no motion held three scans in four still and put
    the whole motion into the fourth (the simulator's robot effects: 0.045 m of error a
    scan). A stale reading now continues the translation per scan the last new reading
    showed (``stale_motion``; docs/method.md §6.1), so every scan moves its 0.1 m."""
    fe, errors = corridor_with_stale_odometry(
        override(SlamConfig(), {"front_end.stale_motion": False}))
    assert fe.counts.degenerate_matches > 20
    assert errors.max() > 0.15, errors
    fe, errors = corridor_with_stale_odometry(SlamConfig())
    assert fe.counts.degenerate_matches > 20
    assert errors[4:].max() < 0.03 and errors[4:].mean() < 0.01, errors  # from the 1st reading on


def test_a_person_walking_down_a_corridor_does_not_carry_the_match_along():
    """Along a plain corridor a walking person is the one thing the match can pin the axis
    to, and pins it to themselves: the keyframe reference held them where they were. Their
    returns there lie where another of its node scans saw through (docs/method.md §6.1,
    "Moved points"): left out, the axis stays degenerate and odometry holds it."""
    errors = corridor_with_people(override(SlamConfig(), {"front_end.drop_moved_points": False}))
    assert errors.max() > 0.5, errors
    errors = corridor_with_people(SlamConfig())
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
    over every heading the robot can turn to in half a second (``recovery.pivot_search_rate`` 3 rad/s:
    ±86°), finds it (docs/method.md §6.1, "Recovery"); without it (``recovery.pivot_search_rate`` 0) the
    prediction stands in, 75° off, there and at the next stale scan."""
    loop = loop_path(80)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop)
    turns = np.r_[np.zeros(5), np.arange(1, 4), np.full(3, 3)] * np.radians(75.0)
    path = np.c_[np.tile(loop[0, :2], (len(turns), 1)), loop[0, 2] + turns]

    def every_second_scan(k):
        return path[k - k % 2]

    slam, errors = heading_errors(SlamConfig(), world, path, every_second_scan, 0.5)
    assert slam.front_end.counts.rescued_matches >= 2 and errors.max() < 1.0, errors
    off = override(SlamConfig(), {"front_end.recovery.pivot_search_rate": 0.0})
    slam, errors = heading_errors(off, world, path, every_second_scan, 0.5)
    assert errors[5] > 70.0 and errors[7] > 70.0, errors


def test_a_stale_reading_is_never_held_to_more_than_a_new_one():
    """Facing a wall 0.6 m off, a scan turned 8° still fits 0.9 of its points where a stale
    reading predicts no turn: no match can gain the 0.1 of ``odometry_gate.fit`` over it.
    Judged only so (``odometry_gate.explained`` 1: the test a new reading gets is off), the
    matches of the turn are refused and the prediction stands, 8° off; judged as against a
    new reading too — the share of the prediction's misses the match fits — they stand
    (docs/method.md §6.1)."""
    errors = pivot_facing_a_near_wall(
        override(SlamConfig(), {"front_end.odometry_gate.explained": 1.0}))
    assert errors.max() > 5.0, errors
    errors = pivot_facing_a_near_wall(SlamConfig())
    assert errors.max() < 1.0, errors


def test_a_match_that_turns_odometrys_heading_past_the_gates_own_part_is_not_a_slide():
    """A match that moves a new reading's position beyond the gate and turns its heading by
    12° — within the gate's share of a 60° turn, beyond its own 5° — is no slide along a
    corridor: odometry's heading is off, and its position with it. Fitting every point
    where the prediction fits few, it overrules odometry; moved 0.35 m down a corridor with
    the heading right, it does not (docs/method.md §6.1)."""
    fe, scan, pose = tracked_in_a_room()
    step = np.array([0.3, 0.0, np.radians(60.0)])
    turned = compose(pose, [0.35, 0.0, np.radians(12.0)])
    fit = fe.gate.fit(scan, pose)
    assert fit > 0.9
    assert fe.gate.overrules(scan, pose, fit, turned, step, True, False)
    fe, scan, pose = tracked_in_a_corridor()
    slid = compose(pose, [0.35, 0.0, 0.0])
    assert not fe.gate.overrules(scan, pose, fe.gate.fit(scan, pose), slid, step, True, False)


def test_a_prediction_that_would_count_as_lost_is_no_place_to_slide_from():
    """The slide along a corridor is refused from a prediction that itself tracks: 0.35 m
    off, odometry's prediction still fits more than ``min_track_inliers`` of the points. At
    0.6 m in the room it fits a tenth of them — odometry's catch-up after a turn put the scan
    where it cannot be (MIT-CSAIL) — and the match fitting them all stands; so does the one
    0.35 m off, which the room's scans fit clearly worse (docs/method.md §6.1)."""
    fe, scan, pose = tracked_in_a_room()
    step = np.array([0.3, 0.0, 0.0])
    fit = fe.gate.fit(scan, pose)
    near, far = compose(pose, [0.35, 0.0, 0.0]), compose(pose, [0.6, 0.0, 0.0])
    limit = fe.config.front_end.min_track_inliers
    assert fe.gate.fit(scan, near) >= limit > fe.gate.fit(scan, far)
    assert fe.gate.overrules(scan, pose, fit, far, step, True, False)
    assert fe.gate.overrules(scan, pose, fit, near, step, True, False)
    fe, scan, pose = tracked_in_a_corridor()
    near = compose(pose, [0.35, 0.0, 0.0])
    assert fe.gate.fit(scan, near) >= limit
    assert not fe.gate.overrules(scan, pose, fe.gate.fit(scan, pose), near, step, True, False)
