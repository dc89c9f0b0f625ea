"""Sparse LDLᵀ for the pose graph's normal equations, compiled, in buffers of fixed capacity.

Why our own: the ``qdldl`` Python package converts its input through scipy on every
``update`` and its traced memory kept growing (tens of kB per thousand refactorisations, seen
by the runtime's zero-growth test), and a robot's solver should not allocate per loop closure.

* Ordering: exact minimum degree on the *node* graph (one vertex per 3×3 block, so a third of
  the work of a scalar ordering), with adjacency as preallocated bitsets and the blocks left in
  an indexed heap — about 1 ms for 1,300 nodes. Quality: on the benchmark graphs the factor has
  about as many entries as with AMD (the ``posegraph`` benchmark prints both
  figures' effect: its time).
* Symbolic and numeric factorisation: the QDLDL algorithm (Stellato, Banjac, Goulart, Bemporad,
  Boyd: elimination tree, column counts, up-looking LDLᵀ) on the permuted upper triangle. The
  three columns of a node's block update each row in one pass, every entry's operations in
  QDLDL's order: the same factor to the bit, sooner.
* The factor's entries are bounded by ``fill_capacity``; a pattern that needs more raises
  :class:`FactorCapacityError` before anything is written.
"""

from __future__ import annotations

import numpy as np
from numba import njit


class FactorCapacityError(RuntimeError):
    """The LDLᵀ factor would need more entries than its fixed capacity."""


@njit(cache=True, inline="always")
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, inline="always")
def _heap_before(degree, a, b):
    """Whether block ``a`` is eliminated before ``b``: lower degree, then lower index."""
    return degree[a] < degree[b] or (degree[a] == degree[b] and a < b)


@njit(cache=True)
def _heap_sift(heap, where, degree, pos, size, up):
    """Move ``heap[pos]`` to its place in the binary heap ``heap[:size]``: first up (``up``:
    its key may have fallen), then down (where a heap is being built, only down)."""
    v = heap[pos]
    while up and pos > 0:
        parent = (pos - 1) // 2
        if not _heap_before(degree, v, heap[parent]):
            break
        heap[pos] = heap[parent]
        where[heap[pos]] = pos
        pos = parent
    while True:
        child = 2 * pos + 1
        if child >= size:
            break
        if child + 1 < size and _heap_before(degree, heap[child + 1], heap[child]):
            child += 1
        if not _heap_before(degree, heap[child], v):
            break
        heap[pos] = heap[child]
        where[heap[pos]] = pos
        pos = child
    heap[pos] = v
    where[v] = pos


@njit(cache=True)
def minimum_degree_blocks(ij, n_nodes, bits, degree, heap, where, order):
    """Elimination order of nodes 1..n−1 (node 0 is fixed) by exact minimum degree, ties to
    the lowest index.

    ``bits``: (capacity, words) uint64 adjacency scratch; ``heap``, ``where``: an indexed
    binary heap of the blocks left, by (degree, index), so that each step finds its block in
    O(log n) rather than by a scan of all. Writes ``order[:n−1]`` with block indices (node − 1)."""
    nb = n_nodes - 1
    words = (nb + 63) // 64
    for v in range(nb):
        for w in range(words):
            bits[v, w] = 0
    one = np.uint64(1)
    for k in range(ij.shape[0]):
        a = ij[k, 0] - 1
        b = ij[k, 1] - 1
        if a < 0 or b < 0 or a == b:
            continue
        bits[a, b >> 6] |= one << np.uint64(b & 63)
        bits[b, a >> 6] |= one << np.uint64(a & 63)
    for v in range(nb):
        d = 0
        for w in range(words):
            d += _popcount(bits[v, w])
        degree[v] = d
        heap[v] = v
        where[v] = v
    for pos in range(nb // 2 - 1, -1, -1):
        _heap_sift(heap, where, degree, pos, nb, False)
    size = nb
    for step in range(nb):
        best = heap[0]
        size -= 1
        heap[0] = heap[size]
        where[heap[0]] = 0
        where[best] = -1
        if size > 0:
            _heap_sift(heap, where, degree, 0, size, False)
        order[step] = best
        # Eliminating ``best`` joins its neighbours (all still in the heap) into a clique.
        for w in range(words):
            word = bits[best, w]
            while word != 0:
                low = word & (~word + one)
                u = w * 64 + _popcount(low - one)
                word ^= low
                for x in range(words):
                    bits[u, x] |= bits[best, x]
                bits[u, u >> 6] &= ~(one << np.uint64(u & 63))
                bits[u, best >> 6] &= ~(one << np.uint64(best & 63))
                d = 0
                for x in range(words):
                    d += _popcount(bits[u, x])
                degree[u] = d
                _heap_sift(heap, where, degree, where[u], size, True)


@njit(cache=True)
def permute_triplets(rows, cols, order, n_blocks, pinv, out_rows, out_cols):
    """Scalar inverse permutation from the block order; triplet indices moved through it."""
    for p in range(n_blocks):
        b = order[p]
        for d in range(3):
            pinv[3 * b + d] = 3 * p + d
    for t in range(rows.shape[0]):
        r = rows[t]
        c = cols[t]
        out_rows[t] = pinv[r] if r >= 0 else -1
        out_cols[t] = pinv[c] if c >= 0 else -1


@njit(cache=True)
def elimination_tree(n, Ap, Ai, work, Lnz, etree, Lp):
    """QDLDL's symbolic step on an upper-triangular CSC matrix: the elimination tree, entries
    per column of L, and ``Lp``; returns the factor's entry count."""
    for i in range(n):
        work[i] = 0
        Lnz[i] = 0
        etree[i] = -1
    for j in range(n):
        work[j] = j
        for p in range(Ap[j], Ap[j + 1]):
            i = Ai[p]
            while work[i] != j:
                if etree[i] == -1:
                    etree[i] = j
                Lnz[i] += 1
                work[i] = j
                i = etree[i]
    Lp[0] = 0
    for i in range(n):
        Lp[i + 1] = Lp[i] + Lnz[i]
    return Lp[n]


@njit(cache=True, inline="always")
def _append(k, c, yc, tmp, Li, Lx, D, Dinv, nextcol, yvals, marker):
    """Row ``k``'s entry in column ``c`` (``yc`` before scaling), and its share of ``D[k]``."""
    Li[tmp] = k
    Lx[tmp] = yc * Dinv[c]
    D[k] -= yc * Lx[tmp]
    nextcol[c] = tmp + 1
    yvals[c] = 0.0
    marker[c] = 0


@njit(cache=True, inline="always")
def _block_columns(k, c, Lp, Li, Lx, D, Dinv, nextcol, yvals, marker):
    """Columns ``c``, ``c + 1``, ``c + 2`` of one 3×3 block (``c`` its first) applied to row
    ``k`` in one pass over the rows below the block, which the three share in a matrix of full
    3×3 blocks (the graph's): each of those rows takes the three updates in the order the
    column-by-column loop gives them, so every entry is the same to the bit, with a third of
    the passes over ``yvals``. False (nothing done) if the columns are not laid out so: the two
    in-block entries first, then the same count of shared rows."""
    p0 = Lp[c]
    p1 = Lp[c + 1]
    p2 = Lp[c + 2]
    t0 = nextcol[c]
    t1 = nextcol[c + 1]
    t2 = nextcol[c + 2]
    shared = t2 - p2
    if (t0 - p0 != shared + 2 or t1 - p1 != shared + 1 or Li[p0] != c + 1
            or Li[p0 + 1] != c + 2 or Li[p1] != c + 2):
        return False
    y0 = yvals[c]
    yvals[c + 1] -= Lx[p0] * y0
    yvals[c + 2] -= Lx[p0 + 1] * y0
    y1 = yvals[c + 1]
    yvals[c + 2] -= Lx[p1] * y1
    y2 = yvals[c + 2]
    for q in range(shared):
        r = Li[p2 + q]
        v = yvals[r]
        v -= Lx[p0 + 2 + q] * y0
        v -= Lx[p1 + 1 + q] * y1
        v -= Lx[p2 + q] * y2
        yvals[r] = v
    _append(k, c, y0, t0, Li, Lx, D, Dinv, nextcol, yvals, marker)
    _append(k, c + 1, y1, t1, Li, Lx, D, Dinv, nextcol, yvals, marker)
    _append(k, c + 2, y2, t2, Li, Lx, D, Dinv, nextcol, yvals, marker)
    return True


@njit(cache=True)
def ldl_factor(n, Ap, Ai, Ax, shift, Lp, Li, Lx, D, Dinv, etree, marker, yidx, ebuf, nextcol, yvals):
    """QDLDL's numeric step on ``A + shift·I`` (upper CSC); False if a pivot is not positive."""
    for i in range(n):
        marker[i] = 0
        yvals[i] = 0.0
        D[i] = 0.0
        nextcol[i] = Lp[i]
    for k in range(n):
        nnz_y = 0
        D[k] = shift
        for p in range(Ap[k], Ap[k + 1]):
            b = Ai[p]
            if b == k:
                D[k] += Ax[p]
                continue
            yvals[b] = Ax[p]
            nxt = b
            if marker[nxt] == 0:
                marker[nxt] = 1
                ebuf[0] = nxt
                ne = 1
                nxt = etree[b]
                while nxt != -1 and nxt < k:
                    if marker[nxt] == 1:
                        break
                    marker[nxt] = 1
                    ebuf[ne] = nxt
                    ne += 1
                    nxt = etree[nxt]
                while ne > 0:
                    ne -= 1
                    yidx[nnz_y] = ebuf[ne]
                    nnz_y += 1
        i = nnz_y - 1
        while i >= 0:
            c = yidx[i]
            if i >= 2 and c % 3 == 0 and yidx[i - 1] == c + 1 and yidx[i - 2] == c + 2:
                if _block_columns(k, c, Lp, Li, Lx, D, Dinv, nextcol, yvals, marker):
                    i -= 3
                    continue
            tmp = nextcol[c]
            yc = yvals[c]
            for j in range(Lp[c], tmp):
                yvals[Li[j]] -= Lx[j] * yc
            _append(k, c, yc, tmp, Li, Lx, D, Dinv, nextcol, yvals, marker)
            i -= 1
        if not D[k] > 0.0:
            return False
        Dinv[k] = 1.0 / D[k]
    return True


@njit(cache=True)
def ldl_solve(n, Lp, Li, Lx, Dinv, pinv, b, x, out):
    """``out = A⁻¹ b`` through the permutation (``x``: scratch of size n)."""
    for i in range(n):
        x[pinv[i]] = b[i]
    for i in range(n):
        for j in range(Lp[i], Lp[i + 1]):
            x[Li[j]] -= Lx[j] * x[i]
    for i in range(n):
        x[i] *= Dinv[i]
    for i in range(n - 1, -1, -1):
        for j in range(Lp[i], Lp[i + 1]):
            x[i] -= Lx[j] * x[Li[j]]
    for i in range(n):
        out[i] = x[pinv[i]]


class SparseLDL:
    """Buffers for ordering, analysing and factorising systems of up to ``max_blocks`` 3×3
    blocks, with at most ``fill_capacity`` entries in L."""

    def __init__(self, max_blocks: int, fill_capacity: int):
        n = 3 * max(max_blocks, 1)
        nb = max(max_blocks, 1)
        self.bits = np.zeros((nb, (nb + 63) // 64), np.uint64)
        self.degree = np.zeros(nb, np.int64)
        self.heap = np.zeros(nb, np.int64)
        self.where = np.zeros(nb, np.int64)
        self.order = np.zeros(nb, np.int64)
        self.pinv = np.zeros(n, np.int64)
        self.work = np.zeros(n, np.int64)
        self.Lnz = np.zeros(n, np.int64)
        self.etree = np.zeros(n, np.int64)
        self.Lp = np.zeros(n + 1, np.int64)
        self.Li = np.zeros(fill_capacity, np.int64)
        self.Lx = np.zeros(fill_capacity)
        self.D = np.zeros(n)
        self.Dinv = np.zeros(n)
        self.marker = np.zeros(n, np.int64)
        self.yidx = np.zeros(n, np.int64)
        self.ebuf = np.zeros(n, np.int64)
        self.nextcol = np.zeros(n, np.int64)
        self.yvals = np.zeros(n)
        self.x = np.zeros(n)
        self.n = 0
        self.fill = 0

    def order_blocks(self, ij, n_nodes: int) -> None:
        minimum_degree_blocks(ij, n_nodes, self.bits, self.degree, self.heap, self.where,
                              self.order)

    def analyse(self, n: int, Ap, Ai) -> int:
        fill = elimination_tree(n, Ap, Ai, self.work, self.Lnz, self.etree, self.Lp)
        if fill > self.Li.shape[0]:
            raise FactorCapacityError(
                f"the factor needs {fill} entries but its capacity is {self.Li.shape[0]} "
                "(raise optimizer.fill_ratio)")
        self.n, self.fill = n, fill
        return fill

    def factor(self, Ap, Ai, Ax, shift: float = 0.0) -> bool:
        return ldl_factor(self.n, Ap, Ai, Ax, shift, self.Lp, self.Li, self.Lx, self.D,
                          self.Dinv, self.etree, self.marker, self.yidx, self.ebuf,
                          self.nextcol, self.yvals)

    def solve(self, b, out) -> None:
        ldl_solve(self.n, self.Lp, self.Li, self.Lx, self.Dinv, self.pinv, b, self.x, out)
