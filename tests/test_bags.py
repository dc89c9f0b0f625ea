"""ROS bags in and out (swarmslam.formats.bags, swarmslam convert, replay BAG, lidar --bag): written
in the test, read back to what the CARMEN reader gives, with LaserScan's whole contract."""

import json
import math
import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.formats.bags import BagError, BagRecorder, BagWriter, read_bag, write_bag
from swarmslam.formats.carmen import flaser_angles, read_carmen
from swarmslam.cli import main
from swarmslam.replay import bag_sweep, replay_run
from swarmslam.formats.tum import read_tum

from test_hostile_inputs import log_lines

FORMATS = {"ros1": "run.bag", "mcap": "run.mcap", "sqlite3": "run-db"}


@pytest.fixture(scope="module")
def carmen_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("carmen") / "loop.clf"
    path.write_text("".join(log_lines(40)))
    return path


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_carmen_log_goes_through_every_bag_format_unchanged(carmen_log, tmp_path, fmt):
    """Stamps, ranges, angles, odometry, the laser's mount: bit for bit, and so the replay."""
    bag = tmp_path / FORMATS[fmt]
    assert main(["convert", str(carmen_log), str(bag)]) == 0
    original, back = read_carmen(carmen_log), read_bag(bag)
    assert len(back.lasers) == len(original.lasers) == 40
    for a, b in zip(original.lasers, back.lasers):
        assert a.timestamp == b.timestamp and np.array_equal(a.angles, b.angles)
        assert np.array_equal(a.odometry, b.odometry)
        assert np.array_equal(np.where(a.ranges < a.max_range, a.ranges, np.nan), b.ranges,
                              equal_nan=True)
    runs = [replay_run(path, label=str(path))[1].slam.trajectory()[1] for path in (carmen_log, bag)]
    assert np.array_equal(runs[0], runs[1])
    again = tmp_path / "again.clf"  # and back to CARMEN
    assert main(["convert", str(bag), str(again)]) == 0
    assert np.array_equal(read_carmen(again).lasers[5].ranges, original.lasers[5].ranges)


def _scans(steps=40):
    """A robot's true poses around a room and the room (for scans taken there)."""
    poses = loop_path(60)[:steps]
    return poses, room_world(0, size=(12.0, 9.0), boxes=10, walls=0, keep_clear=poses)


def _write(path, poses, world, mount=(0.0, 0.0, 0.0), mirrored=False, odometry="odom",
           angle_step=math.pi / 180):
    """A bag of LaserScans taken by a laser at ``mount`` on the robot (upside down if
    ``mirrored``: its beams sweep the other way), with odometry as Odometry or tf."""
    writer = BagWriter(path)
    writer.mount(0.0, np.array(mount, float), mirrored)
    n = int(round(math.pi / angle_step)) + 1
    beam = -math.pi / 2 + angle_step * np.arange(n)  # the laser's own angles
    for k, pose in enumerate(poses):
        stamp = 0.2 * k
        laser = compose(pose, np.array(mount, float))
        seen = -beam if mirrored else beam  # an upside-down laser's beam a points to -a
        ranges = scan_at(world, laser, seen, 50.0)
        writer.scan(stamp, beam, ranges, 50.0)
        if odometry == "odom":
            writer.odometry(stamp, pose)
        elif odometry == "tf":
            msg = writer.m.static(stamp, "odom", "base_link", pose)
            writer._write("/tf", stamp, msg, "tf2_msgs/msg/TFMessage")
    return writer.close()


def test_an_upside_down_laser_offset_0_3_m_gives_the_upright_ones_map(tmp_path):
    poses, world = _scans()
    upright = _write(tmp_path / "upright.mcap", poses, world)
    flipped = _write(tmp_path / "flipped.mcap", poses, world, mount=(0.3, 0.0, 0.0),
                     mirrored=True)
    walls, trajectories = [], []
    for path in (upright, flipped):
        _, runtime = replay_run(path, label=str(path))
        grid = runtime.slam.global_map()
        rows, cols = np.nonzero(grid.probability() > 0.65)
        walls.append(grid.origin + (np.c_[cols, rows] + 0.5) * grid.resolution)
        trajectories.append(runtime.slam.trajectory()[1])
    assert np.abs(trajectories[0] - trajectories[1]).max() < 0.03
    for a, b in (walls, walls[::-1]):  # the same walls: each map's within a cell of the other's
        near, _ = cKDTree(b).query(a, distance_upper_bound=0.08)
        assert np.mean(np.isfinite(near)) > 0.9


def test_odometry_from_tf_equals_odometry_from_odometry_messages(tmp_path):
    poses, world = _scans(12)
    odom = read_bag(_write(tmp_path / "odom.bag", poses, world))
    told = []
    tf = read_bag(_write(tmp_path / "tf.bag", poses, world, odometry="tf"), warn=told.append)
    assert any("odometry from tf" in t for t in told)
    for a, b in zip(odom.lasers, tf.lasers):
        assert np.array_equal(a.odometry, b.odometry)


def test_two_laserscan_topics_need_a_choice(tmp_path):
    poses, world = _scans(5)
    path = tmp_path / "two.mcap"
    writer = BagWriter(path)
    writer.connections["/scan_rear"] = writer.writer.add_connection(
        "/scan_rear", "sensor_msgs/msg/LaserScan", typestore=writer.m.store)
    beam = flaser_angles(181)
    for k, pose in enumerate(poses):
        ranges = scan_at(world, pose, beam, 50.0)
        writer.scan(0.2 * k, beam, ranges, 50.0)
        writer._write("/scan_rear", 0.2 * k, writer.m.scan(0.2 * k, "laser", beam, ranges, 50.0),
                      "sensor_msgs/msg/LaserScan")
    writer.close()
    with pytest.raises(BagError, match=r"2 LaserScan topics \(/scan, /scan_rear\).*--scan-topic"):
        read_bag(path)
    assert len(read_bag(path, scan_topic="/scan_rear").lasers) == 5


@pytest.mark.parametrize("name", ["cut.bag", "cut.mcap"])
def test_a_truncated_bag_keeps_every_scan_before_the_damage_and_says_where(tmp_path, name):
    poses, world = _scans(40)
    whole = _write(tmp_path / name.replace("cut", "whole"), poses, world)
    data = whole.read_bytes()
    cut = tmp_path / name
    cut.write_bytes(data[: len(data) * 6 // 10])
    told = []
    log = read_bag(cut, warn=told.append)
    complete = read_bag(whole).lasers
    assert 10 < len(log.lasers) < 40 and log.stopped
    for a, b in zip(log.lasers, complete):  # every scan kept is whole and the same
        assert a.timestamp == b.timestamp and np.array_equal(a.ranges, b.ranges, equal_nan=True)
    assert any("damaged" in t and f"{len(log.lasers)} scans" in t for t in told)


def test_a_replay_of_a_truncated_bag_says_so_and_is_not_ok(tmp_path):
    """The scans before the damage are replayed and their outputs written, but the run's
    status is not ok and metrics.json says where reading stopped."""
    poses, world = _scans(40)
    data = _write(tmp_path / "whole.mcap", poses, world).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 6 // 10])
    out = tmp_path / "run"
    main(["replay", str(cut), "--out", str(out)])
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"].startswith("damaged input") and metrics["read_stopped"]
    whole = tmp_path / "whole-run"
    main(["replay", str(tmp_path / "whole.mcap"), "--out", str(whole)])
    metrics = json.loads((whole / "metrics.json").read_text())
    assert metrics["status"] == "ok" and "read_stopped" not in metrics


def test_rep_117_ranges_are_read_as_no_return(tmp_path):
    path = tmp_path / "rep117.mcap"
    writer = BagWriter(path)
    beam = np.linspace(-0.5, 0.5, 6)
    message = writer.m.scan(0.0, "laser", beam, np.ones(6), 10.0)
    message.ranges[:] = [np.inf, -np.inf, np.nan, 0.05, 12.0, 2.0]  # 0.05 < range_min below
    message.range_min = 0.1
    writer._write("/scan", 0.0, message, "sensor_msgs/msg/LaserScan")
    writer.close()
    (record,) = read_bag(path).lasers
    assert np.isnan(record.ranges[:5]).all() and record.ranges[5] == 2.0


def test_a_scan_whose_beam_count_contradicts_its_angles_is_skipped_and_counted(tmp_path):
    path = tmp_path / "bad.mcap"
    writer = BagWriter(path)
    beam = flaser_angles(181)
    for k in range(3):
        message = writer.m.scan(0.2 * k, "laser", beam, np.full(181, 3.0), 50.0)
        if k == 1:
            message.angle_max = 3.0  # 181 beams cannot span that at 1°
        writer._write("/scan", 0.2 * k, message, "sensor_msgs/msg/LaserScan")
    writer.close()
    log = read_bag(path)
    assert len(log.lasers) == 2 and log.skipped == {"beam count": 1}


def test_a_missing_mount_is_taken_at_the_origin_and_said(tmp_path):
    path = tmp_path / "nomount.mcap"
    writer = BagWriter(path)
    writer.static_written = True  # (no tf_static at all)
    writer.scan(0.0, flaser_angles(181), np.full(181, 3.0), 50.0)
    writer.close()
    told = []
    (record,) = read_bag(path, warn=told.append).lasers
    assert not np.any(record.laser_offset) and any("no tf_static" in t for t in told)


def test_the_live_run_records_a_bag_replay_reads_back(tmp_path):
    # lockstep: each scan the live run takes gets the whole swarm budget, as in the replay, so
    # a loaded machine drops scans (counted as stale) but never cuts a match short
    config = tmp_path / "lockstep.toml"
    config.write_text('[runtime]\nschedule = "lockstep"\n')
    emu = subprocess.Popen([sys.executable, "-m", "swarmslam.cli", "emulate", "--model", "a1",
                            "--link", str(tmp_path / "lidar"), "--world", "office"],
                           stdout=subprocess.PIPE, text=True)
    try:
        assert "virtual RPLidar" in emu.stdout.readline()
        live = subprocess.run([sys.executable, "-m", "swarmslam.cli", "lidar", "--port",
                               str(tmp_path / "lidar"), "--model", "a1", "--seconds", "12",
                               "--out", str(tmp_path / "live"), "--bag",
                               str(tmp_path / "live.mcap"), "--config", str(config)],
                              capture_output=True, text=True, timeout=600)
    finally:
        emu.terminate()
        emu.wait(timeout=10)
    assert live.returncode == 0, live.stdout + live.stderr
    log = read_bag(tmp_path / "live.mcap")
    assert len(log.lasers) >= 20
    assert main(["replay", str(tmp_path / "live.mcap"), "--out", str(tmp_path / "re")]) == 0
    stamps_live, poses_live = read_tum(tmp_path / "live" / "trajectory.tum")
    stamps_re, poses_re = read_tum(tmp_path / "re" / "trajectory.tum")
    common = np.intersect1d(np.round(stamps_live, 3), np.round(stamps_re, 3))
    assert len(common) >= 0.8 * len(stamps_live)
    a = poses_live[np.isin(np.round(stamps_live, 3), common)]
    b = poses_re[np.isin(np.round(stamps_re, 3), common)]
    # each run's map frame is its own first scan, and the bag holds every rotation, also those a
    # loaded machine's live run dropped before its first match: compare in the first common frame
    a, b = between(a, a[0]), between(b, b[0])
    assert np.abs(a[:, :2] - b[:, :2]).max() < 0.1  # the same path, binned beams aside


def test_bench_bags_times_every_format_and_compares_the_replays(carmen_log, tmp_path):
    from swarmslam.bench.bags import bench_bags

    out = tmp_path / "bags.json"
    results = bench_bags({"loop": carmen_log}, repeats=1, json_path=out, echo=lambda t: None)
    entry = results["logs"]["loop"]
    assert entry["trajectory_identical"] is True and entry["scans"] == 40
    assert set(entry["formats"]) == {"ros1", "sqlite3", "mcap"}
    for figures in entry["formats"].values():
        assert figures["read_seconds"] > 0
        assert figures["share_of_replay"] == figures["read_seconds"] / entry["replay_wall_seconds"]
    assert out.exists() and "meta" in json.loads(out.read_text())


def test_a_bag_whose_scans_give_their_beams_timing_is_replayed_with_that_sweep(carmen_log,
                                                                                tmp_path):
    """A ROS LaserScan's ``time_increment`` is its sweep, and its stamp marks the first ray: the
    replay undoes the turn over that sweep, stamped at its start; a bag without it (and the
    CARMEN log) runs as configured."""
    log = read_carmen(carmen_log)
    beams = len(log.lasers[0].ranges)
    timed = replace(log, lasers=[replace(r, time_increment=0.1 / (beams - 1))
                                 for r in log.lasers])
    swept, plain = tmp_path / "swept.mcap", tmp_path / "plain.mcap"
    write_bag(timed, swept)
    write_bag(log, plain)
    sensor = replay_run(swept, limit=10)[1].config.sensor
    assert sensor.sweep_seconds == pytest.approx(0.1) and sensor.sweep_stamp == 0.0
    for path in (plain, carmen_log):
        sensor = replay_run(path, limit=10)[1].config.sensor
        assert sensor.sweep_seconds == 0.0 and sensor.sweep_stamp == 1.0


def test_a_bags_unusable_beam_timing_is_named_and_not_used():
    said = []

    def scans(ti):
        return [SimpleNamespace(time_increment=ti, ranges=np.ones(361)) for _ in range(3)]

    assert bag_sweep(scans(math.nan), None, said.append) is None
    assert bag_sweep(scans(-1e-4), None, said.append) is None
    assert bag_sweep(scans(0.01), None, said.append) is None  # a 3.6 s sweep: past the bound
    assert len(said) == 3 and "not a number" in said[0] and "sweep_seconds: must be <= 1.0" in said[2]
    config = bag_sweep(scans(1e-4), SlamConfig(), said.append)
    assert config.sensor.sweep_seconds == pytest.approx(0.036)
    assert config.sensor.sweep_stamp == 0.0


@pytest.mark.parametrize("offset", [(1e300, 0.0, 0.0), (float("nan"), 0.0, 0.0), (101.0, 0.0, 0.0)])
def test_a_mount_not_finite_or_beyond_a_robots_reach_is_refused_by_name(tmp_path, offset):
    """A laser mounted 1e300 m away used to reach a kernel unchecked (a segfault)."""
    path = tmp_path / "far.mcap"
    writer = BagWriter(path)
    writer.mount(0.0, offset)
    writer.scan(0.0, flaser_angles(181), np.full(181, 3.0), 50.0)
    writer.close()
    with pytest.raises(BagError, match="tf_static"):
        read_bag(path)


def test_a_mount_within_reach_is_read_as_written(tmp_path):
    path = tmp_path / "near.mcap"
    writer = BagWriter(path)
    writer.mount(0.0, (99.0, -0.5, 0.25))
    writer.scan(0.0, flaser_angles(181), np.full(181, 3.0), 50.0)
    writer.close()
    (record,) = read_bag(path).lasers
    assert np.allclose(record.laser_offset, (99.0, -0.5, 0.25))


def test_convert_never_replaces_a_folder_that_is_not_a_bag(carmen_log, tmp_path, monkeypatch,
                                                           capsys):
    mine = tmp_path / "mydata"
    mine.mkdir()
    (mine / "thesis.txt").write_text("three years of work")
    assert main(["convert", str(carmen_log), str(mine)]) == 2
    assert "not a ROS 2 bag" in capsys.readouterr().err
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.txt"]
    assert main(["convert", str(carmen_log), str(mine), "--format", "mcap"]) == 2
    monkeypatch.chdir(mine)
    assert main(["convert", str(carmen_log), "."]) == 2
    assert "working folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mydata"]  # no .writing left
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.txt"]


def test_convert_replaces_a_bag_folder_it_wrote_before(carmen_log, tmp_path):
    bag = tmp_path / "run-db"
    assert main(["convert", str(carmen_log), str(bag)]) == 0
    (bag / "metadata.yaml").read_text()
    assert main(["convert", str(carmen_log), str(bag)]) == 0
    assert len(read_bag(bag).lasers) == 40


@pytest.mark.parametrize("fmt", FORMATS)
def test_the_recorder_writes_every_format_from_its_own_thread(tmp_path, fmt):
    """A sqlite3 bag's connection belongs to its thread: the recorder's writer is made, used
    and closed on the recorder's (ROS 2 bag folders used to fail every time)."""
    recorder = BagRecorder(tmp_path / FORMATS[fmt], 360, 10.0)
    angles = np.linspace(-math.pi, math.pi, 400, endpoint=False)
    for k in range(5):
        recorder.put(angles, np.full(400, 2.0 + 0.1 * k), 0.1 * k)
    path = recorder.close()
    lasers = read_bag(path).lasers
    assert len(lasers) == 5 and recorder.recorded == 5
    assert np.nanmedian(lasers[4].ranges) == pytest.approx(2.4, abs=1e-3)


def test_the_recorder_refuses_a_folder_that_is_not_a_bag_before_the_run(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(BagError, match="not a ROS 2 bag"):
        BagRecorder(mine, 360, 10.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
