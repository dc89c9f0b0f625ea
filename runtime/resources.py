"""What a configuration's capacities cost in memory, checked before anything is allocated
(docs/runtime.md §4): a run that cannot fit is refused at start-up, naming the fields, not
killed by the kernel hours in.

    check_memory(config)        # ValueError when the buffers would not fit
"""

from __future__ import annotations

import os

from swarmslam.runtime.config import SlamConfig

FLOAT, INT = 8, 8  # bytes
# The share of the memory available now that a run may take: the rest is the interpreter's,
# the maps drawn on demand and every other program's.
MEMORY_SHARE = 0.8


def estimated_bytes(config: SlamConfig) -> dict[str, int]:
    """The buffers fixed at start-up, by what sizes them (the large ones; the rest is small
    and constant)."""
    c = config
    points, nodes = c.sensor.max_points, c.capacity.max_nodes
    cells = c.matcher.grid_cells
    coarse = cells * c.matcher.resolution / c.matcher.coarse_resolution \
        if c.matcher.coarse_resolution > 0 else 1
    grid = cells * cells if c.matcher.scan_to_map else 0  # the local grid (uint8)
    reference = cells * cells * 4 + grid + int(coarse) ** 2 * 4  # fields (float32)
    return {
        "capacity.max_nodes × sensor.max_points (node scans)": nodes * (points * 2 * FLOAT
                                                                        + 9 * FLOAT + 4 * FLOAT),
        # per edge: its measurement, information, error and odometry's part
        "capacity.max_edges (pose graph)": c.capacity.max_edges * (3 + 9 + 3 + 2) * FLOAT,
        "capacity.max_scans (trajectory)": c.capacity.max_scans * 5 * FLOAT,
        "matcher.grid_cells (reference grids, three matchers)": 3 * reference,
        "sensor.max_points × submaps": points * 2 * FLOAT * (
            c.front_end.submap_nodes + 2 * c.loop_closure.submap_nodes + 1
            + c.loop_closure.wide_search.query_nodes),
        "matcher.swarm.members (swarm workspaces)": 3 * (c.matcher.swarm.members or 100) * 16
        * FLOAT,
        "runtime.latency_window": c.runtime.latency_window * FLOAT,
    }


def available_bytes() -> int | None:
    """The memory available to a new program now (Linux's MemAvailable), if known."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(config: SlamConfig, available: int | None = None) -> None:
    """Refuse a configuration whose buffers would take more than ``MEMORY_SHARE`` of the
    memory ``available`` (default: what the system has available now)."""
    parts = estimated_bytes(config)
    total = sum(parts.values())
    available = available_bytes() if available is None else available
    if available is None or total <= MEMORY_SHARE * available:
        return
    largest = max(parts, key=parts.get)
    raise ValueError(f"the configured capacities need about {total / 2**30:.1f} GiB, more than "
                     f"{MEMORY_SHARE:.0%} of the {available / 2**30:.1f} GiB available; the "
                     f"largest part: {largest}, {parts[largest] / 2**30:.1f} GiB (lower it)")
