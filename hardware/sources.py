"""What the emulator's virtual scanner sees: ``distances(angles_deg) → mm`` for the rotation
under way, ``next_rotation()`` to move on, ``reset()`` when a scan starts.

Angles are the scanner's (degrees, clockwise from its front); distances are in mm, 0 for no
return. A recorded log and a simulated world, which need other packages, are in
:mod:`swarmslam.emulator_sources`.
"""

from __future__ import annotations

import numpy as np


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
