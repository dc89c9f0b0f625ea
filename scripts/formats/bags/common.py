"""What the bag reader, salvage, writer and recorder share: the message types, the formats,
the one error, exact numbers (float32 fields and angles as the decimals they were written
from), headings of quaternions and back, and the laser's mount chained through ``tf_static``.

float32 fields are read as the shortest decimal that rounds to them, and angles within their
float32 rounding of a fraction of π (−π/2, π/180, ...) as that fraction: a log written from
decimal text (CARMEN) reads back as it was, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from swarmslam.formats.carmen import MAX_LASER_OFFSET

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



# ---------------------------------------------------------------------- the mount
# A quaternion's norm may differ from 1 by this (rounding); beyond, it is not a rotation.
UNIT_QUATERNION = 1e-3


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
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))
                and abs(math.sqrt(sum(float(v) ** 2 for v in q)) - 1.0) <= UNIT_QUATERNION):
            raise BagError(f"the laser {laser!r}'s mount in tf_static is not finite or not a "
                           f"rotation: translation {tuple(t)}, rotation {tuple(q)}")
        r = rotation_matrix(q)
        rotation, translation = r @ rotation, r @ translation + np.asarray(t, float)
    if abs(abs(rotation[2, 2]) - 1.0) > 1e-3:
        raise BagError(f"the laser {laser!r} is tilted out of the plane in tf_static: not a "
                       f"2-D scanner")
    if np.any(np.abs(translation[:2]) > MAX_LASER_OFFSET):
        raise BagError(f"the laser {laser!r} is mounted {np.hypot(*translation[:2]):.3g} m from "
                       f"{base!r} in tf_static, beyond the {MAX_LASER_OFFSET:g} m a robot's "
                       f"laser can be")
    mirrored = bool(rotation[2, 2] < 0)  # z down: the beams' angles run the other way
    if len(chain) == 1 and not mirrored:  # the heading as written, exactly
        yaw = yaw_of(chain[0][2])
    else:
        yaw = math.atan2(rotation[1, 0], rotation[0, 0])
    return Mount(np.array([translation[0], translation[1], yaw]), mirrored)

