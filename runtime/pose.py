"""2-D poses ``(x, y, θ)`` and their algebra (docs/method.md §1, Eqs. 1–6).

Two flavours of every operation:

* numpy functions (``compose``, ``between``, ...) that broadcast over arrays of poses of
  shape ``(..., 3)``, for readers, metrics and tests;
* numba kernels (``*_nb``) on scalars, for the compiled hot paths. They return tuples, which
  numba keeps in registers: no allocation.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------- numba kernels (scalars)
@njit(cache=True, inline="always")
def wrap_angle_nb(d):
    """Eq. 3: ``mp(d) = d − 2π·floor((d+π)/2π)``, in ``[-π, π)``."""
    w = d - TWO_PI * math.floor((d + math.pi) / TWO_PI)
    # Rounding can land exactly on +π for inputs a hair below it; keep the half-open range.
    if w >= math.pi:
        w -= TWO_PI
    return w


@njit(cache=True, inline="always")
def compose_nb(xb, yb, tb, x, y, t):
    """Eq. 1: ``Va = Vb ⊕ D``."""
    c = math.cos(tb)
    s = math.sin(tb)
    return xb + x * c - y * s, yb + x * s + y * c, wrap_angle_nb(tb + t)


@njit(cache=True, inline="always")
def between_nb(xa, ya, ta, xb, yb, tb):
    """Eq. 2: ``D = Va ⊖ Vb``, the pose of ``a`` seen from ``b``."""
    c = math.cos(tb)
    s = math.sin(tb)
    dx = xa - xb
    dy = ya - yb
    return dx * c + dy * s, -dx * s + dy * c, wrap_angle_nb(ta - tb)


@njit(cache=True, inline="always")
def transform_point_nb(x, y, t, px, py):
    """Eq. 5: point ``(px, py)`` of frame ``(x, y, t)`` in the parent frame."""
    c = math.cos(t)
    s = math.sin(t)
    return x + px * c - py * s, y + px * s + py * c


@njit(cache=True)
def place_points_nb(poses, a, b, points, count, out, offset):
    """Points ``points[:count]`` of frame ``poses[a]`` written into ``out[offset:]`` in the
    frame of ``poses[b]`` (Eqs. 2 and 5, no temporaries); returns the next offset."""
    x, y, t = between_nb(poses[a, 0], poses[a, 1], poses[a, 2], poses[b, 0], poses[b, 1], poses[b, 2])
    for i in range(count):
        out[offset + i, 0], out[offset + i, 1] = transform_point_nb(x, y, t, points[i, 0], points[i, 1])
    return offset + count


# ---------------------------------------------------------------- numpy (vectorised)
def wrap_angle(d):
    """Eq. 3 on arrays or scalars, result in ``[-π, π)``."""
    d = np.asarray(d, dtype=np.float64)
    w = d - TWO_PI * np.floor((d + np.pi) / TWO_PI)
    return np.where(w >= np.pi, w - TWO_PI, w)


def _split(p):
    p = np.asarray(p, dtype=np.float64)
    if p.shape[-1] != 3:
        raise ValueError(f"a pose has 3 components (x, y, theta); got shape {p.shape}")
    return p[..., 0], p[..., 1], p[..., 2]


def compose(vb, d):
    """Eq. 1: ``Vb ⊕ D`` for poses of shape ``(..., 3)`` (broadcasting)."""
    xb, yb, tb = _split(vb)
    x, y, t = _split(d)
    c, s = np.cos(tb), np.sin(tb)
    return np.stack([xb + x * c - y * s, yb + x * s + y * c, wrap_angle(tb + t)], axis=-1)


def between(va, vb):
    """Eq. 2: ``Va ⊖ Vb``, the pose of ``a`` in the frame of ``b``."""
    xa, ya, ta = _split(va)
    xb, yb, tb = _split(vb)
    c, s = np.cos(tb), np.sin(tb)
    dx, dy = xa - xb, ya - yb
    return np.stack([dx * c + dy * s, -dx * s + dy * c, wrap_angle(ta - tb)], axis=-1)


def interpolate(va, vb, w):
    """Poses ``w`` of the way from ``va`` to ``vb`` (``w`` in [0, 1], broadcasting): the
    position on the line, the heading along the shorter arc (Eq. 3)."""
    xa, ya, ta = _split(va)
    xb, yb, tb = _split(vb)
    w = np.asarray(w, dtype=np.float64)
    return np.stack([xa + w * (xb - xa), ya + w * (yb - ya),
                     wrap_angle(ta + w * wrap_angle(tb - ta))], axis=-1)


def inverse(d):
    """Eq. 4: ``Dba = (0,0,0) ⊖ Dab``."""
    d = np.asarray(d, dtype=np.float64)
    return between(np.zeros_like(d), d)


def transform_points(pose, points):
    """Eq. 5: points ``(N, 2)`` of frame ``pose`` expressed in the parent frame."""
    x, y, t = _split(pose)
    pts = np.asarray(points, dtype=np.float64)
    c, s = np.cos(t), np.sin(t)
    return np.stack(
        [x + pts[..., 0] * c - pts[..., 1] * s, y + pts[..., 0] * s + pts[..., 1] * c], axis=-1
    )


def to_matrix(pose):
    """Eq. 6: homogeneous 3×3 matrix (or ``(..., 3, 3)``) of a pose."""
    x, y, t = _split(pose)
    c, s = np.cos(t), np.sin(t)
    m = np.zeros(np.shape(x) + (3, 3))
    m[..., 0, 0], m[..., 0, 1], m[..., 0, 2] = c, -s, x
    m[..., 1, 0], m[..., 1, 1], m[..., 1, 2] = s, c, y
    m[..., 2, 2] = 1.0
    return m


def from_matrix(m):
    """Inverse of :func:`to_matrix`."""
    m = np.asarray(m, dtype=np.float64)
    return np.stack([m[..., 0, 2], m[..., 1, 2], np.arctan2(m[..., 1, 0], m[..., 0, 0])], axis=-1)
