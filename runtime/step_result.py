"""What one scan through the SLAM (mapping or localization) gives back."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class StepResult:
    pose: np.ndarray  # the scan's pose in the map frame, after this step's back-end work
    node_added: bool
    loop_closed: bool  # a loop closure was kept during this step
    error: float  # λ of the front end's alignment
    front_end_seconds: float = 0.0  # measured only when a clock is given
