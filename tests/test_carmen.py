import gzip

import numpy as np
import pytest

from scripts.carmen import CarmenFormatError, read_carmen

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
