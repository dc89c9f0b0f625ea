"""The scans between nodes smoothed with odometry's motion (swarmslam.runtime.front_end.between_scans,
docs/method.md §6.2 "Between-scan poses")."""

import copy

import numpy as np
import pytest

from swarmslam.runtime.front_end.between_scans import (FIRST_READING, NEW_READING, NO_READING,
                                             STALE_READING, BetweenSmoothing, estimate_noise,
                                             smooth_headings, smooth_positions)
from swarmslam.runtime.config import SlamConfig, override, to_dict
from swarmslam.runtime.pose import between, compose, wrap_angle
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.session import migrate
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at

from old_sessions import as_version_6
from slam_scenes import ANGLES, run


def survey(n=3000, per_node=3, match=0.004, node_noise=0.0, odometry=0.002, seed=0):
    """A run's record: true headings, every ``per_node``-th scan a node's; the between scans'
    matches err by ``match`` (rad, white), the nodes by ``node_noise``, odometry's turn by
    ``odometry`` a reading (a random walk)."""
    rng = np.random.default_rng(seed)
    truth = np.cumsum(rng.normal(0.0, 0.01, n))
    node = np.arange(n) // per_node
    is_node = np.arange(n) % per_node == 0
    placed = truth + rng.normal(0.0, node_noise, n)  # where the graph put each node ...
    frame = placed[node * per_node]  # ... and so its frame
    rel = np.zeros((n, 3))
    rel[:, 2] = np.where(is_node, 0.0, truth - frame + rng.normal(0.0, match, n))
    reading = truth + np.cumsum(rng.normal(0.0, odometry, n))
    nodes = n // per_node
    step = np.full((nodes, 3), np.nan)
    step[:-1, 2] = frame[per_node::per_node] - frame[:-per_node:per_node]
    return dict(node=node, rel=rel, is_node=is_node, headings=frame + rel[:, 2],
                odometry=reading, kind=np.full(n, NEW_READING), step=step), truth - frame


def poses(headings):
    out = np.zeros((len(headings), 3))
    out[:, 2] = headings
    return out


def smoothed(record, **config):
    """The headings in node frames, the between ones smoothed (None: nothing was), and the
    noise."""
    return smooth_headings(record["node"], record["rel"], record["is_node"],
                           poses(record["headings"]), poses(record["odometry"]), record["kind"],
                           record["step"], BetweenSmoothing(**config))


def error(headings, truth, is_node):
    return float(np.mean(np.abs(wrap_angle(headings - truth))[~is_node]))


def test_the_three_noises_are_told_apart():
    record, _ = survey(n=6000, match=0.004, node_noise=0.003, odometry=0.002)
    d = np.asarray(wrap_angle(record["headings"] - record["odometry"]))
    noise = estimate_noise(lambda p, q: wrap_angle(d[q] - d[p]), record["is_node"],
                           record["kind"], 30)
    assert np.sqrt(noise.between) == pytest.approx(0.004, rel=0.15)
    assert np.sqrt(noise.node) == pytest.approx(0.003, rel=0.25)
    assert np.sqrt(noise.odometry) == pytest.approx(0.002, rel=0.2)
    assert noise.trusted(2.0)


def test_noisy_matches_are_smoothed_and_the_nodes_kept():
    record, truth = survey(match=0.004, node_noise=0.002, odometry=0.002)
    out, noise = smoothed(record)
    assert noise.trusted(2.0)
    assert error(out, truth, record["is_node"]) < 0.8 * error(record["rel"][:, 2], truth,
                                                              record["is_node"])
    assert np.array_equal(out[record["is_node"]], record["rel"][record["is_node"], 2])


def test_odometry_noisier_than_the_matches_changes_nothing():
    record, _ = survey(match=0.0005, odometry=0.01)
    out, noise = smoothed(record)
    assert not noise.trusted(2.0) and out is None


def test_too_few_pairs_changes_nothing():
    record, _ = survey(n=60)
    out, noise = smoothed(record)
    assert noise is None and out is None


def test_a_scan_without_a_new_reading_keeps_its_match():
    record, _ = survey()
    kind = record["kind"]
    kind[4], kind[7] = STALE_READING, NO_READING  # both between scans (4 % 3, 7 % 3 = 1)
    out, noise = smoothed(record)
    assert noise.trusted(2.0)
    assert out[4] == record["rel"][4, 2] and out[7] == record["rel"][7, 2]
    assert out[5] != record["rel"][5, 2]


def test_odometry_restarting_in_another_frame_is_not_a_turn():
    """After a scan without a reading, or where odometry starts afresh, its headings may be
    in another frame: no turn is taken across either. (The frame turns by less than the gate
    lets through, so only the break keeps it out.)"""
    for gap in (NO_READING, FIRST_READING):
        record, _ = survey(seed=1)
        plain, _ = smoothed(record)
        half = len(record["node"]) // 2 + 1  # a between scan, a between scan after it
        record["odometry"][half:] += 0.015  # odometry's frame turned from here
        record["kind"][half] = gap
        out, _ = smoothed(record)
        read = [half + 1] if gap == NO_READING else [half, half + 1]
        assert np.abs(out[read] - plain[read]).max() < 0.003  # (taken as a turn: 0.007-0.009)


def test_a_turn_odometry_got_wrong_is_not_taken_in():
    record, truth = survey(seed=2)
    plain, _ = smoothed(record)
    record["odometry"][301:] += 0.05  # a wheel slipped between scans 300 and 301 (both between)
    out, _ = smoothed(record)
    assert abs(out[301] - truth[301]) < 3 * 0.004
    assert abs(out[301] - plain[301]) < 0.004


def test_the_front_end_records_what_odometry_read_at_each_scan():
    path = loop_path(80)[:12]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    readings = [path[0], path[1], path[1], None, path[4], path[5]]
    for k, reading in enumerate(readings):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, reading, float(k))
    fe = slam.front_end
    assert fe.scans.reading[: fe.scans.n].tolist() == [
        FIRST_READING, NEW_READING, STALE_READING, NO_READING, FIRST_READING, NEW_READING]
    assert np.allclose(fe.scans.odometry[[0, 1, 4, 5]], path[[0, 1, 4, 5]])
    # a session keeps them; one saved before odometry's pose was kept (its heading alone, or
    # nothing) is migrated with none read
    state = slam.state()
    again = GraphSlam(SlamConfig(), seed=0)
    again.restore(state)
    assert np.array_equal(again.front_end.scans.reading[:6], fe.scans.reading[:6])
    assert np.array_equal(again.front_end.scans.odometry[:6], fe.scans.odometry[:6])
    v6 = as_version_6({"slam": state, "inbox": {}, "config": to_dict(SlamConfig())})
    saved = v6["slam"]["front_end"].pop("scan_odometry")
    v6["slam"]["front_end"]["scan_odometry_heading"] = saved[:, 2]
    old = GraphSlam(SlamConfig(), seed=0)
    old.restore(migrate(copy.deepcopy(v6), 6)["slam"])
    assert not old.front_end.scans.reading[:6].any()
    del v6["slam"]["front_end"]["scan_reading"], v6["slam"]["front_end"]["scan_odometry_heading"]
    older = GraphSlam(SlamConfig(), seed=0)
    older.restore(migrate(v6, 6)["slam"])
    assert not older.front_end.scans.reading[:6].any()
    state["front_end"]["scan_odometry"] = saved
    state["front_end"]["scan_reading"] = np.full(6, 7, np.int8)
    with pytest.raises(ValueError, match="odometry readings"):
        GraphSlam(SlamConfig(), seed=0).restore(state)
    state["front_end"]["scan_reading"] = fe.scans.reading[:6].copy()
    state["front_end"]["scan_odometry"] = np.where(np.arange(6)[:, None] == 4, np.nan, saved)
    with pytest.raises(ValueError, match="finite pose"):
        GraphSlam(SlamConfig(), seed=0).restore(state)


def noisy_run(config):
    """A run whose odometry is far better than its matches: its record, odometry's pose at
    every scan, the truth; the matches made noisier than the run's, as a far-reaching
    scanner's in a wide hall."""
    slam, truth, _ = run(steps=150, laps=1.0, config=config)
    fe = slam.front_end
    n = fe.scans.n
    node = fe.scans.node[:n]
    is_node = np.r_[True, node[1:] != node[:-1]]
    rng = np.random.default_rng(0)
    fe.scans.reading[:n] = NEW_READING
    fe.scans.odometry[:n] = truth[:n]
    fe.scans.odometry[:n, 2] += np.cumsum(rng.normal(0.0, 1e-4, n))
    fe.scans.odometry[:n, :2] += np.cumsum(rng.normal(0.0, 1e-4, (n, 2)), axis=0)
    return slam, truth[:n], is_node, rng


def test_the_trajectory_smooths_the_headings_between_nodes_only():
    """Noisy matched headings: the trajectory's between scans come nearer the truth in
    heading, its node scans stay where the graph put them."""
    config = override(SlamConfig(), {"front_end.between_scans.min_pairs": 10,
                                     "front_end.between_scans.positions": False})
    slam, truth, is_node, rng = noisy_run(config)
    fe = slam.front_end
    fe.scans.rel[: fe.scans.n, 2] += np.where(is_node, 0.0, rng.normal(0.0, 0.01, fe.scans.n))
    _, smoothed_poses = slam.trajectory()
    assert fe.scans.heading_noise.trusted(BetweenSmoothing().significance)
    fe.scans.config = override(config, {"front_end.between_scans.headings": False}).front_end
    _, matched = slam.trajectory()
    assert np.array_equal(smoothed_poses[is_node], matched[is_node])
    assert np.allclose(smoothed_poses[:, :2], matched[:, :2], rtol=0, atol=1e-12)
    assert error(smoothed_poses[:, 2], truth[:, 2], is_node) < 0.6 * error(
        matched[:, 2], truth[:, 2], is_node)


def test_the_trajectory_smooths_the_positions_between_nodes_only():
    """Noisy matched positions: the between scans come nearer the truth in position, the
    node scans stay where the graph put them and no heading moves."""
    config = override(SlamConfig(), {"front_end.between_scans.min_pairs": 10,
                                     "front_end.between_scans.headings": False})
    slam, truth, is_node, rng = noisy_run(config)
    fe = slam.front_end
    n = fe.scans.n
    fe.scans.rel[:n, :2] += np.where(is_node[:, None], 0.0, rng.normal(0.0, 0.02, (n, 2)))
    _, smoothed_poses = slam.trajectory()
    assert fe.scans.position_noise.trusted(BetweenSmoothing().significance)
    fe.scans.config = override(config, {"front_end.between_scans.positions": False}).front_end
    _, matched = slam.trajectory()
    assert np.array_equal(smoothed_poses[is_node], matched[is_node])
    assert np.array_equal(smoothed_poses[:, 2], matched[:, 2])

    def distance(p):
        return float(np.hypot(*(p[:, :2] - truth[:, :2]).T)[~is_node].mean())
    assert distance(smoothed_poses) < 0.6 * distance(matched)


def test_positions_are_smoothed_in_each_node_frame():
    """On a record of positions (odometry's a random walk of 2 mm a reading in a frame of its
    own, the matches 4 mm white, the robot turning), the fit recovers both noises and the
    smoothed positions come nearer the truth; odometry noisier than the matches changes
    nothing."""
    rng = np.random.default_rng(3)
    n, per_node = 3000, 3
    heading = np.cumsum(rng.normal(0.0, 0.02, n))
    truth = np.zeros((n, 3))
    truth[:, 2] = heading
    truth[1:, 0] = np.cumsum(0.1 * np.cos(heading[:-1]))
    truth[1:, 1] = np.cumsum(0.1 * np.sin(heading[:-1]))
    node = np.arange(n) // per_node
    is_node = np.arange(n) % per_node == 0
    frame = truth[node * per_node]
    exact = between(truth, frame)  # each scan in its node's frame
    for walk, white, engaged in ((0.002, 0.004, True), (0.02, 0.0005, False)):
        rel = exact.copy()
        rel[:, :2] += np.where(is_node[:, None], 0.0, rng.normal(0.0, white, (n, 2)))
        odometry = compose(np.array([5.0, -2.0, 2.0]), truth)  # in a frame of its own
        odometry[:, :2] += np.cumsum(rng.normal(0.0, walk, (n, 2)), axis=0)
        step = np.full((n // per_node, 3), np.nan)
        step[:-1] = between(truth[per_node::per_node], truth[:-per_node:per_node])
        out, noise = smooth_positions(node, rel, is_node, compose(frame, rel), odometry,
                                      np.full(n, NEW_READING), step, BetweenSmoothing())
        assert noise.trusted(2.0) == engaged
        if not engaged:
            assert out is None
            continue
        assert np.sqrt(noise.between) == pytest.approx(white, rel=0.15)
        assert np.sqrt(noise.odometry) == pytest.approx(walk, rel=0.25)
        assert np.array_equal(out[is_node], rel[is_node, :2])
        miss = lambda p: np.hypot(*(p - exact[:, :2]).T)[~is_node].mean()
        assert miss(out) < 0.8 * miss(rel[:, :2])
