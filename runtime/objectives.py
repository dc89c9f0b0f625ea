"""Scan-matching objectives evaluated at a candidate relative pose ``ΔP = (x, y, θ)``.

* :func:`scan_to_scan_error` — Eq. 14, ``log(1 + Σ ‖ΔP ⊕ v_i − vr_nn(i)‖²)``, with the
  nearest-neighbour distances read from the reference's distance field; or, with the Cauchy
  kernel, the per-point robust form ``Σ log(1 + d_i²/c²)`` the spec suggests measuring.
* :func:`scan_to_map_cost` — Eq. 16 as intended (method.md §3, note): a beam end costs 0 on an
  occupied cell and 1 on a free one, and each occupied cell in the robot's ``(ρ+2)²`` square
  costs ``1/(ρ+2)²``. The grid keeps the paper's convention (0 = occupied, 255 = free), so the
  printed terms are taken with their signs swapped, which is what the intent requires.
"""

from __future__ import annotations

import math

from numba import njit

from runtime.distance_field import INV_RES, NX, NY, OX, OY, field_lookup
from runtime.local_map import UNKNOWN

KERNEL_PAPER = 0
KERNEL_CAUCHY = 1
KERNELS = {"paper": KERNEL_PAPER, "cauchy": KERNEL_CAUCHY}


@njit(cache=True, inline="always")
def scan_to_scan_error(field, meta, pts, n, stride, x, y, t, kernel, inv_c2):
    """Eq. 14 (or its per-point Cauchy variant) over every ``stride``-th of the first ``n`` points."""
    c = math.cos(t)
    s = math.sin(t)
    acc = 0.0
    if kernel == KERNEL_PAPER:
        for i in range(0, n, stride):
            px = x + c * pts[i, 0] - s * pts[i, 1]  # Eq. 5
            py = y + s * pts[i, 0] + c * pts[i, 1]
            acc += field_lookup(field, meta, px, py)
        return math.log1p(acc)
    for i in range(0, n, stride):
        px = x + c * pts[i, 0] - s * pts[i, 1]
        py = y + s * pts[i, 0] + c * pts[i, 1]
        acc += math.log1p(field_lookup(field, meta, px, py) * inv_c2)
    return acc


@njit(cache=True, inline="always")
def _cell(grid, meta, x, y):
    j = int(round((x - meta[OX]) * meta[INV_RES]))
    i = int(round((y - meta[OY]) * meta[INV_RES]))
    if 0 <= i < int(meta[NY]) and 0 <= j < int(meta[NX]):
        return grid[i, j]
    return UNKNOWN


@njit(cache=True, inline="always")
def scan_to_map_cost(grid, meta, pts, n, x, y, t, half):
    """Eq. 16 (intent) with ``half = ρ//2 + 1``, i.e. a ``(2·half+1)² = (ρ+2)²`` square."""
    c = math.cos(t)
    s = math.sin(t)
    beams = 0.0
    for i in range(n):
        px = x + c * pts[i, 0] - s * pts[i, 1]  # Eq. 15: the beam end's cell
        py = y + s * pts[i, 0] + c * pts[i, 1]
        beams += _cell(grid, meta, px, py)
    body = 0.0
    res = 1.0 / meta[INV_RES]
    for k in range(-half, half + 1):
        for l in range(-half, half + 1):
            body += 255.0 - _cell(grid, meta, x + k * res, y + l * res)
    side = 2 * half + 1
    return beams / 255.0 + body / (255.0 * side * side)
