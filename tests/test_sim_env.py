"""SwarmSlam-v0: Gymnasium's checks, determinism, vector envs, physics, SLAM in the loop, RL."""

import math
import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import swarmslam_sim  # noqa: F401  (registers SwarmSlam-v0)
from swarmslam_sim.exploration import FrontierExplorer
from swarmslam_sim.world import World

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

BOX = World("box", np.array([[0, 0, 4, 0], [4, 0, 4, 3], [4, 3, 0, 3], [0, 3, 0, 0]], float),
            (-0.5, -0.5, 4.5, 3.5), (1.0, 1.5, 0.0))


def test_check_env_passes_without_warnings():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make("swarmslam_sim:SwarmSlam-v0", render_mode="rgb_array")
        check_env(env.unwrapped)
        env.close()
        env.close()  # idempotent
    assert [str(w.message) for w in caught] == []


def run_episode(seed, steps=40, **kwargs):
    env = gym.make("SwarmSlam-v0", **kwargs)
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    trace = [(obs, 0.0, info)]
    for _ in range(steps):
        obs, reward, _, _, info = env.step(env.action_space.sample())
        trace.append((obs, reward, info))
    return trace


def same(a, b):
    return all(np.array_equal(x[0][k], y[0][k]) for x, y in zip(a, b) for k in ("scan", "pose", "map")) \
        and [x[1] for x in a] == [y[1] for y in b] \
        and all(np.array_equal(x[2]["estimated_pose"], y[2]["estimated_pose"]) for x, y in zip(a, b))


def test_same_seed_same_episode_slam_included():
    a, b, c = run_episode(11), run_episode(11), run_episode(12)
    assert same(a, b)
    assert not same(a, c)
    assert a[-1][2]["slam_nodes"] > 1  # the SLAM ran, and was reproduced bit for bit


def test_observations_lie_in_their_space_and_info_is_complete():
    env = gym.make("SwarmSlam-v0", world="maze", lidar="lms200", optimizer="pso")
    obs, info = env.reset(seed=0)
    for _ in range(20):
        obs, reward, terminated, truncated, info = env.step(np.array([0.5, 0.2], np.float32))
        assert env.observation_space.contains(obs)
        assert np.isfinite(reward)
    assert obs["scan"].shape == (181,) and obs["map"].shape == (64, 64)
    for key in ("true_pose", "estimated_pose", "pose_error", "heading_error", "coverage",
                "collisions", "odometry", "slam_nodes", "loop_closures", "slam_status"):
        assert key in info
    assert info["pose_error"] < 0.2 and 0 < info["coverage"] < 1
    timed = gym.make("SwarmSlam-v0", timing_in_info=True)
    timed.reset(seed=0)
    assert timed.step(np.zeros(2, np.float32))[4]["slam_ms"] > 0


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="optimizer"):
        gym.make("SwarmSlam-v0", optimizer="ga")
    with pytest.raises(ValueError, match="unknown world"):
        gym.make("SwarmSlam-v0", world="nowhere")
    # gymnasium warns of the unknown mode before our constructor refuses it
    with pytest.raises(ValueError, match="render_mode"), pytest.warns(UserWarning, match="ascii"):
        gym.make("SwarmSlam-v0", render_mode="ascii")
    env = gym.make("SwarmSlam-v0").unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2, np.float32))


def test_collisions_stop_the_robot_and_are_counted():
    env = gym.make("SwarmSlam-v0", world=BOX, slam=False, coverage_goal=None, max_episode_steps=100)
    env.reset(seed=0)
    u = env.unwrapped
    u.robot.body.angle = 0.0  # face the east wall, 2.83 m ahead of the robot's edge
    for _ in range(60):  # 11 s at 0.5 m/s: would be 5.5 m without the wall
        _, reward, terminated, _, info = env.step(np.array([1.0, 0.0], np.float32))
    x = info["true_pose"][0]
    assert 4.0 - u.robot_radius - 0.07 <= x <= 4.0 - u.robot_radius + 0.07
    assert info["collisions"] == 1 and info["in_contact"] and not terminated
    strict = gym.make("SwarmSlam-v0", world=BOX, slam=False, coverage_goal=None,
                      terminate_on_collision=True)
    strict.reset(seed=0)
    strict.unwrapped.robot.body.angle = 0.0
    ends = [strict.step(np.array([1.0, 0.0], np.float32)) for _ in range(60)]
    hit = next(k for k, e in enumerate(ends) if e[2])
    assert ends[hit][4]["collisions"] == 1 and ends[hit][1] < 0  # the penalty


def test_rewards_sum_to_the_area_mapped_and_coverage_terminates():
    env = gym.make("SwarmSlam-v0", slam=False, coverage_goal=0.3, reward_per_m2=2.0)
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    known_at_start = u.known_cells
    assert 0 < info["coverage"] < 0.3  # the first scan maps part of the office
    policy = FrontierExplorer.for_env(env)
    total = 0.0
    for _ in range(200):
        action = policy.act(info["estimated_pose"], u.map, info["in_contact"])
        obs, reward, terminated, truncated, info = env.step(action)
        total += reward
        if terminated:
            break
    assert terminated and info["coverage"] >= 0.3 and info["collisions"] == 0
    assert total == pytest.approx(2.0 * (u.known_cells - known_at_start) * u.cell_area)
    assert info["coverage"] == pytest.approx(u.known_cells / u.mappable_cells)


def test_exploring_with_slam_tracks_the_true_pose():
    env = gym.make("SwarmSlam-v0", max_episode_steps=250)
    obs, info = env.reset(seed=5)
    policy = FrontierExplorer.for_env(env)
    errors = []
    for _ in range(250):
        action = policy.act(info["estimated_pose"], env.unwrapped.map, info["in_contact"])
        obs, reward, terminated, truncated, info = env.step(action)
        errors.append(info["pose_error"])
        if terminated or truncated:
            break
    assert info["coverage"] > 0.5 and info["collisions"] == 0
    assert info["slam_nodes"] > 20
    assert max(errors) < 0.2 and info["heading_error"] < 0.05
    odometry_error = math.hypot(*(info["odometry"][:2] - info["true_pose"][:2]))
    assert odometry_error > info["pose_error"]  # SLAM beats dead reckoning


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_vector_envs_run(mode):
    envs = gym.make_vec("SwarmSlam-v0", num_envs=2, vectorization_mode=mode,
                        vector_kwargs={} if mode == "sync" else {"context": "spawn"})
    obs, info = envs.reset(seed=[1, 2])
    assert obs["scan"].shape == (2, 360)
    for _ in range(5):
        obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert rewards.shape == (2,) and not np.array_equal(obs["pose"][0], obs["pose"][1])
    envs.close()


def test_rgb_array_and_human_rendering():
    env = gym.make("SwarmSlam-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([0.5, 0.0], np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 4  # map, walls, paths, scan
    pytest.importorskip("pygame", reason="the optional 'human' extra is not installed")
    human = gym.make("SwarmSlam-v0", render_mode="human")
    human.reset(seed=0)
    assert human.render() is None
    human.close()


def test_stable_baselines3_ppo_trains(tmp_path):
    sb3 = pytest.importorskip("stable_baselines3", reason="the optional 'rl' extra is not installed")
    from stable_baselines3.common.logger import configure

    env = gym.make("SwarmSlam-v0", slam=False, max_episode_steps=200)
    model = sb3.PPO("MultiInputPolicy", env, n_steps=512, batch_size=128, n_epochs=2, seed=0,
                    device="cpu", verbose=0)
    # SB3's default logger makes a folder in the system's temp dir on every learn()
    model.set_logger(configure(str(tmp_path), []))
    model.learn(total_timesteps=2048)
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(action)
