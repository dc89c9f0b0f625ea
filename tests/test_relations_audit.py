"""``swarmslam relations audit``: relations checked against the log's own scans."""

import doctest
import gzip
import json

import numpy as np
import pytest

import swarmslam.evaluation.relations_audit as relations_audit
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.formats.carmen import flaser_angles
from swarmslam.cli import main
from swarmslam.view.plots import gross_failures_figure
from swarmslam.formats.relations import Relations, relations_text
from swarmslam.formats.tum import write_tum


def write_room_log(path, steps=12, seed=1):
    """FLASER scans of a synthetic room along a path; returns the true poses and stamps."""
    poses = loop_path(40)[:steps]  # ~0.5 m and 9° apart: consecutive scans overlap
    world = room_world(seed, size=(12.0, 9.0), boxes=10, walls=0, keep_clear=poses)
    angles = flaser_angles(180)
    stamps = 100.0 + np.arange(steps)
    with gzip.open(path, "wt") as f:
        for p, t in zip(poses, stamps):
            ranges = " ".join(f"{v:.3f}" for v in scan_at(world, p, angles, 50.0))
            pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
            f.write(f"FLASER 180 {ranges} {pose} {pose} {t:.3f} host {t:.3f}\n")
    return poses, stamps


def test_the_modules_example_runs_as_written():
    result = doctest.testmod(relations_audit)
    assert result.attempted > 0 and result.failed == 0


def test_true_relations_pass_and_displaced_ones_are_flagged_and_scored_apart(tmp_path, capsys):
    poses, stamps = write_room_log(tmp_path / "room.clf.gz")
    i = np.r_[np.arange(len(poses) - 1), np.arange(len(poses) - 2)]
    j = np.r_[i[: len(poses) - 1] + 1, i[len(poses) - 1:] + 2]
    delta = between(poses[j], poses[i])
    wrong = np.arange(len(i)) % 3 == 1  # every third relation displaced as a bad reference is
    displacement = np.array([0.4, -0.3, 0.08])
    delta[wrong] = compose(delta[wrong], displacement)
    (tmp_path / "room.relations").write_text(relations_text(stamps[i], stamps[j], delta))
    write_tum(tmp_path / "truth.tum", stamps, poses)

    out = tmp_path / "audit.json"
    assert main(["relations", "audit", str(tmp_path / "room.clf.gz"),
                 str(tmp_path / "room.relations"), "--trajectory", str(tmp_path / "truth.tum"),
                 "--json", str(out), "--plots", str(tmp_path / "plots")]) == 0
    figure = (tmp_path / "plots" / "audit-room.relations.png").read_bytes()
    assert figure[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads(out.read_text())
    assert result["checked"] == len(i)
    flagged = {(r["t1"], r["t2"]) for r in result["contradicted_relations"]}
    assert flagged == {(float(stamps[a]), float(stamps[b])) for a, b in zip(i[wrong], j[wrong])}
    back = between(np.zeros(3), displacement)
    for r in result["contradicted_relations"]:  # ICP took each back to the truth, nearly
        assert np.hypot(*(np.array(r["correction"][:2]) - back[:2])) < 0.1  # of 0.5
        assert abs(r["correction"][2] - back[2]) < 0.02
    scores = result["scores"]  # the true trajectory errs only where the reference does
    confirmed, contradicted = scores["confirmed"], scores["contradicted"]
    assert confirmed["eT"] < 1e-3 and confirmed["relations_used"] == (~wrong).sum()
    assert contradicted["eT"] > 0.4 and contradicted["relations_used"] == wrong.sum()
    printed = capsys.readouterr().out
    assert "contradicted" in printed and "clock: the trajectory's" in printed
    assert result["short"]["eR_short_confirmed_deg"] < 0.05  # 0.08 rad off: not gross
    assert result["short"]["eR_short_over_10deg"] == 0 and "0 above 10°" in printed
    # the worst relations of the (true) trajectory: the displaced ones, 0.08 rad off, where
    # odometry (the truth here) errs alike; each with the fastest turn between its scans
    worst = result["worst"]
    assert len(worst) == len(i) and "worst relations of the trajectory" in printed
    assert all(w["contradicted"] for w in worst[: wrong.sum()])
    assert not any(w["contradicted"] for w in worst[wrong.sum():])
    assert worst[0]["eR_deg"] == pytest.approx(np.degrees(0.08), abs=0.05)
    assert worst[0]["odometry_eR_deg"] == pytest.approx(worst[0]["eR_deg"], abs=0.05)
    turns = np.degrees(np.abs(np.diff(np.unwrap(poses[:, 2]))))  # ° per 1 s step
    for w in worst:
        a, b = int(w["t1"] - stamps[0]), int(w["t2"] - stamps[0])
        assert w["turn_rate_deg_s"] == pytest.approx(turns[a:b].max(), abs=0.01)
    # the true trajectory, on the reference's clock, has no slope; odometry (= truth) agrees
    # with every relation but the displaced ones
    assert abs(result["clock"]["trajectory_slope_ms"]) < 0.01  # (the TUM file rounds)
    assert result["clock"]["odometry_agreement"] == pytest.approx((~wrong).mean())


def test_a_relation_naming_a_scan_the_log_lacks_is_not_checked(tmp_path):
    poses, stamps = write_room_log(tmp_path / "room.clf.gz", steps=3)
    delta = between(poses[[1, 2]], poses[[0, 1]])
    (tmp_path / "room.relations").write_text(
        relations_text([stamps[0], stamps[1]], [stamps[1], 999.0], delta))
    out = tmp_path / "audit.json"
    assert main(["relations", "audit", str(tmp_path / "room.clf.gz"),
                 str(tmp_path / "room.relations"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert (result["relations"], result["checked"], result["contradicted"]) == (2, 1, 0)


def test_a_relation_its_scans_do_not_show_is_unsupported_and_scored_apart(tmp_path, capsys):
    # One relation, 11 s long (odometry's motion is no start for ICP), puts the second scan
    # 30 m and 29° off, where not one of its points lies near the first scan's and ICP (pairing
    # within 0.5 m) finds nothing to move it by: the scans do not show it either way. It is
    # not contradicted, and a trajectory is scored apart on it and on the relations the scans
    # support.
    poses, stamps = write_room_log(tmp_path / "room.clf.gz")
    i = np.r_[np.arange(len(poses) - 1), 0]
    j = np.r_[np.arange(1, len(poses)), len(poses) - 1]
    delta = between(poses[j], poses[i])
    delta[-1] = compose(delta[-1], np.array([0.0, 30.0, 0.5]))
    (tmp_path / "room.relations").write_text(relations_text(stamps[i], stamps[j], delta))
    write_tum(tmp_path / "truth.tum", stamps, poses)
    out = tmp_path / "audit.json"
    assert main(["relations", "audit", str(tmp_path / "room.clf.gz"),
                 str(tmp_path / "room.relations"), "--trajectory", str(tmp_path / "truth.tum"),
                 "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    counts = result["contradicted"], result["unsupported"], result["unsupported_local"]
    assert counts == (0, 1, 1)
    assert [(r["t1"], r["t2"]) for r in result["unsupported_relations"]] == [
        (float(stamps[0]), float(stamps[-1]))]
    scores = result["scores"]
    assert scores["unsupported"]["relations_used"] == 1 and scores["unsupported"]["eT"] > 29
    assert scores["supported"]["relations_used"] == len(i) - 1
    assert scores["supported"]["eT"] < 1e-3  # the true trajectory errs only there
    worst = result["worst"]  # the trajectory's worst: the relation, which its scans do not show
    assert (worst[0]["t1"], worst[0]["t2"]) == (float(stamps[0]), float(stamps[-1]))
    assert worst[0]["unsupported"] and not any(w["unsupported"] for w in worst[1:])
    printed = capsys.readouterr().out
    assert "1 unsupported" in printed and "  unsupported  eT" in printed
    assert "do not show it" in printed.split("worst relations")[1]


def test_a_bad_min_gain_is_refused_before_any_work(tmp_path, capsys):
    assert main(["relations", "audit", str(tmp_path / "none.clf"), str(tmp_path / "none"),
                 "--min-gain", "0"]) == 2
    assert "--min-gain" in capsys.readouterr().err


def test_a_relation_far_off_in_heading_is_refined_from_odometrys_motion(tmp_path):
    # A relation off by 0.6 m and 17° lies beyond ICP's reach from the relation and its ±8°
    # turns: from there ICP settles on a wrong fit. Odometry's motion between the two scans
    # (the truth in this log) is a start near the right pose, and the audit's correction then
    # takes the relation back to the truth.
    poses, stamps = write_room_log(tmp_path / "room.clf.gz")
    scans, scan_stamps, odometry = relations_audit.log_scans(tmp_path / "room.clf.gz")
    i = np.arange(len(poses) - 2)
    j = i + 2
    delta = between(poses[j], poses[i])
    displacement = np.array([0.0, 0.6, 0.3])
    delta[1::2] = compose(delta[1::2], displacement)
    relations = Relations(stamps[i], stamps[j], delta)
    back = between(np.zeros(3), displacement)

    with_odometry = relations_audit.audit_scans(scans, scan_stamps, relations,
                                                odometry=odometry)
    assert with_odometry.contradicted.tolist() == [False, True] * (len(i) // 2)
    assert np.abs(with_odometry.correction[1::2] - back).max() < 0.05
    assert with_odometry.fit_aligned[1::2].min() > 0.75

    without = relations_audit.audit_scans(scans, scan_stamps, relations)
    assert np.abs(without.correction[1::2] - back).max(axis=1).max() > 0.3

    slow = 100.0 + np.arange(len(poses)) * relations_audit.ODOMETRY_START_GAP / 2
    far = relations_audit.audit_scans(  # scans this far apart: odometry is no start
        scans, slow, Relations(slow[i], slow[j], delta), odometry=odometry)
    assert far.checked.all()
    assert np.abs(far.correction[1::2] - back).max(axis=1).max() > 0.3


def test_short_gross_failures_are_told_from_relations_the_scans_contradict(tmp_path):
    poses, stamps = write_room_log(tmp_path / "room.clf.gz")
    scans, scan_stamps, odometry = relations_audit.log_scans(tmp_path / "room.clf.gz")
    i = np.r_[np.arange(len(poses) - 1), np.arange(len(poses) - 2)]
    j = np.r_[i[: len(poses) - 1] + 1, i[len(poses) - 1:] + 2]
    slipped = 6  # the trajectory's pose of this scan is turned 17°: a gross failure of ours
    touches = (i == slipped) | (j == slipped)
    wrong = (np.arange(len(i)) % 3 == 1) & ~touches  # a bad reference, 14° off
    delta = between(poses[j], poses[i])
    delta[wrong] = compose(delta[wrong], np.array([0.4, -0.3, 0.25]))
    relations = Relations(stamps[i], stamps[j], delta)
    audit = relations_audit.audit_scans(scans, scan_stamps, relations, odometry=odometry)
    assert audit.contradicted.tolist() == wrong.tolist()

    trajectory = poses.copy()
    trajectory[slipped, 2] += 0.3
    tail = relations_audit.short_tail_apart(stamps, trajectory, relations, audit)
    assert tail["eR_short_over_10deg"] == wrong.sum() + touches.sum()
    assert tail["eR_short_over_10deg_confirmed"] == touches.sum()
    listed = {(r["t1"], r["t2"]) for r in tail["short_over_10deg_confirmed"]}
    assert listed == {(float(stamps[a]), float(stamps[b])) for a, b in zip(i[touches],
                                                                          j[touches])}
    assert tail["relations_short_confirmed"] == (~wrong).sum()
    assert tail["eR_short_confirmed_deg"] == pytest.approx(
        np.degrees(0.3) * touches.sum() / (~wrong).sum(), rel=0.01)

    # Each gross failure listed with its scans placed both ways: here the relation is the
    # truth and the trajectory slipped, so the scans fit the relation's placement ...
    # (odometry, the truth in this log, is the third witness and sides with the relation)
    placed = relations_audit.fits_of_gross_failures(tail, scans, scan_stamps, stamps, trajectory,
                                                    odometry)
    assert len(placed) == touches.sum()
    slip = np.degrees(0.3)
    for r in tail["short_over_10deg_confirmed"]:
        assert r["fit_relation"] > 0.8 and r["fit_trajectory"] < r["fit_relation"] - 0.3
        assert r["fit_odometry"] == pytest.approx(r["fit_relation"], abs=0.02)
        assert r["odometry_eR_deg"] < 0.01
        assert r["odometry_vs_trajectory_deg"] == pytest.approx(slip, abs=0.01)
    # ... and the other way round when the trajectory is the truth and the relation slipped
    swapped = {"short_over_10deg_confirmed": [
        {**r, "delta": list(compose(np.asarray(r["delta"]), np.array([0.0, 0.0, 0.3])))}
        for r in tail["short_over_10deg_confirmed"]]}
    relations_audit.fits_of_gross_failures(swapped, scans, scan_stamps, stamps, poses, odometry)
    for r in swapped["short_over_10deg_confirmed"]:
        assert r["fit_trajectory"] > 0.8 and r["fit_relation"] < r["fit_trajectory"] - 0.3
        assert r["fit_odometry"] == pytest.approx(r["fit_trajectory"], abs=0.02)
        assert r["odometry_eR_deg"] == pytest.approx(slip, abs=0.01)
        assert r["odometry_vs_trajectory_deg"] < 0.01
    figure = gross_failures_figure(tmp_path / "plots", "room", placed)
    assert figure.name == "audit-room-gross.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # without odometry: two placements, no odometry fields
    alone = relations_audit.fits_of_gross_failures(
        {"short_over_10deg_confirmed": [{k: r[k] for k in ("t1", "t2", "eR_deg", "delta")}
                                        for r in swapped["short_over_10deg_confirmed"]]},
        scans, scan_stamps, stamps, poses)
    assert alone and all("by_odometry" not in g and "fit_odometry" not in g for g in alone)
    assert gross_failures_figure(tmp_path / "two", "room", alone).exists()

    # relations 10 s apart or more are not short: nothing to report
    later = Relations(stamps[i], stamps[j] + relations_audit.SHORT_GAP, delta)
    assert relations_audit.short_tail_apart(
        np.r_[stamps, stamps + relations_audit.SHORT_GAP], np.r_[trajectory, trajectory],
        later, audit) == {}
