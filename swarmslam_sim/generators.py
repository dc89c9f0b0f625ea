"""Seeded procedural worlds: rooms off a corridor, a maze, open space with clutter.

Each generator is a pure function of its seed, so a seed names a world. Obstacles keep a
clearance around the start pose so that an episode never begins in collision.
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam_sim.world import World, box_segments

START_CLEARANCE = 0.8  # m between the start pose and any obstacle


def _outline(w, h):
    return [(0, 0, w, 0), (w, 0, w, h), (w, h, 0, h), (0, h, 0, 0)]


def _wall_with_doors(a, b, fixed, doors, horizontal):
    """Segments of a straight wall from ``a`` to ``b`` at ``fixed``, minus door intervals."""
    segs, pos = [], a
    for d0, d1 in sorted(doors):
        if d0 > pos:
            segs.append((pos, d0))
        pos = max(pos, d1)
    if pos < b:
        segs.append((pos, b))
    return [(s, fixed, e, fixed) if horizontal else (fixed, s, fixed, e) for s, e in segs]


def _place_boxes(rng, segs, count, region, size, keep_clear, clearance=START_CLEARANCE):
    (x0, y0, x1, y1), (smin, smax) = region, size
    for _ in range(count):
        w, h = rng.uniform(smin, smax, size=2)
        cx, cy = rng.uniform(x0 + w, x1 - w), rng.uniform(y0 + h, y1 - h)
        if any(math.hypot(cx - px, cy - py) < clearance + max(w, h) for px, py in keep_clear):
            continue
        segs += box_segments(cx, cy, w, h, rng.uniform(0, math.pi))


def rooms(seed: int = 0, rooms_per_side: int = 4, room=(4.0, 4.5), corridor: float = 2.0) -> World:
    """Rooms on both sides of a straight corridor, one door each, furniture inside."""
    rng = np.random.default_rng(seed)
    w = rooms_per_side * room[0]
    h = 2 * room[1] + corridor
    ys, yn = room[1], room[1] + corridor  # corridor walls
    segs = _outline(w, h)
    start = (1.0, ys + corridor / 2, 0.0)
    for side_y, room_y in ((ys, 0.0), (yn, yn)):
        doors = []
        for k in range(rooms_per_side):
            d = rng.uniform(k * room[0] + 0.4, (k + 1) * room[0] - 1.6)
            doors.append((d, d + rng.uniform(0.9, 1.2)))
            if k:
                segs.append((k * room[0], room_y, k * room[0], room_y + room[1]))
            _place_boxes(rng, segs, 2, (k * room[0] + 0.3, room_y + 0.3, (k + 1) * room[0] - 0.3,
                                        room_y + room[1] - 0.3), (0.4, 1.0),
                         keep_clear=[start[:2], ((doors[-1][0] + doors[-1][1]) / 2, side_y)],
                         clearance=1.2)
        segs += _wall_with_doors(0, w, side_y, doors, horizontal=True)
    return World(f"rooms-{seed}", np.array(segs, float), (-0.5, -0.5, w + 0.5, h + 0.5), start)


def maze(seed: int = 0, cells=(7, 5), cell: float = 2.0) -> World:
    """A perfect maze (randomised depth-first search) of ``cells`` square cells."""
    rng = np.random.default_rng(seed)
    nx, ny = cells
    # walls[0][x, y]: wall on the east side of cell (x, y); walls[1][x, y]: on its north side
    east = np.ones((nx, ny), bool)
    north = np.ones((nx, ny), bool)
    seen = np.zeros((nx, ny), bool)
    stack = [(0, 0)]
    seen[0, 0] = True
    while stack:
        x, y = stack[-1]
        options = [(dx, dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
                   if 0 <= x + dx < nx and 0 <= y + dy < ny and not seen[x + dx, y + dy]]
        if not options:
            stack.pop()
            continue
        dx, dy = options[rng.integers(len(options))]
        if dx == 1:
            east[x, y] = False
        elif dx == -1:
            east[x - 1, y] = False
        elif dy == 1:
            north[x, y] = False
        else:
            north[x, y - 1] = False
        seen[x + dx, y + dy] = True
        stack.append((x + dx, y + dy))
    segs = _outline(nx * cell, ny * cell)
    for x in range(nx):
        for y in range(ny):
            if east[x, y] and x < nx - 1:
                segs.append(((x + 1) * cell, y * cell, (x + 1) * cell, (y + 1) * cell))
            if north[x, y] and y < ny - 1:
                segs.append((x * cell, (y + 1) * cell, (x + 1) * cell, (y + 1) * cell))
    start = (cell / 2, cell / 2, 0.0)
    return World(f"maze-{seed}", np.array(segs, float),
                 (-0.5, -0.5, nx * cell + 0.5, ny * cell + 0.5), start)


def clutter(seed: int = 0, size=(14.0, 14.0), obstacles: int = 40) -> World:
    """Open space walled in, strewn with boxes of 0.2–1 m."""
    rng = np.random.default_rng(seed)
    w, h = size
    segs = _outline(w, h)
    start = (w / 2, h / 2, 0.0)
    _place_boxes(rng, segs, obstacles, (0.0, 0.0, w, h), (0.2, 1.0), keep_clear=[start[:2]])
    return World(f"clutter-{seed}", np.array(segs, float), (-0.5, -0.5, w + 0.5, h + 0.5), start)


GENERATORS = {"rooms": rooms, "maze": maze, "clutter": clutter}
