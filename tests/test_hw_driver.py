"""The driver against the emulator over a real pseudo-terminal: requests, standard / express /
dense scans decoded to the emulator's ranges within quantisation, and faults survived."""

import os
import threading
import time

import numpy as np
import pytest

from swarmslam.hardware import protocol as p
from swarmslam.hardware.driver import LidarError, RPLidar
from swarmslam.hardware.emulator import Faults, VirtualRPLidar
from swarmslam.hardware.sources import FunctionSource


def room(angles_deg):
    """A smooth scene: 2 m ± 0.5 m around the scanner (mm)."""
    return 2000.0 + 500.0 * np.sin(np.radians(angles_deg))


class Scans:
    def __init__(self):
        self.items = []
        self.lock = threading.Lock()

    def __call__(self, angles, ranges, stamp):
        with self.lock:
            self.items.append((angles.copy(), ranges.copy(), stamp))

    def wait(self, count, timeout=10.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.lock:
                if len(self.items) >= count:
                    return list(self.items)
            time.sleep(0.02)
        raise AssertionError(f"only {len(self.items)} of {count} rotations in {timeout} s")


def eventually(condition, timeout=2.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture
def emulator_factory():
    started = []

    def make(model="a1", faults=None, link=None, source=None):
        emu = VirtualRPLidar(source or FunctionSource(room), model, faults, seed=1, link=link)
        emu.start()
        started.append(emu)
        return emu

    yield make
    for emu in started:
        emu.stop()


def test_info_health_samplerate_and_conf(emulator_factory):
    emu = emulator_factory("a2")
    with RPLidar(emu.path, "a2") as lidar:
        info = lidar.get_info()
        assert info.major_model == 2 and info.serial == bytes(range(0x10, 0x20))
        assert lidar.get_health() == (0, 0)
        assert lidar.get_samplerate() == (508, 250)
        assert lidar.get_lidar_conf(p.CONF_MAX_DISTANCE) == 12.0
        assert lidar.get_lidar_conf(p.CONF_ANSWER_TYPE, 1) == p.ANS_CAPSULE
        assert lidar.get_lidar_conf(p.CONF_MODE_NAME, 1) == "Express"
        lidar.start_motor()  # A2: accessory board flag → PWM (no reply: wait for it to land)
        assert eventually(lambda: emu.motor_on)
        lidar.stop_motor()
        assert eventually(lambda: not emu.motor_on)


def test_silence_is_a_clear_error_not_a_hang():
    import os
    import tty

    master, slave = os.openpty()  # a port where nothing answers
    tty.setraw(slave)
    try:
        lidar = RPLidar(os.ttyname(slave), "a1", timeout=0.3)
        lidar.connect()
        with pytest.raises(LidarError, match="0x50: no response descriptor within 0.3 s"):
            lidar.get_info()
        lidar.close()
    finally:
        os.close(master)
        os.close(slave)


def rotations_in(emulator_factory, model, mode, count=4):
    """``count`` rotations the driver decodes from an emulated ``model`` scanning in ``mode``,
    the driver's report, and the samples per rotation the emulator sends."""
    emu = emulator_factory(model)
    scans = Scans()
    with RPLidar(emu.path, model, on_scan=scans) as lidar:
        lidar.start(mode)
        got = scans.wait(count)
        lidar.stop()
        report = lidar.report()
    return got, report, emu._per_rotation


@pytest.mark.parametrize("model,mode,quantum_m", [
    ("a1", "standard", 0.00025),  # distances in 1/4 mm
    ("a1", "express", 0.001),  # legacy capsules: whole mm
    ("s2", "express", 0.001),  # dense capsules: whole mm
])
def test_scans_decode_to_the_emulators_ranges(emulator_factory, model, mode, quantum_m):
    got, report, per_rotation = rotations_in(emulator_factory, model, mode)
    for angles, ranges, _ in got:
        assert abs(len(angles) - per_rotation) <= 1
        # the scene at the decoded (robot-frame, counter-clockwise) angles
        expected = room(np.degrees(-angles)) / 1000.0
        # angle quantisation (1/64°) moves the scene by ≤ 0.5 mm/° · 1/64° · ...: tiny
        assert np.max(np.abs(ranges - expected)) <= quantum_m + 2e-4
        # one whole turn (express samples are not in order: dθ shifts each one back)
        turn = np.sort(np.mod(-angles, 2 * np.pi))
        gaps = np.diff(np.r_[turn, turn[0] + 2 * np.pi])
        assert gaps.max() < np.radians(3)
    assert report["checksum_errors"] == 0 and report["resyncs"] == 0


@pytest.mark.parametrize("model,mode", [("a1", "standard"), ("a1", "express"), ("s1", "express")])
def test_garbage_and_corruption_are_survived_and_counted(emulator_factory, model, mode):
    emu = emulator_factory(model, Faults(garbage=0.02, corrupt=0.02))
    scans = Scans()
    with RPLidar(emu.path, model, on_scan=scans) as lidar:
        lidar.start(mode)
        got = scans.wait(8, timeout=20)
        lidar.stop()
        report = lidar.report()
    assert report["resyncs"] > 0 and report["dropped_bytes"] > 0
    if mode == "express":
        assert report["checksum_errors"] > 0
    good = 0
    for angles, ranges, _ in got[1:]:
        expected = room(np.degrees(-angles)) / 1000.0
        ok = np.abs(ranges - expected) <= 0.0015
        good += ok.mean() > 0.9  # damage costs samples, never garbage in the scan
        assert ok.mean() > 0.75
    assert good >= len(got) - 2


def test_a_stall_restarts_the_scan(emulator_factory):
    emu = emulator_factory("a1", Faults(stall_every=1.0, stall_for=1.0))
    scans = Scans()
    with RPLidar(emu.path, "a1", on_scan=scans, timeout=0.4) as lidar:
        lidar.start("express")
        time.sleep(0.2)
        before = len(scans.items)
        scans.wait(before + 8, timeout=15)  # rotations keep coming after the stalls
        lidar.stop()
        report = lidar.report()
    assert emu.stats["stalls"] >= 1 and report["timeouts"] >= 1


def test_a_vanished_port_is_reopened_by_name(emulator_factory, tmp_path):
    link = tmp_path / "rplidar"
    emu = emulator_factory("a1", Faults(vanish_after=1.0, vanish_for=0.8), link=link)
    scans = Scans()
    with RPLidar(str(link), "a1", on_scan=scans, timeout=0.5, retry=0.1) as lidar:
        lidar.start("express")
        scans.wait(3)
        deadline = time.monotonic() + 10
        while emu.stats["vanished"] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        count = len(scans.items)
        scans.wait(count + 5, timeout=15)  # scanning again on the new device node
        lidar.stop()
        report = lidar.report()
    assert emu.stats["vanished"] == 1
    assert report["reconnects"] >= 1


def test_a_port_that_vanishes_before_the_scan_starts_is_reopened_too(emulator_factory,
                                                                      tmp_path):
    """The port answers, then vanishes before the scan is started (a warm-up longer than the
    port lasted): start() does not fail; the reader reopens it and scans."""
    link = tmp_path / "rplidar"
    emu = emulator_factory("a1", Faults(vanish_after=0.3, vanish_for=0.8), link=link)
    scans = Scans()
    with RPLidar(str(link), "a1", on_scan=scans, timeout=0.5, retry=0.1) as lidar:
        deadline = time.monotonic() + 10
        while emu.stats["vanished"] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        lidar.start("express")
        scans.wait(5, timeout=15)
        lidar.stop()
        report = lidar.report()
    assert emu.stats["vanished"] == 1 and len(scans.items) >= 5
    assert report["reconnects"] >= 1


def test_faults_parse_and_refuse_unknown_ones():
    f = Faults.parse("garbage=0.01, corrupt=0.02, stall=10:2, vanish=30")
    assert (f.garbage, f.corrupt, f.stall_every, f.stall_for, f.vanish_after, f.vanish_for) == \
        (0.01, 0.02, 10.0, 2.0, 30.0, 1.0)
    with pytest.raises(ValueError, match="unknown fault 'smoke'"):
        Faults.parse("smoke=1")


def test_emulator_replays_a_carmen_log(tmp_path):
    """Each rotation shows the next laser record; beams outside its field of view are empty."""
    from swarmslam.emulator_sources import CarmenSource

    ranges = " ".join(f"{1.0 + 0.01 * k:.2f}" for k in range(181))  # 181 beams over 180°
    log = tmp_path / "tiny.log"
    log.write_text("".join(f"FLASER 181 {ranges} 0 0 0 0 0 0 {t}.0 host {t}.0\n"
                           for t in range(3)))
    emu = VirtualRPLidar(CarmenSource(log), "a1", seed=0)
    emu.start()
    scans = Scans()
    try:
        with RPLidar(emu.path, "a1", on_scan=scans) as lidar:
            lidar.start("standard")
            got = scans.wait(2)
            lidar.stop()
    finally:
        emu.stop()
    angles, r, _ = got[-1]
    front = np.abs(angles) < np.radians(85)  # inside the record's ±90°
    # beam k at −90° + k°, range 1 + 0.01 k: the nearest beam's (a neighbour at a tie, ½°)
    k = np.degrees(angles[front]) + 90.0
    nearest = 1.0 + 0.01 * np.round(k)
    assert np.all(np.abs(r[front] - nearest) < 0.0101)
    assert np.mean(np.abs(r[front] - nearest) < 0.001) > 0.95
    assert np.all(r[np.abs(angles) > np.radians(95)] == 0.0)  # behind: no return


def test_a_failing_consumer_does_not_stop_the_stream(emulator_factory):
    emu = emulator_factory("a1")
    calls = []

    def broken(angles, ranges, stamp):
        calls.append(stamp)
        raise ValueError("consumer bug")

    with RPLidar(emu.path, "a1", on_scan=broken) as lidar:
        lidar.start("express")
        assert eventually(lambda: len(calls) >= 3, timeout=10)  # rotations keep coming
        lidar.stop()
        report = lidar.report()
    assert report["on_scan_errors"] >= 3
    assert report["last_on_scan_error"] == "ValueError: consumer bug"


@pytest.mark.parametrize("model", ["a1", "a2", "a3", "s1", "s2", "c1"])
def test_the_driver_reads_the_scan_modes_and_starts_the_typical_one(emulator_factory, model):
    from swarmslam.hardware.models import model as get_model

    table = get_model(model)
    emu = emulator_factory(model)
    scans = Scans()
    with RPLidar(emu.path, model, on_scan=scans) as lidar:
        modes = lidar.scan_modes()
        assert [(m.name, m.answer_type, m.us_per_sample) for m in modes] == [
            (m.name, m.answer_type, m.us_per_sample) for m in table.modes]
        assert lidar.typical_mode() == table.typical
        lidar.start()  # typical by default, as Slamtec's SDK starts
        scans.wait(3)
        assert lidar.scan_mode == table.mode("typical")
        lidar.stop()


@pytest.mark.parametrize("model,mode,quantum_m", [
    ("a2", "Boost", 0.0045),  # ultra capsules: 2-4 mm steps from 0.5 m, the major truncates
    ("a3", "Stability", 0.0045),
    ("s2", "HQ", 0.00025),  # HQ nodes: 1/4 mm
    ("s2", "UltraDense", 0.0035),  # ultra-dense: 3 mm steps beyond 2 m, halved averages
])
def test_every_capsule_mode_decodes_to_the_emulators_ranges(emulator_factory, model, mode,
                                                            quantum_m):
    got, report, per_rotation = rotations_in(emulator_factory, model, mode)
    for angles, ranges, _ in got[1:]:
        assert len(angles) >= 0.97 * per_rotation  # a whole turn (an edge may lose a sample)
        expected = room(np.degrees(-angles)) / 1000.0
        assert np.max(np.abs(ranges - expected)) <= quantum_m + 2e-4
    assert report["checksum_errors"] == 0 and report["resyncs"] == 0


def test_an_unknown_scan_mode_is_refused_by_name(emulator_factory):
    emu = emulator_factory("a2")
    with RPLidar(emu.path, "a2") as lidar:
        with pytest.raises(ValueError, match="no scan mode 'Turbo'.*Sensitivity"):
            lidar.start("Turbo")


def test_the_link_switches_baud_where_the_model_allows(emulator_factory):
    emu = emulator_factory("a2")
    with RPLidar(emu.path, "a2") as lidar:
        assert lidar.negotiate_baud(256000) == 256000  # what the scanner measured
        assert eventually(lambda: emu.baud == 256000)  # confirmed: it stays at the new rate
        assert lidar.serial.baudrate == 256000
        assert lidar.get_info().major_model == 2  # and answers there
        with pytest.raises(ValueError, match="runs at 115200, 256000 bps, not 1000000"):
            lidar.negotiate_baud(1000000)
    emu = emulator_factory("a1")
    with RPLidar(emu.path, "a1") as lidar:
        with pytest.raises(ValueError, match="the A1 runs at 115200 bps"):
            lidar.negotiate_baud(256000)


@pytest.mark.parametrize("kind", ["file", "folder", "other link"])
def test_the_link_never_replaces_what_the_user_has(tmp_path, kind):
    link = tmp_path / "rplidar"
    if kind == "file":
        link.write_text("my notes")
    elif kind == "folder":
        link.mkdir()
    else:
        link.symlink_to(tmp_path / "elsewhere")
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(FileExistsError, match="will not replace"):
        VirtualRPLidar(FunctionSource(room), "a1", seed=1, link=link).start()
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no .new left either
    if kind == "file":
        assert link.read_text() == "my notes"


def test_the_link_a_killed_emulator_left_is_taken_over(emulator_factory, tmp_path):
    link = tmp_path / "rplidar"
    link.symlink_to("/dev/pts/999")  # its pseudo-terminal gone with it
    emu = emulator_factory("a1", link=link)
    assert os.readlink(link) == emu.path
