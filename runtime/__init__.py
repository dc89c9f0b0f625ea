"""The embeddable SLAM core (README, "Layout"; docs/runtime.md), in rooms that mirror the
architecture: ``matching`` (scans, fields, the swarm optimizers, the matcher, the place search),
``front_end`` (local SLAM), ``back_end`` (global SLAM), ``localization`` and ``realtime`` (the
fixed-rate runtime), joined by :mod:`swarmslam.runtime.slam`.

The names the README's examples use come from here:

    >>> from swarmslam.runtime import GraphSlam, LoopDrive, PointScan, SlamRuntime, preset
    >>> preset("rplidar-a1").sensor.max_points
    973

Importing the package first makes sure no compiled kernel cached from older sources runs
(:mod:`swarmslam.runtime.realtime.kernel_cache`).
"""

from pathlib import Path

from swarmslam.runtime.realtime.kernel_cache import refresh

refresh(Path(__file__).parent)  # before any kernel is loaded

# The public names (after the refresh: each import below loads compiled kernels).
from swarmslam.runtime.config import SlamConfig, preset  # noqa: E402
from swarmslam.runtime.matching.scan import PointScan  # noqa: E402
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime  # noqa: E402
from swarmslam.runtime.realtime.warm_up import LoopDrive  # noqa: E402
from swarmslam.runtime.slam import GraphSlam  # noqa: E402

__all__ = ["GraphSlam", "LoopDrive", "PointScan", "SlamConfig", "SlamRuntime", "preset"]
