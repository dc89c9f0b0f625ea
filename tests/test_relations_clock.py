"""On whose clock a relations file's headings are (scripts/evaluation/relations_clock.py)."""

import doctest

import numpy as np
import pytest

import swarmslam.evaluation.relations_clock as relations_clock
from swarmslam.runtime.pose import between
from swarmslam.formats.relations import Relations
from swarmslam.evaluation.metrics import nearest_stamps
from swarmslam.evaluation.relations_clock import heading_slope, reference_clock, turn_rates
from swarmslam_sim.survey import OdometryModel, drive, integrate_odometry, site

LATENCY = 0.04  # s


def turning_run(seed=0):
    """A robot driving 0.5 m/s and weaving (turn rate up to 0.6 rad/s) at 10 Hz: its true
    poses and stamps, and local relations 0.5–20 s apart."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 120.0, 0.1)
    omega = 0.6 * np.sin(0.7 * t) * np.sin(0.11 * t)
    heading = np.cumsum(omega) * 0.1
    xy = np.cumsum(0.05 * np.c_[np.cos(heading), np.sin(heading)], axis=0)
    poses = np.c_[xy, heading]
    i = rng.integers(0, len(t) - 200, 400)
    j = i + rng.integers(5, 200, 400)
    return t, poses, omega, i, j


def later(poses, omega, delay):
    """Each pose ``delay`` seconds after its stamp (turned by ω × delay; the few millimetres it
    moved left aside: the clock is read off the heading)."""
    out = poses.copy()
    out[:, 2] += omega * delay
    return out


def relations_from(t, poses, i, j):
    return Relations(t[i], t[j], between(poses[j], poses[i]))


def test_the_modules_example_runs_as_written():
    result = doctest.testmod(relations_clock)
    assert result.attempted > 0 and result.failed == 0


def test_a_reference_on_odometrys_clock_shows_a_scan_trajectorys_latency():
    t, truth, omega, i, j = turning_run()
    relations = relations_from(t, truth, i, j)  # made from poses at the stamps, as odometry is
    scans = later(truth, omega, LATENCY)  # a SLAM placing each scan where its geometry was
    clock = reference_clock(t, truth, relations, (t, scans))
    assert abs(clock["odometry_slope_ms"]) < 1.0 and clock["odometry_agreement"] == 1.0
    assert clock["trajectory_slope_ms"] == pytest.approx(1e3 * LATENCY, rel=0.05)
    assert clock["trajectory_correlation"] > 0.99
    _, _, before = heading_slope(t, turn_rates(t, truth)[:, 2], relations, scans[:, 2])
    moved = clock["on_reference_clock"]
    assert moved["eR_deg"] < 0.05 * np.degrees(np.nanmean(np.abs(before)))


def test_a_reference_on_the_scans_clock_shows_odometrys_latency_and_not_the_trajectorys():
    t, truth, omega, i, j = turning_run(seed=1)
    scans = later(truth, omega, LATENCY)
    relations = relations_from(t, scans, i, j)  # made by matching the scans
    clock = reference_clock(t, truth, relations, (t, scans))  # odometry: poses at the stamps
    assert clock["odometry_slope_ms"] == pytest.approx(-1e3 * LATENCY, rel=0.05)
    assert abs(clock["trajectory_slope_ms"]) < 1.0
    assert clock["on_reference_clock"]["eR_deg"] < 1e-3  # nothing to move


def test_a_trajectory_of_another_log_is_refused_by_name():
    t, truth, _, i, j = turning_run()
    with pytest.raises(ValueError, match="not the log's"):
        reference_clock(t, truth, relations_from(t, truth, i, j), (t + 0.05, truth))


def test_a_trajectory_stamped_a_hair_after_its_scans_is_still_the_logs():
    t, truth, _, i, j = turning_run()
    relations = relations_from(t, truth, i, j)
    clock = reference_clock(t, truth, relations, (t + 5e-5, truth))  # a rounding's worth late
    assert abs(clock["trajectory_slope_ms"]) < 1.0
    order = np.r_[len(t) - 1, np.arange(len(t) - 1)]  # the log's scans out of order
    assert np.array_equal(nearest_stamps(t[order], t[:3])[0], [1, 2, 3])


def test_noisy_odometry_on_the_references_clock_shows_no_slope():
    """The fit is not fooled by odometry's own noise: wheels five times noisier than the
    simulator's 'noisy' ones, on the same clock as the reference, give a slope of a few ms at
    most and no correlation (a shifted reading of noisy odometry averages neighbouring
    increments, and an estimator that scored shifts by their residual would prefer one)."""
    place = site("building", seed=0)
    poses, motions, _ = drive(place.route, 6.0, 0.5, seconds=600)
    t = np.arange(len(poses)) / 6.0
    rng = np.random.default_rng(1)
    i = rng.integers(0, len(t) - 200, 1500)
    j = i + rng.integers(2, 200, 1500)
    relations = relations_from(t, poses, i, j)
    odometry = integrate_odometry(poses[0], motions, OdometryModel(0.03), rng)[::len(motions[0])]
    clock = reference_clock(t, odometry, relations, (t, poses))
    assert abs(clock["odometry_slope_ms"]) < 15.0 and abs(clock["odometry_correlation"]) < 0.2
    assert abs(clock["trajectory_slope_ms"]) < 1e-6
