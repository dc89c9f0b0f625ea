"""Pose graph (Eqs. 18, 20, 21), Gauss–Newton, g2o files."""

import numpy as np
import pytest

from swarmslam.runtime.back_end.graph_optimizer import GaussNewton
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.pose_graph import LOOP, CapacityError, PoseGraph, information_from_sigma
from swarmslam.formats.g2o import G2oFormatError, read_g2o, write_g2o


def square_loop(n_side=10, step=0.5):
    """True poses around a square, heading along it."""
    poses, p = [], np.zeros(3)
    for side in range(4):
        for _ in range(n_side):
            poses.append(p.copy())
            p = compose(p, [step, 0.0, 0.0])
        p = compose(p, [0.0, 0.0, np.pi / 2])
    return np.array(poses)


def noisy_loop_graph(seed=0, sigma=(0.03, 0.03, 0.01)):
    rng = np.random.default_rng(seed)
    truth = square_loop()
    n = len(truth)
    g = PoseGraph(n, n + 1)
    info = np.diag(1.0 / np.square(sigma))
    g.add_node(truth[0])
    for k in range(1, n):
        z = between(truth[k], truth[k - 1]) + rng.normal(0, sigma)
        g.add_node(compose(g.poses[k - 1], z))  # dead reckoning: drifts
        g.add_edge(k - 1, k, z, info)
    g.add_edge(n - 1, 0, between(truth[0], truth[n - 1]), info, LOOP)  # the loop closure
    return g, truth


def test_eq18_error_zero_at_the_measurement_and_g2o_convention():
    g = PoseGraph(2, 1)
    g.add_node([1.0, 2.0, 0.5])
    g.add_node(compose([1.0, 2.0, 0.5], [0.3, -0.2, 0.4]))
    g.add_edge(0, 1, [0.3, -0.2, 0.4], np.eye(3))
    assert np.allclose(g.errors(), 0.0, atol=1e-12)
    g.z[0] = [0.0, 0.0, 0.0]  # then e = z⁻¹ ⊕ (x_i⁻¹ ⊕ x_j) = the relative pose itself
    assert np.allclose(g.errors()[0], [0.3, -0.2, 0.4])
    assert np.isclose(g.chi2(), 0.3**2 + 0.2**2 + 0.4**2)


def test_eq20_information():
    assert np.allclose(information_from_sigma(0.5), 4 * np.eye(3))
    with pytest.raises(ValueError):
        information_from_sigma(0.0)


def test_optimisation_with_a_loop_recovers_the_truth():
    g, truth = noisy_loop_graph()
    n = len(truth)
    before = np.hypot(*(g.poses[:n, :2] - truth[:, :2]).T)
    report = GaussNewton(g).optimize()
    after = np.hypot(*(g.poses[:n, :2] - truth[:, :2]).T)
    # One loop over exact-noise odometry leaves 3 degrees of freedom: χ² ~ χ²₃ (99.5%: 12.8).
    assert report.chi2 < 12.8 < report.chi2_initial
    assert before[-1] > 0.2 and after[-1] < 0.05  # the loop is closed
    assert after.mean() < before.mean()
    assert np.allclose(g.poses[0], truth[0])  # the first pose is fixed


@pytest.mark.parametrize("solver", ["ldl", "superlu"])
def test_solvers_agree(solver):
    g, _ = noisy_loop_graph(seed=3)
    report = GaussNewton(g, solver=solver).optimize()
    ref, _ = noisy_loop_graph(seed=3)
    GaussNewton(ref, solver="ldl").optimize()
    assert np.allclose(g.poses, ref.poses, atol=1e-7)
    assert report.iterations >= 1


def test_capacity_is_refused_without_corrupting_the_graph():
    g = PoseGraph(2, 1)
    g.add_node([0, 0, 0])
    g.add_node([1, 0, 0])
    g.add_edge(0, 1, [1, 0, 0], np.eye(3))
    with pytest.raises(CapacityError, match="node capacity 2"):
        g.add_node([2, 0, 0])
    with pytest.raises(CapacityError, match="edge capacity 1"):
        g.add_edge(1, 0, [-1, 0, 0], np.eye(3))
    assert g.n_nodes == 2 and g.n_edges == 1 and g.chi2() == 0.0
    with pytest.raises(ValueError, match="two distinct existing nodes"):
        PoseGraph(3, 3).add_edge(0, 1, [0, 0, 0], np.eye(3))


def test_g2o_round_trip(tmp_path):
    g, _ = noisy_loop_graph()
    write_g2o(tmp_path / "g.g2o", g)
    back, ids = read_g2o(tmp_path / "g.g2o")
    assert ids == list(range(g.n_nodes))
    assert np.allclose(back.poses[: g.n_nodes], g.poses[: g.n_nodes], atol=1e-8)
    assert np.allclose(back.info[: g.n_edges], g.info[: g.n_edges], rtol=1e-8)
    assert np.isclose(back.chi2(), g.chi2(), rtol=1e-6)


@pytest.mark.parametrize(
    "text, line, field",
    [
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0\n", 2, "theta"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 7 1 0 0 1 0 0 1 0 1\n", 2, "j"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", 2, "id"),
        ("VERTEX_SE2 0 0 0 x\n", 1, "theta"),
        ("VERTEX_XYZ 0 0 0 0\n", 1, "tag"),
    ],
)
def test_g2o_errors_name_line_and_field(tmp_path, text, line, field):
    p = tmp_path / "bad.g2o"
    p.write_text(text)
    with pytest.raises(G2oFormatError) as info:
        read_g2o(p)
    assert info.value.line == line and info.value.field == field
    assert f"bad.g2o:{line}:" in str(info.value)


def test_zero_iterations_leaves_the_graph_as_it_was():
    g, _ = noisy_loop_graph()
    before = g.poses[: g.n_nodes].copy()
    report = GaussNewton(g, max_iterations=0).optimize()
    assert report.chi2 == report.chi2_initial
    assert np.array_equal(g.poses[: g.n_nodes], before)


def test_without_fallback_an_unsettled_optimisation_restores_the_poses():
    # A closure on trial that Gauss-Newton does not absorb in max_iterations is refused: no
    # Levenberg-Marquardt restart, the poses as they were, the report says so.
    g, _ = noisy_loop_graph()
    before = g.poses[: g.n_nodes].copy()
    report = GaussNewton(g, max_iterations=1).optimize(fallback=False)
    assert not report.converged and report.iterations == 1
    assert np.array_equal(g.poses[: g.n_nodes], before)
    settled = GaussNewton(g).optimize(fallback=False)  # enough steps: converged as before
    assert settled.converged and settled.chi2 < 12.8


def test_swapping_an_edge_is_seen_by_the_cached_solver():
    # A rejected loop edge is removed and another candidate's added: the counts are the same
    # as before, the sparsity pattern is not. The reused optimizer must match a fresh one.
    g, truth = noisy_loop_graph()
    n = len(truth)
    true_loop = (g.z[g.n_edges - 1].copy(), g.info[g.n_edges - 1].copy())
    g.remove_last_edge()
    start = g.poses[:n].copy()
    gn = GaussNewton(g)
    g.add_edge(n - 1, 5, [0.0, 0.0, 0.0], 100 * np.eye(3), LOOP)  # a wrong candidate
    gn.optimize()
    g.remove_last_edge()
    g.poses[:n] = start
    g.add_edge(n - 1, 0, *true_loop, LOOP)
    cached = gn.optimize()
    fresh_graph, _ = noisy_loop_graph()
    fresh = GaussNewton(fresh_graph).optimize()
    assert np.isclose(cached.chi2, fresh.chi2, rtol=1e-9)
    assert np.allclose(g.poses[:n], fresh_graph.poses[:n], atol=1e-9)


def test_a_factor_beyond_its_capacity_is_refused_naming_the_field_that_raises_it():
    from swarmslam.runtime.config import field_names
    from swarmslam.runtime.back_end.sparse_ldl import FactorCapacityError

    truth = square_loop()
    n = len(truth)
    g = PoseGraph(n, 2 * n)
    g.add_node(truth[0])
    for k in range(1, n):
        g.add_node(truth[k])
        g.add_edge(k - 1, k, between(truth[k], truth[k - 1]), np.eye(3))
    for k in range(0, n - 7, 2):  # many loops across the chain: fill-in beyond its pattern
        g.add_edge(k, k + 7, between(truth[k + 7], truth[k]), np.eye(3), LOOP)
    with pytest.raises(FactorCapacityError, match=r"raise optimizer\.fill_ratio") as refused:
        GaussNewton(g, fill_ratio=1.0).optimize()
    assert "optimizer.fill_ratio" in field_names()
    assert "capacity is" in str(refused.value)
    GaussNewton(g).optimize()  # the default capacity holds it
