"""Odometry's distance scale learnt from the steps the match pinned, and applied where it could
not (runtime/odometry_scale.py, docs/method.md §6.1)."""

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.odometry_scale import OdometryScale
from swarmslam.runtime.session import read_session, write_session
from survey_slam import node_steps, slam_over
from swarmslam_sim.survey import OdometryModel, Site, run_survey, site


def scale(window=50, min_steps=5, dead_zone=0.005, confidence=0.0, max_edges=8):
    return OdometryScale(window, min_steps, min_step=0.2, max_turn=0.02, dead_zone=dead_zone,
                         confidence=confidence, max_edges=max_edges)


def feed(s, ratios, counted=0.5):
    for r in ratios:
        s.add_step(np.array([counted * r, 0.001, 0.0]), np.array([counted, 0.0, 0.0]))


def test_the_scale_is_the_median_matched_over_counted_once_enough_steps_were_seen():
    s = scale()
    feed(s, [1.02, 1.01, 1.015, 1.012])
    assert s.scale == 1.0  # four of five steps
    feed(s, [1.3])  # one wild step: the median shrugs
    assert s.scale == pytest.approx(1.015)


def test_within_the_dead_zone_odometry_is_taken_as_it_is():
    s = scale(dead_zone=0.005)
    feed(s, [1.004] * 10)
    assert s.scale == 1.0
    feed(s, [1.008] * 15)
    assert s.scale == pytest.approx(1.008)


def test_a_few_scattered_steps_do_not_move_it():
    s = scale(min_steps=5, dead_zone=0.005, confidence=2.0)
    feed(s, [0.99, 1.04, 1.0, 1.03, 0.985, 1.035])  # median 1.015, but ±3% each: ±2.7%
    assert s.count == 6 and s.scale == 1.0
    feed(s, 1.012 + np.random.default_rng(0).normal(0.0, 0.002, 40))  # steady: it is sure
    assert s.scale == pytest.approx(1.012, abs=0.002)


def test_turns_and_short_steps_teach_nothing():
    s = scale(min_steps=1)
    s.add_step(np.array([0.55, 0.0, 0.1]), np.array([0.5, 0.0, 0.1]))  # turning 0.1 rad
    s.add_step(np.array([0.11, 0.0, 0.0]), np.array([0.1, 0.0, 0.0]))  # 0.1 m
    assert s.count == 0 and s.scale == 1.0
    s.add_step(np.array([0.55, 0.2, 0.0]), np.array([0.5, 0.0, 0.0]))  # sideways: no scale
    assert s.scale == pytest.approx(1.1)


def test_marked_edges_follow_the_scale_and_others_stay():
    s = scale(min_steps=1, dead_zone=0.0)
    z = np.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.3, 0.3, 0.1]])
    s.mark_edge(0, np.array([1.0, 0.0]), np.array([0.5, 0.02, 0.0]), applied=1.0)
    s.mark_edge(1, np.array([0.0, 1.0]), np.array([0.01, 0.4, 0.0]), applied=1.0)
    before = z.copy()
    feed(s, [1.02])
    s.rescale(z, 3)
    assert z[0] == pytest.approx(before[0] + [0.02 * 0.5, 0.0, 0.0])
    assert z[1] == pytest.approx(before[1] + [0.0, 0.02 * 0.4, 0.0])
    assert np.array_equal(z[2], before[2])
    feed(s, [0.98] * 2)  # the median falls back to 0.98: the edges follow, from 1.02
    s.rescale(z, 3)
    assert z[0] == pytest.approx(before[0] + [-0.02 * 0.5, 0.0, 0.0])


def test_state_round_trip_continues_the_same_estimate():
    s = scale(min_steps=1, dead_zone=0.0)
    s.mark_edge(2, np.array([1.0, 0.0]), np.array([0.5, 0.0, 0.0]), applied=1.0)
    feed(s, [1.01, 1.03, 1.02])
    t = scale(min_steps=1, dead_zone=0.0)
    t.restore(s.state(3))
    assert t.scale == s.scale and t.marked[2] and t.count == 3
    feed(s, [1.04])
    feed(t, [1.04])
    assert t.scale == s.scale
    with pytest.raises(ValueError, match="odometry_scale_window"):
        scale(window=49).restore(s.state(3))


def test_a_session_file_keeps_what_was_learnt(tmp_path):
    s = scale(min_steps=1, dead_zone=0.0)
    s.mark_edge(1, np.array([0.0, 1.0]), np.array([0.0, 0.5, 0.0]), applied=1.0)
    feed(s, [1.01, 1.02])
    path = write_session(tmp_path / "s.npz", {"odometry_scale": s.state(2)})
    t = scale(min_steps=1, dead_zone=0.0)
    t.restore(read_session(path)["odometry_scale"])
    z = np.zeros((8, 3))
    t.rescale(z, 2)  # the restored mark follows the restored scale from where it was made
    assert t.scale == pytest.approx(1.015) and z[1, 1] == pytest.approx(0.015 * 0.5)


def _corridor_lengths(window: int):
    """One lap of a ring of plain corridors (`corridor`, 132 m; 360° RPLidar A1 reaching 12 m
    at 5.5 Hz) on odometry whose right wheel is 2% larger than believed: the graph's node
    steps against the true ones, and the run."""
    place = site("corridor", seed=1)
    survey = run_survey(Site(place.world, place.route[:5].copy()), "rplidar-a1", 5.5,
                        OdometryModel(0.003, right_wheel_scale=1.02), seed=1)
    config = override(SlamConfig(), {"front_end.odometry_scale_window": window,
                                      "sensor.max_range": survey.lidar.max_range})
    slam = slam_over(survey, config)
    est, ref = node_steps(slam, survey)
    return np.hypot(*est[:, :2].T).sum(), np.hypot(*ref[:, :2].T).sum(), slam


def test_a_corridor_on_a_mis_sized_wheel_comes_out_its_true_length():
    learnt, truth, slam = _corridor_lengths(100)
    assert slam.front_end.degenerate_matches > 100  # the corridor's axis went unseen
    # the right wheel 2% larger: odometry counts 1/1.0102 of the distance; the few steps the
    # matches pin read it 1.013 (the matches' own place-to-place spread is about ±0.5%)
    assert slam.front_end.odometry_scale.scale == pytest.approx(1.0102, abs=0.004)
    assert abs(learnt / truth - 1.0) < 0.003
    counted, truth, _ = _corridor_lengths(0)
    assert counted / truth - 1.0 < -0.004  # without it, short by odometry's count
