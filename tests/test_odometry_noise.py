"""Odometry's heading noise learnt from the node steps, and the edge's heading fused with it
(runtime/odometry_noise.py, docs/method.md §6.1)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.odometry_noise import OdometryNoise
from swarmslam.runtime.pose import compose
from survey_slam import node_steps, slam_over
from swarmslam_sim.survey import SCANNERS, OdometryModel, Site, run_survey, site

STRAIGHT = np.array([0.5, 0.0, 0.0])


def noise(window=400, min_steps=20, match_sigma=(0.002, 0.006), floor=1e-4):
    return OdometryNoise(window, min_steps, turn_split=0.25, floor=floor,
                         match_sigma=match_sigma)


def feed(n_steps, residuals, step=STRAIGHT):
    for r in residuals:
        n_steps.add(step, compose(step, np.array([0.0, 0.0, r])))


def test_odometry_sigma_is_the_robust_spread_less_the_matchs_share():
    rng = np.random.default_rng(0)
    n = noise()
    r = rng.normal(0.0, 0.01, 400)
    r[::10] = 0.5  # a tenth of the steps wildly off (a slipping wheel): the median shrugs
    feed(n, r)
    bias, spread = n.bias_and_spread(0.0)
    assert abs(bias) < 0.002 and spread == pytest.approx(0.0113, rel=0.12)
    assert n.sigma(0.0) == pytest.approx(math.sqrt(spread**2 - 0.002**2))


def test_a_bias_is_learnt_and_taken_out_of_odometry():
    n = noise()
    rng = np.random.default_rng(4)
    feed(n, 0.006 + rng.normal(0, 0.001, 100))  # every step turned 0.006 rad too far
    bias, _ = n.bias_and_spread(0.0)
    assert bias == pytest.approx(0.006, abs=3e-4)
    match = STRAIGHT
    z, _ = n.fuse(match, np.diag([400.0, 400.0, 2500.0]), compose(match, [0, 0, bias]))
    assert z[2] == pytest.approx(0.0, abs=1e-12)  # odometry's heading, less its bias, agrees


def test_nothing_is_known_before_enough_steps_and_nothing_when_off():
    n = noise(min_steps=20)
    feed(n, np.full(19, 0.001))
    assert n.sigma(0.0) is None
    z, info = n.fuse(STRAIGHT, np.eye(3), compose(STRAIGHT, np.array([0, 0, 0.01])))
    assert np.array_equal(z, STRAIGHT) and np.array_equal(info, np.eye(3))
    off = noise(window=0)
    feed(off, np.full(50, 0.001))
    assert off.sigma(0.0) is None


def test_left_right_and_straight_steps_are_learnt_apart():
    n = noise()
    rng = np.random.default_rng(1)
    feed(n, rng.normal(0, 0.003, 100))
    assert n.sigma(0.5) is None and n.sigma(-0.5) is None
    feed(n, 0.02 + rng.normal(0, 0.03, 100), step=np.array([0.1, 0.0, 0.5]))
    feed(n, -0.02 + rng.normal(0, 0.01, 100), step=np.array([0.1, 0.0, -0.5]))
    assert n.sigma(0.0) < 0.004 < n.sigma(-0.5) < 0.012 < 0.02 < n.sigma(0.5)
    assert n.bias_and_spread(0.5)[0] == pytest.approx(0.02, abs=0.008)
    assert n.bias_and_spread(-0.5)[0] == pytest.approx(-0.02, abs=0.003)


def test_the_ring_keeps_only_the_last_window_of_steps():
    n = noise(window=50)
    rng = np.random.default_rng(2)
    feed(n, rng.normal(0, 0.05, 50))
    assert n.sigma(0.0) > 0.03
    feed(n, rng.normal(0, 0.004, 50))  # the same robot on a better floor
    assert n.sigma(0.0) < 0.006


def test_the_fused_heading_is_the_information_weighted_mean_and_positions_stay_the_matchs():
    n = noise(match_sigma=(0.004, 0.01), floor=1e-4)
    feed(n, np.random.default_rng(5).normal(0, 0.0074, 400))
    bias, spread = n.bias_and_spread(0.0)
    s2 = n.sigma(0.0) ** 2
    weight = 0.004**2 / (0.004**2 + s2)
    assert 0.2 < weight < 0.5
    match = np.array([0.48, 0.03, 0.01])
    odometry = np.array([0.52, -0.02, 0.03])
    info = np.diag([400.0, 400.0, 2500.0])
    z, fused = n.fuse(match, info, odometry)
    assert z[:2] == pytest.approx(match[:2])
    assert z[2] == pytest.approx(0.01 + weight * (0.02 - bias))
    assert fused[2, 2] == pytest.approx(2500.0 / (1.0 - weight))
    assert np.array_equal(fused[:2], info[:2])


def test_state_round_trip_continues_the_same_estimate():
    n = noise(window=30)
    feed(n, np.random.default_rng(3).normal(0, 0.01, 45))
    m = noise(window=30)
    m.restore(n.state())
    assert m.sigma(0.0) == n.sigma(0.0)
    with pytest.raises(ValueError, match="odometry_noise_window"):
        noise(window=31).restore(n.state())


def _node_heading_errors(survey, window: int):
    """|heading error| of each node step of a run (its graph against the truth)."""
    slam = slam_over(survey, override(SlamConfig(), {"front_end.odometry_noise_window": window}))
    est, ref = node_steps(slam, survey)
    return np.abs(np.angle(np.exp(1j * (est[:, 2] - ref[:, 2])))), slam


def _survey(wheel_noise: float):
    """The building ring's first two sides, 181-beam 180° scans at 5 Hz whose ranges scatter
    by 8 cm (a rough, cluttered floor the match finds hard)."""
    place = site("building", seed=0)
    rough = replace(SCANNERS["sick-1"], noise_std=0.08)
    return run_survey(Site(place.world, place.route[:3].copy()), rough, 5.0,
                      OdometryModel(wheel_noise), seed=0)


def test_good_odometry_steadies_a_noisy_matchs_heading():
    fused, slam = _node_heading_errors(_survey(0.0001), 200)
    alone, _ = _node_heading_errors(_survey(0.0001), 0)
    assert slam.front_end.odometry_noise.sigma(0.0) is not None  # it learnt, and it used it
    assert fused.mean() < 0.6 * alone.mean()


def test_poor_odometry_is_given_little_say():
    fused, slam = _node_heading_errors(_survey(0.03), 200)
    alone, _ = _node_heading_errors(_survey(0.03), 0)
    noise = slam.front_end.odometry_noise
    assert noise.sigma(0.0) > 4 * noise.match_share(0.0)
    assert fused.mean() < 1.1 * alone.mean()
