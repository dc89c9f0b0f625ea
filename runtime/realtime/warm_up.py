"""The synthetic drive the runtime warms up on (:meth:`swarmslam.runtime.realtime.fixed_rate.SlamRuntime.warm_up`):
scans of a line-segment world along a loop, so that every compiled path — matching, node
insertion, loop closure, optimisation — runs once before the first real tick. It is part of the
core because a robot must warm up without a simulator or a log; tests, demos and soak runs use
it too.

A deliberately small ray caster in numpy (exact ray/segment intersection); the simulator in
``swarmslam_sim`` has the fast, physical one. Worlds come from seeded generators, so every
synthetic run is reproducible.
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.pose import between, compose


def room_world(seed: int = 0, size=(10.0, 8.0), boxes: int = 6, walls: int = 2,
               keep_clear=None, clearance: float = 0.8) -> np.ndarray:
    """A walled room with interior partial walls and boxes; segments ``(M, 4)`` as x0 y0 x1 y1.

    Boxes centred within ``clearance`` of any point of ``keep_clear`` (``(K, 2)``, e.g. a
    planned path) are left out.
    """
    rng = np.random.default_rng(seed)
    clear = None if keep_clear is None else np.asarray(keep_clear, dtype=np.float64)[:, :2]
    w, h = size
    segs = [(0, 0, w, 0), (w, 0, w, h), (w, h, 0, h), (0, h, 0, 0)]
    for _ in range(walls):  # partial walls from the outer boundary, leaving doorways
        if rng.random() < 0.5:
            x = rng.uniform(0.3 * w, 0.7 * w)
            y1 = rng.uniform(0.3 * h, 0.6 * h)
            segs.append((x, 0, x, y1) if rng.random() < 0.5 else (x, h, x, h - y1))
        else:
            y = rng.uniform(0.3 * h, 0.7 * h)
            x1 = rng.uniform(0.3 * w, 0.6 * w)
            segs.append((0, y, x1, y) if rng.random() < 0.5 else (w, y, w - x1, y))
    for _ in range(boxes):
        cx, cy = rng.uniform(1.0, w - 1.0), rng.uniform(1.0, h - 1.0)
        bw, bh = rng.uniform(0.2, 0.8, size=2)
        a = rng.uniform(0, np.pi)
        if clear is not None and np.min(np.hypot(*(clear - (cx, cy)).T)) < clearance:
            continue
        corners = np.array([[-bw, -bh], [bw, -bh], [bw, bh], [-bw, bh]]) / 2
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        c = corners @ rot.T + (cx, cy)
        for k in range(4):
            segs.append((*c[k], *c[(k + 1) % 4]))
    return np.asarray(segs, dtype=np.float64)


def cast_rays(segments, pose, angles, max_range: float) -> np.ndarray:
    """Ranges from ``pose`` along beam ``angles`` (sensor frame) to the nearest segment.

    Beams that hit nothing within ``max_range`` return ``max_range`` (an invalid reading, as
    real scanners report "no return").
    """
    x, y, t = pose
    a = np.asarray(angles, dtype=np.float64) + t
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]
    s = np.asarray(segments, dtype=np.float64)
    ex, ey = (s[:, 2] - s[:, 0])[None, :], (s[:, 3] - s[:, 1])[None, :]
    wx, wy = (s[:, 0] - x)[None, :], (s[:, 1] - y)[None, :]
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        tr = (wx * ey - wy * ex) / den  # distance along the ray
        us = (wx * dy - wy * dx) / den  # position along the segment
    hit = (np.abs(den) > 1e-12) & (tr > 0) & (us >= 0) & (us <= 1)
    r = np.where(hit, tr, np.inf).min(axis=1)
    return np.minimum(r, max_range)


def scan_at(segments, pose, angles, max_range=12.0, noise=0.0, rng=None) -> np.ndarray:
    """A scan's ranges at ``pose`` with optional Gaussian range noise (std ``noise``, m)."""
    r = cast_rays(segments, pose, angles, max_range)
    if noise > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        valid = r < max_range
        r = r.copy()
        r[valid] += rng.normal(0.0, noise, size=int(valid.sum()))
    return r


def pose_after(pose, motion) -> np.ndarray:
    """The pose reached from ``pose`` by a relative ``motion`` (Eq. 1)."""
    return compose(np.asarray(pose, dtype=np.float64), np.asarray(motion, dtype=np.float64))


def loop_path(steps: int, centre=(6.0, 4.5), radii=(3.6, 2.4)) -> np.ndarray:
    """Poses along an ellipse, heading along the path."""
    s = np.linspace(0.0, 2 * np.pi, steps, endpoint=False)
    x = centre[0] + radii[0] * np.cos(s)
    y = centre[1] + radii[1] * np.sin(s)
    heading = np.arctan2(radii[1] * np.cos(s), -radii[0] * np.sin(s))
    return np.c_[x, y, heading]


class LoopDrive:
    """A robot driving lap after lap of :func:`loop_path` in a seeded room: each ``next()``
    gives the true pose, the integrated noisy wheel odometry and a noisy 360-beam scan.
    Endless, so soak runs can last as long as asked."""

    def __init__(self, seed: int = 0, steps_per_lap: int = 80, odometry_noise=(0.02, 0.02, 0.01),
                 range_noise: float = 0.01, beams: int = 360, max_range: float = 12.0):
        self.path = loop_path(steps_per_lap)
        self.world = room_world(seed, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=self.path)
        self.angles = np.linspace(-np.pi, np.pi, beams, endpoint=False)
        self.max_range = max_range
        self.range_noise = range_noise
        self.odometry_noise = np.asarray(odometry_noise, dtype=np.float64)
        self.rng = np.random.default_rng(seed)
        self.step = 0
        self.odometry = self.path[0].copy()

    def next(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(self.path)
        truth = self.path[self.step % n]
        if self.step:
            previous = self.path[(self.step - 1) % n]
            motion = between(truth, previous) + self.rng.normal(0.0, self.odometry_noise)
            self.odometry = compose(self.odometry, motion)
        ranges = scan_at(self.world, truth, self.angles, self.max_range, self.range_noise, self.rng)
        self.step += 1
        return truth, self.odometry.copy(), ranges
