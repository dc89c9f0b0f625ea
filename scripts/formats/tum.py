"""Trajectories in TUM format (``timestamp tx ty tz qx qy qz qw``), readable by ``evo``."""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.realtime.writers import write_text_atomic


def tum_lines(timestamps, poses) -> str:
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    if len(t) != len(poses):
        raise ValueError(f"{len(t)} timestamps for {len(poses)} poses")
    half = poses[:, 2] / 2.0  # rotation about z: q = (0, 0, sin θ/2, cos θ/2)
    return "".join(
        f"{ti:.6f} {x:.6f} {y:.6f} 0.000000 0.000000 0.000000 {np.sin(h):.9f} {np.cos(h):.9f}\n"
        for ti, (x, y, _), h in zip(t, poses, half)
    )


def write_tum(path, timestamps, poses):
    return write_text_atomic(path, tum_lines(timestamps, poses))


def read_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps and planar poses of a TUM file (yaw from the quaternion)."""
    t, poses = [], []
    with open(path) as f:
        for lineno, line in enumerate(f, start=1):
            if not line.strip() or line.startswith("#"):
                continue
            v = line.split()
            if len(v) != 8:
                raise ValueError(f"{path}:{lineno}: expected 8 fields, got {len(v)}")
            ts, x, y, _, qx, qy, qz, qw = map(float, v)
            t.append(ts)
            poses.append((x, y, 2.0 * np.arctan2(qz, qw)))
    return np.array(t), np.array(poses).reshape(-1, 3)
