"""Global relocalization: a scan's pose in a saved map with no prior, or "ambiguous"
(docs/method.md §8).

    relocalizer = Relocalizer(config, poses, nodes, n_nodes)
    answer = relocalizer.relocalize(scan)        # Located(pose, score) | Ambiguous
    search = relocalizer.begin(scan)             # the same, spread over a runtime's ticks:
    search.advance(clock, budget_end)            # True once search.answer is there

1. search, coarse to fine: an exhaustive branch and bound over every standable cell and
   heading of a coarse hit grid (``coarse_resolution``, blurred by ``COARSE_HIT_SIGMA``) gives
   the best distinct candidates (:func:`swarmslam.runtime.matching.place_search.branch_and_bound`); each is then
   scored at every pose of a small window on the fine grid
   (:func:`swarmslam.runtime.matching.place_search.refine_candidates`). A map of at most ``exact_max_cells``
   fine cells is searched by one exact branch and bound on the fine grid instead;
2. ambiguity: every distinct pose scoring at least ``ambiguity_ratio`` of the best is kept —
   any such rival is a different explanation about as good, and the answer is
   :class:`Ambiguous` (with every such pose, best first);
3. polish: the swarm (Alg. 5) aligns the scan with the nearest node scans in a small box around
   the grid's answer, as loop closure does.

Confirmation (:mod:`swarmslam.runtime.localization.localizer`) tracks the candidates over ``confirm_seconds`` of
scans and searches the newest again. :meth:`Relocalizer.relocalize_merged` merges such scans —
placed by the motion tracked between them — into one query, meant to tell apart what one scan
cannot; measured, it rarely does in corridors (``bench localize``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.matching.place_search import (
    HIT_MAX,
    S_PHASE,
    SEARCH_STATE,
    UNLIMITED,
    PlaceMap,
    branch_and_bound,
    heading_step,
    refine_candidates,
    rotate_query,
    select_query,
)
from swarmslam.runtime.pose import between, compose, wrap_angle
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import ScanMatcher

# The search's internals, fixed (docs/method.md §8). The coarse first pass on a map over
# exact_max_cells: its hit grid's blur (m), its query points at most, the mean hit value (0-1)
# a candidate needs and the share of the pass's best it must score, the candidates refined at
# most (the best distinct ones), and how near (m, rad) two candidates are one.
COARSE_HIT_SIGMA = 0.4
COARSE_POINTS = 24
COARSE_MIN_SCORE = 0.6
COARSE_RATIO = 0.9
COARSE_CANDIDATES = 64
COARSE_DISTINCT_DISTANCE = 0.5
COARSE_DISTINCT_ANGLE = 0.15
REFINE_MOVES = 3  # times a candidate's fine window may move to a best found on its edge
HEADING_LEVELS = 0  # top pyramid levels whose blocks also span 2, 4, … headings (none)
QUERY_SPACING = 0.2  # m: query points at least this far apart along the scan
REFINE_NODES = 5  # nearest node scans the swarm's polish matches against


@dataclass(frozen=True)
class Located:
    """The scan's pose in the map and its score (mean hit value of the query's points, 0–1);
    no distinct pose scored ``ambiguity_ratio`` of it."""

    pose: np.ndarray
    score: float


@dataclass(frozen=True)
class Ambiguous:
    """Distinct poses explaining the scan about equally well (best first), or none at all."""

    poses: tuple
    scores: tuple
    reason: str


class Search:
    """A global search under way (:meth:`Relocalizer.begin`): ``steps``, a generator yielding
    between slices of the search, returns the answer."""

    def __init__(self, steps):
        self._steps = steps
        self.answer = None  # once done: Located | Ambiguous (a list of poses for search())

    def advance(self, clock=None, until: float | None = None) -> bool:
        """Search on: to the end (True; the answer in :attr:`answer`), or — given ``clock`` —
        until it reads ``until`` or later after a slice (False: not done yet)."""
        if self.answer is not None:
            return True
        try:
            while True:
                next(self._steps)
                if clock is not None and until is not None and clock() >= until:
                    return False
        except StopIteration as stop:
            self.answer = stop.value
            return True

    def result(self):
        """The answer, the search gone on with to its end."""
        self.advance()
        return self.answer


def _heading_count(resolution: float, reach: float) -> int:
    return int(math.ceil(2 * math.pi / heading_step(resolution, reach)))


class Relocalizer:
    """The global search over one saved map (read-only): its buffers are allocated here."""

    def __init__(self, config: SlamConfig, poses, nodes: NodeScans, n_nodes: int, seed: int = 0):
        rc = self.config = config.relocalization
        self.poses = poses[:n_nodes]
        self.nodes, self.n_nodes = nodes, n_nodes
        gap = config.matcher.max_gap
        # one exact pass where it is affordable, coarse to fine on a larger map (§8)
        _, (nx, ny) = PlaceMap.extent(poses, nodes, n_nodes, rc, rc.resolution, rc.hit_sigma, 0)
        two = nx * ny > rc.exact_max_cells
        # the answer's grid; with a first pass, only its hit grid is needed (no pyramid)
        self.place = PlaceMap(poses, nodes, n_nodes, rc, gap, rc.resolution, rc.hit_sigma,
                              0 if two else rc.levels, 0 if two else HEADING_LEVELS)
        # the grid the exhaustive branch and bound runs on (docs/method.md §8)
        self.coarse = (PlaceMap(poses, nodes, n_nodes, rc, gap, rc.coarse_resolution,
                                COARSE_HIT_SIGMA, rc.levels, HEADING_LEVELS,
                                standable=self.place)
                       if two else None)
        exhaustive = self.coarse or self.place
        self.n_headings = _heading_count(rc.resolution, rc.query_range)
        n_exhaustive = _heading_count(exhaustive.resolution, rc.query_range)
        ny, nx = exhaustive.shape
        top = 1 << rc.levels
        group = int(exhaustive.groups[-1])
        groups = -(-n_exhaustive // group)
        roots = groups * (-(-ny // top)) * (-(-nx // top))
        self._query = np.zeros((config.sensor.max_points, 2))  # a larger scan gets its own
        # headings past the last (a group's middle may lie there) wrap around the circle
        self._offsets = np.zeros((groups * group if not two else self.n_headings,
                                  rc.query_points, 2), np.int64)
        self._offset_box = np.zeros((len(self._offsets), 4), np.int64)
        self._roots = np.zeros((roots, 5), np.int64)
        self._stack = np.zeros((8 * (rc.levels + 2), 5), np.int64)
        self._state = np.zeros(SEARCH_STATE, np.int64)
        self._found = np.zeros((rc.max_hypotheses, 4), np.int64)
        if two:  # the first pass's query, offsets, candidates
            self._coarse_query = np.zeros((rc.query_points, 2))
            self._coarse_offsets = np.zeros((groups * group, COARSE_POINTS, 2), np.int64)
            self._coarse_offset_box = np.zeros((groups * group, 4), np.int64)
            self._coarse_found = np.zeros((COARSE_CANDIDATES, 4), np.int64)
            self._candidates = np.zeros((COARSE_CANDIDATES, 3), np.int64)
        self.cell_radius = int(math.ceil(rc.distinct_distance / rc.resolution))
        self.matcher = ScanMatcher(replace(config.matcher, guess_window=rc.refine_window,
                                           predict_first=0.0),
                                   seed=seed)
        self.reference = self.matcher.new_reference()
        self._submap = PointScan(config.sensor.max_points * REFINE_NODES)
        self.blocks_scored = 0  # by the last search (blocks and refined poses)

    # ------------------------------------------------------------------ the answer
    def relocalize(self, scan: PointScan) -> Located | Ambiguous:
        """Where ``scan`` (robot frame) was taken in the map, or :class:`Ambiguous`."""
        return self.begin(scan, sliced=False).result()

    def begin(self, scan: PointScan, sliced: bool = True) -> Search:
        """The search for ``scan``, to be gone on with by :meth:`Search.advance` — sliced,
        ``slice_blocks`` branch-and-bound blocks at a time, so that a runtime can spread it
        over ticks; it answers as :meth:`relocalize` does. ``scan`` must stay as it is until
        the answer, and one search at a time shares this relocalizer's buffers."""
        return Search(self._answer(scan, self.config.slice_blocks if sliced else UNLIMITED))

    def relocalize_merged(self, scans, motions) -> Located | Ambiguous:
        """Confirmation: ``scans`` (robot frames) merged into the last one's frame by
        ``motions`` (each scan's pose in the last scan's frame), relocalized as one query."""
        merged = PointScan(sum(s.count for s in scans))
        n = 0
        for s, m in zip(scans, motions):
            pts = compose(np.asarray(m, np.float64), np.c_[s.points, np.zeros(s.count)])
            merged.buffer[n : n + s.count] = pts[:, :2]
            n += s.count
        merged.count = n
        return self.relocalize(merged)

    def _answer(self, scan: PointScan, budget: int):
        """The search as a generator: it yields between slices and returns the answer."""
        rc = self.config
        query = self._query if scan.count <= len(self._query) else np.zeros((scan.count, 2))
        n = select_query(scan.buffer, scan.count, rc.query_range, QUERY_SPACING,
                         rc.query_points, query)
        if n < 3:
            return Ambiguous((), (), f"only {n} usable points within {rc.query_range} m")
        found = yield from self._search(query, n, budget)
        if not found:
            return Ambiguous((), (), "no pose explains the scan (every score below min_score)")
        if len(found) > 1:
            return Ambiguous(tuple(p for p, _ in found), tuple(s for _, s in found),
                             f"{len(found)} distinct poses score within "
                             f"{rc.ambiguity_ratio:.0%} of the best")
        pose, score = found[0]
        polished = self.polish(scan, pose)
        if self.place.score(query, n, polished) >= score:
            pose = polished
        return Located(pose, score)

    # ------------------------------------------------------------------ steps
    def search(self, query, n: int) -> list[tuple[np.ndarray, float]]:
        """The best pose and every distinct pose scoring ``ambiguity_ratio`` of it (at most
        ``max_hypotheses``), as ``(pose, mean hit value)``, best first."""
        return Search(self._search(query, n, UNLIMITED)).result()

    def _search(self, query, n: int, budget: int):
        """:meth:`search` as a generator: it yields between slices of ``budget`` blocks of the
        branch and bound."""
        rc = self.config
        n_headings, step = self._rotate(query, n, self.place, self._offsets, self._offset_box)
        full = HIT_MAX * n
        min_score = int(math.ceil(rc.min_score * full))
        heading_radius = int(math.ceil(rc.distinct_angle / step))
        if self.coarse is None:  # one exhaustive pass
            n_found, self.blocks_scored = yield from self._branch_and_bound(
                budget, self.place.bounds, self.place.shifts, self.place.groups,
                self.place.free, self._offsets, self._offset_box, n, n_headings, min_score,
                rc.ambiguity_ratio, self.cell_radius, heading_radius, self._roots, self._stack,
                self._found)
        else:
            n_candidates, blocks = yield from self._coarse_pass(query, n, budget)
            # each candidate's cell and heading on the fine grid; its window spans one coarse
            # cell and heading step around it, and one fine one more
            coarse = self.coarse
            cells = coarse.resolution / self.place.resolution
            for k in range(n_candidates):
                _, a, row, col = self._coarse_found[k]
                x, y = coarse.position_of(int(row), int(col))
                self._candidates[k, 0] = int(round(a * self._coarse_step / step)) % n_headings
                self._candidates[k, 1:] = self.place.cell_of(x, y)
            # sliced, one candidate at a time (each scores a few thousand poses)
            chunk = max(n_candidates, 1) if budget == UNLIMITED else 1
            n_found, poses = 0, 0
            for first in range(0, n_candidates, chunk):
                last = min(first + chunk, n_candidates)
                n_found, scored = refine_candidates(
                    self.place.bounds, self.place.free, self._offsets, n, n_headings,
                    self._candidates, last, self.cell_radius, heading_radius,
                    int(math.ceil(cells)) + 1, int(math.ceil(self._coarse_step / step)) + 1,
                    REFINE_MOVES, min_score, rc.ambiguity_ratio, self._found, first,
                    n_found, last == n_candidates)
                poses += scored
                if last < n_candidates:
                    yield
            self.blocks_scored = blocks + poses
        found = []
        for score, a, row, col in self._found[:n_found]:
            x, y = self.place.position_of(int(row), int(col))
            found.append((np.array([x, y, wrap_angle(int(a) * step)]), score / full))
        return found

    def _coarse_pass(self, query, n: int, budget: int = UNLIMITED):
        """The first pass: branch and bound on the coarse grid with the query thinned to
        ``COARSE_POINTS``; its best distinct poses (at most ``COARSE_CANDIDATES``, scoring at
        least ``COARSE_RATIO`` of the best) are the candidates. A generator, as
        :meth:`search`; returns ``(how many, blocks scored)``."""
        rc, coarse = self.config, self.coarse
        m = select_query(query, n, math.inf, 0.0, COARSE_POINTS, self._coarse_query)
        n_headings, self._coarse_step = self._rotate(
            self._coarse_query, m, coarse, self._coarse_offsets, self._coarse_offset_box)
        return (yield from self._branch_and_bound(
            budget, coarse.bounds, coarse.shifts, coarse.groups, coarse.free,
            self._coarse_offsets, self._coarse_offset_box, m, n_headings,
            int(math.ceil(COARSE_MIN_SCORE * HIT_MAX * m)),
            COARSE_RATIO, int(math.ceil(COARSE_DISTINCT_DISTANCE / coarse.resolution)),
            int(math.ceil(COARSE_DISTINCT_ANGLE / self._coarse_step)), self._roots,
            self._stack, self._coarse_found))

    def _branch_and_bound(self, budget: int, *args):
        """:func:`swarmslam.runtime.matching.place_search.branch_and_bound` over ``args`` begun afresh, as a
        generator yielding between slices of ``budget`` blocks; returns ``(how many, blocks
        scored)``."""
        self._state[S_PHASE] = 0
        while True:
            n_found, scored, done = branch_and_bound(*args, self._state, budget)
            if done:
                return n_found, scored
            yield

    def _rotate(self, query, n: int, place: PlaceMap, offsets, box) -> tuple[int, float]:
        """The query's cell offsets at each heading of ``place``'s grid (and each heading's
        box of them, into ``box``); the heading step moves the query's farthest point by
        one cell (fewer steps for a scan of a small room than the allocation's
        ``query_range`` allows). Returns ``(headings, step)``."""
        res = place.resolution
        reach = max(float(np.max(np.hypot(query[:n, 0], query[:n, 1]))), res)
        n_headings = min(_heading_count(res, reach), _heading_count(res, self.config.query_range))
        step = 2 * math.pi / n_headings
        rotate_query(query, n, res, step, offsets.shape[0], offsets, box)
        return n_headings, step

    def polish(self, scan: PointScan, pose) -> np.ndarray:
        """The swarm's alignment of ``scan`` with the nearest node scans, in a small box around
        ``pose`` (the grid's answer)."""
        rc = self.config
        d2 = np.sum((self.poses[:, :2] - pose[:2]) ** 2, axis=1)
        near = np.argsort(d2, kind="stable")[: REFINE_NODES]
        anchor = int(near[0])
        submap = self.nodes.place(self.poses, sorted(int(k) for k in near), anchor, self._submap)
        reference = self.matcher.build_reference(submap, self.reference)
        guess = between(pose, self.poses[anchor])
        match = self.matcher.align_scans(scan, reference, guess)
        return compose(self.poses[anchor], match.pose)
