"""The reference scan's distance field: Eq. 14's nearest-neighbour look-ups in O(1).

Eq. 14 needs, for every transformed point of the current scan, the squared distance to its
nearest neighbour in the reference scan. A k-d tree query per point per candidate pose is what
makes naive swarm matchers slow (method.md §3). Instead the squared distance is precomputed on a
grid around the reference scan and read back by bilinear interpolation.

Building must cost less than a match, so the field is *truncated*: each reference point writes
the exact squared distance into the cells within ``radius`` of it, and every other cell holds
``radius²``. With ``radius`` at least the largest nearest-neighbour distance that matters this
is the paper's objective; smaller, it is a truncated-quadratic robust kernel (outliers cost
``radius²`` each, not their full distance). Cost: one pass over the used cells to clear them
plus ``n · (2·radius/resolution)²`` distance evaluations — fractions of a millisecond.

The grid has a fixed capacity (cells per side) allocated once. It covers the bounding box of
the reference points and the sensor; when that box is larger than the capacity, the window is
centred on the sensor and farther points are left out.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Layout of the ``meta`` array describing the used part of a grid.
OX, OY, INV_RES, NX, NY, R2, RES = 0, 1, 2, 3, 4, 5, 6
N_META = 7


@njit(cache=True)
def fit_window(pts, n, res, margin, cap_x, cap_y, meta):
    """Place the grid over the points (and the sensor at the origin) with ``margin`` around."""
    minx = 0.0
    maxx = 0.0
    miny = 0.0
    maxy = 0.0
    for i in range(n):
        x = pts[i, 0]
        y = pts[i, 1]
        minx = min(minx, x)
        maxx = max(maxx, x)
        miny = min(miny, y)
        maxy = max(maxy, y)
    minx -= margin
    miny -= margin
    maxx += margin
    maxy += margin
    nx = int(math.ceil((maxx - minx) / res)) + 1
    ny = int(math.ceil((maxy - miny) / res)) + 1
    if nx > cap_x:  # too wide for the capacity: centre on the sensor
        nx = cap_x
        minx = -0.5 * (cap_x - 1) * res
    if ny > cap_y:
        ny = cap_y
        miny = -0.5 * (cap_y - 1) * res
    meta[OX] = minx
    meta[OY] = miny
    meta[INV_RES] = 1.0 / res
    meta[NX] = nx
    meta[NY] = ny
    meta[RES] = res


@njit(cache=True)
def build_distance_field(pts, n, res, radius, field, meta):
    """Truncated squared distance to the nearest of ``pts[:n]`` at every grid node."""
    fit_window(pts, n, res, radius, field.shape[1], field.shape[0], meta)
    r2 = radius * radius
    meta[R2] = r2
    nx = int(meta[NX])
    ny = int(meta[NY])
    ox = meta[OX]
    oy = meta[OY]
    for i in range(ny):
        for j in range(nx):
            field[i, j] = r2
    reach = int(math.ceil(radius / res))
    for p in range(n):
        px = pts[p, 0]
        py = pts[p, 1]
        cj = int(round((px - ox) / res))
        ci = int(round((py - oy) / res))
        for i in range(max(ci - reach, 0), min(ci + reach + 1, ny)):
            dy = oy + i * res - py
            for j in range(max(cj - reach, 0), min(cj + reach + 1, nx)):
                dx = ox + j * res - px
                d2 = dx * dx + dy * dy
                if d2 < field[i, j]:
                    field[i, j] = d2


@njit(cache=True, inline="always")
def field_lookup(field, meta, x, y):
    """Bilinear squared distance at ``(x, y)``; ``radius²`` outside the window."""
    gx = (x - meta[OX]) * meta[INV_RES]
    gy = (y - meta[OY]) * meta[INV_RES]
    if not (gx >= 0.0 and gy >= 0.0 and gx < meta[NX] - 1.0 and gy < meta[NY] - 1.0):
        return meta[R2]
    j = int(gx)
    i = int(gy)
    fx = gx - j
    fy = gy - i
    top = (1.0 - fx) * field[i, j] + fx * field[i, j + 1]
    bottom = (1.0 - fx) * field[i + 1, j] + fx * field[i + 1, j + 1]
    return (1.0 - fy) * top + fy * bottom
