"""``swarmslam bench env``: simulator throughput, with the SLAM off and on.

Steps per second of ``gymnasium.make("SwarmSlam-v0")`` (its wrappers included) on the office
world with the 360-beam RPLidar A1 preset, driven by seeded random actions held for 10 steps;
LiDAR scans per second of the compiled caster beside pymunk's per-beam queries on the same
poses; and the throughput of 2 environments in ``SyncVectorEnv`` and ``AsyncVectorEnv``.
Everything is measured in one run, so the ratios hold even on a noisy shared machine. The
single environment's two rates are each the median of ``repeats`` runs (a fresh environment,
the same seed and actions each time; every run is recorded): on a shared 2-core machine one
run without SLAM has read a third below another on unchanged code, so a single reading says as
much about the machine's neighbours as about the simulator.
"""

from __future__ import annotations

import statistics
import time

import gymnasium as gym

from swarmslam.view.plots import bars, require_matplotlib
from swarmslam.bench.record import save_results

TARGETS = {"steps_per_s_without_slam": 8000, "steps_per_s_with_slam": 400}


def _actions(space, count, seed):
    space.seed(seed)
    held = [space.sample() for _ in range(count // 10 + 1)]
    return [held[k // 10] for k in range(count)]


def _steps_per_second(slam: bool, steps: int, world: str, seed: int = 0) -> float:
    env = gym.make("swarmslam_sim:SwarmSlam-v0", world=world, slam=slam, coverage_goal=None,
                   max_episode_steps=steps + 1)
    env.reset(seed=seed)
    if slam:  # every SLAM kernel compiled (a cold cache) or loaded before the clock starts
        env.unwrapped.runtime.warm_up()
    actions = _actions(env.action_space, steps, seed)
    for a in actions[:20]:  # warm-up: numba cache loads, first SLAM node
        env.step(a)
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    elapsed = time.perf_counter() - t0
    env.close()
    return steps / elapsed


def _scans_per_second(world: str, scans: int) -> dict:
    from swarmslam_sim.catalog import get_world
    from swarmslam_sim.lidar import PRESETS, Lidar
    from swarmslam_sim.physics import build_space, pymunk_scan

    w = get_world(world)
    lidar = Lidar(w, PRESETS["rplidar-a1"])
    space = build_space(w)
    env = gym.make("swarmslam_sim:SwarmSlam-v0", world=world, slam=False, coverage_goal=None)
    env.reset(seed=1)
    poses = []
    for a in _actions(env.action_space, 200, 1):
        poses.append(env.step(a)[4]["true_pose"])
    lidar.cast(poses[0])
    t0 = time.perf_counter()
    for k in range(scans):
        lidar.cast(poses[k % len(poses)])
    numba_rate = scans / (time.perf_counter() - t0)
    few = min(scans // 20, len(poses))
    t0 = time.perf_counter()
    for k in range(few):
        pymunk_scan(space, poses[k], lidar.angles, lidar.config.max_range)
    pymunk_rate = few / (time.perf_counter() - t0)
    return {"numba_scans_per_s": numba_rate, "pymunk_scans_per_s": pymunk_rate,
            "speed_up": numba_rate / pymunk_rate,
            "numba_ms_per_scan": 1e3 / numba_rate, "pymunk_ms_per_scan": 1e3 / pymunk_rate}


def _vector_steps_per_second(mode: str, slam: bool, steps: int, world: str) -> float:
    kwargs = {"context": "spawn"} if mode == "async" else {}
    envs = gym.make_vec("swarmslam_sim:SwarmSlam-v0", num_envs=2, vectorization_mode=mode,
                        vector_kwargs=kwargs, world=world, slam=slam, coverage_goal=None,
                        max_episode_steps=steps + 50)
    envs.reset(seed=[0, 1])
    envs.action_space.seed(0)
    actions = [envs.action_space.sample() for _ in range(max(steps, 20) // 10 + 1)]
    for k in range(20):  # (warm-up: as many actions however few steps are timed)
        envs.step(actions[k // 10])
    t0 = time.perf_counter()
    for k in range(steps):
        envs.step(actions[k // 10])
    elapsed = time.perf_counter() - t0
    envs.close()
    return 2 * steps / elapsed  # environment steps, both envs


def bench_env(world: str = "office", steps: int = 5000, slam_steps: int = 1000,
              json_path=None, echo=print, plots=None, repeats: int = 3) -> dict:
    """``plots``: a folder for the steps/s bars (PNG); ``repeats``: runs of each single-env
    rate, the median reported."""
    if plots:
        require_matplotlib()
    echo(f"SwarmSlam-v0 on {world}, RPLidar A1 preset (360 beams), seeded random actions")
    r = {"world": world, "beams": 360, "repeats": repeats, "runs": {}}
    for key, slam, n in (("without_slam", False, steps), ("with_slam", True, slam_steps)):
        runs = [_steps_per_second(slam, n, world) for _ in range(repeats)]
        r["runs"][key] = runs
        r[f"steps_per_s_{key}"] = statistics.median(runs)
        echo(f"  {'with SLAM' if slam else 'without SLAM':13s} {r[f'steps_per_s_{key}']:8.0f} "
             f"steps/s   (target ≥ "
             f"{TARGETS[f'steps_per_s_{key}']}; median of {repeats}: "
             f"{', '.join(f'{v:.0f}' for v in runs)})")
    r["lidar"] = _scans_per_second(world, steps)
    lid = r["lidar"]
    echo(f"  LiDAR         {lid['numba_scans_per_s']:8.0f} scans/s compiled ({lid['numba_ms_per_scan']:.3f} ms), "
         f"{lid['pymunk_scans_per_s']:.0f} with pymunk queries ({lid['pymunk_ms_per_scan']:.2f} ms): "
         f"{lid['speed_up']:.0f}×")
    r["vector"] = {}
    for mode in ("sync", "async"):
        for slam, n in ((False, steps // 2), (True, slam_steps // 2)):
            key = f"{mode}_{'slam' if slam else 'no_slam'}"
            r["vector"][key] = _vector_steps_per_second(mode, slam, n, world)
            echo(f"  2 envs {mode:5s} {'with' if slam else 'without'} SLAM  "
                 f"{r['vector'][key]:8.0f} env-steps/s")
    r["targets"] = TARGETS
    r["met"] = {k: r[k] >= v for k, v in TARGETS.items()}
    if plots:
        v = r["vector"]
        bars(plots, "env", f"SwarmSlam-v0 on {world}", "environment steps/s (log)",
             {"one env": {"without SLAM": r["steps_per_s_without_slam"],
                          "with SLAM": r["steps_per_s_with_slam"]},
              "2 envs, sync": {"without SLAM": v["sync_no_slam"], "with SLAM": v["sync_slam"]},
              "2 envs, async": {"without SLAM": v["async_no_slam"],
                                "with SLAM": v["async_slam"]}},
             log=True, targets={"without SLAM": TARGETS["steps_per_s_without_slam"],
                                "with SLAM": TARGETS["steps_per_s_with_slam"]})
    if json_path:
        save_results(json_path, r)
    return r
