"""The simulated side of SwarmSLAM: pymunk worlds, a LiDAR model and ``SwarmSlam-v0``.

Importing the package registers the environment (Gymnasium ≥ 1.0 has no entry-point loader),
so both ``gymnasium.make("swarmslam_sim:SwarmSlam-v0")`` and, after ``import swarmslam_sim``,
``gymnasium.make("SwarmSlam-v0")`` work.
"""

from pathlib import Path

from gymnasium.envs.registration import register, registry

from swarmslam.runtime.realtime.kernel_cache import refresh

refresh(Path(__file__).parent)  # before any kernel of this package is loaded

from swarmslam_sim.env import SwarmSlamEnv  # noqa: E402

ENV_ID = "SwarmSlam-v0"
MAX_EPISODE_STEPS = 500

if ENV_ID not in registry:
    register(id=ENV_ID, entry_point="swarmslam_sim.env:SwarmSlamEnv",
             max_episode_steps=MAX_EPISODE_STEPS)

__all__ = ["SwarmSlamEnv", "ENV_ID"]
