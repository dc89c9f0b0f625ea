"""The wide loop search (docs/method.md §5, "after a long drift"): where, within metres of the
graph's estimate, does a new node's scan fit the map of the old nodes?

After a long stretch with no closure the graph's estimate of a node returning to mapped ground
may be many metres off — farther than the loop match's box (``search_window``) and the
candidate radius reach (metres after a long loop). The ordinary search then finds
nothing, or matches the scan to the wrong corridor nearby. Here the scans of the *old* nodes
(more than ``wide_search.min_gap`` nodes back, within reach of the estimate) are rendered into a hit
grid centred on the estimate, and an exhaustive branch and bound (the relocalization's,
:func:`swarmslam.runtime.matching.place_search.branch_and_bound`) scores the node's scan at every position within
the window and every heading within ``wide_search.angle`` of it. The window's half-width grows with
the path since the last closure with the old map (``wide_search.drift`` of it, from ``wide_search.radius``
up to ``wide_search.max_radius``), and so do the headings (``wide_search.turn_drift`` of it, from
``wide_search.angle`` up to ``wide_search.max_angle``): the farther the robot went unanchored, the farther
it may have drifted and turned. The best pose is a *proposal* only if

* it scores at least ``wide_search.min_score`` (mean hit value),
* no distinct pose (farther than ``DISTINCT_DISTANCE``) scores ``RIVAL_RATIO`` of it — in a
  corridor every position along it fits, and a closure there would be a guess,
* it lies inside the window, not on its edge (the optimum could lie beyond),
* a search whose query shares no scan with this one (of a node ``wide_search.query_nodes`` to twice
  that many back) found the same correction of the graph (the best pose less the
  estimate) within ``AGREEMENT``: two separate looks agree on where the robot is.

A search that fits the scan nowhere (new ground) spares the next ``wide_search.spacing`` − 1 nodes
their wide search (the back end's rule, ``fitted`` says it).

The proposal then goes through the rest of the loop closure — the swarm's alignment against
the old nodes nearest to it, the consistency test after optimising. The submap tests of the
ordinary search (inliers, visibility) are not applied: a scan returning from a long drift
often sees mapped ground only in part, and the search scored it against the whole old map.

Every buffer is allocated here, sized by the configuration: a search allocates nothing.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.config import LoopClosureConfig
from swarmslam.runtime.back_end.loop_closure import nearby_nodes
from swarmslam.runtime.matching.place_search import (
    HIT_MAX,
    S_PHASE,
    SEARCH_STATE,
    UNLIMITED,
    branch_and_bound,
    clear_distances,
    heading_step,
    hits_from_distances,
    pool_bound_level,
    pool_level,
    rotate_query,
    select_query,
    splat_scans,
)
from swarmslam.runtime.pose import between_nb, compose_nb, wrap_angle_nb

# The search's internals, fixed: its scores and pyramid as measured (docs/method.md §5, step 5).
HIT_SIGMA = 0.2  # m: a point this far from a surface scores e^(-1/2)
# m: a run of a node scan's joined points is drawn as one segment while it passes this near
# every point it skips (0 would draw one segment per pair of points)
SURFACE_TOLERANCE = 0.04
LEVELS = 6  # pyramid levels above the hit grid (blocks of 2^LEVELS cells)
QUERY_RANGE = 12.0  # m: the query's points farther from the node are not used (sets the step)
QUERY_POINTS = 128  # query points at most (thinned evenly)
# A distinct pose (farther than DISTINCT_DISTANCE m) scoring RIVAL_RATIO of the best makes the
# search refuse: in a corridor or a repeated room every such pose fits.
RIVAL_RATIO = 0.9
DISTINCT_DISTANCE = 1.0
# m, rad: a proposal needs a search sharing no scan with its own to have found the same
# correction of the graph within these
AGREEMENT = (0.5, 0.05)
WIDE_REFINE_WINDOW = (0.3, 0.3, 0.05)  # half-widths of the swarm's alignment around a proposal
from swarmslam.runtime.matching.scan import PointScan


@njit(cache=True)
def nodes_within(poses, n_nodes, x, y, radius, out):
    """Indices of nodes ``< n_nodes`` within ``radius`` of ``(x, y)``, in index order."""
    count = 0
    r2 = radius * radius
    for k in range(n_nodes):
        dx, dy = poses[k, 0] - x, poses[k, 1] - y
        if dx * dx + dy * dy <= r2:
            out[count] = k
            count += 1
    return count


@njit(cache=True)
def path_length(poses, first, last):
    """The length of the chain of node positions from ``first`` to ``last``."""
    total = 0.0
    for k in range(first, last):
        total += math.hypot(poses[k + 1, 0] - poses[k, 0], poses[k + 1, 1] - poses[k, 1])
    return total


@njit(cache=True)
def turn_points(points, n, angle, out):
    """``points[:n]`` turned by ``angle`` about the origin, into ``out``."""
    c, s = math.cos(angle), math.sin(angle)
    for k in range(n):
        x, y = points[k, 0], points[k, 1]
        out[k, 0] = c * x - s * y
        out[k, 1] = s * x + c * y


@njit(cache=True)
def open_window(free, half, cells, first, last):
    """Rows ``first:last`` of every level of ``free``: level 0 is 1 on the ``(2·cells + 1)²``
    positions centred on cell ``(half, half)`` and 0 elsewhere; level ``h`` at ``(i, j)`` is 1
    where the ``2ʰ × 2ʰ`` block starting there meets the window (what pooling level 0 gives,
    the window lying inside the grid)."""
    nx = free.shape[2]
    low, high = half - cells, half + cells
    for h in range(free.shape[0]):
        w = (1 << h) - 1
        for i in range(first, last):
            row = i <= high and i + w >= low
            for j in range(nx):
                free[h, i, j] = 1 if row and j <= high and j + w >= low else 0


@njit(cache=True)
def nearest_node(poses, index, n, x, y):
    """The node of ``index[:n]`` nearest to ``(x, y)``."""
    best, best_d2 = -1, np.inf
    for e in range(n):
        k = index[e]
        d2 = (poses[k, 0] - x) ** 2 + (poses[k, 1] - y) ** 2
        if d2 < best_d2:
            best, best_d2 = k, d2
    return best


def _in_parts(n, rows, kernel, *args):
    """``kernel(*args, first, last)`` over rows ``0:n``, ``rows`` at a time, yielding after
    each part (a slice of the wide search)."""
    for first in range(0, n, rows):
        kernel(*args, first, min(first + rows, n))
        yield


class WideLoopSearch:
    """The search's grid, pyramid and query buffers (fixed at construction) and its counts."""

    def __init__(self, config: LoopClosureConfig, max_nodes: int, max_points: int,
                 max_gap: float):
        c = self.config = config
        self.max_gap = max_gap
        levels = LEVELS
        # Buffers for the widest window; each search works on the leading part its own
        # window needs, viewed as grids of that size (_use).
        self.widest = max(c.wide_search.radius, c.wide_search.max_radius)
        _, n = self._extent(self.widest)
        self._pyramid_buffer = np.zeros((levels + 2) * n * n, np.uint8)
        self._d2_buffer = np.zeros(n * n)
        self._columns = np.zeros(n)  # a d2 row's node x (place_search.splat_scans)
        self._bounds_buffer = np.zeros((levels + 1) * n * n, np.uint8)
        self._free_buffer = np.zeros((levels + 1) * n * n, np.uint8)
        self._n = 0
        self._use(c.wide_search.radius)
        self.groups = np.ones(levels + 1, np.int64)  # one heading per block at every level
        self.shifts = np.zeros(levels + 1, np.int64)
        res = c.wide_search.resolution
        self.step = heading_step(res, QUERY_RANGE)
        self.widest_angle = max(c.wide_search.angle, c.wide_search.max_angle)
        most = self._headings(self.widest_angle)
        self.n_headings = self._headings(c.wide_search.angle)  # the search under way's
        self._query = np.zeros((max_points, 2))
        self._recent = PointScan(max_points * c.wide_search.query_nodes)
        self._turned = np.zeros((QUERY_POINTS, 2))
        self._offsets = np.zeros((most, QUERY_POINTS, 2), np.int64)
        self._offset_box = np.zeros((most, 4), np.int64)
        self._roots = np.zeros((most * (-(-n // (1 << levels))) ** 2, 5), np.int64)
        self._stack = np.zeros((8 * (levels + 2), 5), np.int64)
        self._search_state = np.zeros(SEARCH_STATE, np.int64)
        self._found = np.zeros((2, 4), np.int64)  # the best and one rival are all we need
        self._index = np.zeros(max_nodes, np.int64)
        self._member_d2 = np.zeros(2 * c.submap_nodes + 1)
        self.cell_radius = int(math.ceil(DISTINCT_DISTANCE / res))
        self.searches = 0  # searches run (old nodes within reach)
        self.fitted = 0  # distinct poses (0-2) the last search found scoring wide_search.min_score
        self.proposed = 0  # proposals made
        self.ambiguous = 0  # refused: a distinct pose scored nearly as well
        self.at_edge = 0  # refused: the best lay on the window's edge
        self.disagreed = 0  # refused: no earlier, separate search found the same correction
        # the last unique bests: their nodes (-1: none) and the corrections they found, kept
        # for as far back as a disjoint query's search may lie (2 × wide_search.query_nodes)
        self.recent_nodes = np.full(2 * c.wide_search.query_nodes, -1, np.int64)
        self.recent_corrections = np.zeros((2 * c.wide_search.query_nodes, 3))
        self._next = 0  # the slot the next unique best goes to
        self._z = np.zeros(3)  # the proposal's relative pose

    def _extent(self, radius: float) -> tuple[int, int]:
        """The grid a window of ``radius`` needs: its centre cell and side. It holds the
        window, the query's reach beyond it and the hit blur, plus one top block so that a root
        block starting before the window still lies on the grid."""
        c = self.config
        reach = radius + QUERY_RANGE + 3.0 * HIT_SIGMA
        half = int(math.ceil(reach / c.wide_search.resolution)) + (1 << LEVELS)
        return half, 2 * half + 1

    def _use(self, radius: float) -> None:
        """Work on a window of ``radius``: views of the leading part of each buffer."""
        c = self.config
        self.cells = int(math.floor(radius / c.wide_search.resolution))
        half, n = self._extent(radius)
        if n == self._n:
            return
        self.half, self._n = half, n
        levels = LEVELS
        self._pyramid = self._pyramid_buffer[: (levels + 2) * n * n].reshape(levels + 2, n, n)
        self._d2 = self._d2_buffer[: n * n].reshape(n, n)
        self.bounds = self._bounds_buffer[: (levels + 1) * n * n].reshape(levels + 1, n, n)
        self.free = self._free_buffer[: (levels + 1) * n * n].reshape(levels + 1, n, n)

    def _headings(self, angle: float) -> int:
        """Headings searched for ``angle`` either side of the estimate's."""
        return 2 * int(math.ceil(angle / self.step)) + 1

    def angle(self, poses, since: int, node: int) -> float:
        """The headings searched either side of ``node``'s estimate: ``wide_search.turn_drift`` of the
        path since node ``since``, within ``wide_search.angle`` and ``wide_search.max_angle`` — a long loop
        turns the heading's estimate as it moves its position."""
        c = self.config
        wanted = c.wide_search.turn_drift * path_length(poses, since, node)
        return min(max(c.wide_search.angle, wanted), self.widest_angle)

    def radius(self, poses, since: int, node: int) -> float:
        """The window's half-width for ``node``: ``wide_search.drift`` of the path the graph travelled
        since node ``since`` (the last closure with the old map), within ``wide_search.radius`` and
        ``wide_search.max_radius``. The farther the robot went unanchored, the farther its estimate
        may have drifted."""
        c = self.config
        wanted = c.wide_search.drift * path_length(poses, since, node)
        return min(max(c.wide_search.radius, wanted), self.widest)

    def propose(self, poses, nodes, node: int, since: int = 0):
        """``(anchor, z)``: the old node nearest to where ``node``'s scan fits, and ``node``'s
        pose in that node's frame — or None (no old node within reach, no pose scoring
        ``wide_search.min_score``, a rival, the best on the window's edge, or no earlier, separate
        search finding the same correction). ``since``: the last node closed with the old
        map, from which the window's drift is reckoned (:meth:`radius`)."""
        steps = self.search(poses, nodes, node, since)
        while True:
            try:
                next(steps)
            except StopIteration as stop:
                return stop.value

    def search(self, poses, nodes, node: int, since: int = 0, sliced: bool = False):
        """:meth:`propose` as a generator that yields between slices and returns the proposal.
        ``sliced``: each slice renders or pools about ``wide_search.slice_cells`` cells, splats
        ``wide_search.slice_nodes`` node scans or scores ``wide_search.slice_blocks`` branch-and-bound blocks,
        so that the fixed-rate runtime can spread a search over ticks (docs/runtime.md §3);
        otherwise each pass is one slice. Either way the proposal is the same. ``poses`` and
        the nodes' scans must stay as they are until it returns."""
        c = self.config
        res = c.wide_search.resolution
        self.fitted = 0
        old = node - c.wide_search.min_gap
        if old <= 0:
            return None
        radius = self.radius(poses, since, node)
        x, y, t = float(poses[node, 0]), float(poses[node, 1]), float(poses[node, 2])
        n_old = nodes_within(poses, old, x, y, radius + QUERY_RANGE, self._index)
        # the query: the node's scan and its predecessors' placed by the graph, a stretch of
        # path whose extent tells one corridor from another where one scan cannot
        recent = nodes.place(poses, range(max(node - c.wide_search.query_nodes + 1, 0), node + 1),
                             node, self._recent)
        n_query = select_query(recent.buffer, recent.count, QUERY_RANGE, res,
                               QUERY_POINTS, self._query)
        if n_old == 0 or n_query < 3:
            return None
        self._use(radius)
        angle = self.angle(poses, since, node)
        self.n_headings = self._headings(angle)
        half, n, sigma = self.half, self._n, HIT_SIGMA
        rows = max(c.wide_search.slice_cells // n, 1) if sliced else n
        ox, oy = x - half * res, y - half * res  # the estimate is cell (half, half)
        # the old nodes' hit grid, its pyramid and the bounds on it, the window's levels
        yield from _in_parts(n, rows, clear_distances, self._d2, sigma)
        per_slice = c.wide_search.slice_nodes if sliced else n_old
        for first in range(0, n_old, per_slice):
            splat_scans(nodes.points, nodes.counts, poses, self._index, first,
                        min(first + per_slice, n_old), QUERY_RANGE + radius,
                        self.max_gap, ox, oy, res, sigma, self._d2, self._columns,
                        SURFACE_TOLERANCE)
            yield
        yield from _in_parts(n, rows, hits_from_distances, self._d2, sigma, self._pyramid[0])
        for h in range(1, self._pyramid.shape[0]):
            yield from _in_parts(n, rows, pool_level, self._pyramid, h)
        for h in range(self.bounds.shape[0]):
            yield from _in_parts(n, rows, pool_bound_level, self._pyramid, self.shifts,
                                 self.bounds, h)
        yield from _in_parts(n, rows, open_window, self.free, half, self.cells)
        start = t - angle  # heading a is start + a·step
        turn_points(self._query, n_query, start, self._turned)
        rotate_query(self._turned, n_query, res, self.step, self.n_headings, self._offsets,
                     self._offset_box)
        min_score = int(math.ceil(c.wide_search.min_score * HIT_MAX * n_query))
        self._search_state[S_PHASE] = 0
        while True:
            n_found, _, done = branch_and_bound(
                self.bounds, self.shifts, self.groups, self.free, self._offsets,
                self._offset_box, n_query, self.n_headings, min_score, RIVAL_RATIO,
                self.cell_radius, self.n_headings, self._roots, self._stack, self._found,
                self._search_state, c.wide_search.slice_blocks if sliced else UNLIMITED)
            if done:
                break
            yield
        self.searches += 1
        self.fitted = n_found
        if n_found == 0:
            return None
        if n_found > 1:
            self.ambiguous += 1
            return None
        _, a, i, j = (int(v) for v in self._found[0])
        if (a in (0, self.n_headings - 1) or abs(i - half) >= self.cells
                or abs(j - half) >= self.cells):
            self.at_edge += 1
            return None
        bx, by, bt = ox + j * res, oy + i * res, start + a * self.step
        agrees = self._agrees(node, x, y, t, bx, by, bt)
        # the correction C with C ⊕ estimate = best: best ⊕ estimate⁻¹
        k = self._next
        self.recent_nodes[k] = node
        self.recent_corrections[k] = compose_nb(bx, by, bt, *between_nb(0.0, 0.0, 0.0, x, y, t))
        self._next = (k + 1) % len(self.recent_nodes)
        if not agrees:
            self.disagreed += 1
            return None
        anchor = nearest_node(poses, self._index, n_old, bx, by)
        self.proposed += 1
        self._z[:] = between_nb(bx, by, bt, poses[anchor, 0], poses[anchor, 1], poses[anchor, 2])
        return anchor, self._z

    def _agrees(self, node, x, y, t, bx, by, bt) -> bool:
        """Whether a search whose query shares no scan with ``node``'s — of a node
        ``wide_search.query_nodes`` to twice that many back — found a correction that puts the
        estimate ``(x, y, t)`` within ``AGREEMENT`` of the best ``(bx, by, bt)``: two
        separate looks agree on where the robot is."""
        q = self.config.wide_search.query_nodes
        distance, angle = AGREEMENT
        for k in range(len(self.recent_nodes)):
            if not node - 2 * q <= self.recent_nodes[k] <= node - q:
                continue
            px, py, pt = compose_nb(*self.recent_corrections[k], x, y, t)
            if math.hypot(px - bx, py - by) <= distance and abs(wrap_angle_nb(pt - bt)) <= angle:
                return True
        return False

    def members(self, poses, node: int, anchor: int, z, out) -> int:
        """The old nodes (as many as ``out`` holds) nearest to where ``z`` in ``anchor``'s
        frame puts ``node``, nearest first: the submap a proposal is aligned with. Returns how
        many."""
        c = math.cos(poses[anchor, 2])
        s = math.sin(poses[anchor, 2])
        x = poses[anchor, 0] + c * z[0] - s * z[1]
        y = poses[anchor, 1] + s * z[0] + c * z[1]
        reach = self.config.wide_search.radius + QUERY_RANGE
        return nearby_nodes(poses, node, x, y, reach, node - self.config.wide_search.min_gap, out,
                            self._member_d2[: out.shape[0]])

    def counts(self) -> dict:
        """The searches run and how they ended, by name (a run's report)."""
        return {"searched": self.searches, "proposed": self.proposed,
                "ambiguous": self.ambiguous, "at_edge": self.at_edge,
                "disagreed": self.disagreed}

    def state(self) -> dict:
        return {"counts": np.array(list(self.counts().values()), np.int64),
                "recent_nodes": self.recent_nodes.copy(),
                "recent_corrections": self.recent_corrections.copy(), "next": self._next}

    def restore(self, state: dict) -> None:
        (self.searches, self.proposed, self.ambiguous, self.at_edge,
         self.disagreed) = (int(v) for v in state["counts"])
        nodes, corrections = state["recent_nodes"], state["recent_corrections"]
        if (nodes.shape != self.recent_nodes.shape
                or corrections.shape != self.recent_corrections.shape
                or np.any(nodes < -1) or not np.all(np.isfinite(corrections))
                or not 0 <= int(state["next"]) < len(nodes)):
            raise ValueError("the wide loop search's recent corrections are not ones it makes "
                             "(another wide_search.query_nodes?)")
        self.recent_nodes[:], self.recent_corrections[:] = nodes, corrections
        self._next = int(state["next"])
