"""The command line, end to end, on data made here (no shared datasets needed)."""

import gzip
import json

import numpy as np
import pytest

from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.formats.carmen import flaser_angles
from swarmslam.cli import main
from swarmslam.formats.tum import read_tum


def write_keyframe_log(path, steps=8, seed=0):
    """A CARMEN keyframe log of a synthetic room: FLASER lines whose poses are the truth."""
    poses = loop_path(40)[:steps]  # keyframes ~0.5 m and 9° apart
    world = room_world(seed, size=(12.0, 9.0), boxes=10, walls=0, keep_clear=poses)
    angles = flaser_angles(180)
    with gzip.open(path, "wt") as f:
        for k, p in enumerate(poses):
            r = scan_at(world, p, angles, 50.0)
            ranges = " ".join(f"{v:.3f}" for v in r)
            pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
            f.write(f"FLASER 180 {ranges} {pose} {pose} {k:.3f} host {k:.3f}\n")
    return poses


def test_bench_matcher_writes_json_with_every_figure(tmp_path, capsys):
    (tmp_path / "corrected").mkdir()
    write_keyframe_log(tmp_path / "corrected" / "intel-corrected.log.gz")
    out = tmp_path / "m.json"
    code = main(["bench", "matcher", "--data", str(tmp_path), "--datasets", "intel",
                 "--optimizers", "abc,pso", "--json", str(out)])
    assert code == 0
    rows = json.loads(out.read_text())["datasets"]["intel"]
    assert set(rows) == {"abc", "pso", "abc-paper", "pso-paper", "icp"}
    for r in rows.values():
        for key in ("fail_rate", "eT", "eT_std", "eR", "eR_std", "ms_median", "ms_p99"):
            assert np.isfinite(r[key])
        assert set(r["eq24"]) == {"ex", "ey", "etheta"}
    assert rows["abc"]["fail_rate"] == 0.0 and rows["abc"]["eT"] < 0.05  # clean synthetic data
    assert "first_call_s" in rows["abc"]
    assert "abc-paper" in capsys.readouterr().out  # the printed table


def test_bench_matcher_says_when_data_is_missing(tmp_path, capsys):
    code = main(["bench", "matcher", "--data", str(tmp_path / "nowhere")])
    assert code == 2
    assert "does not exist" in capsys.readouterr().err


def test_bench_env_reports_the_median_of_its_runs_and_records_each(tmp_path, capsys):
    out = tmp_path / "env.json"
    assert main(["bench", "env", "--steps", "40", "--slam-steps", "10", "--repeats", "3",
                 "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    for key in ("without_slam", "with_slam"):
        runs = r["runs"][key]
        assert len(runs) == 3 and all(v > 0 for v in runs)
        assert r[f"steps_per_s_{key}"] == sorted(runs)[1]
    assert "median of 3" in capsys.readouterr().out


def test_demo_writes_trajectories_figure_and_summary(tmp_path, capsys):
    assert main(["demo", "--matcher-only", "--out", str(tmp_path), "--steps", "30"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["per_step_error_m"] < 0.02
    for name in ("demo.png", "trajectory_true.tum", "trajectory_estimated.tum"):
        assert (tmp_path / name).stat().st_size > 0
    assert len((tmp_path / "trajectory_estimated.tum").read_text().splitlines()) == 30
    assert "drift after" in capsys.readouterr().out


def test_replay_writes_map_trajectory_graph_and_metrics(tmp_path, capsys):
    log = tmp_path / "run.clf.gz"
    poses = write_keyframe_log(log, steps=12)
    rel = tmp_path / "run.relations"
    from swarmslam.runtime.pose import between

    lines = []
    for k in range(len(poses) - 1):
        d = between(poses[k + 1], poses[k])
        lines.append(f"{k:.3f} {k + 1:.3f} {d[0]:.6f} {d[1]:.6f} 0 0 0 {d[2]:.6f}\n")
    rel.write_text("".join(lines))
    out = tmp_path / "out"
    assert main(["replay", str(log), "--relations", str(rel), "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    for key in ("eT", "eT_std", "eR_deg", "eR_std", "relations_used", "wall_seconds",
                "data_seconds", "real_time_factor", "latency_ms_median", "latency_ms_p99"):
        assert key in m
    assert m["relations_used"] == 11 and m["eT"] < 0.05
    for name in ("map.pgm", "map.yaml", "map.png", "trajectory.tum", "graph.g2o"):
        assert (out / name).stat().st_size > 0
    assert "relations: eT" in capsys.readouterr().out


def test_replay_reports_malformed_log_with_line(tmp_path, capsys):
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 3 1.0 2.0\n")
    assert main(["replay", str(bad)]) == 2
    assert "bad.clf:1: range" in capsys.readouterr().err


def test_exploration_demo_maps_the_world_and_writes_its_outputs(tmp_path, capsys):
    # 200 steps: at 150 the maze was 30.3% mapped (29.9% with the simulator's preset of this
    # round), too near the 30% asked for to tell a broken explorer from a route's detour
    assert main(["demo", "--out", str(tmp_path), "--world", "maze", "--steps", "200"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["coverage"] > 0.3 and summary["pose_error_max_m"] < 0.25
    assert "image: map.pgm" in (tmp_path / "map.yaml").read_text()
    for name in ("map.pgm", "map.png", "trajectory.png", "trajectory_true.tum", "trajectory_estimated.tum"):
        assert (tmp_path / name).stat().st_size > 0
    assert "pose error" in capsys.readouterr().out


def test_simlog_then_replay_scores_against_the_simulators_truth(tmp_path, capsys):
    log = tmp_path / "hall.clf.gz"
    assert main(["simlog", str(log), "--site", "hall", "--scanner", "rplidar-a1", "--rate",
                 "4", "--seconds", "150", "--odometry", "noisy"]) == 0
    said = capsys.readouterr().out
    assert "600 scans" in said or "601 scans" in said
    for suffix in (".relations", ".truth.tum", ".world"):
        assert (tmp_path / f"hall{suffix}").stat().st_size > 0
    out = tmp_path / "out"
    assert main(["replay", str(log), "--relations", str(tmp_path / "hall.relations"),
                 "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["eT"] < 0.05 and m["loops_accepted"] > 0
    assert "eT_local" in m and m["relations_local"] + m.get("relations_global", 0) == m[
        "relations_used"]
    for rate in ("0", "1e-9", "inf", "nan", "1e9"):  # none ends, or none is a scanner's
        assert main(["simlog", str(tmp_path / "x.clf"), "--rate", rate]) == 2
    assert not (tmp_path / "x.clf").exists()
    # map once, localize later (no prior), and extend the map from an unknown place
    session = out / "session.npz"
    saved = session.read_bytes()
    loc = tmp_path / "loc"
    assert main(["replay", str(log), "--start", "300", "--localize", str(session),
                 "--out", str(loc)]) == 0
    lm = json.loads((loc / "localization.json").read_text())
    assert lm["scans"] == len(read_tum(loc / "trajectory.tum")[0]) + lm["runtime"][
        "scans_without_pose"]
    assert lm["scans_with_pose"] > 0.8 * lm["scans"] and lm["runtime"]["lost"] == 0
    assert session.read_bytes() == saved  # the map it localized in is untouched
    assert main(["replay", str(log), "--start", "400", "--resume", str(session),
                 "--out", str(tmp_path / "more")]) == 0
    more = json.loads((tmp_path / "more" / "metrics.json").read_text())
    assert more["nodes"] > m["nodes"] and more["status"] == "ok"
    assert main(["replay", str(log), "--localize", str(session), "--preset",
                 "sick-lms200"]) == 2
    assert "--rate must be within 0.1–1000 scans per second, got 0" in capsys.readouterr().err
    # --config may change a saved session's search (no pose scores 1: nothing is found), not
    # how its map is made
    mine = tmp_path / "search.toml"
    found = []
    for score in (0.7, 1.0):
        mine.write_text(f"[relocalization]\nmin_score = {score}\n")
        assert main(["replay", str(log), "--start", "300", "--limit", "80", "--localize",
                     str(session), "--config", str(mine), "--out", str(tmp_path / "s")]) == 0
        found.append(json.loads((tmp_path / "s" / "localization.json").read_text())[
            "scans_with_pose"])
    assert found[0] > 0 and found[1] == 0
    mine.write_text("[front_end]\nnode_distance = 0.4\n")
    assert main(["replay", str(log), "--resume", str(session), "--config", str(mine)]) == 2
    assert "search.toml: [front_end]: a saved session keeps" in capsys.readouterr().err
    assert session.read_bytes() == saved


def test_bench_generalization_reports_every_figure_and_the_floor(tmp_path, capsys):
    from swarmslam.bench.generalization import Case, bench_generalization

    case = Case("hall", "rplidar-a1", 4.0, "good", seed=2, seconds=150)
    r = bench_generalization((case,), tmp_path / "gen.json")
    row = json.loads((tmp_path / "gen.json").read_text())["cases"][0]
    assert row == r["cases"][0]
    for key in ("eT", "eR_deg", "ate_rmse_m", "loops_accepted", "loop_precision", "loop_recall",
                "real_time_factor", "floor_eT", "floor_loop_precision", "eT_over_floor"):
        assert key in row
    assert 0.0 <= row["loop_precision"] <= 1.0 and 0.0 <= row["loop_recall"] <= 1.0
    assert row["revisit_nodes"] > 0 and row["loops_accepted"] > 0
    assert row["ate_rmse_m"] < 0.1 and row["floor_eT"] < 0.05
    assert "worst loop precision" in capsys.readouterr().out


def test_a_count_below_one_is_refused_before_any_work(tmp_path, capsys):
    """--limit 0 used to replay everything and --limit -5 to drop five scans."""
    for value in ("0", "-5", "two"):
        with pytest.raises(SystemExit) as stop:
            main(["replay", str(tmp_path / "never-read.clf"), "--limit", value,
                  "--out", str(tmp_path / "out")])
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert "--limit" in err and ("at least 1" in err or "whole number" in err), err
    assert not (tmp_path / "out").exists()


def test_simlog_never_replaces_a_real_logs_files_beside_it(tmp_path, capsys):
    (tmp_path / "intel.relations").write_text("the published relations")
    (tmp_path / "mine.clf").write_text("ODOM 0 0 0 0 0 0 0 host 0\n")
    for name in ("intel.clf", "mine.clf"):
        assert main(["simlog", str(tmp_path / name), "--site", "hall", "--scanner",
                     "rplidar-a1", "--rate", "4", "--seconds", "5"]) == 2
        assert "is not of an earlier simlog" in capsys.readouterr().err
    assert (tmp_path / "intel.relations").read_text() == "the published relations"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["intel.relations", "mine.clf"]
    again = tmp_path / "sim.clf"  # an earlier simlog's set is its own to replace
    for _ in range(2):
        assert main(["simlog", str(again), "--site", "hall", "--scanner", "rplidar-a1",
                     "--rate", "4", "--seconds", "5"]) == 0
