"""Worlds: static walls as line segments, read from ``.world`` files (the generators are in
:mod:`swarmslam_sim.generators`; a world by name: :func:`swarmslam_sim.catalog.get_world`).

The ``.world`` format — one statement per line, metres and degrees, ``#`` starts a comment::

    name    office                     # optional, defaults to the file name
    bounds  0 0 20 12                  # xmin ymin xmax ymax: the mapped area (required)
    start   1.5 1.5 90                 # x y heading_deg: the robot's start pose (required)
    wall    0 0 20 0 20 12             # a polyline through ≥ 2 points (x y pairs)
    polygon 4 4 6 4 6 5                # a closed polyline through ≥ 3 points
    box     10 6 1.2 0.6 30            # a rectangle: centre x y, width, height, angle_deg

Everything is stored as segments ``(M, 4)`` (x0 y0 x1 y1): the LiDAR caster and the physics see
exactly the same geometry. Bad input raises :class:`swarmslam.runtime.realtime.text_records.DataFormatError`
naming file, line and field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarmslam.runtime.realtime.text_records import DataFormatError, parse_numbers, records
from swarmslam.runtime.realtime.writers import write_text_atomic


MAX_EXTENT = 1000.0  # m per side: a campus floor fits; the ray caster's grid stays small


def first_wall_outside(segments, bounds) -> int:
    """The index of the first segment with an end outside ``bounds``, or -1."""
    x0, y0, x1, y1 = bounds
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    outside = ~((seg[:, [0, 2]] >= x0) & (seg[:, [0, 2]] <= x1)
                & (seg[:, [1, 3]] >= y0) & (seg[:, [1, 3]] <= y1)).all(axis=1)
    return int(np.argmax(outside)) if outside.any() else -1


@dataclass(frozen=True)
class World:
    name: str
    segments: np.ndarray  # (M, 4) float64, x0 y0 x1 y1
    bounds: tuple[float, float, float, float]  # xmin ymin xmax ymax
    start: tuple[float, float, float]  # x y heading (rad)

    def __post_init__(self):
        seg = np.ascontiguousarray(self.segments, dtype=np.float64)
        if seg.ndim != 2 or seg.shape[1] != 4 or len(seg) == 0:
            raise ValueError(f"world {self.name!r}: segments must be (M, 4) with M ≥ 1, got {seg.shape}")
        object.__setattr__(self, "segments", seg)
        x0, y0, x1, y1 = self.bounds
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"world {self.name!r}: empty bounds {self.bounds}")
        if max(x1 - x0, y1 - y0) > MAX_EXTENT:
            raise ValueError(f"world {self.name!r}: bounds {self.bounds} span "
                             f"{x1 - x0:.6g} × {y1 - y0:.6g} m; at most {MAX_EXTENT:g} m a side")
        k = first_wall_outside(seg, self.bounds)
        if k >= 0:
            raise ValueError(f"world {self.name!r}: wall segment {k + 1} "
                             f"{tuple(float(v) for v in seg[k])} leaves the bounds {self.bounds}")
        if not (x0 < self.start[0] < x1 and y0 < self.start[1] < y1):
            raise ValueError(f"world {self.name!r}: start {self.start[:2]} outside bounds {self.bounds}")

    @property
    def size(self) -> tuple[float, float]:
        return self.bounds[2] - self.bounds[0], self.bounds[3] - self.bounds[1]


def distance_to_walls(segments, x: float, y: float) -> float:
    """The distance (m) from ``(x, y)`` to the nearest wall segment (inf with none)."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    if not len(seg):
        return math.inf
    a, d = seg[:, :2], seg[:, 2:] - seg[:, :2]
    length2 = np.maximum(np.sum(d * d, axis=1), 1e-18)
    t = np.clip(((x - a[:, 0]) * d[:, 0] + (y - a[:, 1]) * d[:, 1]) / length2, 0.0, 1.0)
    near = a + t[:, None] * d
    return float(np.min(np.hypot(near[:, 0] - x, near[:, 1] - y)))


def box_segments(cx, cy, width, height, angle) -> list[tuple[float, float, float, float]]:
    c, s = math.cos(angle), math.sin(angle)
    corners = [(-width / 2, -height / 2), (width / 2, -height / 2),
               (width / 2, height / 2), (-width / 2, height / 2)]
    pts = [(cx + c * x - s * y, cy + s * x + c * y) for x, y in corners]
    return [(*pts[k], *pts[(k + 1) % 4]) for k in range(4)]


def _polyline(path, lineno, field, values, closed):
    need = 3 if closed else 2
    if len(values) % 2 or len(values) < 2 * need:
        raise DataFormatError(path, lineno, field,
                              f"needs ≥ {need} x y pairs, got {len(values)} numbers")
    pts = list(zip(values[0::2], values[1::2]))
    if closed:
        pts.append(pts[0])
    segs = [(*a, *b) for a, b in zip(pts[:-1], pts[1:])]
    for k, (x0, y0, x1, y1) in enumerate(segs):
        if x0 == x1 and y0 == y1:
            raise DataFormatError(path, lineno, f"{field} point {k + 2}", "repeats the previous point")
    return segs


def load_world(path) -> World:
    """Read a ``.world`` file (format in the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"world file not found: {path}")
    name, bounds, start, segs = path.stem, None, None, []
    lines: list[int] = []  # the line each segment came from
    for lineno, tokens in records(path):
        comment = next((k for k, t in enumerate(tokens) if t.startswith("#")), len(tokens))
        key, args = tokens[0], tokens[1:comment]
        if key == "name":
            if len(args) != 1:
                raise DataFormatError(path, lineno, "name", "expected one word")
            name = args[0]
        elif key == "bounds":
            bounds = tuple(parse_numbers(path, lineno, ("xmin", "ymin", "xmax", "ymax"), args))
            if not (bounds[2] > bounds[0] and bounds[3] > bounds[1]):
                raise DataFormatError(path, lineno, "bounds", "xmax must exceed xmin and ymax ymin")
            if max(bounds[2] - bounds[0], bounds[3] - bounds[1]) > MAX_EXTENT:
                raise DataFormatError(path, lineno, "bounds", f"the world may span at most "
                                      f"{MAX_EXTENT:g} m a side")
        elif key == "start":
            x, y, deg = parse_numbers(path, lineno, ("x", "y", "heading_deg"), args)
            start = (x, y, math.radians(deg))
        elif key in ("wall", "polygon"):
            values = parse_numbers(path, lineno, [f"{key} value {k + 1}" for k in range(len(args))],
                                   args) if args else []
            segs += _polyline(path, lineno, key, values, closed=key == "polygon")
            lines += [lineno] * (len(segs) - len(lines))
        elif key == "box":
            cx, cy, w, h, deg = parse_numbers(path, lineno, ("cx", "cy", "width", "height", "angle_deg"),
                                              args)
            if w <= 0 or h <= 0:
                raise DataFormatError(path, lineno, "width" if w <= 0 else "height", "must be > 0")
            segs += box_segments(cx, cy, w, h, math.radians(deg))
            lines += [lineno] * (len(segs) - len(lines))
        else:
            raise DataFormatError(path, lineno, "statement",
                                  f"unknown {key!r} (expected name, bounds, start, wall, polygon, box)")
    if bounds is None:
        raise DataFormatError(path, 0, "bounds", "missing (every world needs 'bounds xmin ymin xmax ymax')")
    if start is None:
        raise DataFormatError(path, 0, "start", "missing (every world needs 'start x y heading_deg')")
    if not segs:
        raise DataFormatError(path, 0, "wall", "the world has no walls")
    if not (bounds[0] < start[0] < bounds[2] and bounds[1] < start[1] < bounds[3]):
        raise DataFormatError(path, 0, "start", f"{start[:2]} lies outside bounds {bounds}")
    k = first_wall_outside(segs, bounds)
    if k >= 0:  # World would refuse it too, but without the line
        raise DataFormatError(path, lines[k], "wall", f"reaches outside bounds {bounds}")
    return World(name, np.array(segs, dtype=np.float64), bounds, start)


def save_world(world: World, path) -> None:
    """Write ``world`` as a ``.world`` file (every segment as a two-point wall)."""
    lines = [f"name {world.name}", "bounds " + " ".join(f"{v:.6g}" for v in world.bounds),
             f"start {world.start[0]:.6g} {world.start[1]:.6g} {math.degrees(world.start[2]):.6g}"]
    lines += ["wall " + " ".join(f"{v:.9g}" for v in s) for s in world.segments]
    write_text_atomic(path, "\n".join(lines) + "\n")
