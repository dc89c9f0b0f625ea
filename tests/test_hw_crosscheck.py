"""Independent clients read our emulator, and their samples equal the ones our parsers decode
from the very bytes the emulator sent: the ``rplidar`` package from PyPI (Roboticia's
``rplidar-roboticia``) in standard mode, and Slamtec's own SDK (the ``pyrplidarsdk`` binding) in
every model's typical mode — express, ultra, dense — and in the HQ and ultra-dense answers.
Both are optional test dependencies, installed by ``pip install -e '.[test]'``."""

import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from swarmslam.hardware.emulator import VirtualRPLidar
from swarmslam.hardware.models import model as get_model
from swarmslam.hardware.sources import FunctionSource
from swarmslam.hardware.stream import NodeStream, find_descriptor, stream_for


class Sink:
    def __init__(self):
        self.samples = []

    def add(self, start, quality, angle_q6, distance_q2):
        self.samples.append((start, quality, angle_q6 / 64.0, distance_q2 / 4.0))


def test_pypi_rplidar_reads_our_emulator_like_our_parser():
    rplidar = pytest.importorskip("rplidar", reason="optional test dependency "
                                  "rplidar-roboticia (pip install -e '.[test]') is not installed")
    emu = VirtualRPLidar(FunctionSource(lambda a: 1500.0 + 300.0 * (a % 90) / 90), "a1", seed=3)
    emu.start()
    try:
        client = rplidar.RPLidar(emu.path, baudrate=115200, timeout=1)
        # A pseudo-terminal has no modem lines: the A1's DTR motor switch cannot be set.
        client._serial.setDTR = lambda value: None
        info = client.get_info()
        assert info["model"] == emu.info.model
        assert info["serialnumber"] == emu.info.serial_hex
        assert client.get_health() == ("Good", 0)
        emu.sent.clear()
        emu.record = True
        theirs = []
        for new_scan, quality, angle, distance in client.iter_measures("normal"):
            theirs.append((new_scan, quality, angle, distance))
            if len(theirs) >= 1500:
                break
        client.stop()
        client.disconnect()
    finally:
        emu.stop()
    sent = bytearray(emu.sent)
    found = find_descriptor(sent)  # the health reply its start() asked for, then the scan's
    while found is not None and found[0].answer_type != 0x81:
        del sent[: found[0].length]
        found = find_descriptor(sent)
    assert found is not None
    ours = Sink()
    NodeStream(ours).feed(bytes(sent))
    assert sum(s[0] for s in theirs) >= 3  # several turns
    # ours keeps the newest node until the next is in view (its angle check needs it)
    assert len(ours.samples) >= len(theirs) - 1
    assert ours.samples[: len(theirs)] == theirs[: len(ours.samples)]


SCAN_ANSWERS = range(0x81, 0x87)


class Samples:
    def __init__(self):
        self.samples = []

    def add(self, start, quality, angle_q6, distance_q2):
        if distance_q2 > 0:  # the SDK hands over valid points only
            self.samples.append((angle_q6 / 64.0, distance_q2 / 4.0))


def _slamtec_scans(tmp_path, model, typical):
    """Three whole rotations read by Slamtec's SDK from ``swarmslam emulate`` (its own
    process: the SDK's calls hold the GIL while they wait), and every byte the emulator
    sent, recorded."""
    sdk = pytest.importorskip("pyrplidarsdk", reason="optional test dependency pyrplidarsdk "
                                                     "(pip install -e '.[test]') is not installed")
    link, record = tmp_path / "lidar", tmp_path / "sent.bin"
    command = [sys.executable, "-m", "swarmslam.cli", "emulate", "--model", model, "--link",
               str(link), "--record", str(record)] + (["--typical", typical] if typical else [])
    emulator = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    scans = []
    try:
        assert "virtual RPLidar" in emulator.stdout.readline()
        driver = sdk.RplidarDriver(port=str(link), baudrate=get_model(model).baud)
        assert driver.connect() and driver.start_scan()
        deadline = time.monotonic() + 20
        while len(scans) < 3 and time.monotonic() < deadline:
            got = driver.get_scan_data()
            if got and len(got[0]) > 100:
                scans.append(got)
        driver.stop_scan()
        driver.disconnect()
    finally:
        # it writes the record on stopping. SIGTERM, not SIGINT: a test run started in the
        # background by a script inherits SIGINT ignored, and the emulator would never stop
        emulator.send_signal(signal.SIGTERM)
        try:
            emulator.wait(timeout=20)
        finally:
            if emulator.poll() is None:  # never left running behind a failed test
                emulator.kill()
    assert len(scans) == 3
    return scans, bytearray(record.read_bytes())


@pytest.mark.parametrize("model, typical, answer", [
    ("a1", None, 0x82), ("a2", None, 0x84), ("a3", None, 0x84), ("s1", None, 0x85),
    ("s2", None, 0x85), ("c1", None, 0x85), ("s2", "HQ", 0x83), ("s2", "UltraDense", 0x86)])
def test_slamtec_sdk_reads_our_emulator_in_its_typical_mode_as_our_parser_does(
        tmp_path, model, typical, answer):
    scans, sent = _slamtec_scans(tmp_path, model, typical)
    found = find_descriptor(sent)  # the replies to the SDK's requests, then the scan's
    while found is not None and found[0].answer_type not in SCAN_ANSWERS:
        del sent[: found[0].length]
        found = find_descriptor(sent)
    assert found is not None and found[0].answer_type == answer  # the typical mode's answer
    ours = Samples()
    stream_for(answer, ours).feed(bytes(sent))
    angles = np.array([s[0] for s in ours.samples])
    ranges = np.array([s[1] for s in ours.samples])
    expected = get_model(model).mode(typical or "typical")
    per_rotation = 1e6 / expected.us_per_sample / get_model(model).scan_hz
    for theirs_rad, theirs_m, _ in scans:
        deg, mm = np.degrees(np.array(theirs_rad)), 1000.0 * np.array(theirs_m)
        assert len(deg) > 0.9 * per_rotation  # a whole rotation
        # where their rotation starts in our samples: the same samples follow, one for one
        start = np.flatnonzero((np.abs((angles - deg[0] + 180) % 360 - 180) < 0.01)
                               & (np.abs(ranges - mm[0]) < 1.0))
        best = None
        for k in start[start + len(deg) <= len(angles)]:
            d_angle = np.abs((angles[k:k + len(deg)] - deg + 180) % 360 - 180).max()
            d_range = np.abs(ranges[k:k + len(deg)] - mm).max()
            if best is None or d_angle + d_range < sum(best):
                best = (d_angle, d_range)
        assert best is not None and best[0] < 0.01 and best[1] < 1.0, best
