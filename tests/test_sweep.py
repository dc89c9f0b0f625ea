"""``swarmslam sweep`` (swarmslam.sweep): a spec's runs give the figures of ``replay`` with the
same seed, serially and on Ray; a results file lets a killed sweep go on with only the runs
it lacks; a bad spec is refused naming the file and the field."""

import json
import signal
import subprocess
import sys
import time

import pytest
import ray  # the 'scale' extra, which the test install has

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.replay import replay_run
from swarmslam.runs import RunOptions
from swarmslam.simlog import write_simlog
from swarmslam.sweep import SpecError, read_results, read_spec, summarise, sweep


@pytest.fixture(scope="module")
def tiny_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("logs")
    write_simlog(folder / "hall.clf", "hall", seed=2, lidar="rplidar-a1", rate_hz=4.0,
                 seconds=25)
    return folder / "hall.clf"


def write_spec(folder, log, tail="", name="spec.toml", **fields):
    """A spec of ``log``, abc, seeds 0 and 1; ``fields`` replace or add top-level lines (TOML
    text), ``tail`` goes last (tables)."""
    lines = {"logs": f'["{log}"]', "optimizers": '["abc"]', "seeds": "[0, 1]",
             "results": '"out/results.jsonl"', **fields}
    spec = folder / name
    spec.write_text("".join(f"{k} = {v}\n" for k, v in lines.items()) + tail)
    return spec


GRID = '[grid]\n"front_end.node_distance" = [0.3, 0.5]\n'


def test_a_sweep_gives_replays_figures_and_resumes_without_redoing(tiny_log, tmp_path):
    spec = read_spec(write_spec(tmp_path, tiny_log, GRID))
    runs = spec.runs()
    assert len(runs) == 4 and spec.logs[str(tiny_log)][1].name == "hall.relations"
    said = []
    records = sweep(spec, serial=True, echo=said.append)
    assert [r["key"] for r in records] == [r.key for r in runs]
    # each run is `swarmslam replay` with its seed and changes
    for run, record in zip(runs, records):
        base = override(SlamConfig(), dict(run.changes))
        metrics, _ = replay_run(tiny_log, spec.logs[str(tiny_log)][1],
                                RunOptions(base, "abc", run.seed))
        assert record["eT"] == metrics["eT"] and record["loops_accepted"] == metrics[
            "loops_accepted"], run.key
    assert len({r["eT"] for r in records}) > 1  # the variants and seeds do differ
    # run again: nothing to do; the file keeps one line per run
    said.clear()
    again = sweep(spec, serial=True, echo=said.append)
    assert "0 to run" in said[0] and again == records
    assert len(spec.results.read_text().splitlines()) == 4
    rows = summarise(records)
    assert len(rows) == 2 and all(r["seeds"] == [0, 1] for r in rows)
    assert rows[0]["eT_worst"] >= rows[0]["eT_mean"]


def test_a_killed_sweep_redoes_only_its_unfinished_runs(tiny_log, tmp_path):
    spec_path = write_spec(tmp_path, tiny_log, GRID)
    results = tmp_path / "out" / "results.jsonl"
    cmd = [sys.executable, "-m", "swarmslam.cli", "sweep", str(spec_path), "--serial"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not (results.exists() and results.read_text().count("\n") >= 1):
            assert proc.poll() is None and time.monotonic() < deadline, "no run finished"
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finished = read_results(results)
    assert 1 <= len(finished) < 4
    with open(results, "a") as f:  # a line cut short by the kill
        f.write('{"key": "hall.clf | abc | seed 1 | front_end.no')
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    assert f"{len(finished)} already in" in out and f"{4 - len(finished)} to run" in out
    lines = [json.loads(line) for line in results.read_text().splitlines()]
    assert len(lines) == 4 and len({r["key"] for r in lines}) == 4
    for key, record in finished.items():  # the runs finished before were not redone
        assert [r for r in lines if r["key"] == key] == [record]


def test_on_ray_two_workers_give_the_serial_figures(tiny_log, tmp_path):
    spec = read_spec(write_spec(tmp_path, tiny_log))
    serial = sweep(spec, serial=True, echo=lambda *_: None)
    spec.results = tmp_path / "ray.jsonl"
    on_ray = sweep(spec, workers=2, echo=lambda *_: None)
    assert [r["key"] for r in on_ray] == [r["key"] for r in serial]
    for a, b in zip(serial, on_ray):
        assert (a["eT"], a["eR_deg"], a["nodes"]) == (b["eT"], b["eR_deg"], b["nodes"])
    assert serial[0]["pid"] not in {r["pid"] for r in on_ray}  # ran in Ray's workers
    assert not ray.is_initialized()  # the local Ray started for the sweep is gone


@pytest.mark.parametrize("fields, tail, said", [
    ({"optimizers": '["abc", "xyz"]'}, "", "field 'optimizers': unknown optimizer 'xyz'"),
    ({"seeds": "[]"}, "", "field 'seeds' must be a non-empty list"),
    ({"limit": '"all"'}, "", "field 'limit' must be int"),
    ({"colour": "1"}, "", "unknown field 'colour'"),
    ({}, '[grid]\n"front_end.no_such_field" = [1]\n', "no_such_field"),
    ({}, '[grid]\n"front_end.node_distance" = 0.3\n', "[grid] field 'front_end.node_distance'"),
    ({}, "[grid\n", "not valid TOML"),
])
def test_a_bad_spec_is_refused_naming_the_field(tiny_log, tmp_path, fields, tail, said):
    spec = write_spec(tmp_path, tiny_log, tail, name="bad.toml", **fields)
    with pytest.raises(SpecError, match="bad.toml") as raised:
        read_spec(spec)
    assert said in str(raised.value)


def test_a_log_that_is_not_there_is_named(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text('logs = ["nowhere.clf"]\n')
    with pytest.raises(SpecError, match="'nowhere.clf' is neither one of intel"):
        read_spec(spec)
