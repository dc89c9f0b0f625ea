"""The local occupancy grid of a reference scan, for scan-to-map matching (Eqs. 15–17).

Convention as in the paper: uint8, 0 = certainly occupied, 255 = certainly free, 128 unknown,
linear in between. Cells along each beam are free; cells within ``occupied_radius`` of a beam
end (the matcher's ``OCCUPIED_RADIUS``) ramp linearly from 0 at the end point to 255 at the radius (read from the distance field,
which already holds the (kernelled) squared distance to the nearest end point).
"""

from __future__ import annotations

import math

from numba import njit

from swarmslam.runtime.matching.distance_field import NX, NY, OX, OY, RES

UNKNOWN = 128


def robot_square(diameter: float, cell: float) -> int:
    """Eq. 17: ``ρ = ⌈d/c⌉ + 1`` if ``⌈d/c⌉`` is even, else ``⌈d/c⌉``; always odd."""
    if diameter <= 0.0 or cell <= 0.0:
        raise ValueError(f"robot diameter and cell size must be > 0; got {diameter}, {cell}")
    k = math.ceil(diameter / cell - 1e-9)
    return k + 1 if k % 2 == 0 else k


@njit(cache=True)
def build_local_map(pts, n, field, meta, inv_c2, occupied_radius, grid):
    """Render ``pts[:n]`` (sensor at the origin) into ``grid`` over the field's window.

    ``inv_c2`` is the field's Cauchy kernel (0: the field holds plain ``d²``).
    """
    nx = int(meta[NX])
    ny = int(meta[NY])
    ox = meta[OX]
    oy = meta[OY]
    res = meta[RES]
    for i in range(ny):
        for j in range(nx):
            grid[i, j] = UNKNOWN
    # Free space: walk each beam from the sensor to its end at half-cell steps.
    for p in range(n):
        px = pts[p, 0]
        py = pts[p, 1]
        length = math.sqrt(px * px + py * py)
        steps = int(length / (0.5 * res))
        for s in range(steps):
            f = s / steps if steps > 0 else 0.0
            j = int(round((f * px - ox) / res))
            i = int(round((f * py - oy) / res))
            if 0 <= i < ny and 0 <= j < nx:
                grid[i, j] = 255
    # Obstacles: a linear ramp around every end point.
    reach = int(math.ceil(occupied_radius / res))
    r2 = occupied_radius * occupied_radius
    for p in range(n):
        cj = int(round((pts[p, 0] - ox) / res))
        ci = int(round((pts[p, 1] - oy) / res))
        for i in range(max(ci - reach, 0), min(ci + reach + 1, ny)):
            for j in range(max(cj - reach, 0), min(cj + reach + 1, nx)):
                d2 = field[i, j]
                if inv_c2 > 0.0:
                    d2 = math.expm1(d2) / inv_c2
                if d2 < r2:
                    grid[i, j] = int(255.0 * math.sqrt(d2) / occupied_radius)
