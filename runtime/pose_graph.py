"""The pose graph (docs/method.md §4): nodes, edges and their errors, in capacities fixed at start.

Nothing grows per scan: node poses, edge endpoints, measurements and information matrices live
in arrays sized at construction. When a capacity is reached, ``add_node``/``add_edge`` raise
:class:`CapacityError` and the graph is left as it was, so the caller can keep localising.

* Edge error (Eq. 18, Grisetti et al. 2010; g2o's SE2 convention) for ``i → j`` measuring ``z``:
  ``e = [R_zᵀ (R_iᵀ (t_j − t_i) − t_z) ; mp(θ_j − θ_i − θ_z)]``.
* Information (Eq. 20): ``Ω = I / σλ²``, with ``σλ`` the matcher's running deviation.
* Total error (Eq. 21, Alg. 8): ``F = Σ eᵀ Ω e``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from swarmslam.runtime.pose import wrap_angle_nb

ODOMETRY = 0
LOOP = 1


@njit(cache=True)
def propagate_covariance(cov_prev, pose_prev, z, z_cov, out):
    """Covariance of ``pose_prev ⊕ z`` (world frame) from those of the two, linearised."""
    c = math.cos(pose_prev[2])
    s = math.sin(pose_prev[2])
    # J_x: ∂(x ⊕ z)/∂x ; J_z: ∂(x ⊕ z)/∂z
    jx = np.eye(3)
    jx[0, 2] = -s * z[0] - c * z[1]
    jx[1, 2] = c * z[0] - s * z[1]
    jz = np.zeros((3, 3))
    jz[0, 0] = c
    jz[0, 1] = -s
    jz[1, 0] = s
    jz[1, 1] = c
    jz[2, 2] = 1.0
    out[:, :] = jx @ cov_prev @ jx.T + jz @ z_cov @ jz.T


class CapacityError(RuntimeError):
    """A fixed capacity of the graph is exhausted."""


@njit(cache=True, inline="always")
def edge_error(poses, i, j, zx, zy, zt):
    """Eq. 18 for one edge ``i → j`` measuring ``(zx, zy, zt)``."""
    ci = math.cos(poses[i, 2])
    si = math.sin(poses[i, 2])
    dx = poses[j, 0] - poses[i, 0]
    dy = poses[j, 1] - poses[i, 1]
    ux = ci * dx + si * dy - zx  # R_iᵀ (t_j − t_i) − t_z
    uy = -si * dx + ci * dy - zy
    cz = math.cos(zt)
    sz = math.sin(zt)
    return cz * ux + sz * uy, -sz * ux + cz * uy, wrap_angle_nb(poses[j, 2] - poses[i, 2] - zt)


@njit(cache=True)
def edge_errors(poses, ij, z, out):
    """Eq. 18 for every edge into ``out`` (E × 3)."""
    for k in range(ij.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = edge_error(poses, ij[k, 0], ij[k, 1], z[k, 0], z[k, 1], z[k, 2])


@njit(cache=True)
def weighted_errors(e, info, out):
    """``eᵀ Ω e`` per edge (Alg. 8's summands)."""
    for k in range(e.shape[0]):
        acc = 0.0
        for a in range(3):
            for b in range(3):
                acc += e[k, a] * info[k, a, b] * e[k, b]
        out[k] = acc


@njit(cache=True)
def add_scaled(z, part, change, first, last):
    """``z[k, :2] += change · part[k]`` for edges ``first`` to ``last`` (in place: a trial
    re-scales every edge of a large graph, and an array per call would grow the heap)."""
    for k in range(first, last):
        z[k, 0] += change * part[k, 0]
        z[k, 1] += change * part[k, 1]


def information_from_sigma(sigma_lambda: float) -> np.ndarray:
    """Eq. 20: ``Ω = I / σλ²``."""
    if not sigma_lambda > 0:
        raise ValueError(f"σλ must be > 0 for Eq. 20, got {sigma_lambda}")
    return np.eye(3) / (sigma_lambda * sigma_lambda)


class PoseGraph:
    def __init__(self, max_nodes: int, max_edges: int):
        if max_nodes < 1 or max_edges < 0:
            raise ValueError(f"capacities must be positive, got {max_nodes}, {max_edges}")
        self.poses = np.zeros((max_nodes, 3))
        self.stamps = np.zeros(max_nodes)
        self.ij = np.zeros((max_edges, 2), np.int64)
        self.z = np.zeros((max_edges, 3))
        self.info = np.zeros((max_edges, 3, 3))
        self.kind = np.zeros(max_edges, np.int8)
        # Odometry's scale (docs/method.md §6.1, "Odometry's scale"): per edge, the translation
        # it took from odometry's prediction along a degenerate axis, as read (in its first
        # node's frame); the scale its measurement holds that part at; and the scale fitted
        # now, which the back end's next optimisation brings every edge to (:meth:`rescale`).
        self.odometry_part = np.zeros((max_edges, 2))
        self.scale = 1.0
        self.scale_target = 1.0
        self._e = np.zeros((max_edges, 3))
        self._w = np.zeros(max_edges)
        self.n_nodes = 0
        self.n_edges = 0
        # Bumped by every change of the edge set, so solvers can cache its sparsity pattern:
        # removing an edge and adding another leaves the counts alike but the pattern not.
        self.revision = 0

    @property
    def max_nodes(self) -> int:
        return self.poses.shape[0]

    @property
    def max_edges(self) -> int:
        return self.ij.shape[0]

    def add_node(self, pose, stamp: float = 0.0) -> int:
        if self.n_nodes >= self.max_nodes:
            raise CapacityError(f"node capacity {self.max_nodes} reached")
        k = self.n_nodes
        self.poses[k] = pose
        self.stamps[k] = stamp
        self.n_nodes += 1
        return k

    def add_edge(self, i: int, j: int, z, info, kind: int = ODOMETRY, odometry_part=None) -> int:
        """Edge ``i`` → ``j`` measuring ``z`` (in ``i``'s frame); ``odometry_part``: the
        translation of it odometry's prediction gave along a degenerate axis, as read (``z``
        holds it at :attr:`scale`; none by default)."""
        if self.n_edges >= self.max_edges:
            raise CapacityError(f"edge capacity {self.max_edges} reached")
        if not (0 <= i < self.n_nodes and 0 <= j < self.n_nodes) or i == j:
            raise ValueError(f"edge {i} -> {j} needs two distinct existing nodes")
        k = self.n_edges
        self.ij[k] = (i, j)
        self.z[k] = z
        self.info[k] = info
        self.kind[k] = kind
        if odometry_part is None:
            self.odometry_part[k] = 0.0
        else:
            self.odometry_part[k] = odometry_part
        self.n_edges += 1
        self.revision += 1
        return k

    def rescale(self, scale: float, first: int = 0) -> None:
        """Every edge from ``first`` on with its odometry part at ``scale`` instead of
        :attr:`scale` (which becomes ``scale`` when ``first`` is 0)."""
        change = scale - self.scale
        if change != 0.0:
            add_scaled(self.z, self.odometry_part, change, first, self.n_edges)
        if first == 0:
            self.scale = scale

    def remove_last_edge(self) -> None:
        if self.n_edges == 0:
            raise ValueError("no edge to remove")
        self.n_edges -= 1
        self.revision += 1

    def remove_edges(self, edges) -> None:
        """Take out the edges with indices ``edges`` (distinct), the others keeping their
        order and moving down in place (no array allocated)."""
        m = self.n_edges
        if any(not 0 <= int(k) < m for k in edges):
            raise ValueError(f"no edge {list(edges)} among {m}")
        kept = 0
        for k in range(m):
            if any(int(e) == k for e in edges):
                continue
            if kept != k:
                self.ij[kept], self.z[kept] = self.ij[k], self.z[k]
                self.info[kept], self.kind[kept] = self.info[k], self.kind[k]
                self.odometry_part[kept] = self.odometry_part[k]
            kept += 1
        self.n_edges = kept
        self.revision += 1

    def copy_from(self, other: "PoseGraph") -> None:
        """Take ``other``'s nodes and edges into this graph's buffers (no allocation; the
        capacities must hold them). The revision moves on from this graph's own, so that a
        solver's cached pattern never takes the copy for an edge set it saw before."""
        n, m = other.n_nodes, other.n_edges
        if n > self.max_nodes or m > self.max_edges:
            raise CapacityError(f"{n} nodes and {m} edges exceed the capacities "
                                f"{self.max_nodes} and {self.max_edges}")
        self.poses[:n], self.stamps[:n] = other.poses[:n], other.stamps[:n]
        self.ij[:m], self.z[:m], self.info[:m] = other.ij[:m], other.z[:m], other.info[:m]
        self.kind[:m] = other.kind[:m]
        self.odometry_part[:m] = other.odometry_part[:m]
        self.scale, self.scale_target = other.scale, other.scale_target
        self.n_nodes, self.n_edges = n, m
        self.revision += 1

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        n, m = self.n_nodes, self.n_edges
        return {"poses": self.poses[:n].copy(), "stamps": self.stamps[:n].copy(),
                "ij": self.ij[:m].copy(), "z": self.z[:m].copy(), "info": self.info[:m].copy(),
                "kind": self.kind[:m].copy(), "revision": self.revision,
                "odometry_part": self.odometry_part[:m].copy(),
                "scale": np.array([self.scale, self.scale_target])}

    def restore(self, state: dict) -> None:
        n, m = len(state["poses"]), len(state["ij"])
        if n > self.max_nodes or m > self.max_edges:
            raise ValueError(f"{n} nodes and {m} edges exceed the capacities {self.max_nodes} "
                             f"and {self.max_edges}")
        ij = state["ij"]
        if m and (ij.min() < 0 or ij.max() >= n or np.any(ij[:, 0] == ij[:, 1])):
            raise ValueError("an edge joins nodes that do not exist")
        if not all(np.all(np.isfinite(state[k])) for k in ("poses", "z", "info")):
            raise ValueError("the graph holds non-finite poses or edge measurements")
        part = np.asarray(state["odometry_part"], np.float64)
        scale = np.asarray(state["scale"], np.float64)
        if (part.shape != (m, 2) or scale.shape != (2,) or not np.all(np.isfinite(part))
                or not np.all(np.isfinite(scale)) or not np.all(scale > 0)):
            raise ValueError("the graph's odometry parts are not two finite numbers per edge, "
                             "or its scales not two positive ones")
        self.n_nodes, self.n_edges = n, m
        self.poses[:n], self.stamps[:n] = state["poses"], state["stamps"]
        self.ij[:m], self.z[:m], self.info[:m] = ij, state["z"], state["info"]
        self.kind[:m] = state["kind"]
        self.odometry_part[:m] = part
        self.scale, self.scale_target = float(scale[0]), float(scale[1])
        self.revision = int(state["revision"])

    def errors(self) -> np.ndarray:
        """Eq. 18 for every edge, ``(E, 3)`` (a view of an internal buffer)."""
        n = self.n_edges
        edge_errors(self.poses, self.ij[:n], self.z[:n], self._e[:n])
        return self._e[:n]

    def edge_chi2(self) -> np.ndarray:
        """``eᵀ Ω e`` for every edge (a view of an internal buffer)."""
        n = self.n_edges
        weighted_errors(self.errors(), self.info[:n], self._w[:n])
        return self._w[:n]

    def chi2(self) -> float:
        """Eq. 21 / Alg. 8: the total error ``F = Σ eᵀ Ω e``."""
        return float(np.sum(self.edge_chi2()))

    @classmethod
    def from_arrays(cls, poses, ij, z, info, kind=None, max_nodes=None, max_edges=None):
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        ij = np.asarray(ij, dtype=np.int64).reshape(-1, 2)
        g = cls(max_nodes or max(len(poses), 1), max_edges or len(ij))
        g.n_nodes = len(poses)
        g.poses[: len(poses)] = poses
        g.n_edges = len(ij)
        g.ij[: len(ij)] = ij
        g.z[: len(ij)] = z
        g.info[: len(ij)] = info
        if kind is not None:
            g.kind[: len(ij)] = kind
        return g
