"""Live SLAM end to end: the emulator scans a simulated world while a robot explores it; the
real driver reads it over a pseudo-terminal; ``swarmslam lidar`` runs the fixed-rate runtime
on the rotations (scans only, no odometry) and must track the true pose."""

import json
import subprocess
import sys

import numpy as np

from swarmslam.hardware.emulator import VirtualRPLidar
from swarmslam.runtime.pose import between
from swarmslam.cli import main
from swarmslam.emulator_sources import WorldSource
from swarmslam.formats.tum import read_tum


def test_live_slam_from_the_emulator_tracks_the_true_pose(tmp_path, capsys):
    # still for 8 turns (the first scans the SLAM sees are at the start pose), then exploring
    # for 60 turns (11 s), then still again so the final estimate has a pose to match
    source = WorldSource("office", seed=2, still_before=8, still_after=68)
    emu = VirtualRPLidar(source, "a1", seed=2)
    path = emu.start()
    try:
        code = main(["lidar", "--port", path, "--model", "a1", "--mode", "express",
                     "--out", str(tmp_path), "--seconds", "15"])
    finally:
        emu.stop()
    assert code == 0
    out = capsys.readouterr().out
    assert "scans/s" in out and "pose" in out
    for name in ("map.pgm", "map.yaml", "map.png", "trajectory.tum", "graph.g2o", "session.npz",
                 "summary.json"):
        assert (tmp_path / name).exists(), name
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runtime"]["scans"] >= 60
    assert summary["runtime"]["deadline_misses"] == 0
    truth = np.array(source.truth)
    moved = np.hypot(*(truth[-1, :2] - truth[0, :2]))
    assert moved > 1.0  # the robot did go somewhere
    _, poses = read_tum(tmp_path / "trajectory.tum")
    final_truth = between(truth[-1], truth[0])  # the map frame is the first scan's
    error = np.hypot(*(poses[-1, :2] - final_truth[:2]))
    assert error < 0.15, (error, moved)


def test_emulate_command_prints_the_port_and_serves_it(tmp_path):
    link = tmp_path / "lidar"
    proc = subprocess.Popen([sys.executable, "-m", "swarmslam.cli", "emulate", "--model", "a2",
                             "--link", str(link), "--faults", "garbage=0.01"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert "virtual RPLidar A2" in line and str(link) in line
        from swarmslam.hardware.driver import RPLidar

        with RPLidar(str(link), "a2") as lidar:
            assert lidar.get_info().major_model == 2
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_a_missing_port_is_a_clear_error(tmp_path, capsys):
    missing = tmp_path / "no-such-port"
    assert main(["lidar", "--port", str(missing), "--seconds", "1"]) == 2
    assert f"could not open port {missing}" in capsys.readouterr().err
