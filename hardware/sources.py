"""What the emulator's virtual scanner sees: ``distances(angles_deg) → mm`` for the rotation
under way, ``next_rotation()`` to move on, ``reset()`` when a scan starts.

Angles are the scanner's (degrees, clockwise from its front); distances are in mm, 0 for no
return. The simulated world is :class:`swarmslam_sim.scanner_source.WorldSource`.
"""

from __future__ import annotations

import math

import numpy as np

from runtime.carmen import read_carmen


def robot_angles(angles_deg) -> np.ndarray:
    """Scanner angles (clockwise degrees) → robot-frame angles (counter-clockwise radians)."""
    return -np.radians(np.asarray(angles_deg, dtype=np.float64))


class FunctionSource:
    """A static scene given as ``mm = f(angle_deg)`` (tests, bench checks)."""

    def __init__(self, f):
        self.f = f
        self.rotation = 0

    def reset(self) -> None:
        self.rotation = 0

    def next_rotation(self) -> None:
        self.rotation += 1

    def distances(self, angles_deg) -> np.ndarray:
        return np.asarray(self.f(np.asarray(angles_deg, dtype=np.float64)), dtype=np.float64)


class CarmenSource:
    """A recorded CARMEN log replayed rotation by rotation: each rotation shows the next laser
    record, each angle its nearest beam (none outside the record's field of view)."""

    def __init__(self, path, loop: bool = True):
        self.log = read_carmen(path)
        if not self.log.lasers:
            raise ValueError(f"{path}: no laser records to replay")
        self.loop = loop
        self.index = 0

    def reset(self) -> None:
        pass  # a restarted scan continues the log, as time goes on for a real scanner

    def next_rotation(self) -> None:
        self.index += 1
        if self.index >= len(self.log.lasers):
            self.index = 0 if self.loop else len(self.log.lasers) - 1

    def distances(self, angles_deg) -> np.ndarray:
        record = self.log.lasers[self.index]
        beams = np.asarray(record.angles, dtype=np.float64)
        ranges = np.asarray(record.ranges, dtype=np.float64)
        want = robot_angles(angles_deg)
        want = (want + math.pi) % (2 * math.pi) - math.pi
        k = np.abs(want[:, None] - beams[None, :]).argmin(axis=1)  # the nearest beam
        spacing = np.max(np.abs(np.diff(beams))) if len(beams) > 1 else math.pi
        r = ranges[k]
        ok = (np.abs(beams[k] - want) <= spacing) & (r > 0) & (r < record.max_range)
        return np.where(ok, r * 1000.0, 0.0)
