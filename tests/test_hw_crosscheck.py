"""An independent client — the ``rplidar`` package from PyPI (Roboticia's ``rplidar-roboticia``,
an optional test dependency) — reads standard scans from our emulator, and its samples equal
the ones our parser decodes from the very bytes the emulator sent."""

import pytest

from hardware.emulator import VirtualRPLidar
from hardware.sources import FunctionSource
from hardware.stream import NodeStream, find_descriptor

rplidar = pytest.importorskip("rplidar", reason="optional test dependency rplidar-roboticia "
                                                 "(pip install -e '.[test]') is not installed")


class Sink:
    def __init__(self):
        self.samples = []

    def add(self, start, quality, angle_q6, distance_q2):
        self.samples.append((start, quality, angle_q6 / 64.0, distance_q2 / 4.0))


def test_pypi_rplidar_reads_our_emulator_like_our_parser():
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
