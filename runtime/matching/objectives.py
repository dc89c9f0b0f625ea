"""Scan-matching objectives evaluated at a candidate relative pose ``ΔP = (x, y, θ)``.

* :func:`scan_to_scan_error` — Eq. 14, ``log(1 + Σ ‖ΔP ⊕ v_i − vr_nn(i)‖²)``, with the
  nearest-neighbour distances read from the reference's distance field; or, with the Cauchy
  kernel, the per-point robust form ``Σ log(1 + d_i²/c²)`` the spec suggests measuring.
* :func:`scan_to_map_cost` — Eq. 16 as intended (docs/method.md §3, note): a beam end costs 0 on an
  occupied cell and 1 on a free one, and each occupied cell in the robot's ``(ρ+2)²`` square
  costs ``1/(ρ+2)²``. The grid keeps the paper's convention (0 = occupied, 255 = free), so the
  printed terms are taken with their signs swapped, which is what the intent requires.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.config import KERNEL_NAMES
from swarmslam.runtime.matching.distance_field import (INV_RES, NX, NY, OX, OY, R2, bilinear,
                                               cell_costs, lookup_grid)
from swarmslam.runtime.matching.local_map import UNKNOWN

KERNEL_PAPER = KERNEL_NAMES.index("paper")
KERNEL_CAUCHY = KERNEL_NAMES.index("cauchy")
KERNELS = {name: code for code, name in enumerate(KERNEL_NAMES)}


# Contraction (FMA) and the other flags keep NaN and infinity semantics. Reassociation is left
# out: it let LLVM vectorise the sum differently when this function was inlined into a caller
# compiled in the same process than when the caller was loaded from numba's cache, so the same
# seed gave another run on a cold cache than on a warm one. The
# sum in source order costs 9% of a replay's time.
FAST = {"contract", "nsz", "arcp"}


@njit(cache=True, inline="always")
def _grid_frame(meta, x, y, t):
    """Eq. 5 folded into grid units: a point (px, py) lands at
    ``(gx0 + c·px − s·py, gy0 + s·px + c·py)``; also the grid's last indices and far cost."""
    inv = meta[INV_RES]
    c = math.cos(t) * inv
    s = math.sin(t) * inv
    gx0 = (x - meta[OX]) * inv
    gy0 = (y - meta[OY]) * inv
    return c, s, gx0, gy0, int(meta[NX]) - 1, int(meta[NY]) - 1, meta[R2]


@njit(cache=True, fastmath=FAST)
def scan_to_scan_error(field, meta, pts, n, stride, x, y, t, kernel):
    """Eq. 14 (or its per-point Cauchy variant) over every ``stride``-th of the first ``n`` points.

    The field already holds each point's cost (``d²`` or ``log(1 + d²/c²)``), so the kernels
    differ only in the outer logarithm Eq. 14 puts around the sum. Points are moved by ``ΔP``
    (Eq. 5) straight into grid coordinates.
    """
    c, s, gx0, gy0, last_x, last_y, far = _grid_frame(meta, x, y, t)
    acc = 0.0
    for i in range(0, n, stride):
        gx = gx0 + c * pts[i, 0] - s * pts[i, 1]
        gy = gy0 + s * pts[i, 0] + c * pts[i, 1]
        acc += lookup_grid(field, gx, gy, last_x, last_y, far)
    return math.log1p(acc) if kernel == KERNEL_PAPER else acc


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


@njit(cache=True, inline="always")
def _inlier_limit(distance, slope, px, py, inv_c2):
    """The cost below which point (px, py) counts as an inlier: ``distance + slope·r`` taken
    through the field's kernel (``inv_c2`` 0: plain ``d²``)."""
    d = distance + slope * math.hypot(px, py)
    return math.log1p(d * d * inv_c2) if inv_c2 > 0 else d * d


@njit(cache=True)
def inlier_fraction(field, meta, pts, n, x, y, t, distance, slope, inv_c2):
    """Share of the points within ``distance + slope·r`` of the reference surface at ``ΔP``
    (``r``: the point's range; beams spread and graze farther out). ``inv_c2``: the field's
    Cauchy kernel, ``1/c²`` (0: the field holds plain ``d²``)."""
    if n == 0:
        return 0.0
    c, s, gx0, gy0, last_x, last_y, far = _grid_frame(meta, x, y, t)
    inliers = 0
    for i in range(n):
        gx = gx0 + c * pts[i, 0] - s * pts[i, 1]
        gy = gy0 + s * pts[i, 0] + c * pts[i, 1]
        limit = _inlier_limit(distance, slope, pts[i, 0], pts[i, 1], inv_c2)
        if lookup_grid(field, gx, gy, last_x, last_y, far) <= limit:
            inliers += 1
    return inliers / n


@njit(cache=True)
def surface_inliers(surfaces, count, tiling, heads, links, meta, radius, pts, n, x, y, t,
                    distance, slope, inv_c2, stop):
    """How many points :func:`inlier_fraction` counts on the field a surface list stands for
    (swarmslam.runtime.matching.distance_field.list_surfaces, with the field's ``radius``): the same
    count, to the bit, without building the field. Counting ends once it reaches ``stop``
    (a caller that only asks whether the share reaches some value reads fewer points)."""
    c, s, gx0, gy0, last_x, last_y, far = _grid_frame(meta, x, y, t)
    inliers = 0
    ci = cj = -1  # the cell read last: a dense scan's neighbours often share one
    a = b = e = d = np.float32(0.0)
    for k in range(n):
        gx = gx0 + c * pts[k, 0] - s * pts[k, 1]
        gy = gy0 + s * pts[k, 0] + c * pts[k, 1]
        j = int(math.floor(gx))
        i = int(math.floor(gy))
        if j < 0 or i < 0 or j >= last_x or i >= last_y:
            cost = far
        else:
            if i != ci or j != cj:
                a, b, e, d = cell_costs(surfaces, count, tiling, heads, links, meta, radius,
                                        inv_c2, i, j)
                ci, cj = i, j
            cost = bilinear(a, b, e, d, gx - j, gy - i)
        if cost <= _inlier_limit(distance, slope, pts[k, 0], pts[k, 1], inv_c2):
            inliers += 1
            if inliers >= stop:
                break
    return inliers


@njit(cache=True, inline="always")
def _cost_moved(field, meta, pts, n, x, y, t, a, da, b, db):
    """The summed per-point cost at ``ΔP = (x, y, t)`` with component ``a`` moved by ``da``
    and component ``b`` (another one, or −1: none) by ``db``."""
    moved_x = x + da if a == 0 else (x + db if b == 0 else x)
    moved_y = y + da if a == 1 else (y + db if b == 1 else y)
    moved_t = t + da if a == 2 else (t + db if b == 2 else t)
    return scan_to_scan_error(field, meta, pts, n, 1, moved_x, moved_y, moved_t, KERNEL_CAUCHY)


@njit(cache=True)
def cost_hessian(field, meta, pts, n, x, y, t, h_xy, h_t, out):
    """Central-difference Hessian (3 × 3, into ``out``) of the summed per-point cost at
    ``ΔP``: how sharply the match is pinned in each direction. A plain corridor leaves it
    nearly singular along the corridor (docs/method.md §6.1). Scalars only: it runs every
    tick, and nothing here allocates."""
    f0 = _cost_moved(field, meta, pts, n, x, y, t, -1, 0.0, -1, 0.0)
    for a in range(3):
        ha = h_t if a == 2 else h_xy
        for b in range(a, 3):
            hb = h_t if b == 2 else h_xy
            if a == b:
                v = (_cost_moved(field, meta, pts, n, x, y, t, a, ha, -1, 0.0) - 2.0 * f0
                     + _cost_moved(field, meta, pts, n, x, y, t, a, -ha, -1, 0.0)) / (ha * ha)
            else:
                v = 0.0
                for sa in (-1.0, 1.0):
                    for sb in (-1.0, 1.0):
                        v += sa * sb * _cost_moved(field, meta, pts, n, x, y, t, a, sa * ha,
                                                   b, sb * hb)
                v /= 4.0 * ha * hb
            out[a, b] = v
            out[b, a] = v
