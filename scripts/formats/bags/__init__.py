"""ROS bags in and out: ROS 1 ``.bag``, ROS 2 bag folders (sqlite3 ``.db3`` or MCAP) and bare
``.mcap`` files, read and written with rosbags (pure Python, no ROS install; the extra
``bags``). docs/formats.md §9 says what is read from each message.

    log = read_bag("run.bag")                   # the same ScanLog the CARMEN reader gives
    write_bag(log, "intel.mcap")                # LaserScan, Odometry and tf_static

One module a job, as rosbags keeps them: :mod:`.reader` (a bag into a ScanLog),
:mod:`.salvage` (a damaged bag read up to its damage), :mod:`.writer` (a ScanLog or live
scans into a bag, moved into place whole), :mod:`.recorder` (a live scanner's rotations,
recorded from the driver's thread) and :mod:`.common` (types, exact numbers, the mount).
"""

from swarmslam.formats.bags.common import FORMATS, BagError, format_of, is_bag
from swarmslam.formats.bags.reader import read_bag
from swarmslam.formats.bags.recorder import BagRecorder, bin_ranges
from swarmslam.formats.bags.writer import BagWriter, refuse_to_replace, write_bag

__all__ = ["FORMATS", "BagError", "BagRecorder", "BagWriter", "bin_ranges", "format_of",
           "is_bag", "read_bag", "refuse_to_replace", "write_bag"]
