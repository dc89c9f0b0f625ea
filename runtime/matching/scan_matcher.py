"""Scan matching by swarm optimisation: ``align_scans`` (Alg. 5, docs/method.md §3).

    reference = matcher.build_reference(previous_scan)      # distance field + local grid
    result = matcher.align_scans(scan, reference, guess)    # ΔP, λ, which objective won

1. scan-to-scan: minimise Eq. 14 over the search box with the configured swarm;
2. if λ exceeds the rejection threshold ``μλ + σλ``, fall back to scan-to-map (Eq. 16) on the
   reference's local occupancy grid, and recompute λ there with Eq. 14 so the two compare;
3. update the running threshold with λ.

The whole of one alignment runs in one compiled call on buffers allocated at construction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from swarmslam.runtime.config import MIN_HEADING_STEP, MatcherConfig
from swarmslam.runtime.matching.distance_field import (N_META, N_SURFACE, SPAN_ROWS,
                                               build_distance_field,
                                               list_surfaces)
from swarmslam.runtime.matching.local_map import build_local_map, robot_square
from swarmslam.runtime.matching.objectives import (
    KERNELS,
    cost_hessian,
    inlier_fraction,
    scan_to_map_cost,
    scan_to_scan_error,
    surface_inliers,
)
from swarmslam.runtime.matching.optimizers import SwarmOptimizer, ask, start, tell
from swarmslam.runtime.matching.optimizers.workspace import BEST_VAL, EVALUATIONS, ITERATION, reset_run
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.threshold import RejectionThreshold

# Layout of the ``settings`` array handed to the compiled kernel.
(
    S_KERNEL,
    S_INV_C2,
    S_HALF,
    S_USE_MAP,
    S_MAX_IT,
    S_STAG_IT,
    S_STAG_TOL,
    S_TARGET,
    S_MAX_EVALS,
    S_STRIDE,
    S_REFINE_EVALS,
    S_REFINE_X,
    S_REFINE_Y,
    S_REFINE_T,
    S_COARSE,
    S_PREDICT,
    S_POLISH_XY,
    S_POLISH_T,
    S_POLISH_HALVINGS,
    S_POLISH_EVALS,
    S_GLOBAL_POINTS,
    S_REFINE_POINTS,
    S_STALL_IT,
    S_STALL_TOL,
) = range(24)
N_SETTINGS = 24
# Layout of the ``out`` array it fills.
R_X, R_Y, R_T, R_LAMBDA, R_USED_MAP, R_ITERATIONS, R_EVALUATIONS, R_LAMBDA_SCAN = range(8)
N_OUT = 8

# The matcher's internals, fixed (docs/method.md §3):
# farther neighbours that continue their line (surface_bend) form a surface only while their
# gap is at most this many times the shorter pair's: one surface sampled evenly, not a
# doorway's two sides
SURFACE_GAP_RATIO = 2.0
COARSE_RADIUS = 0.6  # m, truncation of the global stage's coarse field
# The compass search that settles the swarm's match on the fine field: its first steps (m,
# rad), halved this many times before it ends.
POLISH_STEP = (0.01, 0.005)
POLISH_HALVINGS = 6
OCCUPIED_RADIUS = 0.1  # m, ramp around obstacles in the local grid (Eq. 16)
# m per m of range added to an inlier distance: a beam spreads and grazes with range
INLIER_SLOPE = 0.01
# A match within this share of its search box's edge found no optimum inside the box.
BOX_MARGIN = 0.05
CURVATURE_STEP = (0.05, 0.01)  # finite-difference steps (m, rad) of a match's curvature


class ReferenceMaps:
    """A reference scan rendered for matching: its distance fields and local occupancy grid."""

    def __init__(self, cells: int, coarse_cells: int = 1, grid_cells: int | None = None):
        """``grid_cells``: the local grid's side (default ``cells``; 1 where none is built)."""
        grid_cells = cells if grid_cells is None else grid_cells
        self.field = np.zeros((cells, cells), dtype=np.float32)
        self.coarse_field = np.zeros((coarse_cells, coarse_cells), dtype=np.float32)
        # scratch of the builds: the nodes' x (distance_field.column_centres), each band's span
        self.columns = np.zeros(cells)
        self.coarse_columns = np.zeros(coarse_cells)
        self.spans = np.zeros((-(-cells // SPAN_ROWS), 2), dtype=np.int64)
        self.coarse_spans = np.zeros((-(-coarse_cells // SPAN_ROWS), 2), dtype=np.int64)
        self.coarse_meta = np.zeros(N_META, dtype=np.float64)
        self.grid = np.zeros((grid_cells, grid_cells), dtype=np.uint8)
        self.meta = np.zeros(N_META, dtype=np.float64)
        self.ready = False


class SurfaceList:
    """A reference scan's surfaces as the fine field would be built from them, listed and
    indexed by tiles, not rendered: enough to read that field at one scan's points a few
    times (:meth:`ScanMatcher.surface_inliers`)."""

    # Tile entries held per point: tiles are half a field radius a side, so a short
    # segment's box of nodes (a radius either way of it) meets 25–36 of them; a list that
    # needs more falls back to reading every segment (slower, the same values).
    ENTRIES_PER_POINT = 40

    def __init__(self, capacity: int, config: MatcherConfig):
        """``capacity``: the most points of a scan listed (a segment each at most)."""
        capacity = max(capacity, 1)
        side = max(int(math.ceil(0.5 * config.field_radius / config.resolution)), 1)
        tiles = -(-config.grid_cells // side)
        self.surfaces = np.zeros((capacity, N_SURFACE), dtype=np.float64)
        self.tiling = np.array([side, 0, 0], dtype=np.int64)  # see distance_field.TILE_SIDE
        self.heads = np.zeros(tiles * tiles, dtype=np.int64)
        self.links = np.zeros((self.ENTRIES_PER_POINT * capacity, 2), dtype=np.int64)
        self.meta = np.zeros(N_META, dtype=np.float64)
        self.count = 0


@dataclass(frozen=True)
class MatchResult:
    pose: np.ndarray  # ΔP: the current scan's pose in the reference scan's frame
    error: float  # λ, Eq. 14 at ΔP
    scan_error: float  # λ of the scan-to-scan stage alone
    used_map: bool  # the scan-to-map fallback was taken
    iterations: int
    evaluations: int


@njit(cache=True)
def _minimise(kind, ws, settings, mode, kernel, pts, n, stride, field, grid, meta, budget):
    """Run the swarm from scratch over ``ws.lo``–``ws.hi`` on Eq. 14 (mode 0) or Eq. 16 (1)."""
    half = int(settings[S_HALF])
    reset_run(
        ws,
        settings[S_MAX_IT],
        settings[S_STAG_IT],
        settings[S_STAG_TOL],
        settings[S_TARGET],
        budget,
        settings[S_STALL_IT],
        settings[S_STALL_TOL],
    )
    start(kind, ws)
    while True:
        m = ask(kind, ws)
        for r in range(m):
            x = ws.cand[r, 0]
            y = ws.cand[r, 1]
            t = ws.cand[r, 2]
            if mode == 0:
                ws.cand_val[r] = scan_to_scan_error(field, meta, pts, n, stride, x, y, t, kernel)
            else:
                ws.cand_val[r] = scan_to_map_cost(grid, meta, pts, n, x, y, t, half)
        if tell(kind, ws, m):
            return


@njit(cache=True)
def _lambda(settings, field, meta, pts, n, x, y, t):
    """λ: Eq. 14 over all points, the one measure every stage is compared by."""
    return scan_to_scan_error(field, meta, pts, n, 1, x, y, t, int(settings[S_KERNEL]))


@njit(cache=True)
def _take(ws, out, lam):
    """Keep the swarm's best in ``out`` if its λ improves on what is there."""
    out[R_ITERATIONS] += ws.scal[ITERATION]
    out[R_EVALUATIONS] += ws.scal[EVALUATIONS]
    if lam < out[R_LAMBDA]:
        out[R_X] = ws.best[0]
        out[R_Y] = ws.best[1]
        out[R_T] = ws.best[2]
        out[R_LAMBDA] = lam
        return True
    return False


@njit(cache=True)
def _polish(settings, field, meta, pts, n, box, out, stride=1):
    """Settle the swarm's match in its basin by a compass search on the fine field with all
    points (docs/method.md §3): each coordinate in turn is stepped both ways, a step that
    lowers λ taken; after a sweep with none the steps are halved, and the search ends when
    the steps halved ``S_POLISH_HALVINGS`` times gain nothing, or after ``S_POLISH_EVALS``
    evaluations. It stays in the search ``box``, as the swarm does. The swarm finds the
    basin; its samples leave the last centimetre to chance, which a descent does not.
    (``stride``: every how many points it scores, ``out``'s λ then on those alone.)"""
    halvings = int(settings[S_POLISH_HALVINGS])
    budget = int(settings[S_POLISH_EVALS])
    kernel = int(settings[S_KERNEL])
    step_xy = settings[S_POLISH_XY]
    step_t = settings[S_POLISH_T]
    best = out[R_LAMBDA]
    evaluations = 0
    level = 0
    while level <= halvings and evaluations < budget:
        moved = False
        for d in range(3):
            step = step_t if d == 2 else step_xy
            for sign in (1.0, -1.0):
                moved_to = out[R_X + d] + sign * step
                if moved_to < box[0, d] or moved_to > box[1, d]:
                    continue
                x = moved_to if d == 0 else out[R_X]
                y = moved_to if d == 1 else out[R_Y]
                t = moved_to if d == 2 else out[R_T]
                value = scan_to_scan_error(field, meta, pts, n, stride, x, y, t, kernel)
                evaluations += 1
                if value < best:
                    best = value
                    out[R_X] = x
                    out[R_Y] = y
                    out[R_T] = t
                    moved = True
                    break
        if not moved:
            step_xy *= 0.5
            step_t *= 0.5
            level += 1
    out[R_LAMBDA] = best
    out[R_EVALUATIONS] += evaluations


@njit(cache=True)
def _settle(settings, field, meta, pts, n, box, x, y, t, out, stride=1):
    """:func:`_polish` from ``(x, y, t)``: ``out`` gets the pose it settles at and its λ
    (on every ``stride``-th point)."""
    out[R_X] = x
    out[R_Y] = y
    out[R_T] = t
    out[R_LAMBDA] = scan_to_scan_error(field, meta, pts, n, stride, x, y, t,
                                       int(settings[S_KERNEL]))
    out[R_EVALUATIONS] = 1.0
    _polish(settings, field, meta, pts, n, box, out, stride)


@njit(cache=True)
def _settle_headings(settings, field, meta, pts, n, box, step, trial, out):
    """The compass search from headings about ``step`` apart across ``box``, each at its
    centre position, on about ``S_REFINE_POINTS`` of the points (a dense scanner costs what a
    1° one does); the lowest settled again on all of them: ``out`` gets its pose and λ
    (``trial``: scratch)."""
    stride = _stride(n, 1, settings[S_REFINE_POINTS])
    span = box[1, 2] - box[0, 2]
    starts = max(1, int(math.ceil(span / step)))
    x = 0.5 * (box[0, 0] + box[1, 0])
    y = 0.5 * (box[0, 1] + box[1, 1])
    out[R_LAMBDA] = np.inf
    out[R_EVALUATIONS] = 0.0
    for k in range(starts):
        _settle(settings, field, meta, pts, n, box, x, y, box[0, 2] + (k + 0.5) * span / starts,
                trial, stride)
        out[R_EVALUATIONS] += trial[R_EVALUATIONS]
        if trial[R_LAMBDA] < out[R_LAMBDA]:
            out[R_X] = trial[R_X]
            out[R_Y] = trial[R_Y]
            out[R_T] = trial[R_T]
            out[R_LAMBDA] = trial[R_LAMBDA]
    evaluations = out[R_EVALUATIONS]
    _settle(settings, field, meta, pts, n, box, out[R_X], out[R_Y], out[R_T], out)
    out[R_EVALUATIONS] += evaluations


@njit(cache=True)
def _stride(n, stride, points):
    """Every how many of ``n`` points a stage scores: ``stride``, or more so that it scores at
    most about ``points`` of them (0: ``stride``)."""
    s = int(stride)
    if points > 0:
        s = max(s, int(math.ceil(n / points)))
    return s


@njit(cache=True)
def _set_box(ws, lo, hi):
    for d in range(3):
        ws.lo[d] = lo[d]
        ws.hi[d] = hi[d]


@njit(cache=True)
def align_kernel(
    kind, ws, pts, n, field, grid, meta, coarse, coarse_meta, settings, box, threshold, out
):
    """Alg. 5 on preallocated buffers; ``box`` is the search box ``[[lo], [hi]]``."""
    out[:] = 0.0
    out[R_LAMBDA] = np.inf
    kernel = int(settings[S_KERNEL])
    # 0. A prediction trusted (``S_PREDICT``: the λ a match must reach, else 0): the local stage
    # first, at the box's centre — the guess; a match that fits as well as matches here
    # usually do stands, and the global stage is skipped (docs/method.md §3).
    accept = settings[S_PREDICT]
    if accept > 0.0 and settings[S_REFINE_EVALS] > 0:
        for d in range(3):
            w = settings[S_REFINE_X + d]
            ws.lo[d] = 0.5 * (box[0, d] + box[1, d]) - w
            ws.hi[d] = 0.5 * (box[0, d] + box[1, d]) + w
        _minimise(kind, ws, settings, 0, kernel, pts, n, 1, field, grid, meta,
                  settings[S_REFINE_EVALS])
        _take(ws, out, ws.scal[BEST_VAL])
        if out[R_LAMBDA] <= accept:
            _polish(settings, field, meta, pts, n, box, out)
            out[R_LAMBDA_SCAN] = out[R_LAMBDA]
            return
    global_stage(kind, ws, pts, n, field, grid, meta, coarse, coarse_meta, settings, box)
    local_stages(kind, ws, pts, n, field, grid, meta, settings, box, threshold, out)


@njit(cache=True)
def global_stage(kind, ws, pts, n, field, grid, meta, coarse, coarse_meta, settings, box):
    """Alg. 5's first stage: scan-to-scan over the whole box (Eq. 14), on a stride of the
    points and, if set up, on the coarse wide field whose broad basin the swarm finds more
    reliably (then ``field`` is not read). The swarm's best is left in ``ws.best``."""
    stride = _stride(n, settings[S_STRIDE], settings[S_GLOBAL_POINTS])
    _set_box(ws, box[0], box[1])
    if settings[S_COARSE] != 0.0:
        _minimise(kind, ws, settings, 0, 0, pts, n, stride, coarse, grid, coarse_meta,
                  settings[S_MAX_EVALS])
    else:
        _minimise(kind, ws, settings, 0, int(settings[S_KERNEL]), pts, n, stride, field, grid,
                  meta, settings[S_MAX_EVALS])


@njit(cache=True)
def local_stages(kind, ws, pts, n, field, grid, meta, settings, box, threshold, out):
    """Alg. 5 after :func:`global_stage`, on the fine field: its best judged by λ, refined,
    polished, and above ``threshold`` the scan-to-map fallback; ``out`` as
    :func:`align_kernel` fills it."""
    kernel = int(settings[S_KERNEL])
    budget = settings[S_MAX_EVALS]
    _take(ws, out, _lambda(settings, field, meta, pts, n, ws.best[0], ws.best[1], ws.best[2]))
    # Refined by the same swarm on all points in a small box around it, then polished.
    if settings[S_REFINE_EVALS] > 0:
        for d in range(3):
            w = settings[S_REFINE_X + d]
            ws.lo[d] = out[R_X + d] - w
            ws.hi[d] = out[R_X + d] + w
        refine = settings[S_REFINE_EVALS]
        step = _stride(n, 1, settings[S_REFINE_POINTS])
        _minimise(kind, ws, settings, 0, kernel, pts, n, step, field, grid, meta, refine)
        lam = ws.scal[BEST_VAL]
        if step > 1:  # its best judged on all points, as every stage is
            lam = _lambda(settings, field, meta, pts, n, ws.best[0], ws.best[1], ws.best[2])
        _take(ws, out, lam)
    _polish(settings, field, meta, pts, n, box, out)
    out[R_LAMBDA_SCAN] = out[R_LAMBDA]

    # 2. Above the rejection threshold, fall back to scan-to-map (Eq. 16) over the same box.
    # The fallback is kept only where λ (Eq. 14) agrees it overlays the scans better: λ is
    # the one measure both stages share, and a map match that fits worse is no rescue.
    if settings[S_USE_MAP] != 0.0 and out[R_LAMBDA] > threshold:
        _set_box(ws, box[0], box[1])
        _minimise(kind, ws, settings, 1, kernel, pts, n, 1, field, grid, meta, budget)
        lam = _lambda(settings, field, meta, pts, n, ws.best[0], ws.best[1], ws.best[2])
        if _take(ws, out, lam):
            out[R_USED_MAP] = 1.0


def beyond_margin(pose, centre, window, margin: float) -> bool:
    """``pose`` lies within ``margin`` (a share of the half-widths) of the edge of the box
    ``centre`` ± ``window``, or beyond it: the optimum lies at or beyond the box."""
    return bool(np.any(np.abs(np.asarray(pose) - centre) >= (1.0 - margin) * np.asarray(window)))


class ScanMatcher:
    """Aligns scans with a swarm optimizer (Alg. 5); one instance per stream of scans."""

    def __init__(self, config: MatcherConfig | None = None, seed: int = 0):
        self.config = config or MatcherConfig()
        c = self.config
        self.optimizer = SwarmOptimizer(c.swarm, dim=3, seed=seed)
        self.threshold = RejectionThreshold()
        self._default_reference = self.new_reference()
        self._window = np.asarray(c.search_window, dtype=np.float64)
        self._guess_window = np.asarray(c.guess_window, dtype=np.float64)
        rho = robot_square(c.robot_diameter, c.resolution)
        s = np.zeros(N_SETTINGS)
        s[S_KERNEL] = KERNELS[c.kernel]
        s[S_INV_C2] = 1.0 / (c.cauchy_scale * c.cauchy_scale)
        s[S_HALF] = rho // 2 + 1
        s[S_USE_MAP] = 1.0 if c.scan_to_map else 0.0
        sw = c.swarm
        s[S_MAX_IT] = sw.max_iterations
        s[S_STAG_IT] = sw.stagnation_iterations
        s[S_STAG_TOL] = sw.stagnation_tol
        s[S_TARGET] = sw.target_value
        s[S_MAX_EVALS] = sw.max_evaluations
        s[S_STALL_IT] = sw.stall_window
        s[S_STALL_TOL] = sw.stall_tol
        s[S_STRIDE] = c.stride
        s[S_GLOBAL_POINTS] = c.global_points
        s[S_REFINE_POINTS] = c.refine_points
        s[S_REFINE_EVALS] = c.refine_evaluations
        s[S_REFINE_X : S_REFINE_T + 1] = c.refine_window
        s[S_COARSE] = 1.0 if c.coarse_resolution > 0 else 0.0
        s[S_POLISH_XY], s[S_POLISH_T] = POLISH_STEP
        s[S_POLISH_HALVINGS] = POLISH_HALVINGS
        s[S_POLISH_EVALS] = c.polish_evaluations
        self.settings = s
        self._out = np.zeros(N_OUT)
        self._settled = np.zeros(N_OUT)
        self._sought = np.zeros(N_OUT)  # (seek_headings)
        self._box = np.zeros((2, 3))
        self._hessian = np.zeros((3, 3))
        self._kept_rng = self.optimizer.ws.rng.copy()  # (keep_stream)
        self._kept_threshold = self.threshold.state()

    def keep_stream(self) -> None:
        """Remember the swarm's random stream and the rejection threshold, for
        :meth:`rewind_stream` to put back: matches whose outcome is dropped leave no trace."""
        self._kept_rng[:] = self.optimizer.ws.rng
        self._kept_threshold = self.threshold.state()

    def rewind_stream(self) -> None:
        """The stream and the threshold as :meth:`keep_stream` saw them."""
        self.optimizer.ws.rng[:] = self._kept_rng
        self.threshold.restore(self._kept_threshold)

    def state(self) -> dict:
        """The swarm's random stream and buffers, and the rejection threshold."""
        ws = self.optimizer.ws
        return {"swarm": {name: getattr(ws, name).copy() for name in ws._fields},
                "threshold": list(self.threshold.state())}

    def restore(self, state: dict) -> None:
        ws = self.optimizer.ws
        for name in ws._fields:
            getattr(ws, name)[...] = state["swarm"][name]
        self.threshold.restore(state["threshold"])

    def set_evaluation_share(self, share: float) -> int:
        """Scale the stages' evaluation budgets to ``share`` (0–1] of the configured ones: a
        fixed-rate loop gives the swarm the time a tick has left. Returns the evaluations now
        allowed in all."""
        c = self.config
        share = min(max(share, 0.0), 1.0)
        glob = max(int(c.swarm.max_evaluations * share), 1) if c.swarm.max_evaluations else 0
        refine = int(c.refine_evaluations * share)
        polish = int(c.polish_evaluations * share)
        self.settings[S_MAX_EVALS] = glob
        self.settings[S_REFINE_EVALS] = refine
        self.settings[S_POLISH_EVALS] = polish
        return glob + refine + polish

    def new_reference(self) -> ReferenceMaps:
        """A reference buffer of this matcher's capacity (allocate at start-up, then reuse)."""
        c = self.config
        coarse = 1
        if c.coarse_resolution > 0:  # the same extent as the fine grid
            coarse = int(np.ceil(c.grid_cells * c.resolution / c.coarse_resolution))
        return ReferenceMaps(c.grid_cells, coarse, None if c.scan_to_map else 1)

    def new_surfaces(self, capacity: int) -> SurfaceList:
        """A surface list for scans of up to ``capacity`` points (allocate at start-up)."""
        return SurfaceList(capacity, self.config)

    def list_surfaces(self, scan: PointScan, out: SurfaceList) -> None:
        """List ``scan``'s surfaces as :meth:`build_field` would render them, into ``out``
        (capacity at least ``scan.count``)."""
        if scan.count > len(out.surfaces):
            raise ValueError(f"{scan.count} points exceed the surface list's capacity "
                             f"{len(out.surfaces)}")
        c = self.config
        cells = c.grid_cells
        out.count = list_surfaces(scan.buffer, scan.count, c.resolution, c.field_radius,
                                  c.max_gap, self._inv_c2(), cells, cells, out.meta,
                                  out.surfaces, out.tiling, out.heads, out.links,
                                  c.surface_bend, SURFACE_GAP_RATIO)

    def build_reference(self, scan: PointScan, out: ReferenceMaps | None = None) -> ReferenceMaps:
        """Render a reference scan's distance field (Eq. 14) and local grid (Eq. 16)."""
        if scan.count == 0:
            raise ValueError("reference scan is empty")
        ref = self._default_reference if out is None else out
        c = self.config
        self.build_field(scan, ref)
        self.build_coarse(scan, ref)
        if c.scan_to_map:
            build_local_map(
                scan.buffer, scan.count, ref.field, ref.meta, self._inv_c2(), OCCUPIED_RADIUS,
                ref.grid
            )
        ref.ready = True
        return ref

    def build_field(self, scan: PointScan, out: ReferenceMaps) -> None:
        """Render ``scan``'s fine distance field (Eq. 14) alone into ``out``: what
        :meth:`inlier_fraction` reads, not yet a reference to align with (``out.ready`` is
        left as it was)."""
        c = self.config
        build_distance_field(scan.buffer, scan.count, c.resolution, c.field_radius, c.max_gap,
                             self._inv_c2(), out.field, out.meta, out.columns,
                             out.spans, c.surface_bend, SURFACE_GAP_RATIO)

    def build_coarse(self, scan: PointScan, out: ReferenceMaps) -> None:
        """Render ``scan``'s coarse field (the global stage's, plain ``d²``) alone into
        ``out``; nothing without ``coarse_resolution``."""
        c = self.config
        if c.coarse_resolution > 0:
            build_distance_field(scan.buffer, scan.count, c.coarse_resolution, COARSE_RADIUS,
                                 c.max_gap, 0.0, out.coarse_field, out.coarse_meta,
                                 out.coarse_columns, out.coarse_spans, c.surface_bend,
                                 SURFACE_GAP_RATIO)

    def _inv_c2(self) -> float:
        """The fine field's Cauchy kernel, ``1/c²`` (0: the field holds plain ``d²``)."""
        return self.settings[S_INV_C2] if self.config.kernel == "cauchy" else 0.0

    def set_search_box(self, guess=None, window=None) -> None:
        """Centre the search box on ``guess`` (e.g. odometry), else on no motion; ``window``:
        its half-widths around the guess (default: ``guess_window``)."""
        lo, hi = self._box[0], self._box[1]
        half = self._guess_window if window is None else window
        if guess is None:
            for d in range(3):
                lo[d] = -self._window[d]
                hi[d] = self._window[d]
        else:
            for d in range(3):
                g = float(guess[d])
                if not math.isfinite(g):
                    raise ValueError(f"initial guess has a non-finite component: {guess}")
                lo[d] = g - half[d]
                hi[d] = g + half[d]

    def align_into(self, scan: PointScan, reference: ReferenceMaps, guess, out,
                   window=None) -> None:
        """Allocation-free Alg. 5: fills ``out`` (see ``R_*``) and updates the threshold."""
        if scan.count == 0:
            raise ValueError("current scan is empty")
        if not reference.ready:
            raise ValueError("reference maps were never built (call build_reference first)")
        self.set_search_box(guess, window)
        c, t = self.config, self.threshold
        self.settings[S_PREDICT] = (c.predict_first * t.mean if c.predict_first > 0
                                    and guess is not None and t.count > 1 else 0.0)
        align_kernel(
            self.optimizer.kind,
            self.optimizer.ws,
            scan.buffer,
            scan.count,
            reference.field,
            reference.grid,
            reference.meta,
            reference.coarse_field,
            reference.coarse_meta,
            self.settings,
            self._box,
            self.threshold.rejection_threshold,
            out,
        )
        self.threshold.update(out[R_LAMBDA])

    def align_scans(self, scan: PointScan, reference: ReferenceMaps, guess=None,
                    window=None) -> MatchResult:
        """Alg. 5: the pose of ``scan`` in ``reference``'s frame, and its error λ; ``window``
        overrides the half-widths of the box around ``guess``."""
        out = self._out
        self.align_into(scan, reference, guess, out, window)
        return self._result(out)

    @staticmethod
    def _result(out) -> MatchResult:
        return MatchResult(
            pose=out[R_X : R_T + 1].copy(),
            error=float(out[R_LAMBDA]),
            scan_error=float(out[R_LAMBDA_SCAN]),
            used_map=bool(out[R_USED_MAP]),
            iterations=int(out[R_ITERATIONS]),
            evaluations=int(out[R_EVALUATIONS]),
        )

    def align_inside(self, scan: PointScan, reference_scan: PointScan, out: ReferenceMaps,
                     guess, window, margin: float) -> MatchResult | None:
        """Alg. 5 on ``reference_scan``, its fields rendered into ``out`` as they are needed: the
        coarse field and the global stage on it; then, only when the swarm's best lies inside
        the box of ``guess`` ± ``window`` (off its edge by ``margin`` of the half-widths, as
        :func:`beyond_margin` tells), the fine field and the local stages, the match as
        :meth:`align_scans` gives it. None at the edge, where the optimum lies at or beyond the
        box: the fine field, a loop attempt's costliest part, is not built for it
        (docs/method.md §5, step 3). Without a coarse field, with the scan-to-map fallback
        (whose grid is drawn from the fine field), or with ``predict_first`` (whose local stage
        at the guess comes before the global one), Alg. 5 runs whole and is never None."""
        if scan.count == 0:
            raise ValueError("current scan is empty")
        if reference_scan.count == 0:
            raise ValueError("reference scan is empty")
        c = self.config
        if c.coarse_resolution <= 0 or c.scan_to_map or c.predict_first > 0:
            reference = self.build_reference(reference_scan, out)
            return self.align_scans(scan, reference, guess, window)
        out.ready = False
        self.build_coarse(reference_scan, out)
        self.set_search_box(guess, window)
        ws = self.optimizer.ws
        global_stage(self.optimizer.kind, ws, scan.buffer, scan.count, out.field, out.grid,
                     out.meta, out.coarse_field, out.coarse_meta, self.settings, self._box)
        if beyond_margin(ws.best, guess, window, margin):
            return None
        self.build_field(reference_scan, out)
        out.ready = True
        res = self._out
        res[:] = 0.0
        res[R_LAMBDA] = np.inf
        local_stages(self.optimizer.kind, ws, scan.buffer, scan.count, out.field, out.grid,
                     out.meta, self.settings, self._box, self.threshold.rejection_threshold, res)
        self.threshold.update(res[R_LAMBDA])
        return self._result(res)

    def settle(self, scan: PointScan, reference: ReferenceMaps, match: MatchResult
               ) -> MatchResult:
        """``match`` (the last :meth:`align_scans`) settled again by the compass search alone,
        for ``scan`` changed a little since (its sweep undistorted by the match's own motion):
        in the same box, without a swarm, and without counting towards the threshold."""
        out = self._settled
        pose = match.pose
        _settle(self.settings, reference.field, reference.meta, scan.buffer, scan.count,
                self._box, float(pose[0]), float(pose[1]), float(pose[2]), out)
        return MatchResult(pose=out[R_X : R_T + 1].copy(), error=float(out[R_LAMBDA]),
                           scan_error=float(out[R_LAMBDA]), used_map=match.used_map,
                           iterations=match.iterations,
                           evaluations=match.evaluations + int(out[R_EVALUATIONS]))

    def seek_headings(self, scan: PointScan, reference: ReferenceMaps, step: float
                      ) -> MatchResult:
        """The compass search alone, settled from headings ``step`` rad apart across the last
        search box (each at its centre position) on the fine field, on about
        ``refine_points`` of the points; the lowest settled again on all: its pose and λ.
        Alg. 5's swarm looks for the basin on the coarse field, which on a scan crowded by
        people can score a wrong basin lower than the true one, and its local stages refine
        only the basin it chose (docs/method.md §6.1, "Recovery"). Without a swarm, and
        without counting towards the threshold."""
        if not step >= MIN_HEADING_STEP:  # (NaN too: the starts are bounded)
            raise ValueError(f"heading step must be at least {MIN_HEADING_STEP} rad, got {step}")
        if scan.count == 0:
            raise ValueError("current scan is empty")
        if not reference.ready:
            raise ValueError("reference maps were never built (call build_reference first)")
        out = self._sought
        _settle_headings(self.settings, reference.field, reference.meta, scan.buffer,
                         scan.count, self._box, float(step), self._settled, out)
        return MatchResult(pose=out[R_X : R_T + 1].copy(), error=float(out[R_LAMBDA]),
                           scan_error=float(out[R_LAMBDA]), used_map=False, iterations=0,
                           evaluations=int(out[R_EVALUATIONS]))

    def at_box_edge(self, pose, margin: float) -> bool:
        """The last match's ``pose`` ended within ``margin`` (a share of the half-width) of its
        search box's edge: the optimum lies at or beyond the box, not inside it."""
        lo, hi = self._box[0], self._box[1]
        for d in range(3):
            centre, half = 0.5 * (lo[d] + hi[d]), 0.5 * (hi[d] - lo[d])
            if abs(pose[d] - centre) >= (1.0 - margin) * half:
                return True
        return False

    def curvature(self, scan: PointScan, reference: ReferenceMaps, pose, step) -> np.ndarray:
        """The Hessian of the summed per-point cost at ``pose`` (a 3 × 3 buffer, reused);
        ``step``: the finite-difference steps (m, rad)."""
        cost_hessian(reference.field, reference.meta, scan.buffer, scan.count, float(pose[0]),
                     float(pose[1]), float(pose[2]), float(step[0]), float(step[1]), self._hessian)
        return self._hessian

    def inlier_fraction(self, scan: PointScan, reference: ReferenceMaps, pose,
                        distance: float, slope: float = 0.0) -> float:
        """Share of ``scan``'s points within ``distance`` (+ ``slope`` × the point's range) of
        the reference surface at ``pose``."""
        return float(inlier_fraction(reference.field, reference.meta, scan.buffer, scan.count,
                                     float(pose[0]), float(pose[1]), float(pose[2]),
                                     float(distance), float(slope), self._inv_c2()))

    def surface_inliers(self, scan: PointScan, surfaces: SurfaceList, pose, distance: float,
                        slope: float = 0.0, stop: int | None = None) -> int:
        """How many of ``scan``'s points :meth:`inlier_fraction` counts, against a listed
        reference (:meth:`list_surfaces`): the same count, without building its field.
        Counting ends once it reaches ``stop`` (None: every point is read)."""
        return int(surface_inliers(
            surfaces.surfaces, surfaces.count, surfaces.tiling, surfaces.heads, surfaces.links,
            surfaces.meta, self.config.field_radius,
            scan.buffer, scan.count, float(pose[0]), float(pose[1]), float(pose[2]),
            float(distance), float(slope), self._inv_c2(),
            scan.count + 1 if stop is None else int(stop)))
