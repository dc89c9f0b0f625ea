"""Kümmerle et al. (2009) relations files: ``t1 t2 x y z roll pitch yaw`` per line — the
reference relative pose of the scan at ``t2`` seen from the scan at ``t1`` (ipc timestamps)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarmslam.runtime.realtime.text_records import DataFormatError, parse_numbers, records

_FIELDS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")


class RelationsFormatError(DataFormatError):
    pass


@dataclass
class Relations:
    t1: np.ndarray
    t2: np.ndarray
    delta: np.ndarray  # (N, 3): x, y, yaw

    def __len__(self) -> int:
        return len(self.t1)


def read_relations(path) -> Relations:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such relations file")
    rows = [parse_numbers(path, lineno, _FIELDS, tokens, RelationsFormatError)
            for lineno, tokens in records(path)]
    if not rows:
        raise RelationsFormatError(path, 0, "t1", "the file has no relations")
    a = np.array(rows)
    return Relations(a[:, 0], a[:, 1], a[:, [2, 3, 7]])


def relations_text(t1, t2, delta) -> str:
    """Relations as Kümmerle's files have them (``z roll pitch`` zero); floats written in
    their shortest exact form, so a reader gets back the very numbers."""
    return "".join(f"{float(a)!r} {float(b)!r} {float(x)!r} {float(y)!r} 0 0 0 {float(yaw)!r}\n"
                   for a, b, (x, y, yaw) in zip(t1, t2, np.asarray(delta, float).reshape(-1, 3)))
