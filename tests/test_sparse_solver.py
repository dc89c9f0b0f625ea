"""The Gauss–Newton solver's symbolic steps: the minimum-degree ordering and the CSC pattern,
each checked against a plain reference on graphs with what real ones hold (edges to the
fixed node 0, repeated loop edges, one pair joined both ways)."""

import numpy as np
import pytest

from swarmslam.runtime.back_end.graph_optimizer import GaussNewton
from swarmslam.runtime.pose_graph import LOOP, PoseGraph
from swarmslam.runtime.back_end.sparse_ldl import SparseLDL


def random_graph(seed, n):
    """A chain of ``n`` nodes with loop edges between random pairs (some repeated)."""
    rng = np.random.default_rng(seed)
    g = PoseGraph(n, 4 * n)
    info = np.eye(3)
    g.add_node([0.0, 0.0, 0.0])
    for k in range(1, n):
        g.add_node(g.poses[k - 1] + rng.normal(0.0, [0.5, 0.5, 0.3]))
        g.add_edge(k - 1, k, rng.normal(0.0, [0.5, 0.5, 0.3]), info)
    for _ in range(int(rng.integers(0, 2 * n))):
        i, j = rng.integers(0, n, size=2)
        if i != j:
            g.add_edge(int(i), int(j), rng.normal(0.0, 0.3, size=3), info, LOOP)
    if n > 3:
        g.add_edge(1, 3, np.zeros(3), info, LOOP)
        g.add_edge(3, 1, np.zeros(3), info, LOOP)  # both ways: one block pair
    return g


def reference_minimum_degree(ij, n_nodes):
    """Exact minimum degree on the node graph (node 0 fixed), ties to the lowest index."""
    nb = n_nodes - 1
    adj = [set() for _ in range(nb)]
    for a, b in ij - 1:
        if a >= 0 and b >= 0 and a != b:
            adj[a].add(int(b))
            adj[b].add(int(a))
    left, order = set(range(nb)), []
    for _ in range(nb):
        best = min(left, key=lambda v: (len(adj[v]), v))
        order.append(best)
        left.remove(best)
        for u in adj[best]:  # its neighbours become a clique
            adj[u] |= adj[best]
            adj[u] -= {u, best}
    return order


@pytest.mark.parametrize("seed", range(12))
def test_the_ordering_is_exact_minimum_degree_with_ties_to_the_lowest_index(seed):
    n = [2, 3, 5, 9, 17, 40, 70, 130, 64, 65, 129, 200][seed]
    g = random_graph(seed, n)
    ldl = SparseLDL(n - 1, 8)
    ij = g.ij[: g.n_edges]
    ldl.order_blocks(ij, n)
    assert ldl.order[: n - 1].tolist() == reference_minimum_degree(ij, n)


@pytest.mark.parametrize("seed", range(8))
def test_the_csc_pattern_holds_each_upper_entry_once_sorted_and_each_triplet_finds_its_slot(
        seed):
    n = [2, 4, 7, 16, 33, 70, 100, 150][seed]
    g = random_graph(100 + seed, n)
    gn = GaussNewton(g)
    gn._system()  # orders, permutes and finds the pattern
    m, size = g.n_edges, 3 * (n - 1)
    rows, cols = gn._prows[: 36 * m], gn._pcols[: 36 * m]
    kept = (rows >= 0) & (cols >= 0) & (rows <= cols)
    entries = sorted(set(zip(cols[kept].tolist(), rows[kept].tolist())))  # by column, row
    indptr = np.searchsorted([c for c, _ in entries], np.arange(size + 1))
    assert gn._indptr.tolist() == indptr.tolist()
    assert gn._indices.tolist() == [r for _, r in entries]
    where = {entry: k for k, entry in enumerate(entries)}
    slots = [where[(c, r)] if ok else -1 for r, c, ok in zip(rows, cols, kept)]
    assert gn._slot.tolist() == slots
    assert gn._diag.tolist() == [where[(c, c)] for c in range(size)]


def qdldl_reference(n, Ap, Ai, Ax, Lp, etree):
    """QDLDL's up-looking factorisation column by column, in plain Python floats (the same
    IEEE operations in the same order): L's values and D."""
    Li, Lx = [0] * Lp[n], [0.0] * Lp[n]
    D, Dinv, yvals = [0.0] * n, [0.0] * n, [0.0] * n
    nextcol, marker = list(Lp[:n]), [False] * n
    for k in range(n):
        D[k], reach = 0.0, []
        for p in range(Ap[k], Ap[k + 1]):
            b = Ai[p]
            if b == k:
                D[k] += Ax[p]
                continue
            yvals[b] = Ax[p]
            path = []
            while b != -1 and b < k and not marker[b]:
                marker[b] = True
                path.append(b)
                b = etree[b]
            reach += path[::-1]
        for c in reversed(reach):  # children before parents
            yc = yvals[c]
            for j in range(Lp[c], nextcol[c]):
                yvals[Li[j]] -= Lx[j] * yc
            Li[nextcol[c]], Lx[nextcol[c]] = k, yc * Dinv[c]
            D[k] -= yc * Lx[nextcol[c]]
            nextcol[c] += 1
            yvals[c], marker[c] = 0.0, False
        Dinv[k] = 1.0 / D[k]
    return Lx, D


@pytest.mark.parametrize("seed", range(6))
def test_the_factor_is_qdldls_to_the_bit_with_each_blocks_columns_taken_together(seed):
    n = [3, 8, 20, 45, 90, 140][seed]
    g = random_graph(200 + seed, n)
    gn = GaussNewton(g)
    gn._system()
    ldl = gn.ldl
    assert ldl.factor(gn._indptr, gn._indices, gn._data)
    size = ldl.n
    Lx, D = qdldl_reference(size, gn._indptr.tolist(), gn._indices.tolist(), gn._data.tolist(),
                            ldl.Lp.tolist(), ldl.etree.tolist())
    assert ldl.Lx[: ldl.fill].tolist() == Lx
    assert ldl.D[:size].tolist() == D
