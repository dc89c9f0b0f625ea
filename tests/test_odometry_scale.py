"""Odometry's scale: fitted to the matches that pin the motion, held by the pose graph's
edges along degenerate axes, and brought to the fit in a loop closure's trial
(docs/method.md §6.1, "Odometry's scale")."""

import numpy as np
import pytest

from swarmslam.runtime.config import ConfigError, SlamConfig, override
from swarmslam.runtime.front_end.odometry_scale import BINS, OdometryScale
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.pose_graph import ODOMETRY, PoseGraph
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.realtime.warm_up import scan_at

ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))


def _fit(steps, matched, prior=0.0, limits=(0.8, 1.25), dead_zone=0.0):
    fit = OdometryScale(prior, limits, dead_zone)
    for o, m in zip(steps, matched):
        fit.observe(m, o)
    return fit


def test_the_fit_finds_a_wheels_scale_from_noisy_matches():
    rng = np.random.default_rng(0)
    o = np.c_[rng.uniform(0.02, 0.08, 2000), rng.normal(0, 0.005, 2000)]
    m = o * 1.03 + rng.normal(0, 0.002, (2000, 2))
    assert _fit(o, m).scale == pytest.approx(1.03, abs=0.002)


def test_steps_dragged_by_passing_people_hardly_move_the_median():
    """One pinned step in six reads a quarter long (a match dragged along by people walking
    beside the robot): the least-squares ratio moves by 4%, the travel-weighted median by
    less than the dead zone."""
    rng = np.random.default_rng(2)
    o = np.c_[rng.uniform(0.02, 0.08, 900), np.zeros(900)]
    m = o * (1 + rng.normal(0, 0.02, (900, 1)))
    m[::6] *= 1.25
    least_squares = float(np.sum(m * o) / np.sum(o * o))
    assert least_squares > 1.035
    assert _fit(o, m, dead_zone=0.005).scale == 1.0


def test_the_prior_holds_a_short_run_near_odometry_and_gives_way_with_travel():
    o = np.tile([0.05, 0.0], (400, 1))  # 20 m at 5 cm a step
    m = o * 1.04
    # (the median to within its bin, 0.00045 wide)
    assert _fit(o[:20], m[:20], prior=5.0).scale == pytest.approx(1 + 0.04 * 1 / 6, abs=3e-4)
    assert _fit(o, m, prior=5.0).scale == pytest.approx(1 + 0.04 * 20 / 25, abs=3e-4)
    assert OdometryScale(5.0, (0.8, 1.25), 0.0).scale == 1.0  # nothing seen: as odometry reads


def test_turns_in_place_and_unusable_matches_say_nothing_and_the_fit_is_clipped():
    fit = _fit([[0.0, 0.0], [0.05, 0.0], [0.05, np.inf], [1e-150, 0.0]],
               [[0.03, 0.01], [np.nan, 0.0], [0.05, 0.0], [1e200, 0.0]], limits=(0.9, 1.1))
    assert not fit.travel.any() and fit.scale == 1.0
    fit.observe([0.1, 0.0], [0.05, 0.0])  # twice as far: counted at the limit
    assert fit.scale == pytest.approx(1.1, abs=2e-4)


def test_the_dead_zone_shrinks_the_fit_towards_one_without_a_jump():
    o = np.tile([0.05, 0.0], (400, 1))
    assert _fit(o, o * 1.004, dead_zone=0.005).scale == 1.0
    assert _fit(o, o * 0.99, dead_zone=0.005).scale == pytest.approx(0.995, abs=3e-4)
    assert _fit(o, o * 1.0061, dead_zone=0.005).scale == pytest.approx(1.0011, abs=3e-4)


def test_a_saved_fit_restores_and_a_foreign_one_is_refused():
    fit = _fit(np.tile([0.1, 0.0], (30, 1)), np.tile([0.105, 0.0], (30, 1)), prior=1.0)
    again = OdometryScale(1.0, (0.8, 1.25), 0.0)
    again.restore(fit.travel.copy())
    assert again.scale == fit.scale
    for bad in (np.ones(3), np.full(BINS, np.nan), -np.ones(BINS)):
        with pytest.raises(ValueError):
            again.restore(bad)


def test_the_limits_must_hold_odometry_as_it_reads():
    for limits in ([1.05, 1.2], [1.0, 1.0]):
        with pytest.raises(ConfigError, match=r"odometry_scale\.limits"):
            override(SlamConfig(), {"front_end.odometry_scale.limits": limits})


def test_the_graph_brings_each_edges_odometry_part_to_a_scale_and_keeps_it_through_copies():
    g = PoseGraph(4, 4)
    for k in range(4):
        g.add_node([k, 0.0, 0.0])
    info = np.eye(3)
    g.add_edge(0, 1, [1.0, 0.0, 0.0], info, ODOMETRY, [0.8, 0.1])
    g.add_edge(1, 2, [1.0, 0.0, 0.1], info)  # no part: a loop, or a step the scans pinned
    g.add_edge(2, 3, [1.0, 0.2, 0.0], info, ODOMETRY, [0.5, 0.0])
    g.rescale(1.1)
    assert g.scale == 1.1
    assert np.allclose(g.z[:3], [[1.08, 0.01, 0.0], [1.0, 0.0, 0.1], [1.05, 0.2, 0.0]])
    g.rescale(1.0, first=2)  # the last edge alone, as the back end brings later ones along
    assert g.scale == 1.1 and np.allclose(g.z[2], [1.0, 0.2, 0.0])
    copy = PoseGraph(4, 4)
    copy.copy_from(g)
    assert copy.scale == 1.1 and np.array_equal(copy.odometry_part[:3], g.odometry_part[:3])
    restored = PoseGraph(4, 4)
    restored.restore(g.state())
    assert restored.scale == 1.1 and np.array_equal(restored.odometry_part[:3],
                                                    g.odometry_part[:3])
    g.remove_edges([1])  # the parts move down with their edges
    assert np.allclose(g.odometry_part[:2], [[0.8, 0.1], [0.5, 0.0]])
    for key, bad in (("odometry_part", np.full((2, 2), np.nan)), ("scale", np.array([0.0, 1.0]))):
        state = g.state()
        state[key] = bad
        with pytest.raises(ValueError):
            PoseGraph(4, 4).restore(state)
    state = g.state()
    del state["odometry_part"], state["scale"]  # saved before the scale: migrated first
    with pytest.raises(KeyError):  # (session.py's migration gives none, at 1)
        PoseGraph(4, 4).restore(state)


def _short_chain(scale_target, n=60, step=0.5, wheel=1 / 1.05):
    """A GraphSlam whose graph is a straight corridor's chain of ``n`` nodes ``step`` apart,
    each edge odometry's distance along the axis (``wheel`` of the truth: 5% short), and its
    back end ready to close a loop measured by the truth; the front end's fit is
    ``scale_target``."""
    slam = GraphSlam(SlamConfig(), seed=0)
    g, back = slam.graph, slam.back_end
    info = slam.front_end.information()
    for k in range(n):
        g.add_node([k * step * wheel, 0.0, 0.0], float(k))
        if k:
            g.add_edge(k - 1, k, [step * wheel, 0.0, 0.0], info, ODOMETRY, [step * wheel, 0.0])
    g.scale_target = scale_target
    back.z_info[:] = slam.front_end.information(loop=True)
    return slam, back, np.array([(n - 2) * step, 0.0, 0.0])


def test_a_loop_closure_is_judged_with_the_edges_at_the_fitted_scale():
    """Odometry 5% short along a corridor: a true loop across its length repairs 1.4 m of drift
    and is refused for the rise with the edges as read; with the fit (1.05) brought into the
    trial, the edges agree with it, it is kept, and the graph takes the scale with it. A loop
    the scaled edges contradict is refused and leaves the edges as they were."""
    slam, back, z = _short_chain(1.0)
    n = slam.graph.n_nodes
    assert not back.close_loop(0, n - 2, z)
    slam, back, z = _short_chain(1.05)
    g = slam.graph
    before = g.z[: g.n_edges].copy()
    assert not back.close_loop(0, n - 2, z / 1.05)  # measured as odometry reads: now drift
    assert g.scale == 1.0 and np.array_equal(g.z[: g.n_edges], before)
    assert back.close_loop(0, n - 2, z)
    assert g.scale == 1.05
    assert np.allclose(g.z[: n - 1, 0], 0.5)
    assert abs(g.poses[n - 2, 0] - z[0]) < 0.01


def _corridor(config, scans=300, wheel=0.95):
    """A corridor 2 m wide driven straight at 0.1 m a scan, plain for its first 10 m (the
    scans do not pin the motion along it) and ribbed across its walls from 10 m on (they do);
    odometry reports ``wheel`` of each step. The SLAM."""
    walls = [[-2.0, y, 40.0, y] for y in (-1.0, 1.0)]
    ribs = [[x, s, x, 0.7 * s] for x in np.arange(10.0, 30.0, 1.1) for s in (-1.0, 1.0)]
    world = np.array(walls + ribs)
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(scans)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    odometry = path[0].copy()
    for k in range(len(path)):
        if k:
            odometry = compose(odometry, wheel * between(path[k], path[k - 1]))
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, odometry.copy(), float(k))
    return slam


def test_the_front_end_fits_the_scale_where_the_scans_pin_it_and_notes_odometrys_part_elsewhere():
    """The plain part's node edges hold odometry's distance, noted as their odometry part;
    the ribbed part's edges hold far less; its matches show odometry 5% short (the fit:
    1/0.95 shrunk by the prior's 5 m and the dead zone). A saved session carries both; off,
    nothing is fitted or noted."""
    slam = _corridor(SlamConfig())
    g, front = slam.graph, slam.front_end
    node_x = g.poses[: g.n_nodes, 0]
    odometry = g.kind[: g.n_edges] == ODOMETRY
    plain = odometry & (node_x[g.ij[: g.n_edges, 1]] < 7.0)
    ribbed = odometry & (node_x[g.ij[: g.n_edges, 0]] > 13.0)
    assert plain.sum() > 5 and ribbed.sum() > 5
    part, z = g.odometry_part[: g.n_edges], g.z[: g.n_edges]
    assert np.allclose(part[plain, 0], z[plain, 0], rtol=0.05)  # (the graph still at 1)
    assert np.all(np.abs(part[ribbed, 0]) < 0.5 * z[ribbed, 0])
    # (about 20 m of ribs against the prior's 5 m of odometry as read)
    assert front.calibration.fit.scale == pytest.approx(1 + (1 / 0.95 - 1) * 20 / 25 - 0.005,
                                                       abs=0.004)
    assert g.scale_target == pytest.approx(front.calibration.fit.scale, abs=0.002)
    again = GraphSlam(SlamConfig(), seed=0)
    again.restore(slam.state())
    assert np.array_equal(again.front_end.calibration.fit.travel, front.calibration.fit.travel)
    assert np.array_equal(again.graph.odometry_part[: g.n_edges], part)
    off = _corridor(override(SlamConfig(), {"front_end.odometry_scale.enabled": False}))
    assert off.front_end.calibration.fit.scale == 1.0
    assert not off.graph.odometry_part.any()
