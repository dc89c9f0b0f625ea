"""bench robustness (swarmslam.bench.robustness): the perturbed families make readable logs of
the same scans, each seed its own case, and a run far off its median seed's counts as gross."""

import math

import numpy as np
import pytest

from swarmslam.bench.robustness import (FAMILIES, GROSS_ET, perturbed, run_one, summarise,
                                        write_log)
from swarmslam.cli import main
from swarmslam.formats.carmen import read_carmen
from swarmslam.simlog import write_simlog


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    folder = tmp_path_factory.mktemp("logs")
    made = write_simlog(folder / "hall.clf", "hall", seed=2, lidar="rplidar-a1", rate_hz=4.0,
                        seconds=25)
    return folder / "hall.clf", made["relations"]


def path_length(lasers) -> float:
    odo = np.array([r.odometry for r in lasers])
    return float(np.hypot(*np.diff(odo[:, :2], axis=0).T).sum())


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_writes_a_log_of_the_same_scans_the_reader_reads(hall, tmp_path, family):
    lasers = read_carmen(hall[0]).lasers
    made = perturbed(lasers, family, seed=3)
    back = read_carmen(write_log(made, tmp_path / "out.clf")).lasers
    assert len(back) == len(made) and 0 < len(made) <= len(lasers)
    stamps = {r.timestamp for r in lasers}
    for mine, read in zip(made, back):
        assert read.timestamp == mine.timestamp and read.timestamp in stamps
        assert np.allclose(read.angles, mine.angles, atol=1e-9)
        assert np.allclose(read.odometry, mine.odometry, atol=1e-9)
        finite = np.isfinite(mine.ranges)
        assert np.allclose(read.ranges[finite], mine.ranges[finite], atol=5e-4)
    beams = len(lasers[0].ranges)
    assert len(made[0].ranges) == (math.ceil(beams / 2) if family == "half-beams" else beams)
    if family in ("every-2nd", "every-3rd"):
        assert len(made) == math.ceil(len(lasers) / (2 if family == "every-2nd" else 3))
    if family == "start-cut":
        assert made[0].timestamp > lasers[0].timestamp


def test_odometry_drift_differs_by_seed_and_repeats_for_the_same_seed(hall):
    lasers = read_carmen(hall[0]).lasers
    a, again, b = (perturbed(lasers, "odometry-drift", s) for s in (1, 1, 2))
    ends = [np.array(run[-1].odometry) for run in (a, again, b)]
    assert np.array_equal(ends[0], ends[1])
    assert not np.allclose(ends[0], ends[2])
    assert not np.allclose(ends[0], lasers[-1].odometry)
    # the scale error is at most 3%: the path's length within it
    assert abs(path_length(a) / path_length(lasers) - 1) <= 0.03 + 1e-9


def rows(et_global, et=0.03, p99=0.1):
    return [{"seed": s, "eT": et, "eR_deg": 0.3, "eT_scored": et, "eT_global": g, "p99_m": p99}
            for s, g in enumerate(et_global)]


def test_a_run_far_off_the_median_seed_or_past_the_bound_is_gross():
    calm = summarise(rows([0.05] * 9 + [0.09]))
    assert calm["gross"] == [] and calm["eT_global_median"] == pytest.approx(0.05)
    bent = summarise(rows([0.05] * 9 + [0.5]))
    assert [g["seed"] for g in bent["gross"]] == [9]
    assert "eT_global" in bent["gross"][0]["why"][0]
    assert bent["eT_global_spread"] == pytest.approx(10.0)
    poor = summarise(rows([0.05] * 3, et=GROSS_ET * 1.5))
    assert len(poor["gross"]) == 3  # every seed beyond the bound, however alike


def test_a_perturbed_replay_is_scored(hall, tmp_path):
    row = run_one(("hall", hall[0], hall[1], "every-2nd", 0, tmp_path, None))
    assert row["family"] == "every-2nd" and row["status"] == "ok"
    assert 0.0 < row["eT"] < 0.5 and row["p99_m"] > 0.0 and row["eT_scored"] == row["eT"]
    assert list(tmp_path.iterdir()) == []  # the perturbed log is not left behind


def test_bench_robustness_says_when_the_data_is_missing(tmp_path, capsys):
    code = main(["bench", "robustness", "--data", str(tmp_path / "none"), "--datasets", "intel",
                 "--seeds", "0"])
    assert code != 0
    assert "does not exist" in capsys.readouterr().err
