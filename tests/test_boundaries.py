"""No input hangs a run, loses a finished one, or passes off wrong output as ok: at every
boundary — reader, inbox, configuration, session, environment options, output folder, live
link — a value is finite and in its documented range, or it is refused or counted by name
(docs/runtime.md §7)."""

import gzip
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from swarmslam.runtime.config import ConfigError, SlamConfig, from_toml, override
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.realtime.inbox import ScanInbox
from swarmslam.runtime.occupancy_grid import OccupancyGrid, integrate_scan
from swarmslam.runtime.resources import check_memory
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.formats.carmen import flaser_angles, read_carmen
from swarmslam.cli import main
from swarmslam.formats.tum import read_tum
from swarmslam.outputs import MANIFEST

from source_layout import copy_installed_layout
from test_hostile_inputs import edit, log_lines, strict_json


def write_log(path, lines):
    path.write_text("".join(lines))
    return path


def robotlaser1_lines(steps=30):
    """ROBOTLASER1 lines (odometry = truth, the laser 0.1 m ahead) around a synthetic room."""
    poses = loop_path(60)[:steps]
    world = room_world(0, size=(12.0, 9.0), boxes=10, walls=0, keep_clear=poses)
    angles = flaser_angles(181)
    lines = []
    for k, p in enumerate(poses):
        laser = p + [0.1 * math.cos(p[2]), 0.1 * math.sin(p[2]), 0.0]
        ranges = " ".join(f"{v:.3f}" for v in scan_at(world, laser, angles, 50.0))
        lp, rp, t = " ".join(f"{v:.6f}" for v in laser), " ".join(f"{v:.6f}" for v in p), 0.2 * k
        lines.append(f"ROBOTLASER1 0 -1.570796 3.141593 0.017453 50.0 0.01 0 181 {ranges} 0 "
                     f"{lp} {rp} 0 0 0 0 0 {t:.3f} host {t:.3f}\n")
    return lines


def robotlaser1_edit(line, **fields):
    """A ROBOTLASER1 line with fields replaced (by name: start_angle, angular_res, laser_x)."""
    t = line.split()
    where = {"start_angle": 2, "angular_res": 4, "max_range": 5}
    n = int(t[8])
    where["laser_x"] = 8 + 1 + n + 1
    for name, value in fields.items():
        t[where[name]] = value
    return " ".join(t) + "\n"


# ---------------------------------------------------------------- non-finite points
def test_a_scan_of_nan_points_is_refused_and_the_map_stays_drawable():
    runtime = SlamRuntime(SlamConfig())
    assert runtime.process(np.full((50, 2), np.nan)) is None  # refused, counted
    assert runtime.inbox.empty == 1
    assert runtime.global_map().logodds.size > 0  # an empty map of unknown cells, at once
    good = np.c_[np.linspace(-2, 2, 60), np.full(60, 3.0)]
    mixed = np.r_[good, [[np.nan, 1.0], [np.inf, 0.0]]]
    assert runtime.process(mixed, np.zeros(3), 1.0) is not None  # the finite points used
    assert runtime.slam.nodes.counts[0] == 60


def test_the_map_kernel_draws_no_ray_it_cannot_finish():
    """NaN and absurd points, and a pose off the grid: every loop is bounded."""
    grid = OccupancyGrid(100, 100, 0.05)
    pts = np.array([[np.nan, 0.0], [1e15, 1e15], [-1e300, 2.0], [1.0, 1.0]])
    started = time.perf_counter()
    integrate_scan(grid.logodds, grid.region, 0.0, 0.0, 0.05, np.array([2.5, 2.5, 0.0]), pts,
                   4, np.inf)
    integrate_scan(grid.logodds, grid.region, 0.0, 0.0, 0.05, np.array([np.nan, 0.0, 0.0]),
                   pts, 4, np.inf)
    assert time.perf_counter() - started < 30.0  # (a hang would never return)
    assert grid.logodds[int(3.5 / 0.05), int(3.5 / 0.05)] > 0  # the one good point drawn


def test_a_robotlaser1_laser_pose_that_is_not_finite_skips_its_record(tmp_path, capsys):
    lines = robotlaser1_lines()
    lines[0] = robotlaser1_edit(lines[0], laser_x="inf")
    lines[5] = robotlaser1_edit(lines[5], laser_x="1e300")
    out = tmp_path / "out"
    assert main(["replay", str(write_log(tmp_path / "r.clf", lines)), "--out", str(out)]) == 0
    m = strict_json(out / "metrics.json")
    assert m["records_skipped"] == {"laser_pose": 2} and m["scans"] == 28
    assert "r.clf:1: ROBOTLASER1 laser_pose" in capsys.readouterr().err


# ---------------------------------------------------------------- logs with nothing usable
@pytest.mark.parametrize("ranges", ["inf", "81.83"])
def test_a_log_whose_scans_are_all_empty_says_so_and_keeps_the_set_there(tmp_path, capsys,
                                                                          ranges):
    """A good run's outputs, then a run with nothing usable into the same folder: exit 1, and
    the good set is as it was (an empty map used to replace it)."""
    out = tmp_path / "out"
    assert main(["replay", str(write_log(tmp_path / "g.clf", log_lines(12))), "--out",
                 str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    lines = [edit(line, ranges=ranges) for line in log_lines(12)]
    log = write_log(tmp_path / "e.clf", lines)
    assert main(["replay", str(log), "--out", str(out)]) == 1
    said = capsys.readouterr().out
    assert "no usable scan" in said and "nothing written to" in said
    after = {p.name: p.read_bytes() for p in out.iterdir()}
    report = strict_json(out / "unusable-run.json")  # its report beside the set
    assert report["status"].startswith("no usable scan") and report["scans_refused"] == 12
    assert {k: v for k, v in after.items() if k not in ("unusable-run.json", MANIFEST)} == {
        k: v for k, v in before.items() if k != MANIFEST}
    assert main(["replay", str(write_log(tmp_path / "g.clf", log_lines(12))), "--out",
                 str(out)]) == 0
    assert not (out / "unusable-run.json").exists()  # the next set replaces it with the rest
    assert SlamRuntime(SlamConfig()).global_map().logodds.size > 0  # before any scan


def test_a_localized_run_refuses_an_out_that_holds_its_session(tmp_path, capsys):
    """Its output set would replace the mapping run's there: the session and its map gone."""
    log = write_log(tmp_path / "g.clf", log_lines(30))
    out = tmp_path / "run"
    assert main(["replay", str(log), "--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(["replay", str(log), "--start", "10", "--localize", str(out / "session.npz"),
                 "--out", str(out)]) == 2
    assert "is part of the output set there" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    elsewhere = tmp_path / "localized"
    assert main(["replay", str(log), "--start", "10", "--localize", str(out / "session.npz"),
                 "--out", str(elsewhere)]) == 0
    assert (elsewhere / "localization.json").exists()


def test_a_robotlaser1_max_range_of_zero_is_refused_by_name(tmp_path, capsys):
    lines = robotlaser1_lines(5)
    lines[2] = robotlaser1_edit(lines[2], max_range="0")
    assert main(["replay", str(write_log(tmp_path / "z.clf", lines))]) == 2
    assert "z.clf:3: max_range" in capsys.readouterr().err


def test_a_mostly_unusable_log_is_not_ok(tmp_path):
    lines = log_lines(20)
    for k in range(2, 20):
        lines[k] = edit(lines[k], ranges="inf")
    out = tmp_path / "out"
    assert main(["replay", str(write_log(tmp_path / "m.clf", lines)), "--out", str(out)]) == 1
    m = strict_json(out / "metrics.json")
    assert m["status"].startswith("mostly unusable input") and m["unusable_share"] == 0.9


# ---------------------------------------------------------------- stamps
@pytest.mark.parametrize("stamp", ["-inf", "1e300", "-1e300"])
def test_an_impossible_stamp_skips_its_record_by_name(tmp_path, stamp):
    lines = log_lines(20)
    lines[7] = edit(lines[7], stamp=stamp)
    out = tmp_path / "out"
    assert main(["replay", str(write_log(tmp_path / "s.clf", lines)), "--out", str(out)]) == 0
    m = strict_json(out / "metrics.json")
    assert m["records_skipped"] == {"ipc_timestamp": 1} and m["status"] == "ok"
    assert 0 < m["data_seconds"] < 10
    poses = np.loadtxt(out / "trajectory.tum")
    assert len(poses) == 19 and np.all(np.isfinite(poses))


@pytest.mark.parametrize("stamp", [-math.inf, math.inf, math.nan, 1e300])
def test_the_inbox_refuses_an_impossible_stamp(stamp):
    inbox = ScanInbox(10)
    angles, ranges = np.linspace(-1, 1, 5), np.full(5, 2.0)
    assert not inbox.put_ranges(angles=angles, ranges=ranges, stamp=stamp)
    assert inbox.counts()["bad_stamp_scans"] == 1
    assert inbox.put_ranges(angles=angles, ranges=ranges, stamp=1.0)


# ---------------------------------------------------------------- streams
def test_a_log_read_from_a_pipe_a_fifo_or_stdin_loses_no_scan(tmp_path):
    plain = write_log(tmp_path / "small.clf", log_lines(30))
    packed = tmp_path / "small.clf.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    for source in (plain, packed):  # standard input, plain and gzipped
        done = subprocess.run([sys.executable, "-m", "swarmslam.cli", "replay", "-"],
                              input=source.read_bytes(), capture_output=True, cwd=tmp_path,
                              timeout=300)
        assert done.returncode == 0, done.stderr
        assert done.stdout.decode().startswith("30 scans"), done.stdout
    fifo = tmp_path / "log.fifo"
    os.mkfifo(fifo)

    def feed():
        with open(fifo, "wb") as f:
            f.write(packed.read_bytes())

    writer = threading.Thread(target=feed)
    writer.start()
    log = read_carmen(fifo)
    writer.join(timeout=60)
    assert len(log.lasers) == 30


# ---------------------------------------------------------------- absurd finite values
def test_odometry_no_robot_gives_is_dropped_and_counted(tmp_path):
    lines = log_lines(20)
    t = lines[10].split()
    t[2 + 180 + 5] = "1e300"  # odom.theta
    lines[10] = " ".join(t) + "\n"
    out = tmp_path / "out"
    assert main(["replay", str(write_log(tmp_path / "o.clf", lines)), "--out", str(out)]) == 0
    m = strict_json(out / "metrics.json")
    assert m["runtime"]["odometry_out_of_range"] == 1
    _, poses = read_tum(out / "trajectory.tum")
    truth = loop_path(60)[:20]  # (the map frame is the first scan's)
    turned = (poses[:, 2] - poses[0, 2]) - (truth[:, 2] - truth[0, 2])
    # read as a heading (1e300 wraps to about -0.72 rad) it put poses 41° off; dropped, the
    # scans after it go on from the scans' own motion (here 6° a scan: 5° lost, as for a
    # reading that is not finite)
    assert np.max(np.abs(np.angle(np.exp(1j * turned)))) < np.radians(6.0)


@pytest.mark.parametrize("field, value", [("angular_res", "-0.017453"),
                                          ("start_angle", "1e300")])
def test_impossible_scanner_geometry_is_refused_by_name(tmp_path, capsys, field, value):
    lines = robotlaser1_lines(5)
    lines[3] = robotlaser1_edit(lines[3], **{field: value})
    assert main(["replay", str(write_log(tmp_path / "g.clf", lines))]) == 2
    assert f"g.clf:4: {field}" in capsys.readouterr().err


def test_junk_and_utf16_logs_are_refused_by_name(tmp_path, capsys):
    junk = tmp_path / "junk.clf"
    with open(junk, "wb") as f:
        f.write(b"x" * (3 * 2**20))  # one 3 MiB line: refused after reading 1 MiB of it
    assert main(["replay", str(junk)]) == 2
    assert "junk.clf:1: text: a line longer than 1 MiB" in capsys.readouterr().err
    utf16 = tmp_path / "utf16.clf"
    utf16.write_text("".join(log_lines(5)), encoding="utf-16")
    assert main(["replay", str(utf16)]) == 2
    assert "utf16.clf:1: text: a NUL byte" in capsys.readouterr().err


# ---------------------------------------------------------------- the API
def test_the_api_names_the_argument_it_cannot_take():
    runtime = SlamRuntime(SlamConfig())
    inbox = runtime.inbox
    angles = np.linspace(-1.5, 1.5, 90)
    assert inbox.put_ranges(angles=angles.astype(np.float16),
                            ranges=np.full(90, 3.0, np.float16), stamp=0.0)  # converted
    with pytest.raises(ValueError, match="ranges: needs shape"):
        inbox.put_ranges(angles=angles, ranges=np.ones((90, 2)), stamp=1.0)
    with pytest.raises(ValueError, match="ranges: needs real numbers"):
        inbox.put_ranges(angles=angles, ranges=np.ones(90, complex), stamp=1.0)
    with pytest.raises(ValueError, match="stamp: needs a number"):
        inbox.put_ranges(angles=angles, ranges=np.ones(90), stamp="soon")
    with pytest.raises(ValueError, match="odometry: needs"):
        runtime.process(np.ones((5, 2)), odometry=[0.0, 0.0], stamp=2.0)
    points = [[0.5 * k, 3.0] for k in range(-5, 6)]  # a list of points is taken
    assert runtime.process(points, stamp=3.0) is not None


# ---------------------------------------------------------------- resumed sessions
def test_a_session_resumes_from_anywhere_in_its_log(tmp_path):
    lines = log_lines(40)
    log = write_log(tmp_path / "loop.clf", lines)
    assert main(["replay", str(log), "--limit", "20", "--out", str(tmp_path / "s")]) == 0
    for start in (10, 25):  # inside what was mapped, and past it
        out = tmp_path / f"s{start}"
        assert main(["replay", str(log), "--start", str(start), "--limit", "12", "--resume",
                     str(tmp_path / "s" / "session.npz"), "--out", str(out)]) == 0
        assert (out / "session.npz").exists()


# ---------------------------------------------------------------- output folders
def test_a_name_too_long_for_the_file_system_is_refused_before_the_run(tmp_path, capsys):
    log = write_log(tmp_path / "ok.clf", log_lines(8))
    assert main(["replay", str(log), "--out", str(tmp_path / ("x" * 300))]) == 2
    assert "longer than the file system allows" in capsys.readouterr().err
    long_ok = tmp_path / ("y" * 250)  # fits, and so do its staging folders
    assert main(["replay", str(log), "--out", str(long_ok)]) == 0
    assert (long_ok / "map.pgm").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["ok.clf", long_ok.name])


def test_out_dot_writes_the_working_folder_in_place(tmp_path, monkeypatch):
    log = write_log(tmp_path / "ok.clf", log_lines(8))
    here = tmp_path / "here"
    here.mkdir()
    (here / "notes.txt").write_text("mine")
    monkeypatch.chdir(here)
    assert main(["replay", str(log), "--out", "."]) == 0
    assert (here / "map.pgm").exists() and (here / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["here", "ok.clf"]  # nothing beside


def test_a_symlinked_out_writes_its_target_and_stays_a_link(tmp_path):
    log = write_log(tmp_path / "ok.clf", log_lines(8))
    target = tmp_path / "target"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)
    assert main(["replay", str(log), "--out", str(link)]) == 0
    assert link.is_symlink() and (target / "map.pgm").exists()
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_a_group_owned_out_keeps_its_group_and_mode(tmp_path):
    log = write_log(tmp_path / "ok.clf", log_lines(8))
    out = tmp_path / "shared"
    out.mkdir()
    os.chmod(out, 0o2770)
    group = next((g for g in range(1, 65535) if g != os.getgid()), None)
    try:
        os.chown(out, -1, group)
    except PermissionError:
        group = os.getgid()  # not root, nor in another group: the mode alone is checked
    assert main(["replay", str(log), "--out", str(out)]) == 0
    st = out.stat()
    assert st.st_gid == group and (st.st_mode & 0o7777) == 0o2770


def test_a_rerun_leaves_no_file_of_the_previous_set(tmp_path):
    log = write_log(tmp_path / "ok.clf", log_lines(12))
    out = tmp_path / "out"
    assert main(["replay", str(log), "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    (out / "session.npz").unlink()  # a set's file gone meanwhile: the next set writes its own
    shorter = write_log(tmp_path / "short.clf", log_lines(6))
    assert main(["replay", str(shorter), "--out", str(out)]) == 0
    m = strict_json(out / "metrics.json")
    assert m["scans"] == 6 and (out / "notes.txt").read_text() == "mine"
    assert len(read_tum(out / "trajectory.tum")[0]) == 6  # this run's, not the last one's
    assert (out / "session.npz").exists()


# ---------------------------------------------------------------- configuration
@pytest.mark.parametrize("text, message", [
    ("[matcher.swarm]\nmembers = 1000000000\n", "matcher.swarm.members: must be <= 10000"),
    ("[capacity]\nmax_nodes = 1e9\n", "capacity.max_nodes: must be a whole number"),
    ("[capacity]\nmax_nodes = 1000000000\n", "capacity.max_nodes: must be <= 1000000"),
])
def test_capacities_beyond_their_bounds_are_refused_by_key(text, message):
    with pytest.raises(ConfigError, match=message):
        from_toml(text)


def test_capacities_that_would_not_fit_in_memory_are_refused_before_allocating():
    config = override(SlamConfig(), {"capacity.max_nodes": 500_000})
    with pytest.raises(ValueError, match=r"need about .* GiB.*capacity\.max_nodes"):
        check_memory(config, available=4 * 2**30)
    check_memory(SlamConfig(), available=4 * 2**30)  # the defaults fit a small computer


# ---------------------------------------------------------------- the environment
@pytest.mark.parametrize("start, message", [
    ((math.nan, 1.0, 0.0), "finite"), ((1.0, math.inf, 0.0), "finite"),
    ((1000.0, 1000.0, 0.0), "outside the world"), ((1.5, 1.5, 1e300), "finite"),
    ((1.0, 2.0), r"\(x, y, heading\)"),
])
def test_the_environment_refuses_a_start_the_robot_cannot_take(start, message):
    import gymnasium as gym
    import swarmslam_sim  # noqa: F401  (registers the environment)

    env = gym.make("SwarmSlam-v0", slam=False)
    try:
        with pytest.raises(ValueError, match=message):
            env.reset(options={"start": start})
    finally:
        env.close()


def test_the_environment_refuses_a_start_inside_a_wall_and_a_speed_that_tunnels():
    from swarmslam_sim.env import SwarmSlamEnv

    env = SwarmSlamEnv(slam=False)
    wall = env.world.segments[0]
    inside = (0.5 * (wall[0] + wall[2]), 0.5 * (wall[1] + wall[3]), 0.0)
    with pytest.raises(ValueError, match="from a wall"):
        env.reset(options={"start": inside})
    env.reset(options={"start": (*env.world.start[:2], 7.0)})  # a heading wrapped
    assert -math.pi <= env.true_pose[2] <= math.pi
    with pytest.raises(ValueError, match="max_linear must be <"):
        SwarmSlamEnv(slam=False, max_linear=1e9)


# ---------------------------------------------------------------- live runs
def test_a_live_run_that_receives_nothing_says_so(tmp_path):
    """The emulator serves an S2; the run asks for an A1: warned, 'no scans' and exit 1, and
    the output folder holds what it held (an empty set must not replace yesterday's map)."""
    emu = subprocess.Popen([sys.executable, "-m", "swarmslam.cli", "emulate", "--model", "s2",
                            "--link", str(tmp_path / "lidar")], stdout=subprocess.PIPE,
                           text=True)
    out = tmp_path / "out"
    out.mkdir()
    (out / "map.pgm").write_text("an earlier run's map")
    try:
        assert "virtual RPLidar" in emu.stdout.readline()
        live = subprocess.run([sys.executable, "-m", "swarmslam.cli", "lidar", "--port",
                               str(tmp_path / "lidar"), "--model", "a1", "--seconds", "7",
                               "--out", str(out)], capture_output=True, text=True, timeout=300)
    finally:
        emu.terminate()
        emu.wait(timeout=10)
    assert live.returncode == 1, live.stdout + live.stderr
    assert "warning: the scanner reports itself an S2, not the A1" in live.stdout
    assert "no scans for" in live.stdout and "status: no scans received" in live.stdout
    assert "nothing written to" in live.stdout
    assert (out / "map.pgm").read_text() == "an earlier run's map"
    summary = strict_json(out / "unusable-run.json")
    assert summary["status"].startswith("no scans received")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "map.pgm", "unusable-run.json"]


# ---------------------------------------------------------------- an unwritable home
def test_a_user_who_cannot_write_home_nor_the_package_still_runs(tmp_path):
    """Installed where its caches cannot be written, run by a user whose HOME cannot be
    written either: numba's caches go to a folder of the user's in the temporary directory,
    not a traceback at import. (``__pycache__`` a file and HOME a device: no folder can be
    made there, even by root.)"""
    site = copy_installed_layout(tmp_path / "site")
    for package in ("swarmslam", "swarmslam/runtime", "swarmslam/runtime/matching",
                    "swarmslam/runtime/matching/optimizers", "swarmslam/runtime/front_end",
                    "swarmslam/runtime/back_end", "swarmslam/runtime/localization",
                    "swarmslam/runtime/realtime", "swarmslam_sim"):
        (site / package / "__pycache__").write_text("not a folder")
    env = {**{k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"},
           "PYTHONPATH": str(site), "HOME": "/dev/null", "XDG_CACHE_HOME": "/dev/null/cache",
           "PYTHONDONTWRITEBYTECODE": "1"}
    code = ("import numpy as np, numba; "
            "from swarmslam.runtime.matching.scan import ranges_to_points; "
            "out = np.zeros((3, 2)); "
            "print(ranges_to_points(np.ones(3), np.zeros(3), 0.0, 5.0, out), "
            "numba.config.CACHE_DIR)")
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    count, folder = done.stdout.split()
    assert count == "3" and Path(folder).parent == Path(tempfile.gettempdir())
    show = subprocess.run([sys.executable, "-m", "swarmslam.cli", "config", "show"], env=env,
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert show.returncode == 0 and "[sensor]" in show.stdout, show.stderr
