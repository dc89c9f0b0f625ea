"""Watching a run (rerun view and recording, MCAP), video of the simulator, benchmark plots and
the output files' modes."""

import base64
import json
import math
import os
import re
import socket
import stat
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import rerun as rr
from gymnasium.wrappers import RecordVideo
from mcap.reader import make_reader

import swarmslam.view.rerun_view as rerun_view
import swarmslam.view.run_view as run_view
from swarmslam.runtime.config import SensorConfig
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.writers import write_bytes_atomic
from swarmslam.bench.slam import plot_run
from swarmslam.formats.carmen import read_carmen
from swarmslam.cli import main
from swarmslam.view.mcap_recording import laser_ranges
from swarmslam.view.plots import bars, latency_histograms
from swarmslam.formats.relations import read_relations
from swarmslam.replay import replay_run, robot_frame_scan


@pytest.fixture(scope="module")
def hall_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hall")
    log = folder / "hall.clf.gz"
    assert main(["simlog", str(log), "--site", "hall", "--scanner", "rplidar-a1", "--rate", "4",
                 "--seconds", "30"]) == 0
    return log


def entity_rows(path) -> dict:
    """Rows logged per entity in an .rrd file, read back with rerun's own reader."""
    rows = {}
    for line in rr.chunk.RrdReader(path).store().summary().splitlines():
        entity, count = line.split()[0], int(line.split()[1].removeprefix("rows="))
        rows[entity] = rows.get(entity, 0) + count
    return rows


def mcap_messages(path) -> dict:
    out = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(
                (schema.name if schema else None, message.log_time, json.loads(message.data)))
    return out


def test_recordings_hold_the_run_and_change_nothing(hall_log, tmp_path):
    plain, watched = tmp_path / "plain", tmp_path / "watched"
    poses = []  # each tick's pose, from a run without a view

    def follow(k, runtime):
        if k:
            poses.append(runtime.last.pose.copy())

    _, runtime = replay_run(hall_log, out_dir=plain, before_scan=follow)
    poses.append(runtime.last.pose.copy())
    assert main(["replay", str(hall_log), "--out", str(watched), "--record",
                 str(watched / "run.rrd"), "--mcap", str(watched / "run.mcap")]) == 0
    for name in ("trajectory.tum", "map.pgm", "graph.g2o"):  # the view changes no result
        assert (plain / name).read_bytes() == (watched / name).read_bytes(), name

    lasers = read_carmen(hall_log).lasers
    topics = mcap_messages(watched / "run.mcap")
    assert {t: len(m) for t, m in topics.items() if t != "/map"} == {
        "/scan": len(lasers), "/pose": len(lasers), "/tf": len(lasers), "/stats": len(lasers)}
    assert len(topics["/map"]) >= 1 and topics["/map"][0][0] == "foxglove.Grid"
    grid = topics["/map"][-1][2]
    cells = np.frombuffer(base64.b64decode(grid["data"]), np.int8)
    assert len(cells) % grid["column_count"] == 0
    assert (cells >= 65).any() and ((cells >= 0) & (cells <= 20)).any()  # walls and free space
    # the poses are the run's, exactly
    got = np.array([[m["pose"]["position"]["x"], m["pose"]["position"]["y"],
                     2 * math.atan2(m["pose"]["orientation"]["z"], m["pose"]["orientation"]["w"])]
                    for _, _, m in topics["/pose"]])
    assert np.allclose(got, np.array(poses), atol=1e-12, rtol=0)
    # the scans are the log's: every point's range sits in its angle's bin
    scan = PointScan(max(len(r.ranges) for r in lasers))
    config_bins = len(topics["/scan"][0][2]["ranges"])
    for record, (schema, log_time, message) in zip(lasers, topics["/scan"]):
        assert schema == "foxglove.LaserScan" and log_time == round(record.timestamp * 1e9)
        pts = robot_frame_scan(record, scan, SensorConfig()).points
        r = np.hypot(pts[:, 0], pts[:, 1])
        k = np.floor((np.arctan2(pts[:, 1], pts[:, 0]) + math.pi) / (2 * math.pi) * config_bins
                     + 0.5).astype(int) % config_bins
        ranges = np.array(message["ranges"])
        assert np.all(ranges[k] <= r + 1e-12)  # two points in one bin: the nearer is kept
        assert np.count_nonzero(ranges) == len(np.unique(k))

    rows = entity_rows(watched / "run.rrd")
    assert rows["/world/scan"] == len(lasers) and rows["/stats/latency_ms"] == len(lasers)
    for entity in ("/world/map", "/world/robot", "/world/trajectory", "/world/graph/nodes",
                   "/world/graph/edges", "/stats/lambda", "/stats/rejection_threshold"):
        assert rows.get(entity, 0) >= 1, entity


def test_demo_recording_loads_with_the_truth(tmp_path):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--steps", "60", "--record",
                 str(out / "demo.rrd")]) == 0
    rows = entity_rows(out / "demo.rrd")
    assert rows["/world/scan"] == 60 and rows["/stats/pose_error_m"] == 60
    assert {"/world/truth", "/world/map", "/world/graph/nodes"} <= set(rows)
    entities = rr.chunk.RrdReader(out / "demo.rrd").store().schema().entity_paths()
    assert len([e for e in entities if e.startswith(("/world/", "/stats/"))]) >= 12


def test_view_without_a_display_serves_the_web_viewer(hall_log, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["replay", str(hall_log), "--limit", "10", "--out", str(tmp_path), "--view"]) == 0
    said = capsys.readouterr().out
    assert "no display here; open http://localhost:" in said


def test_a_second_viewed_run_serves_on_ports_of_its_own(hall_log, tmp_path, monkeypatch,
                                                          capsys):
    """Where another run holds the viewer's ports, the next one serves on free ones and says
    which (it used to fail to listen and print the first run's address)."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with socket.socket() as grpc, socket.socket() as web:
        for held in (grpc, web):
            held.bind(("0.0.0.0", 0))
            held.listen()
        busy = {grpc.getsockname()[1], web.getsockname()[1]}
        monkeypatch.setattr(rerun_view, "GRPC_PORT", grpc.getsockname()[1])
        monkeypatch.setattr(rerun_view, "WEB_PORT", web.getsockname()[1])
        assert rerun_view.free_port(grpc.getsockname()[1]) not in busy
        assert main(["replay", str(hall_log), "--limit", "5", "--out", str(tmp_path),
                     "--view"]) == 0
    said = capsys.readouterr().out
    ports = {int(p) for p in re.findall(r"localhost:(\d+)", said)}
    assert len(ports) == 2 and not ports & busy, said
    with socket.socket() as probe:  # a free preferred port is kept
        probe.bind(("0.0.0.0", 0))
        free = probe.getsockname()[1]
    assert rerun_view.free_port(free) == free


def test_a_missing_extra_is_refused_before_the_run(hall_log, tmp_path, monkeypatch, capsys):
    real = run_view.importlib.util.find_spec
    monkeypatch.setattr(run_view.importlib.util, "find_spec",
                        lambda name, *a: None if name == "mcap" else real(name, *a))
    out = tmp_path / "out"
    assert main(["replay", str(hall_log), "--out", str(out), "--mcap", str(out / "x.mcap")]) == 2
    assert "--mcap needs the 'mcap' package" in capsys.readouterr().err
    assert not out.exists()  # refused before anything ran


def test_rgb_array_frames_make_a_video(tmp_path):
    env = gym.make("swarmslam_sim:SwarmSlam-v0", render_mode="rgb_array", slam=False,
                   max_episode_steps=15)
    env = RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda episode: True,
                      disable_logger=True)
    env.reset(seed=3)
    frame = env.render()
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1
    from moviepy import VideoFileClip

    with VideoFileClip(str(videos[0])) as clip:
        assert tuple(clip.size) == (frame.shape[1], frame.shape[0])
        assert clip.n_frames >= 15


def test_plots_are_pngs(hall_log, tmp_path):
    _, runtime = replay_run(hall_log)
    plot_run(tmp_path, "hall abc odom seed 0", runtime,
             read_relations(hall_log.with_name("hall.relations")))
    bars(tmp_path, "bars", "t", "y", {"a": {"x": 1.0, "y": 2.0}, "b": {"x": 3.0}}, log=True,
         targets={"x": 2.0})
    latency_histograms(tmp_path, {"off": np.random.default_rng(0).gamma(2, 2, 500)}, 20.0, "lat")
    for name in ("slam-hall-abc-odom-seed-0.png", "bars.png", "lat.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000, name


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o027, 0o640), (0o077, 0o600)])
def test_outputs_get_the_mode_the_umask_gives(hall_log, tmp_path, mask, mode):
    old = os.umask(mask)
    try:
        write_bytes_atomic(tmp_path / "a.bin", b"x")
        out = tmp_path / "run"
        assert main(["replay", str(hall_log), "--limit", "20", "--out", str(out), "--mcap",
                     str(out / "run.mcap"), "--record", str(out / "run.rrd")]) == 0
    finally:
        os.umask(old)
    files = [tmp_path / "a.bin", *out.iterdir()]
    assert {p.name for p in files} >= {"map.pgm", "map.yaml", "trajectory.tum", "session.npz",
                                       "metrics.json", "run.mcap", "run.rrd"}
    for p in files:
        assert stat.S_IMODE(p.stat().st_mode) == mode, p.name
    assert not list(out.glob(".*.tmp"))  # no temp file left behind


def test_laser_ranges_bins_by_angle():
    angles = np.radians([-90.0, 0.0, 0.5, 90.0])
    r = np.array([1.0, 2.0, 3.0, 4.0])
    pts = np.c_[r * np.cos(angles), r * np.sin(angles)]
    ranges = laser_ranges(pts, 720)  # 0.5° bins from −180°
    assert ranges[180] == 1.0 and ranges[360] == 2.0 and ranges[361] == 3.0
    assert ranges[540] == 4.0 and np.count_nonzero(ranges) == 4
    near = laser_ranges(np.array([[2.0, 0.0], [1.0, 0.0]]), 720)  # one bin: the nearer
    assert near[360] == 1.0


def test_the_base_install_needs_none_of_the_extras():
    """The CLI, the demo, replay and every benchmark import without rerun, mcap, matplotlib or
    moviepy: they are loaded only when a view, a recording or plots are asked for."""
    code = ("import sys, swarmslam.cli, swarmslam.demo, swarmslam.replay, swarmslam.live, "
            "swarmslam.bench.slam, swarmslam.bench.runtime, swarmslam.bench.localize, "
            "swarmslam.bench.matcher, swarmslam.bench.env, swarmslam.bench.posegraph, "
            "swarmslam.bench.generalization; "
            "print(sorted(m for m in ('rerun', 'mcap', 'matplotlib', 'moviepy') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_a_redraw_is_handed_over_whole_after_its_cells_are_converted_a_few_rows_at_a_time():
    """The painter draws a few node scans per call, then converts a few rows of cells per
    call; the finished map equals the whole grid converted at once (the map file's values,
    the ROS percentages), and a graph that did not change is not redrawn."""
    from swarmslam.runtime.realtime.warm_up import room_world, scan_at
    from swarmslam.formats.map_io import trinary_image
    from swarmslam.view.map_painter import MapPainter, occupancy_percent

    class Graph:  # what the painter reads of a SLAM run
        def __init__(self, poses, nodes):
            self.graph = type("G", (), {"poses": poses, "n_nodes": len(poses)})()
            self.nodes, self.revision = nodes, 0

    from swarmslam.runtime.config import MapConfig
    from swarmslam.runtime.node_scans import NodeScans

    world = room_world(1, size=(16.0, 10.0), boxes=8, walls=2)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    poses = np.array([(x, 5.0, 0.3 * k) for k, x in enumerate(np.linspace(2.0, 14.0, 7))])
    nodes, scan = NodeScans(len(poses), len(angles)), PointScan(len(angles))
    for k, p in enumerate(poses):
        scan.set_ranges(scan_at(world, p, angles, 12.0), angles, 0.05, 12.0)
        nodes.store(k, scan)
    slam = Graph(poses, nodes)
    painter = MapPainter(MapConfig(), nodes_per_tick=3, cells_per_tick=5000)
    calls, painted = 0, None
    while painted is None:
        painted = painter.paint(slam)
        calls += 1
    rows = painted.grid.logodds.shape[0]
    conversions = -(-rows // max(5000 // painted.grid.logodds.shape[1], 1))
    assert calls == 3 + conversions  # 7 nodes 3 at a time, then the rows
    assert conversions > 1 and not painter.busy
    assert np.array_equal(painted.trinary, trinary_image(painted.grid)[::-1])
    assert np.array_equal(painted.percent, occupancy_percent(painted.grid.logodds))
    assert {0, 254, 205} <= set(np.unique(painted.trinary))
    assert painter.paint(slam) is None and not painter.busy  # unchanged: no new pass
    slam.revision += 1  # a loop closed: the next pass begins
    assert painter.paint(slam) is None and painter.busy
