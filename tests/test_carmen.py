import gzip
import math

import numpy as np
import pytest

from swarmslam.runtime.config import SensorConfig, SlamConfig, override
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.formats.carmen import (
    CarmenFormatError,
    flaser_angles,
    flaser_no_return,
    odometry_at_scans,
    read_carmen,
    regular_stream,
)
from swarmslam.replay import replay_run, robot_frame_scan
from swarmslam.runs import RunOptions

FLASER = "FLASER 4 1.0 2.0 50.0 0.5 0.1 0.2 0.3 0.1 0.2 0.3 {t} host {t}\n"
ODOM = "ODOM 1.0 2.0 0.5 0.0 0.0 0.0 {t} host {t}\n"
RL1 = (
    "ROBOTLASER1 0 -1.5 3.0 1.0 20.0 0.01 0 4 1.0 2.0 3.0 25.0 0 "
    "1.1 0.0 0.0 1.0 0.0 0.0 0.0 0.0 0.5 0.2 0.0 {t} host {t}\n"
)


def write(tmp_path, text, gz=False, name="log.clf"):
    p = tmp_path / (name + (".gz" if gz else ""))
    if gz:
        with gzip.open(p, "wt") as f:
            f.write(text)
    else:
        p.write_text(text)
    return p


@pytest.mark.parametrize("gz", [False, True])
def test_reads_flaser_odom_robotlaser_sorted_by_time(tmp_path, gz):
    text = "# comment\nPARAM a b host 0\n" + FLASER.format(t=2.0) + ODOM.format(t=1.5)
    text += FLASER.format(t=1.0) + RL1.format(t=3.0) + "NEFF 15\n"
    log = read_carmen(write(tmp_path, text, gz))
    assert [r.timestamp for r in log.lasers] == [1.0, 2.0, 3.0]  # Intel's go backwards
    fl = log.lasers[0]
    assert np.allclose(fl.ranges, [1.0, 2.0, 50.0, 0.5])
    assert np.allclose(fl.angles, -np.pi / 2 + np.arange(4) * np.pi / 4)
    assert np.allclose(fl.pose, [0.1, 0.2, 0.3]) and fl.max_range == 50.0
    rl = log.lasers[2]
    assert np.allclose(rl.angles, [-1.5, -0.5, 0.5, 1.5]) and rl.max_range == 20.0
    assert np.allclose(rl.laser_offset, [0.1, 0.0, 0.0])
    assert len(log.odometry) == 1 and np.allclose(log.odometry[0].pose, [1.0, 2.0, 0.5])


@pytest.mark.parametrize(
    "line, field",
    [
        ("FLASER 4 1.0 2.0 x 0.5 0.1 0.2 0.3 0.1 0.2 0.3 1.0 host 1.0\n", "range[2]"),
        ("FLASER 4 1.0 2.0\n", "range"),
        ("FLASER 2.5 1.0 2.0\n", "num_readings"),
        ("FLASER 2 1.0 2.0 0.1 0.2 0.3 0.1 0.2 0.3 1.0 host\n", "ipc_timestamp"),
        ("ODOM 1.0 2.0 nan 0 0 0 1.0 host 1.0\n", "pose.theta"),
    ],
)
def test_malformed_line_names_file_line_and_field(tmp_path, line, field):
    p = write(tmp_path, FLASER.format(t=1.0) + line)
    with pytest.raises(CarmenFormatError) as info:
        read_carmen(p)
    assert info.value.line == 2 and info.value.field.startswith(field)
    assert str(p) in str(info.value) and ":2:" in str(info.value)


def test_missing_and_empty_logs(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such log"):
        read_carmen(tmp_path / "nope.clf")
    with pytest.raises(CarmenFormatError, match="no laser scans"):
        read_carmen(write(tmp_path, ODOM.format(t=1.0)))


def odom(x, theta, t):
    return f"ODOM {x} 0.0 {theta} 0.0 0.0 0.0 {t} host {t}\n"


def flaser(odometry, t):
    x, theta = odometry
    return f"FLASER 4 1.0 2.0 3.0 4.0 {x} 0.0 {theta} {x} 0.0 {theta} {t} host {t}\n"


def test_a_flaser_scan_takes_the_odometry_of_its_own_time_from_a_steady_stream(tmp_path):
    """A FLASER line carries the last ODOM the logger had (stale while the robot turns); from
    a steady ODOM stream the scan's odometry is interpolated at its own timestamp, across
    the ±π seam too. Scans at an ODOM record's time, outside the stream, or read without
    synchronising keep the line's."""
    text = ""
    for k in range(6):  # 10 Hz, 0.1 m and 0.2 rad per record, from theta 2.9 (past pi)
        text += odom(0.1 * k, math.remainder(2.9 + 0.2 * k, 2 * math.pi), 0.1 * k)
    text += flaser((0.1, 3.1), 0.175)  # stale: the record of t = 0.1
    text += flaser((0.2, 3.0), 0.2)  # at a record's time, the record's odometry exactly
    text += flaser((0.5, 9.0), 0.7)  # after the stream's end: its own
    path = write(tmp_path, text)
    log = read_carmen(path)
    between_records, at_record, after = (r.odometry for r in log.lasers)
    assert np.allclose(between_records[:2], [0.175, 0.0])
    assert math.isclose(math.remainder(between_records[2] - (2.9 + 0.2 * 1.75), 2 * math.pi),
                        0.0, abs_tol=1e-12)
    assert np.array_equal(at_record, [0.2, 0.0, math.remainder(2.9 + 0.4, 2 * math.pi)])
    assert np.array_equal(after, [0.5, 0.0, 9.0])
    stale = read_carmen(path, synchronise=False).lasers[0].odometry
    assert np.array_equal(stale, [0.1, 0.0, 3.1])


def test_a_bursty_odometry_stream_is_not_interpolated(tmp_path):
    """ODOM records that reach the logger in bursts (Intel's) carry arrival times, not
    measurement times: the lines' own odometry is kept."""
    assert regular_stream([0.0, 0.1, 0.2, 0.3]) and not regular_stream([0.0, 0.1])
    times = [0.0, 0.001, 0.002, 0.5, 0.501, 0.502, 1.0, 1.001, 1.002]
    assert not regular_stream(times)
    text = "".join(odom(0.1 * k, 0.0, t) for k, t in enumerate(times))
    text += flaser((0.2, 0.0), 0.25)
    assert odometry_at_scans(read_carmen(write(tmp_path, text), synchronise=False).lasers,
                             read_carmen(write(tmp_path, text)).odometry) == 0
    assert np.array_equal(read_carmen(write(tmp_path, text)).lasers[0].odometry, [0.2, 0.0, 0.0])


def flaser_log(tmp_path, no_return: float, scans: int = 40, beams: int = 181):
    """A FLASER log of a scanner reading ``no_return`` for a beam without one: every scan
    sees a wall 3–7 m away over its left half and nothing on its right."""
    rng = np.random.default_rng(4)
    lines = []
    for k in range(scans):
        ranges = np.full(beams, no_return)
        ranges[beams // 2 :] = rng.uniform(3.0, 7.0, beams - beams // 2).round(3)
        rs = " ".join(f"{r:.3f}" for r in ranges)
        lines.append(f"FLASER {beams} {rs} 0 0 0 0 0 0 {k * 0.2:.3f} host {k * 0.2:.3f}\n")
    return write(tmp_path, "".join(lines))


@pytest.mark.parametrize("no_return", [8.183, 81.83])
def test_a_flaser_log_says_its_no_return_reading_by_repeating_it(tmp_path, no_return):
    """A FLASER line has no maximum range: the scanner's "no return" value is found in the
    log (below the old fixed 50 m, an 8 m scanner's beams without a return were read as an
    arc of points 8.183 m around the robot), and those beams give no point."""
    log = read_carmen(flaser_log(tmp_path, no_return))
    assert {r.max_range for r in log.lasers} == {no_return}
    scan = robot_frame_scan(log.lasers[0], PointScan(181), SensorConfig())
    assert scan.count == 91  # the wall's beams, none of the empty half
    assert np.all(np.hypot(*scan.points.T) < 7.0 + 1e-9)
    # a maximum given by the caller stands
    assert {r.max_range for r in read_carmen(flaser_log(tmp_path, no_return), max_range=5.0)
            .lasers} == {5.0}


@pytest.mark.parametrize("beams, first, step", [(181, -90, 1.0), (180, -90, 1.0),
                                                 (361, -90, 0.5), (360, -90, 0.5),
                                                 (401, -50, 0.25), (400, -50, 0.25)])
def test_a_flaser_lines_beams_are_a_sick_lmss_by_their_count(beams, first, step):
    """A FLASER line gives ranges only: 181 beams are the 180° at 1°, 401 the 100° mode's
    0.25° either side of the scanner's axis (spread over 180° they would be 0.45° apart)."""
    degrees = np.degrees(flaser_angles(beams))
    assert degrees[0] == pytest.approx(first) and np.allclose(np.diff(degrees), step)


def test_a_scan_keeps_only_the_readings_within_the_sensors_ranges(tmp_path):
    """A ROBOTLASER1 line's maximum range is the logger's, not the scanner's: fr-clinic's says
    81.9 m and holds readings of 81.83 m, beyond the SICK LMS's 80 m. The sensor's ranges
    apply as well, as the runtime's inbox applies them to a live scanner's scans."""
    line = RL1.replace("20.0 0.01 0 4 1.0 2.0 3.0 25.0", "81.9 0.01 0 4 0.03 2.0 81.83 81.91")
    (record,) = read_carmen(write(tmp_path, line.format(t=1.0))).lasers
    assert record.max_range == 81.9

    def ranges(sensor):
        scan = robot_frame_scan(record, PointScan(4), sensor)  # (the laser's place: ranges)
        return np.hypot(*(scan.points - record.laser_offset[:2]).T).round(2).tolist()

    assert ranges(SensorConfig()) == [2.0]  # 0.05 m < r < 80 m
    assert ranges(SensorConfig(min_range=0.0, max_range=100.0)) == [0.03, 2.0, 81.83]
    assert ranges(SensorConfig(min_range=0.0, max_range=2.0)) == [0.03]


def test_a_replay_takes_the_configured_sensors_ranges(tmp_path):
    """The walls are 3–7 m away: a sensor that reads no farther than 2 m has no usable scan,
    and the run says so rather than ok."""
    log = flaser_log(tmp_path, 81.83, scans=5)
    short = override(SlamConfig(), {"sensor.max_range": 2.0})
    metrics, _ = replay_run(log, options=RunOptions(short), label="short")
    assert metrics["scans_refused"] == 5 and metrics["status"] != "ok"
    metrics, _ = replay_run(log, options=RunOptions(override(short, {"sensor.max_range": 5.0})),
                            label="5 m")
    assert metrics["scans_refused"] == 0 and metrics["status"] == "ok"


def test_no_return_is_the_least_recurring_value_with_nothing_measured_beyond_it():
    wall = np.linspace(0.5, 7.9, 5000)
    # a distance many beams read alike is no "no return": readings go on beyond it
    assert flaser_no_return(np.r_[np.full(900, 1.08), wall, np.full(100, 8.183)]) == 8.183
    # error codes above the no-return value recur too, and do not hide it
    assert flaser_no_return(np.r_[wall, np.full(100, 8.183), np.full(30, 8.191)]) == 8.183
    # a stray reading or two above it do not either
    assert flaser_no_return(np.r_[wall, np.full(100, 8.183), [9.5, 12.0]]) == 8.183
    # a value recurring too seldom to tell, or none: the old default stands
    assert flaser_no_return(np.r_[wall, np.full(3, 8.183)]) == 50.0
    assert flaser_no_return(np.r_[wall, [np.nan, np.inf]]) == 50.0
