"""Writing a bag: scans (LaserScan on /scan), odometry (Odometry on /odom) and the laser's
mount (/tf_static, or /tf where it moves), in ROS 1, ROS 2 sqlite3 or MCAP, written to a
temporary name and moved into place whole.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

import numpy as np

from swarmslam.formats.bags.common import (ODOMETRY_TYPE, SCAN_TYPE, TF_MESSAGE_ROS1, TF_TYPE,
                                           BagError, format_of, quaternion_of, rosbags,
                                           sec_nanosec)
from swarmslam.formats.records import ScanLog


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


def refuse_to_replace(path: Path, fmt: str) -> None:
    """Raise :class:`BagError` when writing a bag at ``path`` would replace what is not a bag:
    the working folder (or one holding it), a folder where a file bag goes, or a folder that
    is not a ROS 2 bag (a bag written before, its ``metadata.yaml`` beside its data, is
    replaced whole; any other folder is the user's)."""
    where = path.resolve()
    cwd = Path.cwd().resolve()
    if where == cwd or where in cwd.parents:
        raise BagError(f"{path}: the working folder (or one holding it) cannot become a bag; "
                       f"name the bag, e.g. {Path(path) / 'out.mcap'}")
    if not path.is_dir():
        return
    if fmt != "sqlite3":
        raise BagError(f"{path}: exists and is a folder; a {fmt} bag is one file")
    if not (path / "metadata.yaml").is_file():
        raise BagError(f"{path}: exists and is not a ROS 2 bag (no metadata.yaml): its files "
                       f"would be replaced; name a new folder, or a file.mcap / file.bag")


class BagWriter:
    """A bag of scans, odometry and the laser's mount, written to a temporary name beside
    ``path`` and moved there whole on :meth:`close` (an interrupted write leaves no bag)."""

    def __init__(self, path, fmt: str | None = None, laser_frame: str = "laser",
                 base_frame: str = "base_link", odom_frame: str = "odom"):
        rb = rosbags()
        self.path = Path(path)
        self.fmt = format_of(self.path, fmt)
        refuse_to_replace(self.path, self.fmt)
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
