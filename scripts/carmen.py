"""CARMEN log reader: ``FLASER``, ``ROBOTLASER1`` and ``ODOM`` lines, plain or gzipped.

Records come back sorted by ``ipc_timestamp`` (Intel's laser timestamps go backwards 631
times). A malformed line raises :class:`CarmenFormatError` naming the file, the line and the
field; other message types (PARAM, SYNC, NEFF, RLASER, ...) are skipped.

Formats (from the logs' own headers)::

    ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp
    FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp
    ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode
                n r1..rn m rem1..remm laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis ipc_timestamp ipc_hostname logger_timestamp

``FLASER`` carries no beam geometry: CARMEN's front laser spans 180° from −90°, at 1° for 180
or 181 beams (0.5° for 360 or 361). Nor does it say what a beam without a return reads: the
scanner's own fixed value, taken from the log (:func:`flaser_no_return`).
"""

from __future__ import annotations

import gzip
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swarmslam.runtime.pose import between
from swarmslam.runtime.text_records import DataFormatError, records

# Readings at or beyond this are "no return" in a FLASER log that does not show its own value
# (Intel's scanner reads 81.83, ACES3's 50.0: see flaser_no_return).
FLASER_MAX_RANGE = 50.0
# A FLASER log's "no return" reading recurs exactly in at least this share of its readings (and
# at least SENTINEL_MIN_COUNT times): Intel's 81.83 is 2.8% of them, ACES3's 50.0 0.8%.
SENTINEL_SHARE = 1e-4
SENTINEL_MIN_COUNT = 10


class CarmenFormatError(DataFormatError):
    """A line of a CARMEN log that cannot be read; says where and what."""


@dataclass
class LaserRecord:
    timestamp: float  # ipc_timestamp
    ranges: np.ndarray
    angles: np.ndarray  # beam angles in the laser frame (rad)
    pose: np.ndarray  # the pose the log gives with the scan (robot frame)
    odometry: np.ndarray  # raw odometry at the scan
    max_range: float
    laser_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))  # laser in robot
    line: int = 0


@dataclass
class OdometryRecord:
    timestamp: float
    pose: np.ndarray
    line: int = 0


@dataclass
class CarmenLog:
    path: str
    lasers: list[LaserRecord]
    odometry: list[OdometryRecord]

    def scan_poses(self) -> np.ndarray:
        """The poses logged with the scans, ``(N, 3)``."""
        return np.array([r.pose for r in self.lasers]).reshape(-1, 3)


def flaser_angles(n: int) -> np.ndarray:
    step = math.pi / (2 * (n // 2)) if n > 1 else 0.0
    return -math.pi / 2 + step * np.arange(n)


def _open(path: Path, mode: str = "rb"):
    with open(path, "rb") as f:
        magic = f.read(2)
    return gzip.open(path, mode) if magic == b"\x1f\x8b" else open(path, mode)


class _Fields:
    """Token cursor that reports the failing field by name."""

    def __init__(self, path, line, tokens):
        self.path, self.line, self.tokens, self.i = path, line, tokens, 1

    def error(self, name, problem):
        return CarmenFormatError(self.path, self.line, name, problem)

    def float(self, name):
        if self.i >= len(self.tokens):
            raise self.error(name, f"missing (line has only {len(self.tokens)} fields)")
        tok = self.tokens[self.i]
        self.i += 1
        try:
            v = float(tok)
        except ValueError:
            raise self.error(name, f"not a number: {tok!r}") from None
        if math.isnan(v):
            raise self.error(name, "NaN")
        return v

    def count(self, name):
        v = self.float(name)
        if v < 0 or v != int(v):
            raise self.error(name, f"not a count: {self.tokens[self.i - 1]!r}")
        return int(v)

    def floats(self, name, n):
        if self.i + n > len(self.tokens):
            raise self.error(
                name, f"expected {n} values, line ends after {len(self.tokens) - self.i}"
            )
        out = np.empty(n)
        for k in range(n):
            out[k] = self.float(f"{name}[{k}]")
        return out

    def pose(self, name):
        return np.array([self.float(f"{name}.x"), self.float(f"{name}.y"), self.float(f"{name}.theta")])

    def timestamp(self):
        # ipc_timestamp ipc_hostname logger_timestamp: the timestamp is third from the end.
        if len(self.tokens) - self.i != 3:
            raise self.error(
                "ipc_timestamp",
                f"expected 'ipc_timestamp ipc_hostname logger_timestamp' after the data, "
                f"found {len(self.tokens) - self.i} trailing fields",
            )
        return self.float("ipc_timestamp")


def _flaser(f: _Fields, max_range: float) -> LaserRecord:
    n = f.count("num_readings")
    if n == 0:
        raise f.error("num_readings", "zero readings")
    ranges = f.floats("range", n)
    pose = f.pose("pose")
    odom = f.pose("odom")
    t = f.timestamp()
    return LaserRecord(t, ranges, flaser_angles(n), pose, odom, max_range, line=f.line)


def _robotlaser1(f: _Fields) -> LaserRecord:
    f.float("laser_type")
    start = f.float("start_angle")
    fov = f.float("fov")
    res = f.float("angular_res")
    max_range = f.float("max_range")
    f.float("accuracy")
    f.float("remission_mode")
    n = f.count("num_readings")
    if n == 0:
        raise f.error("num_readings", "zero readings")
    ranges = f.floats("range", n)
    m = f.count("num_remissions")
    f.floats("remission", m)
    laser = f.pose("laser_pose")
    robot = f.pose("robot_pose")
    for name in ("tv", "rv", "forward_safety", "side_safety", "turn_axis"):
        f.float(name)
    t = f.timestamp()
    if not fov > 0:
        raise f.error("fov", f"must be > 0, got {fov}")
    angles = start + res * np.arange(n)
    # The laser's pose relative to the robot, from the two absolute poses (Eq. 2).
    offset = between(laser, robot)
    return LaserRecord(t, ranges, angles, robot, robot.copy(), max_range, offset, line=f.line)


def _odom(f: _Fields) -> OdometryRecord:
    pose = f.pose("pose")
    for name in ("tv", "rv", "accel"):
        f.float(name)
    return OdometryRecord(f.timestamp(), pose, line=f.line)


def flaser_no_return(ranges, fallback: float = FLASER_MAX_RANGE) -> float:
    """The reading a FLASER log gives a beam without a return, from its readings ``ranges``
    (one flat array): the least value that recurs exactly — at least ``SENTINEL_SHARE`` of the
    readings and ``SENTINEL_MIN_COUNT`` times — with no more than that many readings above it
    that are not such recurring values themselves. A scanner puts "no return" and its error
    codes at the top of its scale, and measures nothing beyond them; a distance many beams
    measure alike (a wall at 1.08 m) has countless readings above it. ``fallback`` when no
    value qualifies (every beam returned, or too few did not to tell).

    >>> flaser_no_return(np.r_[np.linspace(0.5, 30.0, 2000), np.full(40, 81.83)])
    81.83
    >>> flaser_no_return(np.r_[np.full(300, 1.08), np.linspace(0.5, 7.9, 2000), np.full(60, 8.18)])
    8.18
    >>> flaser_no_return(np.linspace(0.5, 30.0, 2000))  # nothing recurs at the top: the default
    50.0
    """
    ranges = np.asarray(ranges, np.float64)
    values, counts = np.unique(ranges[np.isfinite(ranges)], return_counts=True)
    least = max(SENTINEL_MIN_COUNT, SENTINEL_SHARE * counts.sum())
    recurs = counts >= least
    # readings above each value that do not recur (a suffix sum from the top of the scale)
    other = np.where(recurs, 0, counts)
    above = np.cumsum(other[::-1])[::-1] - other
    found = np.flatnonzero(recurs & (above < least))
    return float(values[found[0]]) if len(found) else float(fallback)


def read_carmen(path, max_range: float | None = None, sort: bool = True,
                synchronise: bool = True) -> CarmenLog:
    """Read a CARMEN log. ``max_range`` applies to FLASER lines, which do not carry one:
    readings at or beyond it are "no return"; None: the log's own no-return reading
    (:func:`flaser_no_return`). ``synchronise``: FLASER scans take their odometry from the
    ODOM stream at their own timestamps where the stream's times can be trusted
    (:func:`odometry_at_scans`)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such log file")
    lasers: list[LaserRecord] = []
    flaser: list[LaserRecord] = []  # the FLASER ones among them
    odometry: list[OdometryRecord] = []
    for lineno, tokens in records(path, _open, "ascii", "replace"):
        kind = tokens[0]
        f = _Fields(path, lineno, tokens)
        if kind == "FLASER":
            flaser.append(_flaser(f, FLASER_MAX_RANGE if max_range is None else max_range))
            lasers.append(flaser[-1])
        elif kind == "ROBOTLASER1":
            lasers.append(_robotlaser1(f))
        elif kind == "ODOM":
            odometry.append(_odom(f))
    if not lasers:
        raise CarmenFormatError(path, 0, "FLASER/ROBOTLASER1", "the log has no laser scans")
    if flaser and max_range is None:
        no_return = flaser_no_return(np.concatenate([r.ranges for r in flaser]))
        for r in flaser:
            r.max_range = no_return
    if sort:  # stable: equal timestamps keep file order
        lasers.sort(key=lambda r: r.timestamp)
        odometry.sort(key=lambda r: r.timestamp)
        if synchronise:
            odometry_at_scans(lasers, odometry)
    return CarmenLog(str(path), lasers, odometry)


# ODOM records farther apart than this (s) bracket no scan: the robot may have done anything.
ODOMETRY_MAX_GAP = 0.5
# An ODOM stream whose mean interval exceeds its median by this factor arrives in bursts: its
# times are when messages reached the logger, not when they were measured.
BURST_RATIO = 2.0


def regular_stream(times) -> bool:
    """Whether timestamps ``times`` (sorted) come at a steady rate rather than in bursts
    (Intel's ODOM: median interval 1 ms, mean 100 ms; ACES's: 0.18 s both)."""
    gaps = np.diff(np.asarray(times, dtype=np.float64))
    if len(gaps) < 2:
        return False
    median = float(np.median(gaps))
    return median > 0 and float(np.mean(gaps)) < BURST_RATIO * median


def odometry_at_scans(lasers, odometry, max_gap: float = ODOMETRY_MAX_GAP) -> int:
    """Each FLASER scan's odometry interpolated from the ODOM records at its timestamp, when
    the ODOM stream is regular (:func:`regular_stream`). Returns how many scans changed.

    A FLASER line carries the last odometry the logger had received, stale by up to one ODOM
    interval (ACES: 0.11 s median, 0.18 s at the 90th percentile — 6-10° while turning at
    1 rad/s); the scan-to-scan prediction then jitters, and a match that corrects it by that
    much is refused by the odometry gate. Interpolating the stream at the scan's time removes
    the lag, as a driver synchronising odometry to its scans does. A scan not bracketed by
    ODOM records within ``max_gap`` s, a ROBOTLASER1 scan (its robot pose is already the
    scan's), and every scan of a bursty stream keep the odometry the line gives."""
    if not odometry:
        return 0
    times = np.array([r.timestamp for r in odometry])
    if not regular_stream(times):
        return 0
    poses = np.array([r.pose for r in odometry]).reshape(-1, 3)
    changed = 0
    for r in lasers:
        if np.any(r.laser_offset):
            continue
        k = int(np.searchsorted(times, r.timestamp, side="right")) - 1
        if k < 0 or k + 1 >= len(times) or times[k + 1] - times[k] > max_gap:
            continue
        if times[k] == r.timestamp:
            pose = poses[k].copy()
        else:
            share = (r.timestamp - times[k]) / (times[k + 1] - times[k])
            turn = math.remainder(poses[k + 1, 2] - poses[k, 2], 2 * math.pi)
            pose = poses[k] + share * (poses[k + 1] - poses[k])
            pose[2] = math.remainder(poses[k, 2] + share * turn, 2 * math.pi)
        if not np.array_equal(pose, r.odometry):
            changed += 1
        r.odometry = pose
    return changed


def _num(v: float) -> str:
    return repr(float(v))  # the shortest text that reads back as the same float


def _nums(values) -> str:
    return " ".join(_num(v) for v in values)


def flaser_line(ranges, pose, odometry, stamp: float, host: str = "swarmslam") -> str:
    """A FLASER line (a 180° scan from −90°; CARMEN puts the odometry in both pose fields of a
    raw log)."""
    rs = " ".join(f"{r:.3f}" for r in ranges)
    return (f"FLASER {len(ranges)} {rs} {_nums(pose)} {_nums(odometry)} {_num(stamp)} {host} "
            f"{_num(stamp)}")


def robotlaser1_line(ranges, start_angle: float, angular_res: float, max_range: float, pose,
                     stamp: float, host: str = "swarmslam") -> str:
    """A ROBOTLASER1 line for a scanner at the robot's origin, ``pose`` its odometry."""
    rs = " ".join(f"{r:.3f}" for r in ranges)
    p = _nums(pose)
    fov = angular_res * len(ranges)
    return (f"ROBOTLASER1 0 {_num(start_angle)} {_num(fov)} {_num(angular_res)} "
            f"{_num(max_range)} 0.01 0 {len(ranges)} {rs} 0 {p} {p} 0 0 0 0 0 "
            f"{_num(stamp)} {host} {_num(stamp)}")


def odom_line(pose, stamp: float, host: str = "swarmslam") -> str:
    return f"ODOM {_nums(pose)} 0 0 0 {_num(stamp)} {host} {_num(stamp)}"
