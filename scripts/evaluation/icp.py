"""Point-to-point ICP with a scipy k-d tree: the local-method baseline the swarm is measured
against (Besl & McKay 1992, closed-form 2-D alignment per iteration)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from swarmslam.runtime.pose import compose, transform_points


def icp(reference, current, initial=(0.0, 0.0, 0.0), max_iterations=50, tolerance=1e-6,
        max_correspondence=1.0, tree: cKDTree | None = None):
    """Pose of ``current`` in ``reference``'s frame, from ``initial``.

    Correspondences farther than ``max_correspondence`` (m) are ignored. Returns the pose and
    the iterations used. ``tree``: ``reference``'s k-d tree, when the caller has built it.
    """
    tree = cKDTree(reference) if tree is None else tree
    pose = np.asarray(initial, dtype=np.float64).copy()
    for iteration in range(1, max_iterations + 1):
        moved = transform_points(pose, current)
        dist, idx = tree.query(moved, distance_upper_bound=max_correspondence)
        ok = np.isfinite(dist)
        if ok.sum() < 3:
            break
        p, q = moved[ok], reference[idx[ok]]
        pc, qc = p.mean(axis=0), q.mean(axis=0)
        h = (p - pc).T @ (q - qc)
        theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
        c, s = np.cos(theta), np.sin(theta)
        t = qc - np.array([c * pc[0] - s * pc[1], s * pc[0] + c * pc[1]])
        pose = compose(np.array([t[0], t[1], theta]), pose)
        if np.hypot(t[0], t[1]) < tolerance and abs(theta) < tolerance:
            break
    return pose, iteration
