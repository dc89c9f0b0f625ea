"""What each scan's odometry reading predicts (runtime/odometry_readings.py, docs/method.md
§6.1 "A stale reading"): a new reading's motion since the last new one, a stale reading's
continued translation while fewer scans have passed than the last reading took to come."""

import numpy as np

from swarmslam.runtime.odometry_readings import OdometryReadings


def test_a_new_reading_predicts_its_motion_since_the_last_new_one():
    readings = OdometryReadings(stale_motion=True)
    step, news, first = readings.read([1.0, 2.0, 0.5])
    assert news and first and np.array_equal(step, np.zeros(3))  # odometry starts here
    for _ in range(3):  # the same reading again: the first reading showed no motion
        step, news, first = readings.read([1.0, 2.0, 0.5])
        assert not news and not first and np.array_equal(step, np.zeros(3))
    step, news, first = readings.read([1.0 + 0.8 * np.cos(0.5), 2.0 + 0.8 * np.sin(0.5), 0.9])
    assert news and not first
    np.testing.assert_allclose(step, [0.8, 0.0, 0.4], atol=1e-12)  # in the last reading's frame


def test_a_stale_reading_continues_the_last_readings_translation_per_scan():
    readings = OdometryReadings(stale_motion=True)
    readings.read([0.0, 0.0, 0.0])
    for _ in range(3):
        readings.read([0.0, 0.0, 0.0])
    readings.read([0.8, 0.0, 0.4])  # came after four scans: 0.2 m a scan, the turn not
    steps = [readings.read([0.8, 0.0, 0.4])[0].copy() for _ in range(5)]
    for step in steps[:3]:  # fewer scans than the reading took
        np.testing.assert_allclose(step, [0.2, 0.0, 0.0], atol=1e-12)
    for step in steps[3:]:  # then the robot is taken to have stopped
        assert np.array_equal(step, np.zeros(3))
    off = OdometryReadings(stale_motion=False)
    off.read([0.0, 0.0, 0.0])
    off.read([0.0, 0.0, 0.0])
    off.read([0.4, 0.0, 0.0])
    assert np.array_equal(off.read([0.4, 0.0, 0.0])[0], np.zeros(3))


def test_no_reading_starts_odometry_afresh():
    readings = OdometryReadings(stale_motion=True)
    readings.read([0.0, 0.0, 0.0])
    assert readings.read(None) == (None, False, False)
    step, news, first = readings.read([5.0, 5.0, 1.0])  # no jump from the reading before
    assert news and first and np.array_equal(step, np.zeros(3))
