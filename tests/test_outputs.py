"""Figures, trajectories and atomic writes: what users open in other tools."""

import struct
import zlib

import numpy as np
import pytest

from swarmslam.runtime.realtime import writers
from swarmslam.formats.png import encode_png
from swarmslam.formats.tum import read_tum, write_tum
from swarmslam_sim.canvas import Canvas


def decode_png(data: bytes) -> np.ndarray:
    """Just enough of a PNG reader to check ours (filter 0 rows, 8-bit)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    w, h, _, colour, *_ = header
    channels = 1 if colour == 0 else 3
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, w * channels + 1)
    assert np.all(raw[:, 0] == 0)
    img = raw[:, 1:].reshape(h, w, channels)
    return img[:, :, 0] if channels == 1 else img


@pytest.mark.parametrize("shape", [(7, 5), (4, 9, 3)])
def test_png_round_trip(shape):
    img = np.random.default_rng(0).integers(0, 256, size=shape, dtype=np.uint8)
    assert np.array_equal(decode_png(encode_png(img)), img)


def test_png_rejects_wrong_dtype():
    with pytest.raises(ValueError, match="uint8"):
        encode_png(np.zeros((3, 3), np.float32))


def test_canvas_draws_in_metric_frame():
    c = Canvas((0, 0), (1, 1), pixels_per_metre=10, margin=0)
    c.points([(0.0, 0.0)], (255, 0, 0))
    c.polyline([(0.0, 1.0), (1.0, 1.0)], (0, 0, 255))
    h = c.image.shape[0]
    assert tuple(c.image[h - 1, 0]) == (255, 0, 0)  # origin bottom-left
    assert np.all(c.image[h - 1 - 10, :11] == (0, 0, 255))  # the top line, y = 1 m


def test_tum_round_trip(tmp_path):
    poses = np.array([[0.0, 0.0, 0.0], [1.0, -2.0, 3.0], [0.5, 0.25, -3.1]])
    write_tum(tmp_path / "t.tum", [0.0, 0.1, 0.2], poses)
    t, back = read_tum(tmp_path / "t.tum")
    assert np.allclose(t, [0.0, 0.1, 0.2]) and np.allclose(back, poses, atol=1e-6)
    assert len((tmp_path / "t.tum").read_text().splitlines()[1].split()) == 8


def test_interrupted_write_keeps_previous_file(tmp_path, monkeypatch):
    target = tmp_path / "map.json"
    writers.write_json_atomic(target, {"version": 1})

    def crash(*args):
        raise KeyboardInterrupt  # as if Ctrl-C arrived mid-write

    monkeypatch.setattr(writers.os, "fsync", crash)
    with pytest.raises(KeyboardInterrupt):
        writers.write_json_atomic(target, {"version": 2})
    assert target.read_text().strip().endswith("}") and '"version": 1' in target.read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["map.json"]  # no temp file left behind
