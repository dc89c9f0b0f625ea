"""Bad input never costs a run: every file and device boundary answers hostile input
with a clear error naming the file (and line), or skips and counts a bad record — never a
traceback, a segfault, ``Infinity`` in JSON, or a half-written output folder."""

import gzip
import json
import os
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.realtime.session import SessionError, read_session, write_session
from swarmslam.runtime.realtime.text_records import DataFormatError
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.formats.carmen import flaser_angles, read_carmen
from swarmslam.cli import main
from swarmslam.outputs import _staging, clean_stale, output_set


def strict_json(path):
    """JSON as other readers take it: NaN and Infinity refused."""
    def refuse(name):
        raise ValueError(f"{path}: {name} is not JSON")
    return json.loads(path.read_text(), parse_constant=refuse)


def log_lines(steps=40, seed=0):
    """FLASER lines (odometry = truth) around a synthetic room, 0.2 s apart."""
    poses = loop_path(60)[:steps]
    world = room_world(seed, size=(12.0, 9.0), boxes=10, walls=0, keep_clear=poses)
    angles = flaser_angles(180)
    lines = []
    for k, p in enumerate(poses):
        ranges = " ".join(f"{v:.3f}" for v in scan_at(world, p, angles, 50.0))
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        t = 0.2 * k
        lines.append(f"FLASER 180 {ranges} {pose} {pose} {t:.3f} host {t:.3f}\n")
    return lines


def edit(line, *, odometry=None, stamp=None, ranges=None):
    t = line.split()
    n = int(t[1])
    if ranges is not None:
        t[2:2 + n] = [ranges] * n
    if odometry is not None:
        t[2 + n + 3] = odometry
    if stamp is not None:
        t[-3] = stamp
    return " ".join(t) + "\n"


def replay_metrics(tmp_path, lines, name):
    log = tmp_path / f"{name}.clf"
    log.write_text("".join(lines))
    out = tmp_path / name
    assert main(["replay", str(log), "--out", str(out)]) == 0
    return strict_json(out / "metrics.json"), out


# ---------------------------------------------------------------- bad records: counted skips
@pytest.mark.parametrize("name, change, count", [
    ("no-return", dict(ranges="81.83"), "empty_scans"),  # every beam at max: open space
    ("inf-odometry", dict(odometry="inf"), "odometry_non_finite"),
    ("nan-odometry", dict(odometry="nan"), None),  # the reader refuses NaN, naming the line
    ("inf-stamp", dict(stamp="inf"), "ipc_timestamp"),  # skipped by the reader, by field
])
def test_a_bad_record_is_skipped_and_counted(tmp_path, capsys, name, change, count):
    lines = log_lines()
    lines[20] = edit(lines[20], **change)
    if count is None:
        log = tmp_path / "bad.clf"
        log.write_text("".join(lines))
        assert main(["replay", str(log)]) == 2
        assert "bad.clf:21: odom.x: NaN" in capsys.readouterr().err
        return
    m, out = replay_metrics(tmp_path, lines, name)
    counted = m["records_skipped"] if count == "ipc_timestamp" else m["runtime"]
    assert counted[count] == 1 and m["status"] == "ok"
    assert m["real_time_factor"] is None or np.isfinite(m["real_time_factor"])
    assert "skipped 1" in capsys.readouterr().out
    assert (out / "map.pgm").exists() and (out / "session.npz").exists()


def test_odometry_spikes_and_jumps_are_dropped_not_absorbed(tmp_path):
    clean, _ = replay_metrics(tmp_path, log_lines(), "clean")
    spike = log_lines()
    spike[20] = edit(spike[20], odometry="1e300")  # no robot's: dropped, the next one fine
    m, out = replay_metrics(tmp_path, spike, "spike")
    assert m["runtime"]["odometry_out_of_range"] == 1 and m["runtime"]["odometry_jumps"] == 0
    spike[20] = edit(spike[20], odometry="900.0")  # a jump: it and the one back are dropped
    m, out = replay_metrics(tmp_path, spike, "jump")
    assert m["runtime"]["odometry_jumps"] == 2
    rebased = log_lines()  # odometry re-based by 10 km halfway: followed, never absorbed
    for k in range(20, len(rebased)):
        t = rebased[k].split()
        t[2 + 180 + 3] = str(float(t[2 + 180 + 3]) + 1e4)
        rebased[k] = " ".join(t) + "\n"
    j, jout = replay_metrics(tmp_path, rebased, "rebased")
    assert j["runtime"]["odometry_jumps"] == 1
    for folder in (out, jout):
        poses = np.loadtxt(folder / "trajectory.tum")[:, 1:3]
        assert np.abs(poses).max() < 20.0  # a room, not 1e300 m or 10 km
        assert "resolution: 0.05" in (folder / "map.yaml").read_text()
    assert abs(j["nodes"] - clean["nodes"]) <= 2


def test_the_inbox_drops_odometry_overwritten_after_a_break():
    """A dropped reading whose scan went stale before a tick took it still breaks odometry:
    the newer scan taken goes without it, so the front end starts afresh."""
    rt = SlamRuntime(SlamConfig())
    inbox, pts = rt.inbox, np.ones((5, 2))
    inbox.put_points(pts, 5, 0.0, np.zeros(3))
    assert inbox.take(rt.scan, rt.odometry)[1]
    inbox.put_points(pts, 5, 0.1, np.array([1e4, 0.0, 0.0]))  # jumped: dropped
    inbox.put_points(pts, 5, 0.2, np.array([1e4 + 0.05, 0.0, 0.0]))  # fine, but after it
    got, has_odometry, stamp = inbox.take(rt.scan, rt.odometry)
    assert got and not has_odometry and stamp == 0.2
    inbox.put_points(pts, 5, 0.3, np.array([1e4 + 0.1, 0.0, 0.0]))
    assert inbox.take(rt.scan, rt.odometry)[1]
    assert inbox.counts()["odometry_jumps"] == 1
    assert not inbox.put_points(pts, 5, 0.25, None)  # backwards in time: refused
    assert inbox.counts()["bad_stamp_scans"] == 1


# ---------------------------------------------------------------- damaged and foreign files
def test_a_truncated_or_flipped_gzip_log_names_the_file(tmp_path):
    data = gzip.compress("".join(log_lines()).encode())
    cut = tmp_path / "cut.clf.gz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFormatError, match=r"cut\.clf\.gz:\d+: file: unreadable"):
        read_carmen(cut)
    rng = random.Random(0)
    for k in range(40):  # a flipped byte anywhere: a format error or a damaged stream
        flipped = bytearray(data)
        flipped[rng.randrange(10, len(data))] ^= 1 << rng.randrange(8)
        path = tmp_path / f"flip{k}.clf.gz"
        path.write_bytes(bytes(flipped))
        try:
            read_carmen(path)
        except DataFormatError as exc:
            assert str(exc).startswith(f"{path}:")


@pytest.mark.parametrize("kind", ["relations", "world", "g2o"])
def test_a_binary_file_is_refused_with_its_name(tmp_path, capsys, kind):
    blob = tmp_path / f"blob.{kind}"
    blob.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)  # an image, say
    if kind == "relations":
        log = tmp_path / "ok.clf"
        log.write_text("".join(log_lines(8)))
        assert main(["replay", str(log), "--relations", str(blob)]) == 2
        assert f"{blob}:1: text: not utf-8 text" in capsys.readouterr().err
    elif kind == "world":
        from swarmslam_sim.world import load_world
        with pytest.raises(DataFormatError, match="not utf-8 text"):
            load_world(blob)
    else:
        from swarmslam.formats.g2o import read_g2o
        with pytest.raises(DataFormatError, match="not utf-8 text"):
            read_g2o(blob)


def test_a_fractional_g2o_vertex_id_is_refused(tmp_path):
    from swarmslam.formats.g2o import G2oFormatError, read_g2o
    g2o = tmp_path / "frac.g2o"
    g2o.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1.5 1 0 0\nEDGE_SE2 0 1.5 1 0 0 1 0 0 1 0 1\n")
    with pytest.raises(G2oFormatError, match="frac.g2o:2: id: vertex ids are integers"):
        read_g2o(g2o)


def test_relations_of_another_log_are_refused_before_the_run(tmp_path, capsys):
    log = tmp_path / "ok.clf"
    log.write_text("".join(log_lines(8)))
    rel = tmp_path / "other.relations"
    rel.write_text("1000.0 1001.0 0.1 0 0 0 0 0\n")
    out = tmp_path / "out"
    assert main(["replay", str(log), "--relations", str(rel), "--out", str(out)]) == 2
    assert "none of its 1 relations has both ends at scans" in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------- sessions
@pytest.fixture(scope="module")
def small_session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("session")
    log = folder / "s.clf"
    log.write_text("".join(log_lines(30)))
    assert main(["replay", str(log), "--out", str(folder / "out")]) == 0
    return folder / "out" / "session.npz"


def test_every_flipped_byte_of_a_session_header_is_refused_or_harmless(small_session,
                                                                        tmp_path):
    data = small_session.read_bytes()
    head = list(range(0, 300)) + list(range(len(data) - 2000, len(data)))  # zip headers
    for k in head:
        flipped = bytearray(data)
        flipped[k] ^= 0xFF
        path = tmp_path / "f.npz"
        path.write_bytes(bytes(flipped))
        try:
            read_session(path)  # a date or padding byte: harmless, the checksum holds
        except SessionError as exc:
            assert str(exc).startswith(str(path))


@pytest.mark.parametrize("damage, field", [
    (lambda s: s["slam"]["graph"]["ij"].__setitem__((0, 1), 10**6), "do not exist"),
    (lambda s: s["slam"]["graph"]["poses"].__setitem__((1, 0), np.nan), "non-finite"),
    (lambda s: s["slam"]["front_end"].__setitem__("keyframe", 10**6), "not a stored node"),
    (lambda s: s["slam"]["back_end"].__setitem__("phase", 9), "never takes"),
    (lambda s: s["slam"]["back_end"].__setitem__("queue", np.array([10**6])), "do not exist"),
])
def test_a_session_with_a_valid_checksum_but_wrong_content_is_refused(small_session, tmp_path,
                                                                      damage, field):
    state = read_session(small_session)
    damage(state)
    forged = tmp_path / "forged.npz"
    write_session(forged, state)  # a checksum that holds
    with pytest.raises(SessionError, match=field):
        SlamRuntime.resume(forged)
    if field == "non-finite":  # localization reads only the poses and scans
        with pytest.raises(SessionError, match=field):
            SlamRuntime.localize(forged)


def test_resuming_with_another_scanner_resizes_and_says_so(small_session):
    from swarmslam.live import slam_config_for
    s2 = slam_config_for("s2").sensor
    runtime = SlamRuntime.resume(small_session, sensor=s2)
    assert runtime.config.sensor.max_points >= s2.max_points
    assert runtime.inbox._pending.capacity >= s2.max_points
    assert "re-sized for" in runtime.session_note and s2.name in runtime.session_note
    same = SlamRuntime.resume(small_session, sensor=SlamRuntime.resume(small_session)
                              .config.sensor)
    assert same.session_note == ""
    slower = SlamRuntime.resume(small_session, changes={"runtime.rate_hz": 5.0}, sensor=s2)
    assert slower.config.runtime.rate_hz == 5.0  # --rate is kept on resume


# ---------------------------------------------------------------- output sets
def test_an_interrupted_output_set_leaves_the_previous_one_whole(tmp_path):
    out = tmp_path / "out"
    with output_set(out) as stage:
        (stage / "map.pgm").write_text("old map")
        (stage / "trajectory.tum").write_text("old trajectory")
    (out / "notes.txt").write_text("the user's")
    with pytest.raises(KeyboardInterrupt):
        with output_set(out) as stage:
            (stage / "map.pgm").write_text("new map")
            raise KeyboardInterrupt  # SIGTERM / Ctrl-C mid-write
    assert (out / "map.pgm").read_text() == "old map"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging left
    with output_set(out) as stage:
        (stage / "map.pgm").write_text("new map")
    assert (out / "map.pgm").read_text() == "new map"
    # the previous set's trajectory is not left beside the new map; the user's file stays
    assert not (out / "trajectory.tum").exists()
    assert (out / "notes.txt").read_text() == "the user's"


def test_what_a_killed_writer_left_is_cleaned_and_a_cut_swap_restored(tmp_path):
    out = tmp_path / "out"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    staging = _staging(out, "staging", int(dead))
    staging.mkdir()
    (staging / "map.pgm").write_text("half")
    previous = _staging(out, "old", int(dead))  # killed between the swap's two renames
    previous.mkdir()
    (previous / "map.pgm").write_text("complete")
    clean_stale(out)
    assert (out / "map.pgm").read_text() == "complete"
    assert not staging.exists() and not previous.exists()
    orphan = out / ".map.pgm.abc123.tmp"
    orphan.write_text("torn")
    fresh = out / ".map.yaml.def456.tmp"  # a write in progress elsewhere: left alone
    fresh.write_text("in progress")
    os.utime(orphan, (time.time() - 3600, time.time() - 3600))
    clean_stale(out)
    assert not orphan.exists() and fresh.exists()


def test_an_unwritable_out_is_refused_before_the_run(tmp_path, capsys):
    log = tmp_path / "ok.clf"
    log.write_text("".join(log_lines(8)))
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["replay", str(log), "--out", str(blocker)]) == 2
    assert "is not a folder" in capsys.readouterr().err


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc on this system")
def test_an_out_no_file_can_be_made_in_is_refused_before_the_run_even_for_root(tmp_path,
                                                                               capsys):
    """Whether a file can be made there is tried, not asked of os.access (which says yes to
    root, and to /proc): the run is refused before it starts, and /proc is left as it was."""
    log = tmp_path / "ok.clf"
    log.write_text("".join(log_lines(8)))
    assert main(["replay", str(log), "--out", "/proc/swarmslam-run"]) == 2
    assert "is not writable" in capsys.readouterr().err
    assert not os.path.exists("/proc/swarmslam-run")


# ---------------------------------------------------------------- the simulator
@pytest.mark.parametrize("option, value", [
    ("map_resolution", 0), ("max_linear", float("nan")), ("crop", 0), ("robot_radius", -1),
    ("max_angular", float("inf")), ("map_resolution", 1e-5),
])
def test_bad_env_options_are_refused_by_name(option, value):
    import gymnasium as gym

    import swarmslam_sim  # noqa: F401
    with pytest.raises(ValueError, match=option):
        gym.make("SwarmSlam-v0", slam=False, **{option: value})


def test_a_nan_action_is_refused():
    import gymnasium as gym

    import swarmslam_sim  # noqa: F401
    env = gym.make("SwarmSlam-v0", slam=False)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action must be finite"):
        env.step(np.array([np.nan, 0.0], np.float32))
    assert np.all(np.isfinite(env.unwrapped.true_pose))


@pytest.mark.parametrize("change, message", [
    (lambda t: t.replace("bounds -0.5 -0.5 20.5 12.5", "bounds -0.5 -0.5 1e12 12.5"),
     "at most 1000 m"),
    (lambda t: t + "wall 1 1 1e12 1\n", "reaches outside bounds"),
    (lambda t: t.replace("start 1.5 6.0 0", "start 10 -0.3 0"), "outside the walls"),
    (lambda t: t.replace("start 1.5 6.0 0", "start 1.2 1.5 0"), "inside a box"),
])
def test_a_world_that_cannot_be_explored_is_refused(tmp_path, change, message):
    from importlib import resources

    import gymnasium as gym

    import swarmslam_sim  # noqa: F401
    text = (resources.files("swarmslam.worlds") / "office.world").read_text()
    world = tmp_path / "bad.world"
    world.write_text(change(text))
    with pytest.raises(ValueError, match=message):
        gym.make("SwarmSlam-v0", world=str(world), slam=False)


# ---------------------------------------------------------------- devices and arguments
def test_a_port_failing_in_termios_is_a_lidar_error(monkeypatch):
    import termios

    import serial

    from swarmslam.hardware import driver

    class Vanishing:
        def __init__(self, *args, **kwargs):
            pass

        def reset_input_buffer(self):
            raise termios.error(5, "Input/output error")

        def close(self):
            pass

    monkeypatch.setattr(serial, "Serial", Vanishing)
    with pytest.raises(driver.LidarError, match="/dev/ttyGONE: the port failed"):
        driver.RPLidar("/dev/ttyGONE").connect()


@pytest.mark.parametrize("faults", ["garbage=7", "corrupt=-0.1", "garbage=nan",
                                    "stall=-1:2", "bogus=1"])
def test_fault_rates_outside_their_range_are_refused(faults, capsys):
    assert main(["emulate", "--world", "office", "--faults", faults]) == 2
    assert "--faults" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["bench", "localize", "--queries", "0"], ["bench", "posegraph", "--repeats", "-1"],
    ["bench", "env", "--steps", "0"], ["demo", "--steps", "0"],
    ["replay", "x.clf", "--start", "-3"], ["lidar", "--seconds", "nan"],
    ["lidar", "--rate", "0"], ["bench", "runtime", "--soak", "-2"],
])
def test_count_and_duration_arguments_are_checked_before_any_work(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    assert argv[-2] in capsys.readouterr().err


# ---------------------------------------------------------------- live runs stopped hard
def _emulator(tmp_path):
    """``swarmslam emulate`` on ``tmp_path/lidar``, once it serves."""
    emu = subprocess.Popen([sys.executable, "-m", "swarmslam.cli", "emulate", "--model", "a1",
                            "--link", str(tmp_path / "lidar")], stdout=subprocess.PIPE,
                           text=True)
    assert "virtual RPLidar" in emu.stdout.readline()
    return emu


def _mapping(tmp_path, out):
    """``swarmslam lidar`` on the emulator, autosaving every 3 s, once mapping has begun."""
    config = tmp_path / "fast-autosave.toml"
    config.write_text("[runtime]\nautosave_seconds = 3.0\n")
    live = subprocess.Popen([sys.executable, "-m", "swarmslam.cli", "lidar", "--port",
                             str(tmp_path / "lidar"), "--model", "a1", "--out", str(out),
                             "--config", str(config)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    for line in live.stdout:
        if "scans/s" in line:
            break
    return live


def test_sigterm_saves_and_sigkill_loses_at_most_one_autosave(tmp_path):
    emu = _emulator(tmp_path)
    live = _mapping(tmp_path, tmp_path / "term")
    try:
        time.sleep(4.0)
        live.send_signal(signal.SIGTERM)  # how systemd and docker stop a service
        said = live.communicate(timeout=60)[0]
        assert live.returncode == 0, said
        for name in ("map.pgm", "map.yaml", "trajectory.tum", "graph.g2o", "session.npz",
                     "summary.json"):
            assert (tmp_path / "term" / name).exists(), (name, said)
        killed = tmp_path / "kill"
        live = _mapping(tmp_path, killed)
        time.sleep(8.0)  # more than two autosaves
        live.kill()  # SIGKILL: no handler runs
        live.wait(timeout=10)
        assert (killed / "session.autosave.npz").exists()  # beside the set, never in it
        assert not (killed / "session.npz").exists()
        resumed = SlamRuntime.resume(killed / "session.autosave.npz")
        assert resumed.slam.n_nodes >= 2
        # the SIGTERM'd run's set is left as it was by the next run's autosaves, and the
        # autosave is gone once that run's own set is written
        before = (tmp_path / "term" / "session.npz").read_bytes()
        live = _mapping(tmp_path, tmp_path / "term")
        time.sleep(4.0)
        assert (tmp_path / "term" / "session.autosave.npz").exists()
        assert (tmp_path / "term" / "session.npz").read_bytes() == before
        live.send_signal(signal.SIGTERM)
        said = live.communicate(timeout=60)[0]
        assert live.returncode == 0, said
        assert (tmp_path / "term" / "session.npz").read_bytes() != before
        assert not (tmp_path / "term" / "session.autosave.npz").exists()
    finally:
        live.kill()
        emu.terminate()
        emu.wait(timeout=10)
