"""RLlib on SwarmSlam-v0 (swarmslam.train_rllib): one PPO iteration with 2 env runners on a
local Ray, and a checkpoint that restores."""

import ray
from ray.rllib.algorithms.algorithm import Algorithm  # the 'rllib' extra, in the test one

from swarmslam.cli import main
from swarmslam.train_rllib import train_ppo


def test_one_ppo_iteration_with_two_env_runners(tmp_path):
    said = []
    result = train_ppo(iterations=1, env_runners=2, env_config={"max_episode_steps": 50},
                       batch=256, minibatch=64, checkpoint=tmp_path / "ppo", echo=said.append)
    assert result["env_steps"] >= 256 and result["env_runners"] == 2
    assert "iteration 1/1" in said[0]
    restored = Algorithm.from_checkpoint(result["checkpoint"])
    try:
        assert restored.config.num_env_runners == 2
    finally:
        restored.stop()
        ray.shutdown()  # from_checkpoint started a Ray of its own: no test after sees it


def test_the_cli_trains_with_the_slam_on(tmp_path, capsys):
    assert main(["rllib", "--iterations", "1", "--env-runners", "2", "--slam",
                 "--episode-steps", "40", "--checkpoint", str(tmp_path / "ppo")]) == 0
    out = capsys.readouterr().out
    assert "iteration 1/1" in out and "checkpoint in" in out
