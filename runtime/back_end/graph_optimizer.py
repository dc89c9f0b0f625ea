"""Gauss–Newton on the pose graph (Eq. 21): ``H Δx = −b`` from every edge's Jacobians.

* Assembly: one compiled pass over the edges into preallocated triplets (a Python loop over
  edges was 40× slower), scattered into a CSC pattern that is worked out once per edge set.
* Solve: sparse LDLᵀ (:mod:`swarmslam.runtime.back_end.sparse_ldl`: minimum-degree ordering of the nodes, QDLDL's
  factorisation, compiled, in buffers of fixed capacity; scipy has no sparse Cholesky, and
  SuperLU took over ten times as long per iteration on the benchmark graphs). The ordering and symbolic analysis
  are redone only when the edge set changes; iterations refactor numerically.
* The first pose is fixed by leaving it out of the unknowns. Perturbations are additive on
  ``(x, y, θ)``, as in g2o's ``VertexSE2``, so the χ² reached is g2o's.
* Plain Gauss–Newton, as g2o iterates it: a step that raises χ² is kept (from an odometry
  start χ² may rise many times over before it falls; rejecting such steps stalls far from the
  optimum). Only if it has not converged after ``max_iterations`` (or χ² is no longer
  finite) does it restart from the initial poses with Levenberg–Marquardt damping (Nielsen's
  rule, ``(H + μI) Δx = −b``, as g2o's ``lm`` solver).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.sparse.linalg import splu

from swarmslam.runtime.config import OptimizerConfig
from swarmslam.runtime.pose import wrap_angle_nb
from swarmslam.runtime.pose_graph import LOOP, PoseGraph, edge_error
from swarmslam.runtime.back_end.sparse_ldl import SparseLDL, permute_triplets


@njit(cache=True)
def dcs_weights(chi2, kind, phi, exempt, out):
    """Dynamic covariance scaling (Agarwal et al. 2013) of every loop edge (``kind`` LOOP) but
    those from ``exempt`` on (none when it is negative: loops on trial are the last edges),
    from each edge's ``eᵀΩe`` (``chi2``): ``out[k] = s²``,
    ``s = min(1, 2Φ/(Φ + eᵀΩe))``; 1 for the others. An edge that contradicts the rest of the
    graph loses its pull instead of bending the map (docs/method.md §4.3)."""
    for k in range(chi2.shape[0]):
        out[k] = 1.0
        if kind[k] == LOOP and (exempt < 0 or k < exempt) and chi2[k] > phi:
            s = 2.0 * phi / (phi + chi2[k])
            out[k] = s * s


@njit(cache=True)
def assemble(poses, ij, z, info, weight, rows, cols, vals, b):
    """Fill the triplets of H (36 per edge) and b; return χ² at the current poses, each edge's
    information scaled by ``weight[k]``.

    Node 0 is fixed: its rows and columns are sent to index -1 and dropped by the caller.
    Unknown ``3(k−1)+d`` is component ``d`` of node ``k``.
    """
    b[:] = 0.0
    chi2 = 0.0
    A = np.empty((3, 3))
    B = np.empty((3, 3))
    e = np.empty(3)
    oe = np.empty(3)
    for k in range(ij.shape[0]):
        i = ij[k, 0]
        j = ij[k, 1]
        ci = math.cos(poses[i, 2])
        si = math.sin(poses[i, 2])
        cz = math.cos(z[k, 2])
        sz = math.sin(z[k, 2])
        dx = poses[j, 0] - poses[i, 0]
        dy = poses[j, 1] - poses[i, 1]
        e[0], e[1], e[2] = edge_error(poses, i, j, z[k, 0], z[k, 1], z[k, 2])  # Eq. 18
        # M = R_zᵀ R_iᵀ; ∂e_t/∂t_j = M, ∂e_t/∂t_i = −M, ∂e_t/∂θ_i = R_zᵀ dR_iᵀ/dθ (t_j − t_i)
        m00 = cz * ci - sz * si
        m01 = cz * si + sz * ci
        m10 = -sz * ci - cz * si
        m11 = -sz * si + cz * ci
        gx = -si * dx + ci * dy  # dR_iᵀ/dθ (t_j − t_i)
        gy = -ci * dx - si * dy
        A[0, 0] = -m00
        A[0, 1] = -m01
        A[0, 2] = cz * gx + sz * gy
        A[1, 0] = -m10
        A[1, 1] = -m11
        A[1, 2] = -sz * gx + cz * gy
        A[2, 0] = 0.0
        A[2, 1] = 0.0
        A[2, 2] = -1.0
        B[0, 0] = m00
        B[0, 1] = m01
        B[0, 2] = 0.0
        B[1, 0] = m10
        B[1, 1] = m11
        B[1, 2] = 0.0
        B[2, 0] = 0.0
        B[2, 1] = 0.0
        B[2, 2] = 1.0
        for a in range(3):
            acc = 0.0
            for c in range(3):
                acc += info[k, a, c] * e[c]
            oe[a] = acc
        w = weight[k]
        for a in range(3):
            oe[a] *= w
        chi2 += e[0] * oe[0] + e[1] * oe[1] + e[2] * oe[2]
        base = 36 * k
        oi = 3 * (i - 1)
        oj = 3 * (j - 1)
        for blk in range(4):
            P = A if blk < 2 else B  # blocks ii, ij, ji, jj
            Q = A if blk % 2 == 0 else B
            ro = oi if blk < 2 else oj
            co = oi if blk % 2 == 0 else oj
            for r in range(3):
                for c in range(3):
                    acc = 0.0  # (Pᵀ Ω Q)[r, c]
                    for a in range(3):
                        pa = P[a, r]
                        if pa != 0.0:
                            for d in range(3):
                                acc += pa * info[k, a, d] * Q[d, c]
                    idx = base + 9 * blk + 3 * r + c
                    rows[idx] = ro + r if ro >= 0 else -1
                    cols[idx] = co + c if co >= 0 else -1
                    vals[idx] = w * acc
        for r in range(3):
            ga = 0.0
            gb = 0.0
            for a in range(3):
                ga += A[a, r] * oe[a]
                gb += B[a, r] * oe[a]
            if oi >= 0:
                b[oi + r] += ga
            if oj >= 0:
                b[oj + r] += gb
    return chi2


@njit(cache=True)
def apply_update(poses, dx):
    for k in range(1, poses.shape[0]):
        poses[k, 0] += dx[3 * (k - 1)]
        poses[k, 1] += dx[3 * (k - 1) + 1]
        poses[k, 2] = wrap_angle_nb(poses[k, 2] + dx[3 * (k - 1) + 2])


@njit(cache=True)
def scatter(vals, slot, data):
    """Sum triplet values into their CSC slots (``slot`` −1: dropped)."""
    data[:] = 0.0
    for t in range(vals.shape[0]):
        k = slot[t]
        if k >= 0:
            data[k] += vals[t]


@njit(cache=True)
def csc_pattern(rows, cols, size, cursor, sort_rows, sort_idx, slot, indices, indptr, diag):
    """Upper-triangle CSC pattern of the triplets (row ≤ col, both ≥ 0): ``indices`` and
    ``indptr``, each triplet's ``slot`` in it (−1: dropped) and each column's diagonal slot.

    The triplets come as 3×3 blocks (nine in a row, :func:`assemble`'s layout, permuted block
    by block), so the pattern is found on blocks — a counting sort by block column, then block
    rows sorted and merged within each — and written out three columns at a time: a ninth of
    the entries to sort (a quarter of the time of entry by entry), and the
    same pattern and slots as sorting every entry would give."""
    nb = size // 3
    groups = rows.shape[0] // 9
    for c in range(nb + 1):
        cursor[c] = 0
    for g in range(groups):  # a block's first entry (r = c = 0) says where the block is
        r = rows[9 * g]
        c = cols[9 * g]
        if r >= 0 and c >= 0 and r <= c:
            cursor[c // 3 + 1] += 1
    for c in range(nb):
        cursor[c + 1] += cursor[c]
    for g in range(groups):
        r = rows[9 * g]
        c = cols[9 * g]
        if r >= 0 and c >= 0 and r <= c:
            q = cursor[c // 3]
            sort_rows[q] = r // 3
            sort_idx[q] = g
            cursor[c // 3] = q + 1  # ends as the next block column's start
    for t in range(rows.shape[0]):
        slot[t] = -1
    nnz = 0
    for bc in range(nb):
        a = cursor[bc - 1] if bc > 0 else 0
        b = cursor[bc]
        for k in range(a + 1, b):  # insertion sort by block row: a column holds a few
            r = sort_rows[k]
            g = sort_idx[k]
            q = k - 1
            while q >= a and sort_rows[q] > r:
                sort_rows[q + 1] = sort_rows[q]
                sort_idx[q + 1] = sort_idx[q]
                q -= 1
            sort_rows[q + 1] = r
            sort_idx[q + 1] = g
        distinct = 0
        last = -1
        for k in range(a, b):
            if sort_rows[k] != last:
                last = sort_rows[k]
                distinct += 1
        above = distinct - 1 if last == bc else distinct  # blocks above the diagonal one
        for c in range(3):  # scalar column 3·bc + c: 3 rows per block above, then c + 1
            indptr[3 * bc + c] = nnz
            nnz += 3 * above + (c + 1 if last == bc else 0)
        rank = -1
        last = -1
        for k in range(a, b):
            br = sort_rows[k]
            if br != last:
                last = br
                rank += 1
                for c in range(3):
                    col = 3 * bc + c
                    base = indptr[col] + 3 * rank
                    for r in range(3 if br < bc else c + 1):
                        indices[base + r] = 3 * br + r
                    if br == bc:
                        diag[col] = base + c
            g = sort_idx[k]
            for r in range(3):
                for c in range(3):
                    if br < bc or r <= c:
                        slot[9 * g + 3 * r + c] = indptr[3 * bc + c] + 3 * rank + r
    indptr[size] = nnz
    return nnz


@dataclass
class OptimizeReport:
    chi2_initial: float
    chi2: float
    iterations: int
    seconds: float
    solver: str
    converged: bool = True


class GaussNewton:
    """Optimises a :class:`PoseGraph` in place; triplet buffers sized from its capacities."""

    def __init__(self, graph: PoseGraph, config: OptimizerConfig | None = None, **overrides):
        """``config`` (default: the defaults) with ``overrides`` of its fields, e.g.
        ``GaussNewton(graph, solver="superlu")``; checked as the configuration tree is."""
        c = replace(config or OptimizerConfig(), **overrides)
        self.config = c
        self.graph = graph
        self.max_iterations = c.max_iterations
        self.tolerance = c.tolerance
        self.solver = c.solver
        m = graph.max_edges
        self._rows = np.zeros(36 * m, np.int64)
        self._cols = np.zeros(36 * m, np.int64)
        self._vals = np.zeros(36 * m)
        self._b = np.zeros(3 * max(graph.max_nodes - 1, 1))
        self._saved = np.zeros_like(graph.poses)
        self._lm_saved = np.zeros_like(graph.poses)
        # CSC pattern buffers at capacity: ≤ 6 upper entries per node's diagonal block and 9
        # per edge's off-diagonal block (duplicate edges only share).
        unknowns = 3 * max(graph.max_nodes - 1, 1)
        self._slot_buf = np.zeros(36 * m, np.int64)
        self._indices_buf = np.zeros(6 * graph.max_nodes + 9 * m, np.int64)
        self._indptr_buf = np.zeros(unknowns + 1, np.int64)
        self._diag_buf = np.zeros(unknowns, np.int64)
        self._data_buf = np.zeros(6 * graph.max_nodes + 9 * m)
        self._cursor = np.zeros(unknowns + 1, np.int64)
        self._sort_rows = np.zeros(4 * m, np.int64)  # csc_pattern sorts blocks: 4 an edge
        self._sort_idx = np.zeros(4 * m, np.int64)
        self._prows = np.zeros(36 * m, np.int64)
        self._pcols = np.zeros(36 * m, np.int64)
        self._dx = np.zeros(unknowns)
        self._neg_b = np.zeros(unknowns)
        self.ldl = SparseLDL(max(graph.max_nodes - 1, 1), int(c.fill_ratio * len(self._data_buf)))
        self._pattern_key = None
        self._weight = np.ones(m)  # each edge's information scale (robust loops)

    def _pattern(self, rows, cols, size):
        """The upper triangle's CSC pattern and each triplet's slot in it, in buffers of the
        graph's capacity (nothing allocated: the pattern changes with every new edge)."""
        nnz = csc_pattern(rows, cols, size, self._cursor, self._sort_rows, self._sort_idx,
                          self._slot_buf, self._indices_buf, self._indptr_buf, self._diag_buf)
        self._slot = self._slot_buf[: len(rows)]
        self._indices = self._indices_buf[:nnz]
        self._indptr = self._indptr_buf[: size + 1]
        self._diag = self._diag_buf[:size]
        self._data = self._data_buf[:nnz]

    def _system(self):
        """Assemble at the current poses: upper-triangular H data, b, and χ²."""
        g = self.graph
        n, m = g.n_nodes, g.n_edges
        size = 3 * (n - 1)
        rows, cols, vals = self._rows[: 36 * m], self._cols[: 36 * m], self._vals[: 36 * m]
        b = self._b[:size]
        chi2 = assemble(g.poses[:n], g.ij[:m], g.z[:m], g.info[:m], self._weight[:m], rows,
                        cols, vals, b)
        key = (id(g), n, g.revision)
        if key != self._pattern_key:  # new edge set: order, pattern and analysis again
            self._pattern_key = None
            self.ldl.order_blocks(g.ij[:m], n)
            prows, pcols = self._prows[: 36 * m], self._pcols[: 36 * m]
            permute_triplets(rows, cols, self.ldl.order, n - 1, self.ldl.pinv, prows, pcols)
            self._pattern(prows, pcols, size)
            self.ldl.analyse(size, self._indptr, self._indices)
            self._pattern_key = key
        scatter(vals, self._slot, self._data)
        return b, chi2

    def _solve(self, b, mu):
        """Δx of ``(H + μI) Δx = −b`` (in the buffer ``_dx``)."""
        size = len(b)
        dx = self._dx[:size]
        if self.solver == "superlu":  # reference path: the same permuted system, by SuperLU
            upper = sp.csc_matrix((self._data, self._indices, self._indptr), shape=(size, size))
            full = (upper + sp.triu(upper, k=1).T + mu * sp.eye(size)).tocsc()
            x = splu(full, permc_spec="MMD_AT_PLUS_A").solve(-b[np.argsort(self.ldl.pinv[:size])])
            dx[:] = x[self.ldl.pinv[:size]]
            return dx
        if not self.ldl.factor(self._indptr, self._indices, self._data, mu):
            dx[:] = np.nan  # not positive definite: χ² turns non-finite, LM takes over
            return dx
        np.negative(b, out=self._neg_b[:size])
        self.ldl.solve(self._neg_b[:size], dx)
        return dx

    def optimize(self, exempt: int = -1, fallback: bool = True) -> OptimizeReport:
        """Gauss–Newton until the relative decrease of χ² is below ``tolerance``; edge
        ``exempt`` and those after it keep their full weight under the robust kernel (loop
        closures on trial).
        If it has not converged after ``max_iterations``, Levenberg–Marquardt restarts from
        the first poses — or, without ``fallback``, the poses are restored and the report says
        ``converged=False`` (a closure on trial: an LM restart there takes hundreds of
        iterations, for a closure that is then refused)."""
        t0 = time.perf_counter()
        steps = self.steps(exempt)
        try:
            while True:
                next(steps)
        except StopIteration as stop:
            report = stop.value
        if report.converged or not fallback:
            return report
        chi2, more = self._levenberg_marquardt()
        return OptimizeReport(report.chi2_initial, chi2, report.iterations + more,
                              time.perf_counter() - t0, self.solver + "+lm")

    def steps(self, exempt: int = -1):
        """:meth:`optimize` without its fallback, one Gauss–Newton step at a time: a generator
        that yields after each step that leaves the optimisation unfinished and returns the
        :class:`OptimizeReport` (not converged: the poses it started from restored). A
        closure on trial is optimised a step per back-end slice this way, so that one large
        graph's solve does not overrun a tick (docs/runtime.md §3).
        The robust weights are set once, at the poses the call starts from: re-weighting at
        every step kept χ² from settling (optimisations fell back to Levenberg–Marquardt, several
        times as slow, where plain least squares settled)."""
        g = self.graph
        m = g.n_edges
        phi = self.config.robust_loops
        if phi:
            dcs_weights(g.edge_chi2(), g.kind[:m], phi, exempt, self._weight[:m])
        else:
            self._weight[:m] = 1.0
        t0 = time.perf_counter()
        if g.n_nodes < 2 or g.n_edges == 0:
            c = g.chi2() if g.n_edges else 0.0
            return OptimizeReport(c, c, 0, time.perf_counter() - t0, self.solver)
        poses = g.poses[: g.n_nodes]
        start = self._saved[: g.n_nodes]
        start[:] = poses
        b, chi2 = self._system()
        initial = chi2
        converged, iterations = False, 0
        for iterations in range(1, self.max_iterations + 1):
            apply_update(poses, self._solve(b, 0.0))
            b, new = self._system()
            converged = 0.0 <= chi2 - new <= self.tolerance * chi2
            chi2 = new
            if converged or not np.isfinite(chi2) or iterations == self.max_iterations:
                break
            yield
        if converged:
            return OptimizeReport(initial, chi2, iterations, time.perf_counter() - t0, self.solver)
        poses[:] = start
        return OptimizeReport(initial, initial, iterations, time.perf_counter() - t0,
                              self.solver, converged=False)

    # Nielsen's μ₀ as a share of max diag(H), and how many times max_iterations the
    # Levenberg–Marquardt restart may take: g2o's own choices.
    LM_INITIAL_DAMPING = 1e-5
    LM_ITERATION_FACTOR = 10

    def _levenberg_marquardt(self):
        """Nielsen's damping: shrink μ by the gain ratio on success, grow it on failure."""
        g = self.graph
        poses = g.poses[: g.n_nodes]
        saved = self._lm_saved[: g.n_nodes]
        b, chi2 = self._system()
        mu = self.LM_INITIAL_DAMPING * float(np.max(self._data[self._diag]))
        nu = 2.0
        iterations = 0
        for iterations in range(1, self.LM_ITERATION_FACTOR * self.max_iterations + 1):
            dx = self._solve(b, mu)
            saved[:] = poses
            apply_update(poses, dx)
            b_new, new = self._system()
            predicted = 0.5 * float(dx @ (mu * dx - b))
            if new < chi2:
                rho = 0.5 * (chi2 - new) / predicted if predicted > 0 else 1.0
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                done = chi2 - new <= self.tolerance * chi2
                b, chi2 = b_new, new
                if done:
                    break
            else:
                poses[:] = saved
                b, _ = self._system()
                mu *= nu
                nu *= 2.0
                if not np.isfinite(mu):
                    break
        return chi2, iterations
