"""A rotating scanner's sweep: each point turned to the robot's heading at the scan's stamp
(runtime/matching/sweep_motion.py, docs/method.md §6.1 "The sweep")."""

import math

import numpy as np
import pytest

from swarmslam.runtime.config import SensorConfig, SlamConfig, override
from swarmslam.runtime.localization.localizer import TRACKING, Localizer
from swarmslam.runtime.localization.map_tracking import SavedMap
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.pose import between, wrap_angle
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.matching.sweep_motion import SweepMotion, undistort
from swarmslam.runtime.realtime.warm_up import room_world, scan_at


def _as_seen(points, places, seconds, stamp_place, w, w_last=None):
    """What a robot turning at ``w`` rad/s (or at a rate changing evenly from ``w`` at the
    sweep's first beam to ``w_last`` at its last) sees of the stamp-frame ``points``, each at
    its place in the sweep."""
    dw = 0.0 if w_last is None else w_last - w
    seen = np.empty_like(points)
    for i, (p, f) in enumerate(zip(points, places)):
        heading = seconds * (w * (f - stamp_place) + dw * (f * f - stamp_place**2) / 2)
        seen[i] = between(np.r_[p, 0.0], np.array([0.0, 0.0, heading]))[:2]
    return seen


@pytest.mark.parametrize("stamp_place", [1.0, 0.0, 0.5])
def test_undistort_turns_each_point_to_the_stamps_heading(stamp_place):
    rng = np.random.default_rng(0)
    truth = rng.uniform(-6, 6, (200, 2))
    places = np.sort(rng.uniform(0, 1, 200))
    seen = _as_seen(truth, places, 0.18, stamp_place, 2.0)
    assert np.max(np.hypot(*(seen - truth).T)) > 0.1  # a 20° turn over the sweep
    out = np.empty_like(seen)
    undistort(seen, places, len(seen), 2.0, 0.18, stamp_place, out)
    np.testing.assert_allclose(out, truth, atol=1e-12)


@pytest.mark.parametrize("stamp_place", [1.0, 0.0, 0.5])
def test_undistort_follows_a_turn_rate_that_changes_over_the_sweep(stamp_place):
    """A turn starting within the sweep (0 at its first beam, 3 rad/s at its last): undone at
    the rate changing so, every point lands where it was; at the steady rate of the same
    turn, not."""
    rng = np.random.default_rng(1)
    truth = rng.uniform(-6, 6, (200, 2))
    places = np.sort(rng.uniform(0, 1, 200))
    seen = _as_seen(truth, places, 0.18, stamp_place, 0.0, 3.0)
    out = np.empty_like(seen)
    undistort(seen, places, len(seen), 0.0, 0.18, stamp_place, out, 3.0)
    np.testing.assert_allclose(out, truth, atol=1e-12)
    undistort(seen, places, len(seen), 1.5, 0.18, stamp_place, out)
    assert np.max(np.hypot(*(out - truth).T)) > 0.05


def test_the_turn_given_is_taken_over_the_interval_or_the_sweep_if_longer():
    sensor = SensorConfig(sweep_seconds=0.2)
    sweep = SweepMotion(sensor, 8)
    scan = PointScan(8).set_points([[1.0, 0.0], [0.0, 2.0], [-3.0, 0.5]])
    np.testing.assert_array_equal(scan.sweep[:3], [0.0, 0.5, 1.0])  # their order: the sweep's
    motion = np.array([0.5, 0.1, math.pi / 2])  # (its translation is not read)
    out = sweep.undistort(scan, motion, 0.4)
    expected = np.empty((3, 2))
    undistort(scan.buffer, scan.sweep, 3, math.pi / 2 / 0.4, 0.2, 1.0, expected)
    np.testing.assert_allclose(out.points, expected, atol=1e-12)
    assert out.count == 3 and np.array_equal(out.sweep[:3], scan.sweep[:3])
    assert not np.allclose(out.points, scan.points)
    # a stamp 0.1 s after the last, jittered: the turn taken over the sweep's 0.2 s instead
    shorter = sweep.undistort(scan, motion * 0.25, 0.1).points.copy()
    np.testing.assert_allclose(shorter, sweep.undistort(scan, motion * 0.25, 0.2).points,
                               atol=1e-12)
    assert sweep.undistort(scan, motion, math.nan) is scan  # no interval known yet
    assert SweepMotion(SensorConfig(), 8).undistort(scan, motion, 0.4) is scan  # no sweep


def _weaving(t):
    """Turning at up to 1.6 rad/s one way then the other (a 3 s period) after a second at
    rest, at 0.3 m/s."""
    return (np.where(t < 1.0, 0.0, 1.6 * np.sin(2 * math.pi * (t - 1.0) / 3.0)),
            np.where(t < 1.0, 0.0, 0.3))


def _pivots(t):
    """Standing, then turning in place at 2 rad/s for 1.5 s, from 1.0 s and from 3.95 s: each
    turn starts and ends within a sweep (0.18 s from 0.18 s on), as a pivot does."""
    turning = ((t >= 1.0) & (t < 2.5)) | ((t >= 3.95) & (t < 5.45))
    return np.where(turning, 2.0, 0.0), np.zeros_like(t)


def _swept_drive(seconds=12.0, rate=5.5, sweep=1 / 5.5, beams=360, motion=_weaving):
    """A robot driving through a room as ``motion`` says (its turn rate and speed over time;
    default: weaving): its scans (a 360° scanner sweeping for ``sweep`` s, stamped at the last
    beam), true poses and the room's walls."""
    dt = 0.001
    t = np.arange(0.0, seconds + dt, dt)
    w, v = motion(t)
    heading = np.concatenate([[0.0], np.cumsum(w[:-1] * dt)])
    x = 3.0 + np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(heading[:-1]) * dt)])
    y = 4.0 + np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(heading[:-1]) * dt)])
    fine = np.c_[x, y, heading]
    segments = room_world(3, keep_clear=fine[::100])
    angles = np.linspace(-math.pi, math.pi, beams, endpoint=False)
    stamps = np.arange(sweep, seconds, 1.0 / rate)
    scans, truth = [], []
    for stamp in stamps:
        ranges = np.empty(beams)
        for i in range(beams):
            k = int(round((stamp - sweep * (1.0 - i / (beams - 1))) / dt))
            ranges[i] = scan_at(segments, fine[k], angles[i : i + 1])[0]
        scans.append(ranges)
        truth.append(fine[int(round(stamp / dt))])
    return stamps, np.array(truth), angles, scans, segments


@pytest.fixture(scope="module")
def swept():
    return _swept_drive()


def _heading_errors(swept, sweep_seconds, odometry=True):
    stamps, truth, angles, scans, _ = swept
    config = override(SlamConfig(), {"sensor.sweep_seconds": sweep_seconds,
                                     "sensor.max_range": 12.0})
    slam = GraphSlam(config, seed=0)
    scan = PointScan(len(angles))
    poses = []
    for stamp, pose, ranges in zip(stamps, truth, scans):
        scan.set_ranges(ranges, angles, 0.05, 12.0)
        slam.step(scan, pose.copy() if odometry else None, float(stamp))
        poses.append(slam.front_end.pose())
    est = between(np.array(poses)[1:], np.array(poses)[:-1])
    ref = between(truth[1:], truth[:-1])
    return np.abs(np.degrees(wrap_angle(est[:, 2] - ref[:, 2])))


@pytest.mark.parametrize("odometry", [True, False])
def test_a_weaving_robots_sweep_undistorted_keeps_each_scans_turn(swept, odometry):
    """Turning at 1.6 rad/s an RPLidar's 0.18 s sweep bends every wall by 17°; matched as if
    its beams were simultaneous, the scans' turns err where the robot's turn changes. Told the
    sweep, the front end turns each point to the stamp's heading by the scans' last turn, then
    by the match's own (the match settled again), with exact odometry or none."""
    told = _heading_errors(swept, 1 / 5.5, odometry)
    untold = _heading_errors(swept, 0.0, odometry)
    assert np.mean(told) < 0.5 * np.mean(untold)
    assert np.max(told) < 0.5 * np.max(untold)


@pytest.fixture(scope="module")
def pivots():
    return _swept_drive(seconds=7.0, motion=_pivots)


@pytest.mark.parametrize("odometry", [True, False])
def test_a_turn_starting_within_a_sweep_is_undone_as_its_rate_grows(pivots, odometry):
    """Pivots at 2 rad/s that start and end within a sweep: the second pass undoes the sweep
    at a rate changing evenly from the last interval's to the one that makes the match's turn,
    and the scans' turns err less than matched as if the beams were simultaneous (mean step
    error 1.39 against 1.58° with odometry, 1.48 against 1.73° without). At the match's steady
    rate, the second pass erred more than that (1.79°, 1.77°): the scan before a pivot starts
    has not turned, and the turn of the scan that starts it is not steady."""
    told = _heading_errors(pivots, 1 / 5.5, odometry)
    untold = _heading_errors(pivots, 0.0, odometry)
    assert np.mean(told) < 0.9 * np.mean(untold)


def _localized_heading_errors(swept, sweep_seconds):
    """Each scan's heading error, localized with exact odometry in a map of simultaneous scans
    taken at every fourth true pose."""
    stamps, truth, angles, scans, walls = swept
    config = override(SlamConfig(), {"sensor.sweep_seconds": sweep_seconds,
                                     "sensor.max_range": 12.0})
    at = truth[::4]
    nodes = NodeScans(len(at), len(angles))
    scan = PointScan(len(angles))
    for k, pose in enumerate(at):
        nodes.store(k, scan.set_ranges(scan_at(walls, pose, angles), angles, 0.05, 12.0))
    localizer = Localizer(config, SavedMap(at, nodes, len(at)), seed=0, initial_pose=truth[0])
    headings = []
    for stamp, pose, ranges in zip(stamps, truth, scans):
        scan.set_ranges(ranges, angles, 0.05, 12.0)
        headings.append(localizer.step(scan, pose.copy(), float(stamp)).pose[2])
    assert localizer.phase == TRACKING and localizer.counts["lost"] == 0
    return np.abs(np.degrees(wrap_angle(np.array(headings) - truth[:, 2])))


def test_localization_undoes_the_sweep_as_the_front_end_does(swept):
    """In a saved map the tracked pose's heading lags a turning robot by half the sweep's
    turn (up to 8° here) when the beams are taken as simultaneous; told the sweep, each
    scan is turned by the last turn, then by the match's own from the last pose kept."""
    told = _localized_heading_errors(swept, 1 / 5.5)
    untold = _localized_heading_errors(swept, 0.0)
    assert np.mean(told) < 0.5 * np.mean(untold)
    assert np.max(told) < 0.5 * np.max(untold)
