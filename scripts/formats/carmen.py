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

import contextlib
import gzip
import io
import math
import sys
from pathlib import Path

import numpy as np

from swarmslam.runtime.pose import between, compose
from swarmslam.formats.records import LaserRecord, OdometryRecord, ScanLog
from swarmslam.runtime.realtime.text_records import DataFormatError, records

# Readings at or beyond this are "no return" in a FLASER log that does not show its own value
# (Intel's scanner reads 81.83, ACES3's 50.0: see flaser_no_return).
FLASER_MAX_RANGE = 50.0
# A FLASER log's "no return" reading recurs exactly in at least this share of its readings (and
# at least SENTINEL_MIN_COUNT times): Intel's 81.83 is 2.8% of them, ACES3's 50.0 0.8%.
SENTINEL_SHARE = 1e-4
SENTINEL_MIN_COUNT = 10


# What a record may say. A stamp is seconds since 1970 or since the log began (at most the
# year 2286): a record stamped beyond, or with a laser more than MAX_LASER_OFFSET from its
# robot, is skipped and counted by its field. Odometry is judged where every source's is, in
# the runtime's inbox (docs/runtime.md §7). A scanner's geometry beyond these is refused.
MAX_STAMP = 1e10  # s
MAX_LASER_OFFSET = 100.0  # m
MAX_RANGE = 1e3  # m
SKIPPED_EXAMPLES = 3  # the skipped records named in the warning


class _Skip(Exception):
    """A record with a value no robot or scanner produces: skipped and counted."""

    def __init__(self, field: str, value: str):
        super().__init__(field)
        self.field, self.value = field, value


class CarmenFormatError(DataFormatError):
    """A line of a CARMEN log that cannot be read; says where and what."""


def flaser_angles(n: int) -> np.ndarray:
    """A FLASER line's beam angles, which the line does not give: a SICK LMS's by its beam
    count, as CARMEN guesses them. 180 or 181 beams are 1° apart, 360 or 361 0.5°, from −90°
    (the even counts leave out the last beam of the 180°); 400 or 401 are the 100° mode's
    0.25°, centred as the scanner takes them, from −50° (CARMEN starts every FLASER at −90°).
    Other counts likewise: an odd one spans the 180°, an even one leaves out its last beam."""
    if n in (400, 401):
        return math.radians(-50.0) + math.radians(0.25) * np.arange(n)
    step = math.pi / (2 * (n // 2)) if n > 1 else 0.0
    return -math.pi / 2 + step * np.arange(n)


STDIN = "-"  # the log's path that reads standard input


@contextlib.contextmanager
def open_log(path):
    """The log's bytes, gunzipped if they are gzip, from one opening of the file: a pipe, a
    FIFO or standard input (``-``) gives its bytes once, and a separate look at the first
    two would lose them."""
    raw = sys.stdin.buffer if str(path) == STDIN else open(path, "rb")
    try:
        stream = raw if isinstance(raw, io.BufferedReader) else io.BufferedReader(raw)
        if stream.peek(2)[:2] == b"\x1f\x8b":
            with gzip.GzipFile(fileobj=stream, mode="rb") as unzipped:
                yield unzipped
        else:
            yield stream
    finally:
        if raw is not sys.stdin.buffer:
            raw.close()


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
        if not math.isfinite(v) or v < 0 or v != int(v):
            raise self.error(name, f"not a count: {self.tokens[self.i - 1]!r}")
        return int(v)

    def bounded(self, name, low: float, high: float):
        """A number in ``[low, high]`` (finite): no robot or scanner reads beyond."""
        v = self.float(name)
        if not low <= v <= high:
            raise self.error(name, f"{self.tokens[self.i - 1]!r} is outside [{low:g}, {high:g}]")
        return v

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
        return np.array([self.float(f"{name}.x"), self.float(f"{name}.y"),
                         self.float(f"{name}.theta")])

    def timestamp(self):
        # ipc_timestamp ipc_hostname logger_timestamp: the timestamp is third from the end.
        if len(self.tokens) - self.i != 3:
            raise self.error(
                "ipc_timestamp",
                f"expected 'ipc_timestamp ipc_hostname logger_timestamp' after the data, "
                f"found {len(self.tokens) - self.i} trailing fields",
            )
        t = self.float("ipc_timestamp")
        if not abs(t) <= MAX_STAMP:
            raise _Skip("ipc_timestamp", self.tokens[self.i - 1])
        return t


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
    start = f.bounded("start_angle", -2 * math.pi, 2 * math.pi)
    fov = f.bounded("fov", 0.0, 2 * math.pi + 1e-6)
    res = f.bounded("angular_res", 0.0, 2 * math.pi)
    max_range = f.bounded("max_range", 0.0, MAX_RANGE)
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
    offset = between(laser, robot)  # the laser's pose relative to the robot (Eq. 2)
    if not (np.all(np.isfinite(offset)) and np.all(np.abs(offset[:2]) <= MAX_LASER_OFFSET)):
        raise _Skip("laser_pose", f"{laser[0]!r} {laser[1]!r} {laser[2]!r}")
    for name in ("tv", "rv", "forward_safety", "side_safety", "turn_axis"):
        f.float(name)
    t = f.timestamp()
    for name, value in (("fov", fov), ("angular_res", res), ("max_range", max_range)):
        if not value > 0:
            raise f.error(name, f"must be > 0, got {value!r}")
    angles = start + res * np.arange(n)
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
                synchronise: bool = True) -> ScanLog:
    """Read a CARMEN log. ``max_range`` applies to FLASER lines, which do not carry one:
    readings at or beyond it are "no return"; None: the log's own no-return reading
    (:func:`flaser_no_return`). ``synchronise``: FLASER scans take their odometry from the
    ODOM stream at their own timestamps where the stream's times can be trusted
    (:func:`odometry_at_scans`)."""
    path = Path(path)
    if str(path) != STDIN and not path.exists():
        raise FileNotFoundError(f"{path}: no such log file")
    lasers: list[LaserRecord] = []
    flaser: list[LaserRecord] = []  # the FLASER ones among them
    odometry: list[OdometryRecord] = []
    skipped: dict[str, int] = {}
    examples: list[str] = []
    for lineno, tokens in records(path, lambda p, _: open_log(p), "ascii", "replace"):
        kind = tokens[0]
        f = _Fields(path, lineno, tokens)
        try:
            if kind == "FLASER":
                flaser.append(_flaser(f, FLASER_MAX_RANGE if max_range is None else max_range))
                lasers.append(flaser[-1])
            elif kind == "ROBOTLASER1":
                lasers.append(_robotlaser1(f))
            elif kind == "ODOM":
                odometry.append(_odom(f))
        except _Skip as skip:
            skipped[skip.field] = skipped.get(skip.field, 0) + 1
            if len(examples) < SKIPPED_EXAMPLES:
                examples.append(f"{path}:{lineno}: {kind} {skip.field}: {skip.value}")
    if not lasers:
        raise CarmenFormatError(path, 0, "FLASER/ROBOTLASER1", "the log has no laser scans"
                                + (f" it could use ({sum(skipped.values())} skipped: "
                                   f"{'; '.join(examples)})" if skipped else ""))
    if flaser and max_range is None:
        no_return = flaser_no_return(np.concatenate([r.ranges for r in flaser]))
        for r in flaser:
            r.max_range = no_return
    if sort:  # stable: equal timestamps keep file order
        lasers.sort(key=lambda r: r.timestamp)
        odometry.sort(key=lambda r: r.timestamp)
        if synchronise:
            odometry_at_scans(lasers, odometry)
    return ScanLog(str(path), lasers, odometry, skipped, examples)


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
        pose = pose_between(times, poses, k, r.timestamp)
        if not np.array_equal(pose, r.odometry):
            changed += 1
        r.odometry = pose
    return changed


def pose_between(times, poses, k: int, stamp: float) -> np.ndarray:
    """Odometry at ``stamp`` from readings ``k`` and ``k + 1`` (``times[k] <= stamp``): reading
    ``k`` when stamped so, else the two interpolated, the heading along the shorter turn."""
    if times[k] == stamp:
        return poses[k].copy()
    share = (stamp - times[k]) / (times[k + 1] - times[k])
    turn = math.remainder(poses[k + 1, 2] - poses[k, 2], 2 * math.pi)
    pose = poses[k] + share * (poses[k + 1] - poses[k])
    pose[2] = math.remainder(poses[k, 2] + share * turn, 2 * math.pi)
    return pose


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
                     stamp: float, host: str = "swarmslam", laser_offset=None) -> str:
    """A ROBOTLASER1 line, ``pose`` the robot's odometry, the scanner at ``laser_offset`` on
    the robot (default: its origin)."""
    rs = " ".join(f"{r:.3f}" for r in ranges)
    p = _nums(pose)
    laser = p if laser_offset is None else _nums(compose(np.asarray(pose, float),
                                                          np.asarray(laser_offset, float)))
    fov = angular_res * len(ranges)
    return (f"ROBOTLASER1 0 {_num(start_angle)} {_num(fov)} {_num(angular_res)} "
            f"{_num(max_range)} 0.01 0 {len(ranges)} {rs} 0 {laser} {p} 0 0 0 0 0 "
            f"{_num(stamp)} {host} {_num(stamp)}")


def odom_line(pose, stamp: float, host: str = "swarmslam") -> str:
    return f"ODOM {_nums(pose)} 0 0 0 {_num(stamp)} {host} {_num(stamp)}"
