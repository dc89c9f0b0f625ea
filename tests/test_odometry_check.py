"""What a run shows of its odometry (scripts/evaluation/odometry_check.py)."""

import doctest

import numpy as np
import pytest

from swarmslam.evaluation import odometry_check
from swarmslam.cli import main
from swarmslam.evaluation.odometry_check import odometry_seen, translation_scale
from swarmslam.replay import replay_run
from swarmslam.runtime.front_end.between_scans import NEW_READING, NO_READING, STALE_READING
from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at

ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))


def test_the_docstring_example_runs():
    result = doctest.testmod(odometry_check)
    assert result.attempted >= 1 and result.failed == 0


def test_the_scale_is_read_only_across_readings_odometry_links():
    """Stale readings are passed over (they say nothing of the motion since), and no motion is
    read across a scan without a reading: there odometry starts afresh, here 10 m away."""
    path = np.c_[np.arange(40) * 0.1, np.zeros(40), np.zeros(40)]
    odometry = path * [1.0 / 1.04, 1.0, 1.0]
    odometry[20:, 0] += 10.0  # a restart: read across it, the scale would be near 0
    kind = np.full(40, NEW_READING)
    kind[1::2] = STALE_READING
    kind[20] = NO_READING
    kind[21] = NEW_READING
    scale, pairs = translation_scale(path, odometry, kind)
    assert scale == pytest.approx(1.04)
    assert pairs == 18  # 9 pairs of new readings before the break and 9 after it
    assert translation_scale(path, odometry, np.full(40, NO_READING)) == (None, 0)
    assert translation_scale(path, np.zeros((40, 3)), np.full(40, NEW_READING))[0] is None


def test_a_runs_trajectory_shows_a_wheel_radius_set_too_large():
    """A robot whose odometry counts 5% too far (a wheel radius set 5% large), mapped on the
    demo loop: the run says the robot went 1/1.05 of what odometry read."""
    truth = loop_path(80)
    truth = np.vstack([truth, truth])[:100]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=truth)
    rng = np.random.default_rng(0)
    slam = GraphSlam(SlamConfig(), seed=0)
    odometry = truth[0].copy()
    scan = PointScan(len(ANGLES))
    for k in range(len(truth)):
        if k:
            step = between(truth[k], truth[k - 1]) * [1.05, 1.05, 1.0]
            odometry = compose(odometry, step + rng.normal(0, [0.005, 0.005, 0.002]))
        scan.set_ranges(scan_at(world, truth[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, odometry.copy(), stamp=float(k))
    _, poses = slam.trajectory()
    seen = odometry_seen(slam.front_end, poses)
    assert seen["translation_scale"] == pytest.approx(1 / 1.05, abs=0.01)
    assert seen["pairs"] == len(truth) - 1


def test_a_replays_metrics_report_what_it_saw_of_odometry(tmp_path):
    log = tmp_path / "s.clf"
    assert main(["simlog", str(log), "--scanner", "sick-1", "--rate", "5",
                 "--seconds", "12"]) == 0
    metrics, _ = replay_run(log, label="with odometry")
    assert metrics["odometry_seen"]["translation_scale"] == pytest.approx(1.0, abs=0.02)
    metrics, _ = replay_run(log, odometry=False, label="scans alone")
    assert metrics["odometry_seen"] == {}
