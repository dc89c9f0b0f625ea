"""Recording a live scanner to a bag from the driver's thread, through a bounded queue."""

from __future__ import annotations

import math
import queue
import threading
from pathlib import Path

import numpy as np

from swarmslam.formats.bags.common import BagError
from swarmslam.formats.bags.writer import BagWriter
from swarmslam.runtime.matching.scan import binned_ranges


class BagRecorder:
    """What a live scanner reads, to a bag, from the driver's thread without slowing it: each
    rotation is binned into ``bins`` equal angles over a full turn (a LaserScan's beams are
    evenly spaced; the nearest return in each bin) and handed to a writing thread through a
    bounded queue (a full queue drops the scan, counted). The writer is opened, used and
    closed on that thread alone (a sqlite3 bag's connection belongs to the thread that made
    it)."""

    def __init__(self, path, bins: int, max_range: float, fmt: str | None = None,
                 capacity: int = 256):
        self.bins, self.max_range = int(bins), float(max_range)
        self.angles = -math.pi + (2 * math.pi / self.bins) * np.arange(self.bins)
        self.path, self.fmt = Path(path), fmt
        self.queue: queue.Queue = queue.Queue(maxsize=capacity)
        self.recorded = self.dropped = 0
        self.error: Exception | None = None
        self._opened = threading.Event()
        self._written: Path | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        self._opened.wait()  # what refuses the bag is raised here, before the run
        if self.error is not None:  # (rosbags missing, a folder not a bag, not writable)
            self.thread.join()
            raise self.error

    def put(self, angles, ranges, stamp: float) -> None:
        binned = bin_ranges(np.asarray(angles, float), np.asarray(ranges, float), self.bins,
                            self.max_range)
        try:
            self.queue.put_nowait((float(stamp), binned))
        except queue.Full:
            self.dropped += 1

    def _run(self):
        try:
            writer = BagWriter(self.path, self.fmt)
        except Exception as exc:  # said on the caller's thread
            self.error = exc
            return
        finally:
            self._opened.set()
        while True:
            item = self.queue.get()
            if item is None:
                break
            try:
                if self.error is None:
                    writer.scan(item[0], self.angles, item[1], self.max_range)
                    self.recorded += 1
            except Exception as exc:  # the bag fails, the run goes on (and says so)
                self.error = exc
        if self.error is not None:
            writer.abandon()
            return
        try:
            self._written = writer.close()
        except Exception as exc:
            self.error = exc
            writer.abandon()

    def close(self) -> Path:
        self.queue.put(None)
        self.thread.join()
        if self.error is not None:
            raise BagError(f"recording the bag failed: {self.error}")
        return self._written


def bin_ranges(angles, ranges, bins: int, max_range: float) -> np.ndarray:
    """A rotation's valid returns binned by angle over a full turn (bin ``k`` centred on the
    LaserScan beam −π + 2πk/bins): the nearest in each bin, ``inf`` where none (no return)."""
    valid = np.isfinite(ranges) & (ranges > 0) & (ranges < max_range) & np.isfinite(angles)
    return binned_ranges(angles[valid], ranges[valid], bins, np.inf)
