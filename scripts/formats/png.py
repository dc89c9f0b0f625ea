"""Minimal PNG encoding (8-bit grey or RGB) for maps and figures.

No imaging library is needed to write a PNG: PNG is a
zlib stream of filtered rows in CRC-checked chunks (RFC 2083), a few lines of code.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from swarmslam.runtime.realtime.writers import write_bytes_atomic


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of a uint8 image, ``H×W`` (grey) or ``H×W×3`` (RGB)."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"need uint8 H×W or H×W×3, got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    colour = 0 if img.ndim == 2 else 2
    rows = img.reshape(h, -1)
    raw = np.zeros((h, rows.shape[1] + 1), np.uint8)  # filter byte 0 (None) per row
    raw[:, 1:] = rows

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data) & 0xFFFFFFFF
        )

    header = struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6)) + chunk(b"IEND", b""))


def write_png(path, image: np.ndarray):
    return write_bytes_atomic(path, encode_png(image))
