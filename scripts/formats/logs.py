"""A robot's recording, whatever its format: a CARMEN log (:mod:`swarmslam.formats.carmen`) or a ROS
bag (:mod:`swarmslam.formats.bags`: ROS 1, ROS 2 sqlite3 or MCAP), read into the same records.

    log = read_log("run.mcap", scan_topic="/scan")   # or a .clf / .clf.gz, a pipe, - for stdin
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmslam.formats.bags import is_bag, read_bag
from swarmslam.formats.carmen import read_carmen
from swarmslam.formats.records import ScanLog


@dataclass(frozen=True)
class BagOptions:
    """Which topics and frames of a bag to read (CARMEN logs need none)."""

    scan_topic: str | None = None
    odom_topic: str | None = None
    odom_frame: str = "odom"
    base_frame: str = "base_link"


def read_log(path, options: BagOptions | None = None, warn=None) -> ScanLog:
    """The log's scans and odometry, from a ROS bag (by its name or folder) or a CARMEN log;
    ``warn(text)`` is told what a bag's reader assumed or skipped."""
    if str(path) != "-" and is_bag(path):
        o = options or BagOptions()
        return read_bag(path, o.scan_topic, o.odom_topic, o.odom_frame, o.base_frame, warn)
    return read_carmen(path)
