"""The LiDAR model: beams, field of view, range limits, scan rate, range noise and dropout.

Presets mimic the scanners SwarmSLAM meets: Slamtec's RPLidar A1/A2 (360°, 12 m) and the 180°
SICK LMS200-class lasers of the benchmark datasets (Intel, ACES3). Ranges come from the
compiled caster (:mod:`swarmslam_sim.raycast`); noise and dropout are drawn from the generator
the caller passes (the environment's ``np_random``), into buffers allocated once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from swarmslam.runtime.matching.scan import beam_directions
from swarmslam_sim.raycast import build_grid, cast_scan
from swarmslam_sim.world import World


@dataclass(frozen=True)
class LidarConfig:
    beams: int = 360
    fov: float = 2 * math.pi  # rad; 2π is a full turn (no duplicate beam at ±π)
    min_range: float = 0.15  # m; nearer returns are reported as "no return"
    max_range: float = 12.0  # m
    rate_hz: float = 10.0  # revolutions (scans) per second
    noise_std: float = 0.01  # m, Gaussian range noise
    dropout: float = 0.0  # probability that a beam returns nothing

    def __post_init__(self):
        if self.beams < 2:
            raise ValueError(f"LiDAR needs ≥ 2 beams, got {self.beams}")
        if not 0 < self.fov <= 2 * math.pi + 1e-9:
            raise ValueError(f"fov must be in (0, 2π], got {self.fov}")
        if not 0 <= self.min_range < self.max_range:
            raise ValueError(f"need 0 ≤ min_range < max_range, got {self.min_range}, {self.max_range}")
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {self.rate_hz}")
        if self.noise_std < 0 or not 0 <= self.dropout < 1:
            raise ValueError(f"need noise_std ≥ 0 and 0 ≤ dropout < 1, got {self.noise_std}, {self.dropout}")

    def angles(self) -> np.ndarray:
        """Beam angles in the sensor frame (rad, counter-clockwise, 0 straight ahead)."""
        if self.fov >= 2 * math.pi - 1e-9:
            return -math.pi + np.arange(self.beams) * (2 * math.pi / self.beams)
        return np.linspace(-self.fov / 2, self.fov / 2, self.beams)


PRESETS = {
    # RPLidar A1M8: 0.15–12 m, ~5.5 Hz, ~1° at its standard sample rate
    "rplidar-a1": LidarConfig(360, 2 * math.pi, 0.15, 12.0, 5.5, 0.01, 0.01),
    # RPLidar A2M8: 0.15–12 m, 10 Hz, 0.5°
    "rplidar-a2": LidarConfig(720, 2 * math.pi, 0.15, 12.0, 10.0, 0.01, 0.005),
    # SICK LMS200-class, as in Intel and ACES3: 181 beams over 180°, 1°, tens of metres
    "lms200": LidarConfig(181, math.pi, 0.05, 50.0, 5.0, 0.01, 0.0),
}


def lidar_config(spec) -> LidarConfig:
    """A preset by name, a ``LidarConfig``, or a dict of fields over the A1 preset."""
    if isinstance(spec, LidarConfig):
        return spec
    if isinstance(spec, dict):
        base = PRESETS[spec.get("preset", "rplidar-a1")]
        return replace(base, **{k: v for k, v in spec.items() if k != "preset"})
    if spec not in PRESETS:
        raise ValueError(f"unknown LiDAR preset {spec!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[spec]


class Lidar:
    """A scanner in a static world: ``scan(pose, rng)`` fills and returns a range buffer."""

    def __init__(self, world: World, config: LidarConfig, wall_radius: float = 0.0):
        self.config = config
        self.world = world
        self.wall_radius = float(wall_radius)
        self.angles = config.angles()
        self.directions = np.zeros((config.beams, 2))  # the beams' unit vectors, once
        beam_directions(self.angles, self.directions)
        self.grid, self.cell_start, self.cell_items = build_grid(world.segments, wall_radius,
                                                                 world.bounds)
        self.ranges = np.zeros(config.beams)  # the last scan, no return = max_range
        self._noise = np.zeros(config.beams)
        self._drop = np.zeros(config.beams)
        self._pose = np.zeros(3)

    def cast(self, pose, out=None) -> np.ndarray:
        """Exact ranges (no noise); inf where nothing lies within max_range."""
        out = np.empty(self.config.beams) if out is None else out
        return self.cast_angles(pose, self.angles, out)

    def cast_angles(self, pose, angles, out) -> np.ndarray:
        """Exact ranges of beams at ``angles`` (the scanner's frame) from ``pose``; inf where
        nothing lies within max_range."""
        self._pose[:] = pose
        cast_scan(self._pose, angles, self.config.max_range, self.world.segments,
                  self.wall_radius, self.grid, self.cell_start, self.cell_items, out)
        return out

    def scan(self, pose, rng: np.random.Generator) -> np.ndarray:
        """A measured scan: noisy ranges, ``max_range`` for every beam without a return."""
        c = self.config
        r = self.cast(pose, self.ranges)
        if c.noise_std > 0:  # (in place: no temporary array per scan)
            rng.standard_normal(out=self._noise)
        if c.dropout > 0:
            rng.random(out=self._drop)
        measure(r, self._noise, c.noise_std, self._drop, c.dropout, c.min_range, c.max_range)
        return r


@njit(cache=True)
def measure(ranges, noise, noise_std, draws, dropout, min_range, max_range):
    """Exact ranges made measured ones, in place: ``noise`` (standard normal) scaled by
    ``noise_std`` added, a beam whose uniform draw falls below ``dropout`` lost, then
    :func:`no_return`'s rule — one pass instead of five array operations per scan."""
    for k in range(ranges.shape[0]):
        r = ranges[k]
        if noise_std > 0:
            r += noise[k] * noise_std
        if dropout > 0 and draws[k] < dropout:
            r = math.inf
        ranges[k] = reported(r, min_range, max_range)


@njit(cache=True)
def no_return(ranges, min_range, max_range):
    """Every range below ``min_range``, at or beyond ``max_range`` (or NaN) set to
    ``max_range``: what the scanner reports for a beam without a return."""
    for k in range(ranges.shape[0]):
        ranges[k] = reported(ranges[k], min_range, max_range)


@njit(cache=True, inline="always")
def reported(r, min_range, max_range):
    """What the scanner reports for range ``r``: ``max_range`` (no return) below
    ``min_range``, at or beyond ``max_range``, or NaN; else ``r``."""
    return max_range if r < min_range or not r < max_range else r
