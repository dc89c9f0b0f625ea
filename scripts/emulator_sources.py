"""Sources for the emulated scanner that come from other packages: a recorded CARMEN log
(:class:`CarmenSource`) and a simulated world (:class:`WorldSource`).

A simulated world as the emulated scanner's view: a robot explores it (frontier explorer on
the true pose, no SLAM), one env step per scanner rotation, and the scanner's beams are cast
from the robot's true pose at exactly the angles the emulator streams.

The true pose of every rotation is kept (``truth``), so a client's estimate can be scored.
"""

from __future__ import annotations

import math
import threading

import gymnasium as gym
import numpy as np

from swarmslam.hardware.sources import robot_angles
from swarmslam.formats.carmen import read_carmen
from swarmslam_sim.exploration import FrontierExplorer
from swarmslam_sim.raycast import cast_scan


class WorldSource:
    def __init__(self, world: str = "office", seed: int = 0, lidar: str = "rplidar-a1",
                 range_noise: float = 0.01, max_steps: int = 100_000, still_before: int = 0,
                 still_after: int | None = None):
        """The robot stands still for the first ``still_before`` rotations and from rotation
        ``still_after`` on (so a client's first scan and final estimate have a known pose)."""
        self.env = gym.make("swarmslam_sim:SwarmSlam-v0", world=world, lidar=lidar, slam=False,
                            coverage_goal=None, max_episode_steps=max_steps)
        self.sim = self.env.unwrapped
        _, self.info = self.env.reset(seed=seed)
        self.policy = FrontierExplorer.for_env(self.env)
        # compile the planner now: a first rotation that waits on it would stall the device for
        # most of a second, and its stream would then catch up in a burst no scanner sends
        self.policy.plan(self.sim.true_pose, self.sim.map)
        self.rng = np.random.default_rng(seed)
        self.range_noise = range_noise
        self.still_before = still_before
        self.still_after = still_after
        self.rotation = 0
        self.truth = [self.sim.true_pose.copy()]
        self.lock = threading.Lock()
        self._pose = np.zeros(3)
        self._angles = np.zeros(1)
        self._out = np.zeros(1)

    def reset(self) -> None:
        pass

    def next_rotation(self) -> None:
        with self.lock:
            self.rotation += 1
            if self.still_before <= self.rotation and (self.still_after is None
                                                       or self.rotation < self.still_after):
                action = self.policy.act(self.sim.true_pose, self.sim.map, self.info["in_contact"])
                _, _, terminated, truncated, self.info = self.env.step(action)
                if terminated or truncated:
                    _, self.info = self.env.reset()
            self.truth.append(self.sim.true_pose.copy())

    def pose(self) -> np.ndarray:
        with self.lock:
            return self.sim.true_pose.copy()

    def distances(self, angles_deg) -> np.ndarray:
        lidar = self.sim.lidar
        angles = robot_angles(angles_deg)
        if self._out.shape[0] != angles.shape[0]:
            self._out = np.zeros(angles.shape[0])
        self._pose[:] = self.sim.true_pose
        cast_scan(self._pose, angles, lidar.config.max_range, lidar.world.segments,
                  lidar.wall_radius, lidar.grid, lidar.cell_start, lidar.cell_items, self._out)
        r = self._out
        valid = np.isfinite(r) & (r < lidar.config.max_range) & (r > lidar.config.min_range)
        noisy = r + self.range_noise * self.rng.standard_normal(r.shape[0])
        return np.where(valid, np.maximum(noisy, 0.0) * 1000.0, 0.0)


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
