"""What each scan's odometry reading predicts (runtime/front_end/odometry_readings.py, docs/method.md
§6.1 "A stale reading"): a new reading's motion since the last new one, a stale reading's
continued translation while fewer scans have passed than the last reading took to come."""

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.front_end.odometry_readings import RESTART_GAPS, OdometryReadings


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


def _drive_with_periodic_odometry(periodic_ratio, period=0.8, scan_hz=4.7, speed=0.5, n=400):
    """A robot driving straight at ``speed`` m/s, scanned at ``scan_hz``, its odometry read
    every ``period`` s (exact), each scan carrying the latest reading. Each scan's position as
    the readings predict it (a new reading's step from the scan that brought the last new one,
    a stale one's from the last scan), less the truth: the error (m) of every scan."""
    readings = OdometryReadings(stale_motion=True, periodic_ratio=periodic_ratio)
    stamps = np.arange(n) / scan_hz + 0.013
    x = np.zeros(n)
    arrival = 0
    for k, t in enumerate(stamps):
        taken = np.floor(t / period) * period
        step, news, first = readings.read([speed * taken, 0.0, 0.0], t)
        if first:
            x[k] = speed * t
        elif news:
            x[k] = x[arrival] + step[0]
        else:
            x[k] = x[k - 1] + step[0]
        arrival = k if news else arrival
    return x - speed * stamps


def test_odometry_read_at_its_own_period_is_followed_in_time_not_in_scans():
    """Odometry read every 0.8 s and scans at 4.7 Hz: a reading was taken up to a scan
    interval (0.21 s) before the scan that brings it, a different time for each. Counting
    its motion from scan to scan puts errors of a tenth of a metre into a corridor's axis;
    following each reading's lag behind its scan (docs/method.md §6.1, "Odometry at its own
    period") leaves a few centimetres at most, and builds up no scale error."""
    old = _drive_with_periodic_odometry(0.0)[40:]
    new = _drive_with_periodic_odometry(1.5)[40:]  # (once the period is known)
    old, new = old - old[0], new - new[0]  # from wherever the run had put the scan
    assert np.abs(old).max() > 0.08
    assert np.abs(new).max() < 0.04 and np.ptp(new) < np.ptp(old) / 3, (np.ptp(new), np.ptp(old))
    assert abs(np.mean(new[-100:]) - np.mean(new[:100])) < 0.03  # no drift over 50 m


def test_odometry_read_with_the_scans_is_not_taken_as_periodic():
    """A new reading at every scan (or every other, below ``periodic_ratio`` scan intervals
    apart): no period, the steps as they were."""
    for every in (1, 1.4):
        readings = OdometryReadings(stale_motion=True, periodic_ratio=1.5)
        for k in range(50):
            readings.read([0.1 * np.floor(k / every), 0.0, 0.0], k / 10.0)
        assert readings.period() == 0.0
    readings = OdometryReadings(stale_motion=True, periodic_ratio=1.5)
    for k in range(50):
        readings.read([0.1 * (k // 4), 0.0, 0.0], k / 10.0)
    assert abs(readings.period() - 0.4) < 1e-9


def test_odometry_read_every_one_or_two_scans_is_taken_as_periodic():
    """Readings every 0.8 s and scans at 2 Hz: a new reading comes one scan or two after the
    last (1.6 on average). Gaps of two scans count towards the period although the fewest is
    one: counted only below twice the fewest, they were taken for rests, no period was found,
    and each stale scan was predicted at rest, a quarter of a metre behind the robot (a
    simulated 2 Hz robot survey: eT 0.131 m, 0.025 with the period)."""
    readings = OdometryReadings(stale_motion=True, periodic_ratio=1.5)
    for k in range(100):
        t = k / 2.0 + 0.013
        readings.read([0.5 * np.floor(t / 0.8) * 0.8, 0.0, 0.0], t)
    assert abs(readings.period() - 0.8) < 0.01, readings.period()
    error = _drive_with_periodic_odometry(1.5, scan_hz=2.0)[40:]
    error = error - error[0]  # (from wherever the run had put the scan)
    assert np.abs(error).max() < 0.06, np.abs(error).max()


def test_scans_refused_on_the_way_do_not_hide_the_period():
    """Readings every 0.8 s and scans at 5 Hz (four scans a reading), the scans of 2 s refused
    on the way (no beam returned: the readings never see them), and of 0.6 s again later:
    after each, a reading comes one scan after the one before it. Three gaps of four scans in
    a row outgrow that stray fewest, and the period stays known (a simulated robot survey
    with an 8 m SICK, its scans refused now and then, had lost it for its last 110 s). Never
    restarted (``RESTART_GAPS`` past the run's gaps), the count stops at the
    stray and the period stays what the gaps before it made (0.86 s)."""
    def known_periods(restart_gaps):
        readings = OdometryReadings(stale_motion=True, periodic_ratio=1.5,
                                    restart_gaps=restart_gaps)
        known = []
        for k in range(600):
            t = k / 5.0 + 0.013
            if 11.5 < t < 13.3 or 40.1 < t < 40.7:
                continue
            taken = np.floor((t - 0.2 * (40.7 <= t < 41.0)) / 0.8) * 0.8
            readings.read([0.5 * taken, 0.0, 0.0], t)
            known.append(readings.period())
        return np.array(known)

    known = known_periods(RESTART_GAPS)
    assert abs(known[-1] - 0.8) < 0.02, known[-1]
    assert np.mean(known[100:] > 0) > 0.95
    assert abs(known_periods(1000)[-1] - 0.8) > 0.04


def test_a_restored_session_reads_on_as_the_running_one_would():
    """The period, the lag and the rate are saved with the readings: a session saved in the
    middle of periodic odometry predicts the next steps to the bit."""
    def reading(k):
        return [0.5 * 0.8 * np.floor(k / 4.7 / 0.8), 0.0, 0.0], k / 4.7

    running = OdometryReadings(stale_motion=True, periodic_ratio=1.5)
    for k in range(30):
        running.read(*reading(k))
    assert running.period() > 0
    restored = OdometryReadings(stale_motion=True, periodic_ratio=1.5)
    restored.restore(running.state())
    for k in range(30, 60):
        a, b = running.read(*reading(k)), restored.read(*reading(k))
        assert a[1:] == b[1:] and np.array_equal(a[0], b[0])
    with pytest.raises(KeyError):  # an older session's state is migrated first (session.py)
        OdometryReadings(True, 1.5).restore({"last_odometry": np.zeros(3),
                                             "have_odometry": False})
