"""Seeded procedural worlds: rooms off a corridor, a maze, open space with clutter, and the
building-scale floors of the generalization suite (a building with corridor loops, a long
featureless corridor ring, a hall wider than a scanner's reach).

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


def _rect(x0, y0, x1, y1):
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def _doors(rng, a, b, spacing, width=(0.9, 1.2)):
    """Door intervals along ``[a, b]``, one per ``spacing`` (range) metres, seeded."""
    doors, pos = [], a + rng.uniform(1.0, spacing[0])
    while pos + width[1] < b - 1.0:
        w = rng.uniform(*width)
        doors.append((pos, pos + w))
        pos += w + rng.uniform(*spacing)
    return doors


def _room_row(rng, segs, a, b, y_wall, depth, horizontal, spacing=(3.5, 6.0)):
    """Partition walls every ``spacing`` metres along ``[a, b]``: rooms ``depth`` deep
    behind the wall at ``y_wall`` (``depth`` signed: the side the rooms lie on), a box or two
    of furniture in each."""
    pos = a
    while pos < b - 2.0:
        nxt = min(pos + rng.uniform(*spacing), b)
        if b - nxt < 2.0:
            nxt = b
        if nxt < b:
            segs.append((nxt, y_wall, nxt, y_wall + depth) if horizontal
                        else (y_wall, nxt, y_wall + depth, nxt))
        lo, hi = sorted((y_wall, y_wall + depth))
        for _ in range(rng.integers(1, 3)):
            w, h = rng.uniform(0.4, 1.1, size=2)
            room = (nxt - pos) / 2 - 0.3  # a narrow last room (2 m at least) takes a
            if w > room:  # narrower box, or the draw has no range (and other rooms as before)
                w = room - 0.05
            u = rng.uniform(pos + 0.3 + w, nxt - 0.3 - w)
            v = rng.uniform(lo + 0.3 + h, hi - 0.3 - h)
            segs += box_segments(*((u, v) if horizontal else (v, u)), w, h, rng.uniform(0, math.pi))
        pos = nxt


def building(seed: int = 0, size=(36.0, 22.0), room_depth: float = 4.0,
             corridor: float = 2.0) -> World:
    """A building floor: a ring corridor (a 76 m loop at the default size) between rooms on
    the outer walls and a core of rooms, crossed in the middle by a second corridor (two
    shorter loops); doors into every room, furniture inside."""
    rng = np.random.default_rng(seed)
    w, h = size
    d, c = room_depth, corridor
    segs = _outline(w, h)
    xm = w / 2  # the cross corridor's centre
    # The corridor's outer walls (rooms behind them, on the building's outline).
    for y, depth in ((d, -d), (h - d, d)):
        segs += _wall_with_doors(d, w - d, y, _doors(rng, d, w - d, (3.0, 6.0)), True)
        _room_row(rng, segs, 0.0, w, y, depth, True)
    for x, depth in ((d, -d), (w - d, d)):
        segs += _wall_with_doors(d, h - d, x, _doors(rng, d, h - d, (3.0, 6.0)), False)
        _room_row(rng, segs, d, h - d, x, depth, False)
    # The core: two blocks of rooms either side of the cross corridor.
    y0, y1 = d + c, h - d - c
    for x0, x1 in ((d + c, xm - c / 2), (xm + c / 2, w - d - c)):
        for y, depth in ((y0, (y1 - y0) / 2), (y1, -(y1 - y0) / 2)):
            segs += _wall_with_doors(x0, x1, y, _doors(rng, x0, x1, (3.0, 5.0)), True)
            _room_row(rng, segs, x0, x1, y, depth, True, spacing=(3.0, 4.5))
        segs += [(x0, y0, x0, y1), (x1, y0, x1, y1)]
    start = (d + c / 2, d + c / 2, 0.0)
    return World(f"building-{seed}", np.array(segs, float), (-0.5, -0.5, w + 0.5, h + 0.5), start)


def corridor(seed: int = 0, size=(60.0, 10.0), width: float = 2.0) -> World:
    """A ring of long, plain corridors (a 132 m loop at the default size) around a closed
    core; a shallow door recess every 8–16 m is all that breaks the walls."""
    rng = np.random.default_rng(seed)
    w, h = size
    segs = []
    for x0, y0, x1, y1, out in ((0, 0, w, h, True), (width, width, w - width, h - width, False)):
        for horizontal, fixed, a, b in ((True, y0, x0, x1), (True, y1, x0, x1),
                                        (False, x0, y0, y1), (False, x1, y0, y1)):
            doors = _doors(rng, a, b, (8.0, 16.0))
            segs += _wall_with_doors(a, b, fixed, doors, horizontal)
            # the recess behind each door: 0.3 m deep, away from the corridor
            sign = (-1 if fixed == (y0 if horizontal else x0) else 1) * (1 if out else -1)
            for u0, u1 in doors:
                depth = fixed + 0.3 * sign
                segs += ([(u0, fixed, u0, depth), (u0, depth, u1, depth), (u1, depth, u1, fixed)]
                         if horizontal else
                         [(fixed, u0, depth, u0), (depth, u0, depth, u1), (depth, u1, fixed, u1)])
    start = (width / 2, width / 2, 0.0)
    return World(f"corridor-{seed}", np.array(segs, float), (-1.0, -1.0, w + 1.0, h + 1.0),
                 start)


def hall(seed: int = 0, size=(40.0, 26.0), pillar_spacing: float = 9.0) -> World:
    """A hall wider than a 12 m scanner's reach: bare walls, a grid of 0.5 m pillars and a few
    crates."""
    rng = np.random.default_rng(seed)
    w, h = size
    segs = _outline(w, h)
    for px in np.arange(pillar_spacing / 2 + 2.0, w - 2.0, pillar_spacing):
        for py in np.arange(pillar_spacing / 2 + 1.0, h - 2.0, pillar_spacing):
            segs += box_segments(px, py, 0.5, 0.5, 0.0)
    start = (w / 4, h / 2 - 3.5, 0.0)
    for x0, x1 in ((1.0, w / 4 - 3.0), (3 * w / 4 + 3.0, w - 1.0)):  # crates off the floor's middle
        _place_boxes(rng, segs, 3, (x0, 1.0, x1, h - 1.0), (0.5, 1.5), keep_clear=[])
    return World(f"hall-{seed}", np.array(segs, float), (-0.5, -0.5, w + 0.5, h + 0.5), start)


GENERATORS = {"rooms": rooms, "maze": maze, "clutter": clutter, "building": building,
              "corridor": corridor, "hall": hall}
