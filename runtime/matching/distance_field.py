"""The reference scan's distance field: Eq. 14's nearest-neighbour look-ups in O(1).

Eq. 14 needs, for every transformed point of the current scan, the squared distance to its
nearest neighbour in the reference scan. A k-d tree query per point per candidate pose is what
makes naive swarm matchers slow (docs/method.md §3). Instead the squared distance is precomputed on a
grid around the reference scan and read back by bilinear interpolation.

Nearest neighbours are taken on the reference *surface*: consecutive end points closer than
``max_gap`` are joined by a segment (as PLICP does), and a point's distance is to the nearest
segment or isolated point. With bare points, a robot standing still in a corridor is where every
beam lands exactly on last scan's beam, so the objective prefers "no motion" whatever the true
motion along the corridor was.

Far down a corridor the same holds for neighbours farther apart than ``max_gap``: a wall seen
grazing has its end points metres apart, and as bare points they pull every match towards "no
motion" along the corridor (the simulator's ring of plain corridors comes out 0.45% short, its
odometry true to 2e-5). So, with ``bend`` > 0 (the matcher's default is 3°), a pair farther
apart is joined too when it *continues a line*: the pairs either side of it (one point further
each way) run within ``bend`` of its own direction, and its gap is at most ``gap_ratio`` times
the shorter of theirs — one surface sampled beam by beam. A jump in depth or a corner breaks
the line and stays open (docs/method.md §3: what it gains, and what it cost alone).

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
OX, OY, INV_RES, NX, NY, R2, RES = 0, 1, 2, 3, 4, 5, 6  # R2: cost beyond the radius
N_META = 7
# A build records, for each band of this many rows, the columns its segments reached: a
# band rather than a row, so that the record costs a segment two updates, not one a row.
SPAN_ROWS = 16


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


@njit(cache=True, inline="always")
def continues_line(pts, p, n, cos_bend, gap_ratio):
    """Whether neighbours ``p`` and ``p + 1`` lie on the line the pairs either side of them
    run along: both within the bend (its cosine ``cos_bend``) of their direction, and their gap
    at most ``gap_ratio`` times the shorter of those pairs'."""
    if p < 1 or p + 2 >= n:
        return False
    ux = pts[p, 0] - pts[p - 1, 0]
    uy = pts[p, 1] - pts[p - 1, 1]
    vx = pts[p + 1, 0] - pts[p, 0]
    vy = pts[p + 1, 1] - pts[p, 1]
    wx = pts[p + 2, 0] - pts[p + 1, 0]
    wy = pts[p + 2, 1] - pts[p + 1, 1]
    lu = math.sqrt(ux * ux + uy * uy)
    lv = math.sqrt(vx * vx + vy * vy)
    lw = math.sqrt(wx * wx + wy * wy)
    if lu <= 0.0 or lw <= 0.0 or lv > gap_ratio * min(lu, lw):
        return False
    return (ux * vx + uy * vy >= cos_bend * lu * lv
            and vx * wx + vy * wy >= cos_bend * lv * lw)


@njit(cache=True, inline="always")
def surface_end(pts, p, n, gap2, bend, cos_bend, gap_ratio):
    """The other end of the surface drawn from point ``p``: ``p + 1`` when the two are joined
    (closer than the gap, or continuing the line: :func:`continues_line`), else ``p`` itself
    (a lone point): the rule :func:`build_distance_field` and :func:`list_surfaces` join
    points by."""
    if p + 1 < n:
        dx = pts[p + 1, 0] - pts[p, 0]
        dy = pts[p + 1, 1] - pts[p, 1]
        if dx * dx + dy * dy < gap2 or (bend > 0.0 and continues_line(pts, p, n, cos_bend,
                                                                      gap_ratio)):
            return p + 1
    return p


@njit(cache=True)
def build_distance_field(pts, n, res, radius, max_gap, inv_c2, field, meta, columns, spans,
                         bend=0.0, gap_ratio=2.0):
    """Per-point cost of the nearest reference surface through ``pts[:n]``, at every node.

    ``pts`` are in scan order; neighbours closer than ``max_gap`` are joined (0: points only),
    and farther ones when they continue the line of the pairs either side of them (within
    ``bend`` rad, their gap at most ``gap_ratio`` times the shorter one's; ``bend`` 0: never).
    The cost is the truncated squared distance ``d²`` (``inv_c2 == 0``, Eq. 14's summand) or
    the Cauchy kernel ``log(1 + d²/c²)`` with ``inv_c2 = 1/c²``. Both are monotonic in ``d²``,
    so the minimum over surfaces can be taken on either; baking the kernel in here costs one
    pass at build time instead of a logarithm per point per candidate pose. ``columns``
    (at least a row of ``field`` long) is scratch for the nodes' x (:func:`column_centres`),
    ``spans`` (an integer pair for each band of ``SPAN_ROWS`` rows of ``field``) for the
    columns each band's segments reached: only those take the kernel, the rest of a row is
    one constant (a wide window is mostly far from every surface; the kernel's pass over all
    of it cost more than the segments' own).
    """
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
    gap2 = max_gap * max_gap
    cos_bend = math.cos(bend)
    column_centres(ox, res, nx, columns)
    record = inv_c2 > 0.0  # the spans serve the kernel's pass alone
    if record:
        for g in range((ny + SPAN_ROWS - 1) // SPAN_ROWS):
            spans[g, 0] = nx
            spans[g, 1] = -1
    for p in range(n):
        b = surface_end(pts, p, n, gap2, bend, cos_bend, gap_ratio)
        ax, ay, bx, by = pts[p, 0], pts[p, 1], pts[b, 0], pts[b, 1]
        i0, i1, j0, j1 = splat_segment(ax, ay, bx, by, ox, oy, res, radius, nx, ny, field,
                                       columns)
        if record and j1 >= j0 and i1 >= i0:
            for g in range(i0 // SPAN_ROWS, i1 // SPAN_ROWS + 1):
                spans[g, 0] = min(spans[g, 0], j0)
                spans[g, 1] = max(spans[g, 1], j1)
    if record:
        far = math.log1p(r2 * inv_c2)
        meta[R2] = far
        for i in range(ny):
            lo = spans[i // SPAN_ROWS, 0]
            hi = spans[i // SPAN_ROWS, 1]
            for j in range(lo):  # (lo is nx in a band no segment reached)
                field[i, j] = far
            for j in range(lo, hi + 1):
                v = field[i, j]
                # Most cells are beyond the radius: one constant, no logarithm.
                field[i, j] = math.log1p(v * inv_c2) if v < r2 else far
            for j in range(max(hi + 1, lo), nx):
                field[i, j] = far


@njit(cache=True, inline="always")
def segment_box(ax, ay, bx, by, ox, oy, res, radius, nx, ny):
    """Rows ``i0…i1`` and columns ``j0…j1`` of the nodes within ``radius`` of segment a–b
    (cut to the window's ``nx × ny``; empty when ``j1 < j0`` or ``i1 < i0``): the box
    :func:`splat_segment` walks and :func:`list_surfaces` records."""
    j0 = max(int(math.floor((min(ax, bx) - radius - ox) / res)), 0)
    j1 = min(int(math.ceil((max(ax, bx) + radius - ox) / res)), nx - 1)
    i0 = max(int(math.floor((min(ay, by) - radius - oy) / res)), 0)
    i1 = min(int(math.ceil((max(ay, by) + radius - oy) / res)), ny - 1)
    return i0, i1, j0, j1


@njit(cache=True, inline="always")
def column_centres(ox, res, nx, columns):
    """``columns[j] = ox + j·res``, the x of the window's node column ``j`` (``j < nx``), as
    :func:`splat_segment` reads it."""
    for j in range(nx):
        columns[j] = ox + j * res


@njit(cache=True)
def splat_segment(ax, ay, bx, by, ox, oy, res, radius, nx, ny, field, columns):
    """Lower every node within ``radius`` of segment a–b to its squared distance from it;
    ``columns``: the nodes' x (:func:`column_centres` of ``ox``, ``res``, ``nx``).

    The hot loop of every build: each row is a slice walked from 0 with a select, not a
    branch, so that it compiles to vector instructions (a negative index check or a
    conditional store would keep it scalar: 1.7× the time), and the point case (a = b) needs
    no projection. The select is ``np.fmin``: written ``d2 if d2 < f else f``, LLVM turned it
    into a masked store of the lowered lanes (``vmaskmovps``), which AMD's Zen 3 runs in
    microcode: a build took 1.4 times as long.
    ``fmin`` stores every lane, the same value (the operands are finite). A node's x is read
    from ``columns``, not computed from its index: on a CPU without AVX-512 (Zen 3) the
    index's conversion to a double runs lane by lane, a third of a build. The arithmetic is the same, operation for
    operation, so the field is too. Returns the box of nodes walked (:func:`segment_box`)."""
    ux = bx - ax
    uy = by - ay
    uu = ux * ux + uy * uy
    i0, i1, j0, j1 = segment_box(ax, ay, bx, by, ox, oy, res, radius, nx, ny)
    if j1 < j0:
        return i0, i1, j0, j1
    m = j1 - j0 + 1
    xs = columns[j0 : j1 + 1]
    for i in range(i0, i1 + 1):
        cy = oy + i * res
        row = field[i, j0 : j1 + 1]
        if uu > 0.0:
            wy = (cy - ay) * uy
            for k in range(m):
                cx = xs[k]
                t = ((cx - ax) * ux + wy) / uu  # the nearest point's place along a–b
                t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
                dx = ax + t * ux - cx
                dy = ay + t * uy - cy
                d2 = dx * dx + dy * dy
                row[k] = np.fmin(d2, row[k])
        else:
            dy = ay - cy
            for k in range(m):
                dx = ax - xs[k]
                d2 = dx * dx + dy * dy
                row[k] = np.fmin(d2, row[k])
    return i0, i1, j0, j1


@njit(cache=True, inline="always")
def bilinear(a, b, c, d, fx, fy):
    """The cost at ``(fx, fy)`` inside a cell whose nodes hold ``a`` (its own), ``b`` (the next
    column), ``c`` (the next row) and ``d``."""
    return a + (b - a) * fx + (c - a) * fy + (a - b - c + d) * fx * fy


@njit(cache=True, inline="always")
def lookup_grid(field, gx, gy, last_x, last_y, far):
    """Bilinear cost at grid coordinates ``(gx, gy)``; ``far`` outside ``[0, last)``."""
    j = int(math.floor(gx))
    i = int(math.floor(gy))
    if j < 0 or i < 0 or j >= last_x or i >= last_y:
        return far
    fx = gx - j
    fy = gy - i
    return bilinear(field[i, j], field[i, j + 1], field[i + 1, j], field[i + 1, j + 1], fx, fy)


@njit(cache=True, inline="always")
def field_lookup(field, meta, x, y):
    """Bilinear per-point cost at ``(x, y)``; the truncation cost outside the window."""
    gx = (x - meta[OX]) * meta[INV_RES]
    gy = (y - meta[OY]) * meta[INV_RES]
    return lookup_grid(field, gx, gy, int(meta[NX]) - 1, int(meta[NY]) - 1, meta[R2])


# A surface list's rows: a segment's ends and the box of nodes it lowers (see segment_box).
SAX, SAY, SBX, SBY, SI0, SI1, SJ0, SJ1 = 0, 1, 2, 3, 4, 5, 6, 7
N_SURFACE = 8
# Its index: square tiles of nodes, each a linked list of the segments whose box, widened by a
# node down and left, meets it; so the tile of a cell's first node lists every segment that
# lowers one of the cell's four. TILE_SIDE, TILES_X, INDEXED: ``tiling``'s entries.
TILE_SIDE, TILES_X, INDEXED = 0, 1, 2


@njit(cache=True)
def list_surfaces(pts, n, res, radius, max_gap, inv_c2, cap_x, cap_y, meta, surfaces, tiling,
                  heads, links, bend=0.0, gap_ratio=2.0):
    """The segments :func:`build_distance_field` would splat for ``pts[:n]`` into a
    ``cap_y × cap_x`` field, each with its box of nodes, into ``surfaces`` (a row each, see
    ``SAX…SJ1``); ``meta`` as that field's. Returns how many.

    A field read at one scan's points a few times costs less from this list than built: a
    node's value is the least over the segments whose box holds it, by the same arithmetic
    (:func:`cell_costs`), where building writes the whole window twice. The segments are
    indexed by tiles of ``tiling[TILE_SIDE]`` nodes (``heads``: a tile's first entry, −1 for
    none; ``links``: an entry's segment and the next entry); with more entries than
    ``links`` holds, ``tiling[INDEXED]`` is 0 and a look-up reads every segment."""
    fit_window(pts, n, res, radius, cap_x, cap_y, meta)
    r2 = radius * radius
    meta[R2] = math.log1p(r2 * inv_c2) if inv_c2 > 0.0 else r2
    nx = int(meta[NX])
    ny = int(meta[NY])
    ox = meta[OX]
    oy = meta[OY]
    side = tiling[TILE_SIDE]
    tiles_x = (nx + side - 1) // side
    tiling[TILES_X] = tiles_x
    for k in range(tiles_x * ((ny + side - 1) // side)):
        heads[k] = -1
    gap2 = max_gap * max_gap
    cos_bend = math.cos(bend)
    count = 0
    used = 0
    indexed = True
    for p in range(n):
        b = surface_end(pts, p, n, gap2, bend, cos_bend, gap_ratio)
        ax, ay, bx, by = pts[p, 0], pts[p, 1], pts[b, 0], pts[b, 1]
        i0, i1, j0, j1 = segment_box(ax, ay, bx, by, ox, oy, res, radius, nx, ny)
        if j1 < j0 or i1 < i0:
            continue  # no node of the window within reach: the splat writes nothing
        row = surfaces[count]
        row[SAX], row[SAY], row[SBX], row[SBY] = ax, ay, bx, by
        row[SI0], row[SI1], row[SJ0], row[SJ1] = i0, i1, j0, j1
        t0, t1 = max(i0 - 1, 0) // side, i1 // side
        u0, u1 = max(j0 - 1, 0) // side, j1 // side
        if used + (t1 - t0 + 1) * (u1 - u0 + 1) > len(links):
            indexed = False
        if indexed:
            for ti in range(t0, t1 + 1):
                for tj in range(u0, u1 + 1):
                    tile = ti * tiles_x + tj
                    links[used, 0] = count
                    links[used, 1] = heads[tile]
                    heads[tile] = used
                    used += 1
        count += 1
    tiling[INDEXED] = 1 if indexed else 0
    return count


@njit(cache=True, inline="always")
def _lowered(v, ax, ay, ux, uy, uu, cx, cy):
    """``v`` lowered to the squared distance of node (cx, cy) from segment a–(a + u), as
    :func:`splat_segment` computes and stores it (float32)."""
    if uu > 0.0:
        t = ((cx - ax) * ux + (cy - ay) * uy) / uu
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        dx = ax + t * ux - cx
        dy = ay + t * uy - cy
    else:
        dx = ax - cx
        dy = ay - cy
    d2 = dx * dx + dy * dy
    return np.float32(d2) if d2 < v else v


@njit(cache=True, inline="always")
def _kernel(v, r2, inv_c2):
    """A node's stored value after :func:`build_distance_field`'s kernel pass."""
    if inv_c2 > 0.0:
        return np.float32(math.log1p(v * inv_c2) if v < r2 else math.log1p(r2 * inv_c2))
    return v


@njit(cache=True)
def cell_costs(surfaces, count, tiling, heads, links, meta, radius, inv_c2, i, j):
    """The four nodes of cell (``i``, ``j``) — its own, the next column's, the next row's and
    the diagonal one's — as :func:`build_distance_field` would store them, from a surface
    list (:func:`list_surfaces`)."""
    ox, oy, res = meta[OX], meta[OY], meta[RES]
    r2 = radius * radius
    a = b = c = d = np.float32(r2)
    x0, x1 = ox + j * res, ox + (j + 1) * res
    y0, y1 = oy + i * res, oy + (i + 1) * res
    side = tiling[TILE_SIDE]
    e = heads[(i // side) * tiling[TILES_X] + j // side] if tiling[INDEXED] else -1
    k = -1
    while True:  # the tile's entries, or every segment: count or fewer passes
        if tiling[INDEXED]:
            if e < 0:
                break
            k = links[e, 0]
            e = links[e, 1]
        else:
            if k + 1 >= count:
                break
            k += 1
        row = surfaces[k]
        if i + 1 < row[SI0] or i > row[SI1] or j + 1 < row[SJ0] or j > row[SJ1]:
            continue
        ax, ay = row[SAX], row[SAY]
        ux, uy = row[SBX] - ax, row[SBY] - ay
        uu = ux * ux + uy * uy
        in_i0, in_i1 = row[SI0] <= i, i + 1 <= row[SI1]
        in_j0, in_j1 = row[SJ0] <= j, j + 1 <= row[SJ1]
        if in_i0 and in_j0:
            a = _lowered(a, ax, ay, ux, uy, uu, x0, y0)
        if in_i0 and in_j1:
            b = _lowered(b, ax, ay, ux, uy, uu, x1, y0)
        if in_i1 and in_j0:
            c = _lowered(c, ax, ay, ux, uy, uu, x0, y1)
        if in_i1 and in_j1:
            d = _lowered(d, ax, ay, ux, uy, uu, x1, y1)
    return (_kernel(a, r2, inv_c2), _kernel(b, r2, inv_c2), _kernel(c, r2, inv_c2),
            _kernel(d, r2, inv_c2))
