"""The log every reader gives and every writer takes: scans with the pose and odometry logged
beside each, odometry's own readings, and what reading skipped. Format-neutral: the CARMEN
reader (:mod:`swarmslam.formats.carmen`) and the bag reader (:mod:`swarmslam.formats.bags`)
both fill it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LaserRecord:
    """One scan: its stamp, ranges and beam angles, and the poses logged with it."""

    timestamp: float  # ipc_timestamp
    ranges: np.ndarray
    angles: np.ndarray  # beam angles in the laser frame (rad)
    pose: np.ndarray  # the pose the log gives with the scan (robot frame)
    odometry: np.ndarray  # raw odometry at the scan
    max_range: float
    laser_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # laser in robot
    line: int = 0  # the record's line (a bag's message number)
    time_increment: float = 0.0  # s between beams (a bag's LaserScan; 0: not known)


@dataclass
class OdometryRecord:
    """One odometry reading."""

    timestamp: float
    pose: np.ndarray
    line: int = 0


@dataclass
class ScanLog:
    """A log's records in time order; ``path`` names where they came from."""

    path: str
    lasers: list[LaserRecord]
    odometry: list[OdometryRecord]
    skipped: dict = field(default_factory=dict)  # records skipped, by the field that failed
    skipped_examples: list = field(default_factory=list)  # "file:line: kind field: value"
    stopped: str | None = None  # where a damaged file stopped being read (what came before kept)

    def scan_poses(self) -> np.ndarray:
        """The poses logged with the scans, ``(N, 3)``."""
        return np.array([r.pose for r in self.lasers]).reshape(-1, 3)
