"""Reading a bag into a :class:`~swarmslam.formats.records.ScanLog`.

The LaserScan topic is found by type, or ``scan_topic``; several without one is an error
listing them. Odometry comes from ``nav_msgs/Odometry`` (``odom_topic``) or, when the bag has
none, from ``tf`` (``odom_frame`` → ``base_frame``), interpolated to each scan's header stamp
(not the bag's receive time). The laser's mounting comes from ``tf_static`` (``base_frame`` →
the scan's ``frame_id``; none: zero, with a warning). A LaserScan is read whole: ``angle_min``,
``angle_increment`` (negative, or a laser mounted upside down in ``tf_static``, mirrors the
beams), ``range_min``/``range_max`` (a reading outside, ``inf`` or ``NaN`` is no return, REP
117) and ``time_increment``; intensities are not used. A scan whose beam count contradicts its
angles is skipped and counted. A damaged bag keeps every scan read before the damage and says
where it stopped (:mod:`swarmslam.formats.bags.salvage`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from swarmslam.formats.bags.common import (ODOMETRY_TYPE, SCAN_TYPE, TF_TYPE, BagError, Mount,
                                           canonical, canonical_angle, mount_of, rosbags,
                                           stamp_of, yaw_of)
from swarmslam.formats.bags.salvage import mcap_records, ros1_records, salvaged
from swarmslam.formats.carmen import ODOMETRY_MAX_GAP, pose_between
from swarmslam.formats.records import LaserRecord, OdometryRecord, ScanLog


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
        salvage = {".bag": ros1_records, ".mcap": mcap_records}.get(path.suffix)
        if salvage is None:
            raise BagError(f"{path}: not a bag that can be read ({type(exc).__name__}: "
                           f"{exc})") from None
        return salvaged(path, salvage)
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
