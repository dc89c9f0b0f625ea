"""Kümmerle et al. (2009) relations files: ``t1 t2 x y z roll pitch yaw`` per line — the
reference relative pose of the scan at ``t2`` seen from the scan at ``t1`` (ipc timestamps)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_FIELDS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")


class RelationsFormatError(ValueError):
    def __init__(self, path, line: int, field: str, problem: str):
        self.path, self.line, self.field = str(path), line, field
        super().__init__(f"{path}:{line}: {field}: {problem}")


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
    rows = []
    with open(path) as f:
        for lineno, line in enumerate(f, start=1):
            tokens = line.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            if len(tokens) != 8:
                raise RelationsFormatError(path, lineno, _FIELDS[min(len(tokens), 7)],
                                           f"expected 8 fields, got {len(tokens)}")
            vals = []
            for name, tok in zip(_FIELDS, tokens):
                try:
                    v = float(tok)
                except ValueError:
                    raise RelationsFormatError(path, lineno, name, f"not a number: {tok!r}") from None
                if not math.isfinite(v):
                    raise RelationsFormatError(path, lineno, name, f"not finite: {tok!r}")
                vals.append(v)
            rows.append(vals)
    if not rows:
        raise RelationsFormatError(path, 0, "t1", "the file has no relations")
    a = np.array(rows)
    return Relations(a[:, 0], a[:, 1], a[:, [2, 3, 7]])
