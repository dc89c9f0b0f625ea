"""Graph SLAM end to end on synthetic scans with known poses: loop closure, the map, scans
alone, capacity, the submap reference."""

import os
from pathlib import Path

import numpy as np
import pytest

from swarmslam.formats.map_io import read_pgm, write_map
from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.pose_graph import LOOP
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.runtime.slam import GraphSlam

from slam_scenes import ANGLES, run


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


@pytest.mark.parametrize("stamp, odometry", [(float("nan"), None), (float("inf"), None),
                                              (2.0, (0.0, float("nan"), 0.0)),
                                              (2.0, (float("-inf"), 0.0, 0.0))])
def test_a_step_refuses_what_is_not_finite_and_the_run_goes_on(stamp, odometry):
    slam = GraphSlam(SlamConfig(), seed=0)
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=loop_path(80))
    scan = PointScan(len(ANGLES))
    path = loop_path(80)[:4]
    for k, pose in enumerate(path):
        scan.set_ranges(scan_at(world, pose, ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        if k == 2:
            with pytest.raises(ValueError, match="stamp|odometry"):
                slam.step(scan, odometry, stamp)
        else:
            slam.step(scan, between(pose, path[0]), float(k))
    stamps, poses = slam.trajectory()
    assert list(stamps) == [0.0, 1.0, 3.0] and np.all(np.isfinite(poses))


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


DATA = Path(os.environ.get("SWARMSLAM_DATASETS", Path(__file__).parents[1] / ".." / "shared" / "datasets"))


@pytest.mark.skipif(not (DATA / "radish" / "intel.clf.gz").exists(),
                    reason=f"integration data absent: {DATA / 'radish' / 'intel.clf.gz'}")
def test_intel_first_scans_stay_bounded():
    from swarmslam.replay import replay

    m = replay(DATA / "radish" / "intel.clf.gz", DATA / "radish" / "intel.relations", limit=400)
    assert m["relations_used"] >= 20
    assert m["eT"] < 0.1 and m["eR_deg"] < 1.0, m


def test_submap_reference_tracks_and_closes_the_loop():
    slam, truth, _ = run(config=override(SlamConfig(), {"front_end.submap_nodes": 4}))
    _, poses = slam.trajectory()
    err = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    assert slam.loops_closed >= 1
    assert err.max() < 0.15 and err.mean() < 0.05, (err.max(), err.mean())
    # The reference really holds several scans: more points than the newest scan alone.
    assert slam.front_end.submap.scan.count > slam.nodes.counts[slam.keyframe]
