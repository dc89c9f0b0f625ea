"""Where in the whole map does a scan fit? An exhaustive, branch-and-bound search over every
standable cell and every heading (docs/method.md §8).

The saved map is rendered once into a *hit grid*: each cell holds how well a scan point landing
there fits the map's surfaces (255·exp(−d²/2σ²), ``d`` the distance to the nearest surface —
the stored node scans, consecutive points joined as in the distance field). A pose's *score* is
the sum over the query's points of the hit grid at their cells, so a perfect fit scores
255 per point.

Branch and bound (Olson's multi-resolution correlative search, as Cartographer uses it): level
``h`` of a pyramid holds, at ``(i, j)``, the largest hit value of the ``2ʰ × 2ʰ`` block of cells
starting there, so scoring a heading and a block of ``2ʰ × 2ʰ`` positions on level ``h`` bounds
every position in it from above. Blocks are split best first and dropped as soon as their bound
falls below the floor, so the answer is the exact best pose on the grid, found without scoring
most of the poses. A block in which the robot could not stand (no cell seen free by the map's
scans) is never scored.

To know whether a second, *distinct* pose explains the scan about as well (a symmetric room, a
corridor), the floor is ``ratio`` of the best so far rather than the best itself, and every pose
above it is kept, merged with a kept pose of the same place: any distinct one left at the end is
a rival.

Everything here is compiled and works on buffers allocated when the map is loaded.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.config import RelocalizationConfig
from swarmslam.runtime.matching.distance_field import column_centres, splat_segment
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.occupancy_grid import integrate_scan
from swarmslam.runtime.pose import compose

HIT_MAX = 255  # a point exactly on a surface
# Columns of a search candidate (stack and root rows): score, level, heading, row, column.
C_SCORE, C_LEVEL, C_HEADING, C_ROW, C_COL = range(5)


@njit(cache=True)
def render_hits(points, counts, poses, index, n_index, max_range, max_gap, ox, oy, res, sigma,
                d2, hits):
    """The hit grid of the scans of nodes ``index[:n_index]`` placed at ``poses`` (``d2``:
    scratch of its shape); the grid's cell ``(i, j)`` is the point ``(ox, oy) + (j, i)·res``.
    Its three passes may also be run a part at a time (rows, nodes), as the wide loop search
    does; the grid is the same."""
    ny = hits.shape[0]
    clear_distances(d2, sigma, 0, ny)
    splat_scans(points, counts, poses, index, 0, n_index, max_range, max_gap, ox, oy, res,
                sigma, d2, np.empty(d2.shape[1]))
    hits_from_distances(d2, sigma, hits, 0, ny)


@njit(cache=True)
def clear_distances(d2, sigma, first, last):
    """Rows ``first:last`` of ``d2`` set to the splat's reach squared (nothing near)."""
    radius = 3.0 * sigma
    r2 = radius * radius
    for i in range(first, last):
        for j in range(d2.shape[1]):
            d2[i, j] = r2


@njit(cache=True)
def splat_scans(points, counts, poses, index, first, last, max_range, max_gap, ox, oy, res,
                sigma, d2, columns, tolerance=0.0):
    """The scans of nodes ``index[first:last]`` splatted into ``d2`` (each cell the least
    squared distance to a surface, within ``3·sigma``); points beyond ``max_range`` of their
    node are left out, consecutive points closer than ``max_gap`` joined. ``columns``: scratch
    of a row's length (:func:`splat_segment`).

    With ``tolerance`` > 0 a run of joined points is drawn as one segment (no longer than the
    splat's reach) while every point it skips lies within ``tolerance`` of it: a dense scan's
    wall costs a few splats instead of one per beam, and no distance moves by more than
    ``tolerance`` (docs/method.md §5, step 5). With 0 every pair is its own segment."""
    ny, nx = d2.shape
    radius = 3.0 * sigma
    gap2 = max_gap * max_gap
    reach2 = max_range * max_range
    column_centres(0.0, res, nx, columns)  # the points are moved by (-ox, -oy) instead
    for e in range(first, last):
        m = index[e]
        c, s = math.cos(poses[m, 2]), math.sin(poses[m, 2])
        n = counts[m]
        pts = points[m]
        covered = False  # the point ends the segment drawn last
        p = 0
        while p < n:
            px, py = pts[p, 0], pts[p, 1]
            if px * px + py * py > reach2:
                p += 1
                covered = False
                continue
            q = chain_end(pts, n, p, gap2, reach2, tolerance, radius)
            if q == p and covered and tolerance > 0.0:  # drawn already, as a segment's end
                p += 1
                covered = False
                continue
            qx, qy = pts[q, 0], pts[q, 1]
            ax = poses[m, 0] + c * px - s * py - ox
            ay = poses[m, 1] + s * px + c * py - oy
            bx = poses[m, 0] + c * qx - s * qy - ox
            by = poses[m, 1] + s * qx + c * qy - oy
            splat_segment(ax, ay, bx, by, 0.0, 0.0, res, radius, nx, ny, d2, columns)
            covered = q > p
            p = q if q > p else p + 1


@njit(cache=True, inline="always")
def chain_end(pts, n, p, gap2, reach2, tolerance, length):
    """The last point of the segment drawn from point ``p``: ``p`` itself when the next point
    is not joined to it (``gap2``); else the farthest point of the joined run (each joined
    point within ``reach2`` of the sensor but the last) whose chord from ``p`` is at most
    ``length`` long and passes within ``tolerance`` of every point between (0: the next)."""
    if p + 1 >= n:
        return p
    dx, dy = pts[p + 1, 0] - pts[p, 0], pts[p + 1, 1] - pts[p, 1]
    if dx * dx + dy * dy >= gap2:
        return p
    end = p + 1
    if tolerance <= 0.0:
        return end
    tol2 = tolerance * tolerance
    len2 = length * length
    ax, ay = pts[p, 0], pts[p, 1]
    while end + 1 < n:
        ex, ey = pts[end, 0], pts[end, 1]
        if ex * ex + ey * ey > reach2:
            break  # beyond the range the next segment would not be drawn
        q = end + 1
        dx, dy = pts[q, 0] - ex, pts[q, 1] - ey
        if dx * dx + dy * dy >= gap2:
            break
        ux, uy = pts[q, 0] - ax, pts[q, 1] - ay
        uu = ux * ux + uy * uy
        if uu > len2 or uu <= 0.0:
            break
        for k in range(p + 1, q):
            wx, wy = pts[k, 0] - ax, pts[k, 1] - ay
            t = min(max((wx * ux + wy * uy) / uu, 0.0), 1.0)
            dx, dy = wx - t * ux, wy - t * uy
            if dx * dx + dy * dy > tol2:
                return end
        end = q
    return end


@njit(cache=True)
def hits_from_distances(d2, sigma, hits, first, last):
    """Rows ``first:last`` of the hit grid from the squared distances: 255·exp(−d²/2σ²), 0
    beyond the splat's reach."""
    radius = 3.0 * sigma
    r2 = radius * radius
    inv = 1.0 / (2.0 * sigma * sigma)
    for i in range(first, last):
        for j in range(d2.shape[1]):
            v = d2[i, j]
            hits[i, j] = 0 if v >= r2 else int(HIT_MAX * math.exp(-v * inv) + 0.5)


@njit(cache=True)
def pool_pyramid(levels):
    """Level ``h`` from level ``h − 1``: the largest value of each ``2ʰ × 2ʰ`` block."""
    for h in range(1, levels.shape[0]):
        pool_level(levels, h, 0, levels.shape[1])


@njit(cache=True)
def pool_level(levels, h, first, last):
    """Rows ``first:last`` of level ``h`` of the pyramid (:func:`pool_pyramid`); level
    ``h − 1`` must be whole."""
    _block_max(levels[h - 1], levels[h], 1 << (h - 1), first, last)


@njit(cache=True)
def _block_max(src, dst, d, first, last):
    """Rows ``first:last`` of ``dst``: at ``(i, j)`` the largest of ``src`` at ``(i, j)``,
    ``(i, j + d)``, ``(i + d, j)`` and ``(i + d, j + d)``, those on the grid. Each row is split
    where ``j + d`` leaves it, so that the loops hold no test and compile to vector maxima."""
    ny, nx = dst.shape[0], dst.shape[1]
    inner = max(nx - d, 0)  # columns whose j + d is on the grid
    for i in range(first, last):
        if i + d < ny:
            for j in range(inner):
                dst[i, j] = max(max(src[i, j], src[i, j + d]),
                                max(src[i + d, j], src[i + d, j + d]))
            for j in range(inner, nx):
                dst[i, j] = max(src[i, j], src[i + d, j])
        else:
            for j in range(inner):
                dst[i, j] = max(src[i, j], src[i, j + d])
            for j in range(inner, nx):
                dst[i, j] = src[i, j]


def bound_shift(group: int) -> int:
    """Cells a query point may move while the heading turns by half of a group of ``group``
    heading steps: one cell per step at the query's reach (:func:`heading_step`), plus one for
    the arc's excess over the chord and one for rounding the two offsets."""
    return 0 if group == 1 else group // 2 + 2


@njit(cache=True)
def pool_bounds(pyramid, shifts, bounds):
    """``bounds[h]`` at ``(i, j)``: the largest hit value of the ``w × w`` block starting
    there, ``w = 2ʰ + 2·shifts[h]`` (level 0: the hit grid itself) — the reach of a level-``h``
    search block's points over its heading group and ``2ʰ × 2ʰ`` positions. Two overlapping
    power-of-two blocks of ``pyramid`` per side cover the block exactly."""
    for h in range(bounds.shape[0]):
        pool_bound_level(pyramid, shifts, bounds, h, 0, bounds.shape[1])


@njit(cache=True)
def pool_bound_level(pyramid, shifts, bounds, h, first, last):
    """Rows ``first:last`` of ``bounds[h]`` (:func:`pool_bounds`); ``pyramid`` must be
    whole (of the same rows and columns)."""
    w = (1 << h) + 2 * shifts[h]
    p = 0
    while (2 << p) <= w:
        p += 1
    _block_max(pyramid[p], bounds[h], w - (1 << p), first, last)


# Columns of a heading's offset box (rotate_query): its least and greatest row and column
# offsets.
E_ROW0, E_ROW1, E_COL0, E_COL1 = range(4)


@njit(cache=True)
def rotate_query(points, n, res, step, n_headings, offsets, extent):
    """Each point's cell offset from the robot's cell at each of ``n_headings`` headings
    ``a·step``, and each heading's box of offsets (``extent[a]``: ``E_*`` columns)."""
    inv = 1.0 / res
    for a in range(n_headings):
        c, s = math.cos(a * step), math.sin(a * step)
        extent[a, E_ROW0] = extent[a, E_COL0] = 0  # (no points: an empty box at 0)
        extent[a, E_ROW1] = extent[a, E_COL1] = 0
        for k in range(n):
            x, y = points[k, 0], points[k, 1]
            r = int(math.floor((s * x + c * y) * inv + 0.5))
            q = int(math.floor((c * x - s * y) * inv + 0.5))
            offsets[a, k, 0] = r
            offsets[a, k, 1] = q
            if k == 0 or r < extent[a, E_ROW0]:
                extent[a, E_ROW0] = r
            if k == 0 or r > extent[a, E_ROW1]:
                extent[a, E_ROW1] = r
            if k == 0 or q < extent[a, E_COL0]:
                extent[a, E_COL0] = q
            if k == 0 or q > extent[a, E_COL1]:
                extent[a, E_COL1] = q


@njit(cache=True, inline="always")
def _score(bounds, h, shift, offsets, a, n, i, j, floor):
    """The query's score at heading ``a`` and cell ``(i, j)`` of ``bounds[h]`` — or, once the
    points left cannot lift it to ``floor``, some value below ``floor``: every caller drops a
    score below its floor, so the search finds what it found scoring every point."""
    ny, nx = bounds.shape[1], bounds.shape[2]
    total = 0
    slack = n * HIT_MAX - floor  # what the points may still fall short of HIT_MAX
    i -= shift
    j -= shift
    for k in range(n):
        r = i + offsets[a, k, 0]
        q = j + offsets[a, k, 1]
        v = 0
        if 0 <= r < ny and 0 <= q < nx:  # (not _read: through it, searches took 1.2-1.3× the time)
            v = bounds[h, r, q]
        total += v
        slack -= HIT_MAX - v
        if slack < 0:
            return total  # < floor: HIT_MAX for every point left would not reach it
    return total


@njit(cache=True, inline="always")
def _read(bounds, h, r, q):
    """``bounds[h]`` at ``(r, q)``; 0 off the grid."""
    if 0 <= r < bounds.shape[1] and 0 <= q < bounds.shape[2]:
        return bounds[h, r, q]
    return 0


@njit(cache=True)
def _score_children(bounds, h, shift, offsets, extent, a, n, i, j, half, floor, on0, on1, on2,
                    on3):
    """:func:`_score` of the four blocks ``(i, j)``, ``(i, j + half)``, ``(i + half, j)`` and
    ``(i + half, j + half)`` of ``bounds[h]`` at heading ``a`` (those ``on``), point by point
    together: a point's four reads go to memory at once, and on the lower levels they share
    cache lines, where one block at a time waits for each read in turn (the same answers,
    sooner; least where the blocks lie far apart). Returns the four scores, each
    the exact score where it reaches ``floor`` and −1 otherwise (and for a block not
    ``on``): what :func:`_score` gives, as its callers read it."""
    ny, nx = bounds.shape[1], bounds.shape[2]
    full = n * HIT_MAX - floor  # a block's slack, as in _score
    t0 = t1 = t2 = t3 = 0
    s0 = full if on0 else -1
    s1 = full if on1 else -1
    s2 = full if on2 else -1
    s3 = full if on3 else -1
    i -= shift
    j -= shift
    inside = (i + extent[a, E_ROW0] >= 0 and i + half + extent[a, E_ROW1] < ny
              and j + extent[a, E_COL0] >= 0 and j + half + extent[a, E_COL1] < nx)
    for k in range(n):
        if s0 < 0 and s1 < 0 and s2 < 0 and s3 < 0:
            break  # none can reach the floor any more
        r = i + offsets[a, k, 0]
        q = j + offsets[a, k, 1]
        if inside:  # every point of the four blocks on the grid: no test per cell
            v0 = bounds[h, r, q]
            v1 = bounds[h, r, q + half]
            v2 = bounds[h, r + half, q]
            v3 = bounds[h, r + half, q + half]
        else:
            v0 = _read(bounds, h, r, q)
            v1 = _read(bounds, h, r, q + half)
            v2 = _read(bounds, h, r + half, q)
            v3 = _read(bounds, h, r + half, q + half)
        t0 += v0
        t1 += v1
        t2 += v2
        t3 += v3
        s0 -= HIT_MAX - v0
        s1 -= HIT_MAX - v1
        s2 -= HIT_MAX - v2
        s3 -= HIT_MAX - v3
    # once a slack is below 0 it stays there, and the block's score is below the floor
    return (t0 if s0 >= 0 else -1, t1 if s1 >= 0 else -1, t2 if s2 >= 0 else -1,
            t3 if s3 >= 0 else -1)


@njit(cache=True, inline="always")
def _push(stack, base, depth, score, level, heading, row, col):
    """Insert a child into ``stack[base:depth]``, kept ascending by score (a child scoring
    the same as one before it goes above it); returns the new depth."""
    k = depth
    while k > base and stack[k - 1, C_SCORE] > score:
        for c in range(5):
            stack[k, c] = stack[k - 1, c]
        k -= 1
    stack[k, C_SCORE] = score
    stack[k, C_LEVEL] = level
    stack[k, C_HEADING] = heading
    stack[k, C_ROW] = row
    stack[k, C_COL] = col
    return depth + 1


@njit(cache=True)
def _keep(found, n_found, cell_radius, heading_radius, n_headings, s, a, i, j):
    """Add the pose to ``found`` (rows: score, heading, row, column; best first), merged with
    a pose of the same place (within the radii) it beats, or instead of the worst when full.
    Returns the new count."""
    for e in range(n_found):
        d = abs(a - found[e, 1]) % n_headings
        if (min(d, n_headings - d) <= heading_radius
                and (i - found[e, 2]) ** 2 + (j - found[e, 3]) ** 2 <= cell_radius ** 2):
            if s <= found[e, 0]:
                return n_found
            # the same place, better: drop the old row, then insert below
            for f in range(e, n_found - 1):
                for c in range(4):
                    found[f, c] = found[f + 1, c]
            n_found -= 1
            break
    if n_found == found.shape[0]:
        if s <= found[n_found - 1, 0]:
            return n_found
        n_found -= 1
    k = n_found
    while k > 0 and found[k - 1, 0] < s:
        for c in range(4):
            found[k, c] = found[k - 1, c]
        k -= 1
    found[k, 0], found[k, 1], found[k, 2], found[k, 3] = s, a, i, j
    return n_found + 1


@njit(cache=True)
def _sort_descending(rows, n):
    """Heapsort ``rows[:n]`` by their score column, largest first, in place."""
    for start in range(n // 2 - 1, -1, -1):
        _sift(rows, start, n)
    for end in range(n - 1, 0, -1):
        for c in range(rows.shape[1]):
            rows[0, c], rows[end, c] = rows[end, c], rows[0, c]
        _sift(rows, 0, end)


@njit(cache=True, inline="always")
def _sift(rows, root, n):
    # a min-heap, so that the sorted order is descending
    while True:
        child = 2 * root + 1
        if child >= n:
            return
        if child + 1 < n and rows[child + 1, C_SCORE] < rows[child, C_SCORE]:
            child += 1
        if rows[child, C_SCORE] < rows[root, C_SCORE]:
            for c in range(rows.shape[1]):
                rows[root, c], rows[child, c] = rows[child, c], rows[root, c]
            root = child
        else:
            return


# the state of a branch and bound between slices (:func:`branch_and_bound`): a search with
# S_PHASE 0 has not begun
S_PHASE, S_NEXT, S_ROOTS, S_ROOT, S_DEPTH, S_FLOOR, S_FOUND, S_SCORED = range(8)
SEARCH_STATE = 8
UNLIMITED = 1 << 62  # a budget no search reaches: the whole search in one call


@njit(cache=True)
def branch_and_bound(bounds, shifts, groups, free, offsets, extent, n_points, n_headings,
                     min_score, ratio, cell_radius, heading_radius, roots, stack, found, state,
                     budget):
    """The best pose on the grid scoring at least ``min_score``, and the distinct poses (farther
    than ``cell_radius`` cells or ``heading_radius`` steps from each other) scoring at least
    ``ratio`` of it: rows of ``found`` (score, heading, row, column), best first. Returns
    ``(how many, blocks scored, done)``.

    A search block of level ``h`` spans ``groups[h]`` headings and ``2ʰ × 2ʰ`` positions; its
    bound scores the query at the middle heading on ``bounds[h]``, shifted by ``shifts[h]``.
    Blocks whose bound is below ``ratio`` of the best so far are dropped: nothing in them can
    beat the best or rival it. ``offsets`` and ``extent`` are the query's, from
    :func:`rotate_query`; ``roots`` and ``stack`` are scratch (rows of ``C_*`` columns).

    Sliced: the search scores about ``budget`` blocks, then returns with ``done`` False and
    its place kept in ``state`` (``SEARCH_STATE`` integers; ``state[S_PHASE] = 0`` begins a
    new search), ``roots``, ``stack`` and ``found``; the next call goes on from there. Slices
    visit the blocks in the same order as one call with ``UNLIMITED``, so they find the same.
    """
    top = bounds.shape[0] - 1
    ny, nx = bounds.shape[1], bounds.shape[2]
    w = 1 << top
    g = groups[top]
    na, ni, nj = (n_headings + g - 1) // g, (ny + w - 1) // w, (nx + w - 1) // w
    if state[S_PHASE] == 3:  # done already
        return state[S_FOUND], state[S_SCORED], True
    if state[S_PHASE] == 0:
        state[S_PHASE], state[S_NEXT], state[S_ROOTS], state[S_SCORED] = 1, 0, 0, 0
    scored = state[S_SCORED]
    limit = scored + budget
    n_roots = state[S_ROOTS]
    if state[S_PHASE] == 1:  # every top-level block scored, in heading, row, column order
        for t in range(state[S_NEXT], na * ni * nj):
            if scored >= limit:
                state[S_NEXT], state[S_ROOTS], state[S_SCORED] = t, n_roots, scored
                return 0, scored, False
            a, i, j = (t // (ni * nj)) * g, ((t // nj) % ni) * w, (t % nj) * w
            if free[top, i, j] == 0:
                continue
            s = _score(bounds, top, shifts[top], offsets, a + g // 2, n_points, i, j,
                       min_score)
            scored += 1
            if s < min_score:
                continue
            roots[n_roots, C_SCORE] = s
            roots[n_roots, C_LEVEL] = top
            roots[n_roots, C_HEADING] = a
            roots[n_roots, C_ROW] = i
            roots[n_roots, C_COL] = j
            n_roots += 1
        _sort_descending(roots, n_roots)
        state[S_PHASE], state[S_ROOTS], state[S_ROOT], state[S_DEPTH] = 2, n_roots, 0, 0
        state[S_FLOOR], state[S_FOUND] = min_score, 0
    floor, n_found = state[S_FLOOR], state[S_FOUND]
    r, depth = state[S_ROOT], state[S_DEPTH]
    while r < n_roots:
        if depth == 0:  # the next root
            if roots[r, C_SCORE] < floor:
                break  # sorted: no later root reaches the floor either
            for c in range(5):
                stack[0, c] = roots[r, c]
            depth = 1
        while depth > 0:
            if scored >= limit:
                state[S_ROOT], state[S_DEPTH], state[S_FLOOR] = r, depth, floor
                state[S_FOUND], state[S_SCORED] = n_found, scored
                return n_found, scored, False
            depth -= 1
            s = stack[depth, C_SCORE]
            if s < floor:
                continue
            h, a = stack[depth, C_LEVEL], stack[depth, C_HEADING]
            i, j = stack[depth, C_ROW], stack[depth, C_COL]
            if h == 0:
                if free[0, i, j]:
                    n_found = _keep(found, n_found, cell_radius, heading_radius, n_headings,
                                    s, a, i, j)
                    floor = max(floor, int(math.ceil(ratio * found[0, 0])))
                    if n_found == found.shape[0]:
                        # full: a pose must beat the last row to change anything (_keep)
                        floor = max(floor, found[n_found - 1, 0] + 1)
                continue
            # the four (or, with the heading group halved, eight) children, pushed worst first
            # so that the best is popped next; a heading's four are scored together
            half = 1 << (h - 1)
            cg = groups[h - 1]
            base = depth
            right, up = j + half < nx, i + half < ny
            on0 = free[h - 1, i, j] != 0
            on1 = right and free[h - 1, i, j + half] != 0
            on2 = up and free[h - 1, i + half, j] != 0
            on3 = right and up and free[h - 1, i + half, j + half] != 0
            for ca in range(groups[h] // cg):
                aa = a + ca * cg
                if aa >= n_headings:
                    continue
                scored += on0 + on1 + on2 + on3
                s0, s1, s2, s3 = _score_children(bounds, h - 1, shifts[h - 1], offsets, extent,
                                                 aa + cg // 2, n_points, i, j, half, floor,
                                                 on0, on1, on2, on3)
                # (in the order one at a time took them: a tie goes above the one before)
                if s0 >= floor:
                    depth = _push(stack, base, depth, s0, h - 1, aa, i, j)
                if s1 >= floor:
                    depth = _push(stack, base, depth, s1, h - 1, aa, i, j + half)
                if s2 >= floor:
                    depth = _push(stack, base, depth, s2, h - 1, aa, i + half, j)
                if s3 >= floor:
                    depth = _push(stack, base, depth, s3, h - 1, aa, i + half, j + half)
        r += 1
    floor = max(min_score, int(math.ceil(ratio * found[0, 0]))) if n_found else min_score
    while n_found > 0 and found[n_found - 1, 0] < floor:  # rivals the best outgrew
        n_found -= 1
    state[S_PHASE], state[S_FOUND], state[S_SCORED] = 3, n_found, scored
    return n_found, scored, True


@njit(cache=True)
def refine_candidates(hits, free, offsets, n_points, n_headings, candidates, n_candidates,
                      cell_radius, heading_radius, window_cells, window_headings, max_moves,
                      min_score, ratio, found, first=0, n_found=0, finish=True):
    """The best pose of each candidate's window on the (fine) hit grid — every cell within
    ``window_cells`` and heading within ``window_headings`` steps of the candidate (rows of
    ``candidates``: heading, row, column on this grid); a best on the window's edge moves the
    window there, up to ``max_moves`` times, so that the answer is a local best of the grid.
    Kept as :func:`branch_and_bound` keeps its leaves: merged with a kept pose of the same
    place, the distinct ones scoring at least ``ratio`` of the best in ``found``, best first.
    Returns ``(how many, poses scored)``. ``hits`` is a one-level stack (``bounds[:1]``).

    Sliced: candidates ``first`` to ``n_candidates`` join the ``n_found`` rows ``found`` holds;
    the rivals the best outgrew are dropped once ``finish``."""
    ny, nx = hits.shape[1], hits.shape[2]
    scored = 0
    for c in range(first, n_candidates):
        ca, ci, cj = candidates[c, 0], candidates[c, 1], candidates[c, 2]
        best, ba, bi, bj = -1, 0, 0, 0
        for _ in range(max_moves + 1):
            edge = False
            for t in range(-window_headings, window_headings + 1):
                a = (ca + t) % n_headings
                for i in range(max(ci - window_cells, 0), min(ci + window_cells + 1, ny)):
                    for j in range(max(cj - window_cells, 0), min(cj + window_cells + 1, nx)):
                        if free[0, i, j] == 0:
                            continue
                        s = _score(hits, 0, 0, offsets, a, n_points, i, j, best + 1)
                        scored += 1
                        if s > best:
                            best, ba, bi, bj = s, a, i, j
                            edge = (abs(t) == window_headings or abs(i - ci) == window_cells
                                    or abs(j - cj) == window_cells)
            if not edge:
                break
            ca, ci, cj = ba, bi, bj
        if best >= min_score:
            n_found = _keep(found, n_found, cell_radius, heading_radius, n_headings, best, ba,
                            bi, bj)
    if n_found and finish:
        floor = max(min_score, int(math.ceil(ratio * found[0, 0])))
        while found[n_found - 1, 0] < floor:
            n_found -= 1
    return n_found, scored


@njit(cache=True)
def select_query(scan, n, max_range, spacing, max_points, out):
    """The query's points: within ``max_range``, at least ``spacing`` apart along the scan,
    at most ``max_points`` of them (thinned evenly). Returns how many."""
    kept = 0
    lx, ly = np.inf, np.inf
    sp2 = spacing * spacing
    r2 = max_range * max_range
    for k in range(n):
        x, y = scan[k, 0], scan[k, 1]
        if x * x + y * y > r2:
            continue
        if (x - lx) ** 2 + (y - ly) ** 2 < sp2:
            continue
        out[kept, 0], out[kept, 1] = x, y
        lx, ly = x, y
        kept += 1
        if kept == out.shape[0]:
            break
    if kept <= max_points:
        return kept
    for k in range(max_points):  # evenly thinned, in place (k ≤ source index)
        src = (k * kept) // max_points
        out[k, 0], out[k, 1] = out[src, 0], out[src, 1]
    return max_points


def heading_step(resolution: float, reach: float) -> float:
    """The angle that moves a point ``reach`` away by one cell (Cartographer's choice)."""
    return math.acos(max(1.0 - resolution * resolution / (2.0 * reach * reach), -1.0))


class PlaceMap:
    """A saved map rendered for the global search at one resolution: the hit grid, its bound
    pyramid (``levels`` above it) and where the robot may stand, over the bounding box of the
    node scans. Built once (start-up); read-only afterwards."""

    def __init__(self, poses, nodes: NodeScans, n_nodes: int, config: RelocalizationConfig,
                 max_gap: float, resolution: float, hit_sigma: float, levels: int,
                 heading_levels: int = 0, standable: PlaceMap | None = None):
        """``standable``: a finer map whose standable cells decide this one's — a coarse cell
        is standable if any of its fine cells is, since a coarse cell in a narrow corridor also
        holds wall and would otherwise count as occupied."""
        c = self.config = config
        self.resolution = res = resolution
        self.n_levels = levels + 1
        # headings are searched in groups on the top heading_levels levels (docs/method.md §8)
        first = levels - heading_levels
        self.groups = np.array([1 << max(h - first, 0) for h in range(self.n_levels)], np.int64)
        self.shifts = np.array([bound_shift(int(g)) for g in self.groups], np.int64)
        reach = c.map_range
        points, counts = nodes.points, nodes.counts
        lo, (nx, ny) = self.extent(poses, nodes, n_nodes, c, resolution, hit_sigma,
                                   (1 << levels) + 2 * int(self.shifts[-1]))
        if nx * ny > c.max_cells:
            raise ValueError(f"the map needs {nx}×{ny} cells at {res} m for the global search, "
                             f"more than relocalization.max_cells={c.max_cells}")
        self.origin = lo  # cell (i, j) is the point origin + (j, i)·res
        pyramid = np.zeros((self.n_levels + 1, ny, nx), np.uint8)
        d2 = np.zeros((ny, nx))
        render_hits(points, counts, poses, np.arange(n_nodes), n_nodes, reach, max_gap, lo[0],
                    lo[1], res, hit_sigma, d2, pyramid[0])
        pool_pyramid(pyramid)
        self.bounds = np.zeros((self.n_levels, ny, nx), np.uint8)
        pool_bounds(pyramid, self.shifts, self.bounds)
        # level 0 bounds a single pose: the hit grid itself, unless its heading group is wider
        self.hits = self.bounds[0] if self.shifts[0] == 0 else pyramid[0].copy()
        del pyramid, d2
        # Where the robot may stand: cells the node scans saw through (log-odds below zero).
        self.free = np.zeros((self.n_levels, ny, nx), np.uint8)
        if standable is None:
            logodds = np.zeros((ny, nx), np.float32)
            region = np.zeros((ny, nx), np.uint8)
            for m in range(n_nodes):
                integrate_scan(logodds, region, lo[0], lo[1], res, poses[m], points[m],
                               counts[m], reach)
            self.free[0] = logodds < 0
        else:
            rows, cols = np.nonzero(standable.free[0])
            x, y = standable.position_of(rows, cols)
            self.free[0][self.cell_of(x, y)] = 1
        pool_pyramid(self.free)

    @staticmethod
    def extent(poses, nodes: NodeScans, n_nodes: int, config: RelocalizationConfig,
               resolution: float, hit_sigma: float, pad: int):
        """The grid's origin and ``(columns, rows)``: the node scans' bounding box, widened by
        3σ and ``pad`` cells. A bound's block may start that far before the map and still cover
        part of it: the padding is empty space (docs/method.md §8)."""
        ends = nodes.extent_points(poses, n_nodes, config.map_range)
        lo = ends.min(axis=0) - 3 * hit_sigma - pad * resolution
        hi = ends.max(axis=0) + 3 * hit_sigma + pad * resolution
        return lo, (np.ceil((hi - lo) / resolution).astype(int) + 1).tolist()

    def cell_of(self, x, y):
        """The (row, column) of the cell holding the point (or arrays of them)."""
        res = self.resolution
        row = np.floor((np.asarray(y) - self.origin[1]) / res + 0.5).astype(np.int64)
        col = np.floor((np.asarray(x) - self.origin[0]) / res + 0.5).astype(np.int64)
        return (row, col) if row.ndim else (int(row), int(col))

    @property
    def shape(self) -> tuple[int, int]:
        return self.hits.shape

    def position_of(self, row: int, col: int) -> tuple[float, float]:
        res = self.resolution
        return self.origin[0] + col * res, self.origin[1] + row * res

    def score(self, points, n: int, pose) -> float:
        """The mean hit value (0–1) of ``points[:n]`` (robot frame) placed at ``pose``."""
        if n == 0:
            return 0.0
        world = compose(pose, np.c_[points[:n], np.zeros(n)])
        rows, cols = self.cell_of(world[:, 0], world[:, 1])
        ny, nx = self.shape
        inside = (rows >= 0) & (rows < ny) & (cols >= 0) & (cols < nx)
        return float(self.hits[rows[inside], cols[inside]].sum()) / (HIT_MAX * n)
