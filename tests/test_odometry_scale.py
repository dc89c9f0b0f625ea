"""Odometry's scale, fitted to the matches that pin the motion (docs/method.md §6.1)."""

import numpy as np
import pytest

from swarmslam.runtime.config import ConfigError, SlamConfig, override
from swarmslam.runtime.fixed_rate import SlamRuntime
from swarmslam.runtime.odometry_scale import OdometryScale, ScaledEdges
from swarmslam.runtime.pose_graph import ODOMETRY
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.scan import PointScan
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.warm_up import scan_at

ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))


def _observed(scale, odometry_steps, matched_steps):
    for o, m in zip(odometry_steps, matched_steps):
        scale.apply(o)
        scale.observe(m)
    return scale


def test_the_fit_finds_a_wheels_scale_from_noisy_matches():
    rng = np.random.default_rng(0)
    o = np.c_[rng.uniform(0.02, 0.08, 2000), rng.normal(0, 0.005, 2000), np.zeros(2000)]
    m = o * 1.03 + np.c_[rng.normal(0, 0.002, (2000, 2)), np.zeros(2000)]
    scale = _observed(OdometryScale(0.0, (0.8, 1.25), 0.0, 0.0), o, m)
    assert scale.scale == pytest.approx(1.03, abs=0.002)
    # the prediction is odometry's translation scaled, its turn as read
    step = scale.apply(np.array([0.1, -0.02, 0.3]))
    assert np.allclose(step, [0.1 * scale.scale, -0.02 * scale.scale, 0.3])


def test_the_prior_holds_a_short_run_near_odometry_and_gives_way_with_travel():
    o = np.tile([0.05, 0.0, 0.0], (400, 1))  # 20 m at 5 cm a step
    m = o * 1.04
    short = _observed(OdometryScale(5.0, (0.8, 1.25), 0.0, 0.0), o[:20], m[:20])  # 1 m travelled
    assert short.scale == pytest.approx(1 + 0.04 * 1 / 6)  # 1 m of 1.04 against 5 m of 1
    long = _observed(OdometryScale(5.0, (0.8, 1.25), 0.0, 0.0), o, m)
    assert long.scale == pytest.approx(1 + 0.04 * 20 / 25)
    assert OdometryScale(5.0, (0.8, 1.25), 0.0, 0.0).scale == 1.0  # nothing observed: as odometry reads


def test_turns_in_place_and_unusable_matches_say_nothing_and_the_fit_is_clipped():
    scale = OdometryScale(0.0, (0.9, 1.1), 0.0, 0.0)
    _observed(scale, [np.array([0.0, 0.0, 0.5])], [np.array([0.03, 0.01, 0.5])])  # mount offset
    _observed(scale, [np.array([0.05, 0.0, 0.0])], [np.array([np.nan, 0.0, 0.0])])
    assert not scale.sums.any() and scale.scale == 1.0
    _observed(scale, [np.array([0.05, 0.0, 0.0])] * 2, [np.array([0.1, 0.0, 0.0])] * 2)
    assert scale.scale == 1.1  # twice as far, clipped


def test_a_fit_within_the_dead_zone_leaves_odometry_as_it_reads():
    o = np.tile([0.05, 0.0, 0.0], (400, 1))
    near = _observed(OdometryScale(0.0, (0.8, 1.25), 0.005, 0.0), o, o * 1.004)
    assert near.scale == 1.0
    assert np.array_equal(near.apply(np.array([0.1, 0.2, 0.3])), [0.1, 0.2, 0.3])
    far = _observed(OdometryScale(0.0, (0.8, 1.25), 0.005, 0.0), o, o * 0.99)
    assert far.scale == pytest.approx(0.99)


def test_a_fit_is_used_only_once_the_steps_scatter_leaves_it_clear_of_the_dead_zone():
    """Steps 1.5% long with 4 mm of scatter each (8% of a 5 cm step): a few metres cannot
    tell 1.015 from the dead zone's edge, tens of metres can."""
    rng = np.random.default_rng(1)
    o = np.c_[np.full(2000, 0.05), np.zeros(2000), np.zeros(2000)]
    m = o * 1.015 + np.c_[rng.normal(0, 0.004, (2000, 2)), np.zeros(2000)]
    few = _observed(OdometryScale(0.0, (0.8, 1.25), 0.005, 2.0), o[:40], m[:40])  # 2 m
    assert few.scale == 1.0
    many = _observed(OdometryScale(0.0, (0.8, 1.25), 0.005, 2.0), o, m)  # 100 m
    assert many.scale == pytest.approx(1.015, abs=0.003)
    exact = _observed(OdometryScale(0.0, (0.8, 1.25), 0.005, 2.0), o[:3], o[:3] * 1.015)
    assert exact.scale == pytest.approx(1.015)  # no scatter: three steps suffice


def test_a_saved_fit_restores_and_a_foreign_one_is_refused():
    scale = _observed(OdometryScale(1.0, (0.8, 1.25), 0.0, 0.0), [np.array([0.1, 0, 0])] * 30,
                      [np.array([0.105, 0, 0])] * 30)
    again = OdometryScale(1.0, (0.8, 1.25), 0.0, 0.0)
    again.restore(scale.sums.copy())
    assert again.scale == scale.scale
    for bad in ([1.0, 2.0, 1.0], [np.nan, 1.0, 1.0, 1.0, 2.0], [1.0, -1.0, 1.0, 1.0, 2.0]):
        with pytest.raises(ValueError):
            again.restore(bad)


def test_the_limits_must_hold_odometry_as_it_reads():
    with pytest.raises(ConfigError):
        override(SlamConfig(), {"front_end.odometry_scale_limits": [1.05, 1.2]})


def _corridor(config, ribs_from, ribs_to, wheel=0.95, scans=300):
    """A corridor 2 m wide with ribs across its walls from ``ribs_from`` to ``ribs_to`` m (there
    the scans pin the motion; elsewhere they do not pin it along the axis), driven straight at
    0.1 m a scan; odometry reports ``wheel`` of each step. The SLAM and the path."""
    walls = [[-2.0, y, 40.0, y] for y in (-1.0, 1.0)]
    ribs = [[x, s, x, 0.7 * s] for x in np.arange(ribs_from, ribs_to, 1.1) for s in (-1.0, 1.0)]
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(scans)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    odometry = path[0].copy()
    for k in range(len(path)):
        if k:
            odometry = compose(odometry, wheel * between(path[k], path[k - 1]))
        scan.set_ranges(scan_at(np.array(walls + ribs), path[k], ANGLES, 12.0, 0.01, rng),
                        ANGLES, 0.05, 12.0)
        slam.step(scan, odometry.copy(), float(k))
    return slam, path


def _plain_part(slam, end):
    """The summed length along the axis of the node edges that end before ``end`` m, and the
    true distance they span (a node's stamp is its scan's index, 0.1 m apart)."""
    g = slam.graph
    edges = [k for k in range(g.n_edges)
             if g.kind[k] == ODOMETRY and 0.1 * g.stamps[g.ij[k][1]] < end]
    first, last = g.ij[edges[0]][0], g.ij[edges[-1]][1]
    return float(np.sum(g.z[edges, 0])), 0.1 * (g.stamps[last] - g.stamps[first])


def test_a_corridors_first_pass_follows_the_scale_learnt_after_it():
    """A plain corridor first (odometry's distance stands in along it, at a scale not yet
    known), then ribs that show odometry 5% short: the node edges of the plain part follow
    the scale learnt afterwards, so they come to the corridor's true length; without, they
    keep odometry's 5% short."""
    off = override(SlamConfig(), {"front_end.calibrate_odometry_scale": False})
    slam_off, _ = _corridor(off, 10.0, 30.0)
    slam_on, _ = _corridor(SlamConfig(), 10.0, 30.0)
    assert slam_on.front_end.odometry_scale.scale == pytest.approx(1 / 0.95, abs=0.015)
    length_off, true_off = _plain_part(slam_off, 8.0)
    length_on, true_on = _plain_part(slam_on, 8.0)
    assert length_off < 0.96 * true_off
    edges = slam_on.front_end.scaled_edges
    assert np.any(edges.raw[: slam_on.graph.n_edges, 0] > 0.3)  # the plain part's edges
    assert edges.applied == slam_on.front_end.odometry_scale.scale
    assert length_on == pytest.approx(0.95 * true_on * edges.applied, rel=0.01)
    assert length_on > 0.98 * true_on


def test_a_resumed_session_keeps_the_scale_and_the_edges_odometry_parts(tmp_path):
    slam, _ = _corridor(SlamConfig(), 0.0, 12.0, scans=200)  # ribs, then 8 m plain
    runtime = SlamRuntime(SlamConfig(), seed=0)
    runtime.slam = slam
    runtime.save(tmp_path / "s.session")
    resumed = SlamRuntime.resume(tmp_path / "s.session").slam.front_end
    front = slam.front_end
    n = slam.graph.n_edges
    assert front.odometry_scale.scale != 1.0
    assert resumed.odometry_scale.scale == front.odometry_scale.scale
    assert np.any(front.scaled_edges.raw[:n] != 0)
    for part in ("raw", "used"):
        assert np.array_equal(getattr(resumed.scaled_edges, part)[:n],
                              getattr(front.scaled_edges, part)[:n])
    assert resumed.scaled_edges.applied == front.scaled_edges.applied
    with pytest.raises(ValueError):
        ScaledEdges(10).restore({"raw": np.zeros((3, 2)), "used": np.full((3, 2), np.nan),
                                 "pending": np.zeros((2, 2)), "applied": 1.0}, 3)


def _ribbed_then_plain_corridor(config, wheel=0.95):
    """A corridor 2 m wide with ribs across its walls for 20 m (the scans pin the motion),
    then plain (they do not pin it along the axis), driven straight at 0.1 m a scan; odometry
    reports ``wheel`` of each step. The front end, and the trajectory's error along the axis
    at the end."""
    walls = [[-2.0, y, 40.0, y] for y in (-1.0, 1.0)]
    ribs = [[x, s, x, 0.7 * s] for x in np.arange(0.5, 20.0, 1.1) for s in (-1.0, 1.0)]
    world = np.array(walls + ribs)
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(300)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    odometry = path[0].copy()
    for k in range(len(path)):
        if k:
            odometry = compose(odometry, wheel * between(path[k], path[k - 1]))
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, odometry.copy(), float(k))
    _, poses = slam.trajectory()
    return slam.front_end, abs(poses[-1, 0] - path[-1, 0])


def test_a_plain_corridor_is_measured_with_the_scale_the_scans_showed_before_it():
    """Where the ribs are, the matches show odometry short by 5%; along the corridor, where the
    prediction stands in, the scaled prediction keeps the trajectory near the truth where
    odometry as read falls behind by 5% of the corridor's length."""
    off = override(SlamConfig(), {"front_end.calibrate_odometry_scale": False})
    fe_off, error_off = _ribbed_then_plain_corridor(off)
    fe_on, error_on = _ribbed_then_plain_corridor(SlamConfig())
    assert fe_off.degenerate_matches > 60 and fe_on.degenerate_matches > 60
    assert fe_off.odometry_scale.scale == 1.0  # off: nothing fitted
    # (20 m of ribs against the prior's 5 m of odometry as read)
    assert fe_on.odometry_scale.scale == pytest.approx(1 / 0.95, abs=0.015)
    assert error_off > 0.3  # 5% of the ~10 m of corridor
    assert error_on < 0.4 * error_off, (error_on, error_off)
