"""``swarmslam convert IN OUT``: a log from one format to another — CARMEN (``.clf``, plain
or gzipped) ⇄ ROS 1 bag (``.bag``), ROS 2 bag in MCAP (``.mcap``) or sqlite3 (a bag folder)
— so the benchmark logs open in Foxglove and ``ros2 bag play``, and a robot's bags become
CARMEN for other tools (docs/formats.md §9).

A bag gets what a ROS driver would publish: each scan as a LaserScan (no return as ``inf``,
REP 117), the odometry each scan has as an Odometry stamped with it, and the laser's mount
in ``tf_static``. A CARMEN log gets a FLASER line per scan where the scan is one (180° from
−90°, at the robot's origin), else a ROBOTLASER1 line, and the bag's odometry readings as
ODOM lines.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from swarmslam.runtime.realtime.writers import write_bytes_atomic
from swarmslam.formats.bags import format_of, refuse_to_replace, write_bag
from swarmslam.formats.carmen import flaser_angles, flaser_line, odom_line, robotlaser1_line
from swarmslam.formats.logs import BagOptions, read_log

CARMEN_SUFFIXES = (".clf", ".log", ".gz", ".txt")


def output_format(path, given: str | None) -> str:
    if given is not None:
        return given
    return "carmen" if Path(path).suffix in CARMEN_SUFFIXES else format_of(path)


def carmen_text(log, warn=None) -> str:
    """``log`` as CARMEN lines, in time order: ODOM for each odometry reading, FLASER or
    ROBOTLASER1 for each scan."""
    warn = warn or (lambda text: None)
    lines = ["# swarmslam convert: CARMEN log"]
    events = [(r.timestamp, 0, r) for r in log.odometry] + [(r.timestamp, 1, r) for r in log.lasers]
    last = np.zeros(3)
    missing = 0
    for stamp, kind, record in sorted(events, key=lambda e: (e[0], e[1])):
        if kind == 0:
            lines.append(odom_line(record.pose, stamp))
            continue
        odometry = record.odometry
        if not np.all(np.isfinite(odometry)):  # CARMEN has no "unknown": the last one holds
            odometry, missing = last, missing + 1
        last = odometry
        ranges = np.where(np.isfinite(record.ranges) & (record.ranges < record.max_range),
                          record.ranges, record.max_range)  # no return: the scanner's maximum
        n = len(ranges)
        if (n in (180, 181, 360, 361) and not np.any(record.laser_offset)
                and np.allclose(record.angles, flaser_angles(n), atol=1e-9)):
            lines.append(flaser_line(ranges, odometry, odometry, stamp))
        else:
            step = float(record.angles[1] - record.angles[0]) if n > 1 else 0.0
            lines.append(robotlaser1_line(ranges, float(record.angles[0]), step,
                                          record.max_range, odometry, stamp,
                                          laser_offset=record.laser_offset))
    if missing:
        warn(f"{missing} scans had no odometry: the last reading written for them (replay "
             f"with --no-odometry if the bag had none)")
    return "\n".join(lines) + "\n"


def convert(source, output, fmt: str | None = None, bag: BagOptions | None = None,
            warn=None) -> dict:
    """``source`` (CARMEN or a bag) written to ``output`` in ``fmt`` (default: from its name);
    returns what was written."""
    fmt = output_format(output, fmt)
    if fmt != "carmen":  # before the reading, not after it
        refuse_to_replace(Path(output), fmt)
    log = read_log(source, bag, warn)
    if fmt == "carmen":
        text = carmen_text(log, warn).encode("ascii")
        out = Path(output)
        write_bytes_atomic(out, gzip.compress(text, mtime=0) if out.suffix == ".gz" else text)
        readings = len(log.odometry)
    else:
        write_bag(log, output, fmt)
        readings = sum(bool(np.all(np.isfinite(r.odometry))) for r in log.lasers)
    return {"output": str(output), "format": fmt, "scans": len(log.lasers),
            "odometry": readings}
