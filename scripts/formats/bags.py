"""ROS bags in and out: ROS 1 ``.bag``, ROS 2 bag folders (sqlite3 ``.db3`` or MCAP) and bare
``.mcap`` files, read and written with rosbags (pure Python, no ROS install; the extra
``bags``). docs/formats.md §9 says what is read from each message.

    log = read_bag("run.bag")                   # the same ScanLog the CARMEN reader gives
    write_bag(log, "intel.mcap")                # LaserScan, Odometry and tf_static

Reading: the LaserScan topic (found by type, or ``scan_topic``; several without one is an
error listing them), odometry from ``nav_msgs/Odometry`` (``odom_topic``) or, when the bag has
none, from ``tf`` (``odom_frame`` → ``base_frame``), interpolated to each scan's header stamp
(not the bag's receive time), and the laser's mounting from ``tf_static`` (``base_frame`` →
the scan's ``frame_id``; none: zero, with a warning). A LaserScan is read whole: ``angle_min``,
``angle_increment`` (negative, or a laser mounted upside down in ``tf_static``, mirrors the
beams), ``range_min``/``range_max`` (a reading outside, ``inf`` or ``NaN`` is no return, REP
117) and ``time_increment``; intensities are not used. A scan whose beam count contradicts its
angles is skipped and counted. A damaged bag keeps every scan read before the damage and says
where it stopped.

float32 fields are read as the shortest decimal that rounds to them, and angles within their
float32 rounding of a fraction of π (−π/2, π/180, ...) as that fraction: a log written from
decimal text (CARMEN) reads back as it was, bit for bit.
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import shutil
import threading
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from swarmslam.formats.carmen import ODOMETRY_MAX_GAP, pose_between
from swarmslam.formats.records import LaserRecord, OdometryRecord, ScanLog
from swarmslam.runtime.matching.scan import binned_ranges

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
FORMATS = ("ros1", "sqlite3", "mcap")
MAX_DENOMINATOR = 7200  # angles snapped to fractions of π with at most this denominator
DECIMAL_PLACES = 6  # ... unless written as a decimal of at most this many places
TF_MESSAGE_ROS1 = "geometry_msgs/TransformStamped[] transforms\n"


class BagError(ValueError):
    """A bag that cannot be read or written as asked; says why."""


def rosbags():
    """The rosbags modules, or a clear error naming the extra that brings them."""
    try:
        import rosbags.highlevel  # noqa: F401
        import rosbags.rosbag1
        import rosbags.rosbag2
        import rosbags.typesys
    except ImportError:
        raise BagError("ROS bags need the rosbags package: pip install 'swarmslam[bags]'") \
            from None
    return rosbags


def is_bag(path) -> bool:
    """A ROS 1 bag, a ROS 2 bag folder, or a bare ``.mcap`` / ``.db3`` file."""
    path = Path(path)
    return (path.suffix in (".bag", ".mcap", ".db3")
            or (path.is_dir() and (path / "metadata.yaml").exists()))


def format_of(path, given: str | None = None) -> str:
    """The bag format to write ``path`` in: ``given``, else from its name (``.bag`` ROS 1,
    ``.mcap`` MCAP, any other name a ROS 2 sqlite3 bag folder)."""
    if given is not None:
        if given not in FORMATS:
            raise BagError(f"unknown bag format {given!r}; choose one of {', '.join(FORMATS)}")
        return given
    suffix = Path(path).suffix
    return "ros1" if suffix == ".bag" else "mcap" if suffix == ".mcap" else "sqlite3"


# ---------------------------------------------------------------------- exact numbers
def canonical(values) -> np.ndarray:
    """float32 values as the float64 of the shortest decimal that rounds to each."""
    return np.asarray(values, dtype=np.float32).astype(str).astype(np.float64)


def canonical_angle(value) -> float:
    """A float32 angle as the decimal it was written from, when its shortest decimal has at
    most DECIMAL_PLACES places (CARMEN's −1.570796); else as the fraction of π it rounds from
    (denominator ≤ MAX_DENOMINATOR: −π/2, π/360); else as its shortest decimal."""
    single = np.float32(value)
    text = str(single)
    if not math.isfinite(single) or len(text.partition(".")[2]) <= DECIMAL_PLACES:
        return float(text)
    ratio = Fraction(float(single) / math.pi).limit_denominator(MAX_DENOMINATOR)
    candidate = math.pi * ratio.numerator / ratio.denominator
    if ratio.numerator and np.float32(candidate) == single:
        return candidate
    return float(text)


def stamp_of(sec: int, nanosec: int) -> float:
    """A header stamp as seconds: the double nearest its exact decimal."""
    return float(f"{int(sec)}.{int(nanosec):09d}")


def sec_nanosec(stamp: float) -> tuple[int, int]:
    sec = math.floor(stamp)
    nanosec = round((stamp - sec) * 1e9)
    if nanosec >= 10**9:
        sec, nanosec = sec + 1, nanosec - 10**9
    return int(sec), int(nanosec)


def yaw_of(q) -> float:
    """The heading of a quaternion ``(x, y, z, w)`` about z (its tilt ignored); a rotation
    about z alone (x = y = 0, as a 2-D robot's) read as 2·atan2(z, w)."""
    x, y, z, w = (float(v) for v in q)
    if x == 0.0 and y == 0.0:
        return 2.0 * math.atan2(z, w)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_of(yaw: float) -> tuple[float, float, float, float]:
    """A rotation about z by ``yaw`` whose :func:`yaw_of` gives ``yaw`` back exactly (the
    sine and cosine nudged by an ulp or two where rounding would lose it)."""
    z, w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    if yaw_of((0.0, 0.0, z, w)) == yaw:
        return 0.0, 0.0, z, w
    for dz in range(-3, 4):
        for dw in range(-3, 4):
            zz = z + dz * math.ulp(z)
            ww = w + dw * math.ulp(w)
            if yaw_of((0.0, 0.0, zz, ww)) == yaw:
                return 0.0, 0.0, zz, ww
    return 0.0, 0.0, z, w


def rotation_matrix(q) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


# ---------------------------------------------------------------------- reading
@dataclass
class Mount:
    """The laser on the robot: its pose in the base frame, and whether it is mounted upside
    down (its beams then sweep the other way)."""

    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    mirrored: bool = False


def mount_of(transforms: dict, base: str, laser: str) -> Mount | None:
    """The laser's mount from ``transforms`` (child → (parent, translation, quaternion)),
    chained from ``laser`` up to ``base``; None when no chain reaches it."""
    chain, frame = [], laser
    while frame != base:
        if frame not in transforms or len(chain) > len(transforms):
            return None
        chain.append(transforms[frame])
        frame = transforms[frame][0]
    rotation, translation = np.eye(3), np.zeros(3)
    for _, t, q in chain:  # from the laser up: each parent's view of the frame below
        r = rotation_matrix(q)
        rotation, translation = r @ rotation, r @ translation + np.asarray(t, float)
    if abs(abs(rotation[2, 2]) - 1.0) > 1e-3:
        raise BagError(f"the laser {laser!r} is tilted out of the plane in tf_static: not a "
                       f"2-D scanner")
    mirrored = bool(rotation[2, 2] < 0)  # z down: the beams' angles run the other way
    if len(chain) == 1 and not mirrored:  # the heading as written, exactly
        yaw = yaw_of(chain[0][2])
    else:
        yaw = math.atan2(rotation[1, 0], rotation[0, 0])
    return Mount(np.array([translation[0], translation[1], yaw]), mirrored)


def _transforms(message) -> list:
    return [(t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/"),
             (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z),
             (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
              t.transform.rotation.w), stamp_of(t.header.stamp.sec, t.header.stamp.nanosec))
            for t in message.transforms]


def _one_topic(topics: dict, msgtype: str, chosen: str | None, what: str,
               option: str) -> list[str]:
    """The topic to read (a list of at most one): ``chosen``, or the one of ``msgtype``."""
    of_type = sorted(t for t, m in topics.items() if m == msgtype)
    if chosen is not None:
        if chosen not in topics:
            raise BagError(f"no topic {chosen!r} in the bag; its {what} topics: "
                           f"{', '.join(of_type) or 'none'}")
        return [chosen]
    if len(of_type) > 1:
        raise BagError(f"the bag has {len(of_type)} {what} topics ({', '.join(of_type)}): "
                       f"choose one with {option}")
    return of_type


def read_bag(path, scan_topic: str | None = None, odom_topic: str | None = None,
             odom_frame: str = "odom", base_frame: str = "base_link", warn=None) -> ScanLog:
    """A bag's scans, with their odometry and the laser's mount, as a :class:`ScanLog`
    (see the module doc). ``warn(text)`` is told what was assumed or skipped."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such bag")
    warn = warn or (lambda text: None)
    topics, messages = _open_messages(path)
    scans = _one_topic(topics, SCAN_TYPE, scan_topic, "LaserScan", "--scan-topic")
    if not scans:
        raise BagError(f"{path}: no sensor_msgs/LaserScan topic")
    odometry_topic = _one_topic(topics, ODOMETRY_TYPE, odom_topic, "Odometry", "--odom-topic")
    wanted = set(scans) | set(odometry_topic) | {t for t, m in topics.items() if m == TF_TYPE}
    raw_scans, readings, static, dynamic, moving = [], [], {}, [], {}
    count, stopped = 0, None
    try:
        for topic, msgtype, message in messages(wanted):
            count += 1
            if msgtype == SCAN_TYPE:
                raw_scans.append((count, message))
            elif msgtype == ODOMETRY_TYPE:
                p, q = message.pose.pose.position, message.pose.pose.orientation
                readings.append((stamp_of(message.header.stamp.sec, message.header.stamp.nanosec),
                                 np.array([p.x, p.y, yaw_of((q.x, q.y, q.z, q.w))])))
            else:
                for parent, child, t, q, stamp in _transforms(message):
                    if topic.endswith("tf_static"):
                        static[child] = (parent, t, q)
                    elif parent == odom_frame and child == base_frame:
                        dynamic.append((stamp, np.array([t[0], t[1], yaw_of(q)])))
                    elif parent == base_frame:  # a laser mount that moves (per scan)
                        moving[(child, stamp)] = (parent, t, q)
    except Exception as exc:  # a damaged bag: what came before stays
        stopped = f"stopped after message {count}: {type(exc).__name__}: {exc}"
    if stopped or getattr(messages, "salvaged", False):
        stopped = stopped or "stopped where the file ends"
        warn(f"{path}: damaged; {len(raw_scans)} scans read before the damage ({stopped})")
    if not readings and dynamic:
        readings = dynamic
        warn(f"{path}: odometry from tf ({odom_frame} → {base_frame})")
    elif not readings:
        warn(f"{path}: no odometry (no nav_msgs/Odometry, no tf {odom_frame} → {base_frame}): "
             f"scans only")
    skipped: dict[str, int] = {}
    examples: list[str] = []
    mounts: dict[str, Mount] = {}
    lasers = []
    for index, message in raw_scans:
        frame = message.header.frame_id.lstrip("/")
        if frame not in mounts:
            mount = mount_of(static, base_frame, frame)
            if mount is None:
                warn(f"{path}: no tf_static {base_frame} → {frame}: the laser taken at the "
                     f"robot's origin")
            mounts[frame] = mount or Mount()
        stamp = stamp_of(message.header.stamp.sec, message.header.stamp.nanosec)
        mount = mounts[frame]
        if (frame, stamp) in moving:  # the mount published with this scan
            mount = mount_of({frame: moving[(frame, stamp)]}, base_frame, frame)
        record = _laser(message, mount, index)
        if isinstance(record, str):
            skipped[record] = skipped.get(record, 0) + 1
            if len(examples) < 3:
                examples.append(f"{path}: message {index}: LaserScan {record}")
            continue
        lasers.append(record)
    if not lasers:
        raise BagError(f"{path}: no usable LaserScan" + (f" ({stopped})" if stopped else ""))
    lasers.sort(key=lambda r: r.timestamp)
    readings.sort(key=lambda r: r[0])
    odometry = [OdometryRecord(t, pose, line=k) for k, (t, pose) in enumerate(readings)]
    times = np.array([t for t, _ in readings])
    poses = np.array([pose for _, pose in readings]).reshape(-1, 3)
    for record in lasers:
        record.odometry = odometry_at(times, poses, record.timestamp)
        record.pose = record.odometry.copy()
    return ScanLog(str(path), lasers, odometry, skipped, examples, stopped)


def _open_messages(path: Path):
    """The bag's topics (topic → message type) and a function giving its messages of chosen
    topics as (topic, type, message), in order. A bag rosbags cannot open (a ROS 1 bag or
    MCAP file cut short: no index, no summary) is read from its start until its damage."""
    rb = rosbags()
    store = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
    try:
        reader = rb.highlevel.AnyReader([path], default_typestore=store)
        reader.open()
    except Exception as exc:  # rosbags raises its own errors for every damaged file
        salvage = {".bag": _ros1_records, ".mcap": _mcap_records}.get(path.suffix)
        if salvage is None:
            raise BagError(f"{path}: not a bag that can be read ({type(exc).__name__}: "
                           f"{exc})") from None
        return _salvaged(path, salvage)
    topics = {c.topic: c.msgtype for c in reader.connections}

    def messages(wanted):
        try:
            chosen = [c for c in reader.connections if c.topic in wanted]
            for connection, _, data in reader.messages(connections=chosen):
                yield connection.topic, connection.msgtype, reader.deserialize(
                    data, connection.msgtype)
        finally:
            reader.close()

    return topics, messages


def _salvaged(path: Path, records):
    """Topics and messages of a damaged bag, read in one pass from its start (the messages
    are kept in memory: a cut file has no index to come back through)."""
    topics, kept, stopped = {}, [], None
    try:
        for topic, msgtype, message in records(path):
            topics.setdefault(topic, msgtype)
            kept.append((topic, msgtype, message))
    except Exception as exc:
        stopped = exc

    def messages(wanted):
        for item in kept:
            if item[0] in wanted:
                yield item
        if stopped is not None:
            raise stopped

    messages.salvaged = True
    return topics, messages


def _ros1_type(name: str) -> str:
    package, _, kind = name.partition("/")
    return f"{package}/msg/{kind}"


def _ros1_records(path: Path):
    """(topic, type, message) of a ROS 1 bag, record by record from its start (format 2.0)."""
    import bz2
    import struct

    rb = rosbags()
    store = rb.typesys.get_typestore(rb.typesys.Stores.ROS1_NOETIC)
    store.register(rb.typesys.get_types_from_msg(TF_MESSAGE_ROS1, TF_TYPE))
    connections = {}

    def fields(header: bytes) -> dict:
        out, i = {}, 0
        while i < len(header):
            (size,) = struct.unpack_from("<I", header, i)
            name, _, value = header[i + 4:i + 4 + size].partition(b"=")
            out[name.decode()] = value
            i += 4 + size
        return out

    def records(data: bytes):
        """(header, body, whole) of each record; the last may be cut short (not whole)."""
        i = 0
        while i + 4 <= len(data):
            (size,) = struct.unpack_from("<I", data, i)
            if i + 8 + size > len(data):
                raise BagError("a record cut short")
            header = data[i + 4:i + 4 + size]
            (length,) = struct.unpack_from("<I", data, i + 4 + size)
            body = data[i + 8 + size:i + 8 + size + length]
            yield fields(header), body, len(body) == length
            i += 8 + size + length

    def messages(data: bytes):
        for header, body, whole in records(data):
            op = header.get("op", b"\0")[0]
            if not whole and not (op == 0x05 and header["compression"] == b"none"):
                raise BagError("a record cut short")
            if op == 0x07:  # connection
                info = fields(body)
                connections[struct.unpack("<I", header["conn"])[0]] = (
                    header["topic"].decode(), _ros1_type(info["type"].decode()))
            elif op == 0x02:  # message data
                topic, msgtype = connections[struct.unpack("<I", header["conn"])[0]]
                if msgtype in store.types:
                    yield topic, msgtype, store.deserialize_ros1(body, msgtype)
            elif op == 0x05:  # a chunk: its records within
                kind = header["compression"].decode()
                inner = body if kind == "none" else bz2.decompress(body) if kind == "bz2" \
                    else _lz4(body)
                yield from messages(inner)  # (a chunk cut short: the records it still holds)
                if not whole:
                    raise BagError("a chunk cut short")

    raw = path.read_bytes()
    if not raw.startswith(b"#ROSBAG V2.0\n"):
        raise BagError(f"{path}: not a ROS 1 bag (format 2.0)")
    yield from messages(raw[len(b"#ROSBAG V2.0\n"):])


def _lz4(body: bytes) -> bytes:
    import lz4.frame

    return lz4.frame.decompress(body)


def _zstd(body: bytes) -> bytes:
    try:  # Python 3.14's own, else the backport rosbags installs
        from compression import zstd
    except ImportError:
        from backports import zstd
    return zstd.decompress(body)


def _mcap_records(path: Path):
    """(topic, type, message) of an MCAP file, record by record from its start; the records
    an uncompressed chunk cut short still holds are read too (MCAP's record layout:
    opcode u8, length u64, body)."""
    import struct

    rb = rosbags()
    store = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
    schemas, channels = {}, {}

    def text(body: bytes, i: int):
        (size,) = struct.unpack_from("<I", body, i)
        return body[i + 4:i + 4 + size].decode(), i + 4 + size

    def records(data: bytes):
        i = 0
        while i + 9 <= len(data):
            opcode, length = struct.unpack_from("<BQ", data, i)
            body = data[i + 9:i + 9 + length]
            yield opcode, body, len(body) == length
            i += 9 + length

    def messages(data: bytes):
        for opcode, body, whole in records(data):
            if opcode == 0x06:  # a chunk: its records within
                compression, at = text(body, 28)  # after start, end, size (u64), crc (u32)
                if compression not in ("", "zstd", "lz4") or (compression and not whole):
                    raise BagError(f"a chunk cut short or compressed as {compression!r}")
                inner = body[at + 8:]
                if compression == "zstd":
                    inner = _zstd(inner)
                elif compression == "lz4":
                    inner = _lz4(inner)
                yield from messages(inner)
                if not whole:
                    raise BagError("a chunk cut short")
            elif not whole:
                raise BagError("a record cut short")
            elif opcode == 0x03:  # schema
                (sid,) = struct.unpack_from("<H", body)
                schemas[sid], _ = text(body, 2)
            elif opcode == 0x04:  # channel
                cid, sid = struct.unpack_from("<HH", body)
                topic, _ = text(body, 4)
                channels[cid] = (topic, schemas.get(sid, ""))
            elif opcode == 0x05:  # message
                (cid,) = struct.unpack_from("<H", body)
                topic, msgtype = channels[cid]
                if msgtype in store.types:
                    yield topic, msgtype, store.deserialize_cdr(body[22:], msgtype)

    raw = path.read_bytes()
    magic = b"\x89MCAP0\r\n"
    if not raw.startswith(magic):
        raise BagError(f"{path}: not an MCAP file")
    yield from messages(raw[len(magic):])


def odometry_at(times, poses, stamp: float) -> np.ndarray:
    """Odometry at ``stamp``: a reading stamped so, or the two around it (within
    ODOMETRY_MAX_GAP) interpolated; NaN when none brackets it (the scan goes without)."""
    k = int(np.searchsorted(times, stamp, side="right")) - 1
    if k < 0 or (times[k] != stamp and (k + 1 >= len(times)
                                        or times[k + 1] - times[k] > ODOMETRY_MAX_GAP)):
        return np.full(3, np.nan)
    return pose_between(times, poses, k, stamp)


def _laser(message, mount: Mount, index: int) -> LaserRecord | str:
    """A LaserScan as a record, or the name of what makes it unusable."""
    n = len(message.ranges)
    start, step = canonical_angle(message.angle_min), canonical_angle(message.angle_increment)
    end = canonical_angle(message.angle_max)
    if n == 0 or not (math.isfinite(start) and math.isfinite(step)) or step == 0:
        return "angles"
    if abs(start + (n - 1) * step - end) > abs(step) / 2 + 1e-4:
        return "beam count"
    ranges = canonical(message.ranges)
    low, high = canonical(message.range_min)[()], canonical(message.range_max)[()]
    if not (math.isfinite(high) and high > 0):
        return "range_max"
    # REP 117: inf is no return, -inf too near, NaN no reading; outside the scanner's span
    # likewise no reading, and range_max itself is how many drivers write no return
    ranges[~np.isfinite(ranges) | (ranges < low) | (ranges >= high)] = np.nan
    angles = start + step * np.arange(n)
    if mount.mirrored:
        angles = -angles
    return LaserRecord(stamp_of(message.header.stamp.sec, message.header.stamp.nanosec),
                       ranges, angles, np.zeros(3), np.zeros(3), float(high),
                       mount.offset.copy(), line=index,
                       time_increment=float(message.time_increment))


# ---------------------------------------------------------------------- writing
class _Messages:
    """The message classes and serializer of the format being written."""

    def __init__(self, fmt: str):
        rb = rosbags()
        ts = rb.typesys
        self.ros1 = fmt == "ros1"
        self.store = ts.get_typestore(ts.Stores.ROS1_NOETIC if self.ros1 else ts.Stores.ROS2_HUMBLE)
        if self.ros1 and TF_TYPE not in self.store.types:
            self.store.register(ts.get_types_from_msg(TF_MESSAGE_ROS1, TF_TYPE))
        self.t = self.store.types

    def serialize(self, message, msgtype: str) -> bytes:
        return (self.store.serialize_ros1 if self.ros1 else self.store.serialize_cdr)(message,
                                                                                      msgtype)

    def header(self, stamp: float, frame: str):
        sec, nanosec = sec_nanosec(stamp)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        if self.ros1:
            return self.t["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=frame)
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame)

    def vector(self, x=0.0, y=0.0, z=0.0):
        return self.t["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def quaternion(self, yaw: float, mirrored: bool = False):
        x, y, z, w = quaternion_of(yaw)
        if mirrored:  # roll π after the yaw: z points down
            x, y, z, w = w, z, -y, -x
        return self.t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def scan(self, stamp, frame, angles, ranges, max_range, time_increment=0.0):
        n = len(ranges)
        start = float(angles[0])
        step = float(angles[1] - angles[0]) if n > 1 else 0.0
        out = np.asarray(ranges, np.float64).astype(np.float32)
        out[~np.isfinite(ranges) | (np.asarray(ranges) >= max_range)] = np.inf  # REP 117
        return self.t[SCAN_TYPE](
            header=self.header(stamp, frame), angle_min=start, angle_max=start + (n - 1) * step,
            angle_increment=step, time_increment=float(time_increment), scan_time=0.0,
            range_min=0.0, range_max=float(max_range), ranges=out,
            intensities=np.zeros(0, np.float32))

    def odometry(self, stamp, pose, frame="odom", child="base_link"):
        point = self.t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0)
        pose_msg = self.t["geometry_msgs/msg/Pose"](position=point,
                                                    orientation=self.quaternion(pose[2]))
        twist = self.t["geometry_msgs/msg/Twist"](linear=self.vector(), angular=self.vector())
        return self.t[ODOMETRY_TYPE](
            header=self.header(stamp, frame), child_frame_id=child,
            pose=self.t["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg,
                                                                covariance=np.zeros(36)),
            twist=self.t["geometry_msgs/msg/TwistWithCovariance"](twist=twist,
                                                                  covariance=np.zeros(36)))

    def static(self, stamp, parent, child, offset, mirrored=False):
        transform = self.t["geometry_msgs/msg/Transform"](
            translation=self.vector(offset[0], offset[1]),
            rotation=self.quaternion(offset[2], mirrored))
        stamped = self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp, parent), child_frame_id=child, transform=transform)
        return self.t[TF_TYPE](transforms=[stamped])


class BagWriter:
    """A bag of scans, odometry and the laser's mount, written to a temporary name beside
    ``path`` and moved there whole on :meth:`close` (an interrupted write leaves no bag)."""

    def __init__(self, path, fmt: str | None = None, laser_frame: str = "laser",
                 base_frame: str = "base_link", odom_frame: str = "odom"):
        rb = rosbags()
        self.path = Path(path)
        self.fmt = format_of(self.path, fmt)
        self.frames = (laser_frame, base_frame, odom_frame)
        self.m = _Messages(self.fmt)
        # written in a folder of its own beside the bag, under the bag's own name (a ROS 2
        # bag's files are named after it), then moved into place
        self.folder = self.path.parent / f".{self.path.name}.{os.getpid()}.writing"
        shutil.rmtree(self.folder, ignore_errors=True)
        self.folder.mkdir()
        self.tmp = self.folder / self.path.name
        if self.fmt == "ros1":
            self.writer = rb.rosbag1.Writer(self.tmp)
        else:
            plugin = rb.rosbag2.StoragePlugin.MCAP if self.fmt == "mcap" else \
                rb.rosbag2.StoragePlugin.SQLITE3
            self.writer = rb.rosbag2.Writer(self.tmp, version=9, storage_plugin=plugin)
        self.writer.open()
        self.connections = {}
        for topic, msgtype in (("/scan", SCAN_TYPE), ("/odom", ODOMETRY_TYPE),
                               ("/tf_static", TF_TYPE), ("/tf", TF_TYPE)):
            options = {"latching": 1} if self.fmt == "ros1" and topic == "/tf_static" else {}
            self.connections[topic] = self.writer.add_connection(
                topic, msgtype, typestore=self.m.store, **options)
        self.static_written = False

    def _write(self, topic, stamp, message, msgtype):
        nanoseconds = sum(x * y for x, y in zip(sec_nanosec(stamp), (10**9, 1)))
        self.writer.write(self.connections[topic], nanoseconds,
                          self.m.serialize(message, msgtype))

    def mount(self, stamp: float, offset, mirrored: bool = False, moving: bool = False) -> None:
        """The laser's pose on the robot: on /tf_static, or (``moving``) on /tf for the scan
        stamped ``stamp``."""
        laser, base, _ = self.frames
        self._write("/tf" if moving else "/tf_static", stamp,
                    self.m.static(stamp, base, laser, offset, mirrored), TF_TYPE)
        self.static_written |= not moving

    def scan(self, stamp: float, angles, ranges, max_range: float, time_increment=0.0):
        if not self.static_written:
            self.mount(stamp, np.zeros(3))
        self._write("/scan", stamp, self.m.scan(stamp, self.frames[0], angles, ranges,
                                                 max_range, time_increment), SCAN_TYPE)

    def odometry(self, stamp: float, pose) -> None:
        _, base, odom = self.frames
        self._write("/odom", stamp, self.m.odometry(stamp, pose, odom, base), ODOMETRY_TYPE)

    def close(self) -> Path:
        self.writer.close()
        if self.fmt == "mcap":  # one MCAP file, as Foxglove and ros2 bag play open it
            (inner,) = self.tmp.glob("*.mcap")
            os.replace(inner, self.path)
        else:
            if self.path.is_dir():  # a bag folder written before: replaced whole
                shutil.rmtree(self.path)
            os.replace(self.tmp, self.path)
        shutil.rmtree(self.folder, ignore_errors=True)
        return self.path

    def abandon(self) -> None:
        with contextlib.suppress(Exception):
            self.writer.close()
        shutil.rmtree(self.folder, ignore_errors=True)


def write_bag(log: ScanLog, path, fmt: str | None = None) -> Path:
    """``log``'s scans (LaserScan on /scan), the odometry each scan has (Odometry on /odom,
    stamped with the scan) and the laser's mount (/tf_static; where it differs from scan to
    scan, as ROBOTLASER1's may, also on /tf with each scan), as a bag at ``path``."""
    lasers = sorted(log.lasers, key=lambda r: r.timestamp)
    if not lasers:
        raise BagError("nothing to write: the log has no scans")
    writer = BagWriter(path, fmt)
    try:
        offsets = np.array([r.laser_offset for r in lasers])
        moving = bool(np.any(offsets != offsets[0]))  # (ROBOTLASER1: a laser pose per scan)
        writer.mount(lasers[0].timestamp, offsets[0])
        for record in lasers:
            if moving:
                writer.mount(record.timestamp, record.laser_offset, moving=True)
            if np.all(np.isfinite(record.odometry)):
                writer.odometry(record.timestamp, record.odometry)
            writer.scan(record.timestamp, record.angles, record.ranges, record.max_range,
                        record.time_increment)
        return writer.close()
    except BaseException:
        writer.abandon()
        raise


class BagRecorder:
    """What a live scanner reads, to a bag, from the driver's thread without slowing it: each
    rotation is binned into ``bins`` equal angles over a full turn (a LaserScan's beams are
    evenly spaced; the nearest return in each bin) and handed to a writing thread through a
    bounded queue (a full queue drops the scan, counted)."""

    def __init__(self, path, bins: int, max_range: float, fmt: str | None = None,
                 capacity: int = 256):
        self.bins, self.max_range = int(bins), float(max_range)
        self.angles = -math.pi + (2 * math.pi / self.bins) * np.arange(self.bins)
        self.writer = BagWriter(path, fmt)
        self.queue: queue.Queue = queue.Queue(maxsize=capacity)
        self.recorded = self.dropped = 0
        self.error: Exception | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def put(self, angles, ranges, stamp: float) -> None:
        binned = bin_ranges(np.asarray(angles, float), np.asarray(ranges, float), self.bins,
                            self.max_range)
        try:
            self.queue.put_nowait((float(stamp), binned))
        except queue.Full:
            self.dropped += 1

    def _run(self):
        while True:
            item = self.queue.get()
            if item is None:
                return
            try:
                self.writer.scan(item[0], self.angles, item[1], self.max_range)
                self.recorded += 1
            except Exception as exc:  # the bag fails, the run goes on (and says so)
                self.error = exc

    def close(self) -> Path:
        self.queue.put(None)
        self.thread.join()
        if self.error is not None:
            self.writer.abandon()
            raise BagError(f"recording the bag failed: {self.error}")
        return self.writer.close()


def bin_ranges(angles, ranges, bins: int, max_range: float) -> np.ndarray:
    """A rotation's valid returns binned by angle over a full turn (bin ``k`` centred on the
    LaserScan beam −π + 2πk/bins): the nearest in each bin, ``inf`` where none (no return)."""
    valid = np.isfinite(ranges) & (ranges > 0) & (ranges < max_range) & np.isfinite(angles)
    return binned_ranges(angles[valid], ranges[valid], bins, np.inf)
