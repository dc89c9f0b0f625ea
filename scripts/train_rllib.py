"""``swarmslam rllib``: PPO on ``SwarmSlam-v0`` with RLlib, its env runners spread over Ray —
a local Ray by default, a cluster with ``--address`` (docs/sweeps.md §4).

    result = train_ppo(iterations=10, env_runners=4, env_config={"slam": True})

Each env runner builds its own environments from ``env_config`` (``gymnasium.make`` keyword
arguments); the Dict observation is flattened for RLlib's default model. The result holds
the env steps sampled, the mean episode return seen and the checkpoint's folder, if saved.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym

import swarmslam_sim  # noqa: F401  (registers SwarmSlam-v0, in each env runner's process too)
from swarmslam.sweep import ray_session


class RLlibEnv(gym.Wrapper):
    """``SwarmSlam-v0`` built from one config dict, as RLlib builds an environment class in
    each env runner's own process (no name to look up in a registry there)."""

    def __init__(self, env_config: dict | None = None):
        super().__init__(gym.make("SwarmSlam-v0", **dict(env_config or {})))


def ppo_config(env_runners: int = 2, env_config: dict | None = None, seed: int = 0,
               batch: int = 512, minibatch: int = 128, epochs: int = 1,
               fragment: int = 64):
    """RLlib's PPO on the environment: ``env_runners`` runner actors (one CPU each), a batch of
    ``batch`` env steps per iteration, ``epochs`` passes over it in minibatches."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.connectors.env_to_module import FlattenObservations

    return (PPOConfig()
            .environment(RLlibEnv, env_config=dict(env_config or {}))
            .framework("torch")
            .env_runners(num_env_runners=env_runners, num_envs_per_env_runner=1,
                         rollout_fragment_length=fragment,
                         env_to_module_connector=lambda env, spaces=None, device=None:
                         FlattenObservations())
            .training(train_batch_size_per_learner=batch, minibatch_size=minibatch,
                      num_epochs=epochs)
            .debugging(seed=seed))


def train_ppo(iterations: int = 1, env_runners: int = 2, env_config: dict | None = None,
              seed: int = 0, checkpoint: Path | None = None, address: str | None = None,
              echo=print, **ppo) -> dict:
    """``iterations`` PPO iterations; returns the env steps sampled, the last mean episode
    return (None before an episode ended) and the checkpoint folder (if ``checkpoint``)."""
    with ray_session(address, None if address else env_runners + 1):
        algo = ppo_config(env_runners, env_config, seed, **ppo).build_algo()
        try:
            for k in range(iterations):
                result = algo.train()
                runners = result.get("env_runners", {})
                steps = int(runners.get("num_env_steps_sampled_lifetime", 0))
                ret = runners.get("episode_return_mean")
                echo(f"iteration {k + 1}/{iterations}: {steps} env steps sampled, mean episode "
                     f"return {'—' if ret is None else f'{ret:.2f}'}")
            saved = None
            if checkpoint is not None:
                saved = str(Path(checkpoint).resolve())
                algo.save_to_path(saved)
            return {"env_steps": steps, "episode_return_mean": ret, "checkpoint": saved,
                    "env_runners": env_runners}
        finally:
            algo.stop()
