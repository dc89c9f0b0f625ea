"""Atomic file writing: a temp file in the same folder, flushed and fsynced, then renamed.

An interrupted write leaves the previous file intact: a rename within one file system is
atomic, so readers see either the old file or the complete new one, never a torn one.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


def creation_mode() -> int:
    """The mode ``open()`` gives a new file under the process's umask (0644 under 022):
    ``mkstemp`` makes its temp files 0600, which a map server running as another user
    cannot read."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:  # Linux: read, not set
            for line in f:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)  # elsewhere: set and restore (a brief window for other threads)
    os.umask(mask)
    return 0o666 & ~mask


class AtomicFile:
    """A file that appears at ``path`` complete or not at all: written to a temp file beside
    it, then :meth:`commit` flushes, fsyncs and renames it; :meth:`discard` (or leaving a
    ``with`` block by an exception) removes it."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, self.tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp",
                                        dir=self.path.parent)
        try:
            os.fchmod(fd, creation_mode())
        except BaseException:
            os.close(fd)
            os.unlink(self.tmp)
            raise
        self.file = os.fdopen(fd, "wb")

    def commit(self) -> Path:
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            os.replace(self.tmp, self.path)
        except BaseException:
            self.discard()
            raise
        return self.path

    def discard(self) -> None:
        self.file.close()
        try:
            os.unlink(self.tmp)
        except FileNotFoundError:
            pass

    def __enter__(self):
        return self.file

    def __exit__(self, kind, value, tb):
        if kind is None:
            self.commit()
        else:
            self.discard()


def write_bytes_atomic(path, data: bytes) -> Path:
    out = AtomicFile(path)
    with out as f:
        f.write(data)
    return out.path


def write_text_atomic(path, text: str) -> Path:
    return write_bytes_atomic(path, text.encode("utf-8"))


def finite_json(obj):
    """``obj`` with every non-finite float as ``null``: NaN and Infinity are not JSON (other
    readers refuse Python's ``NaN``/``Infinity``), and a missing figure is a null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.generic):
        return finite_json(obj.item())
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    return obj


def write_json_atomic(path, obj) -> Path:
    """Strict JSON (non-finite figures as null, see :func:`finite_json`), written atomically."""
    text = json.dumps(finite_json(obj), indent=2, sort_keys=False, allow_nan=False)
    return write_text_atomic(path, text + "\n")
