"""``swarmslam demo``: a robot explores the office world on its own, with SLAM running.

The frontier explorer (:mod:`swarmslam_sim.exploration`) drives ``SwarmSlam-v0`` from the SLAM's
estimated pose and map until the map covers the goal share of the floor or no frontier is left.
Written atomically to ``out_dir``: the SLAM's map (``map.pgm`` + ``map.yaml`` for ROS
map_server, ``map.png``), ``trajectory.png`` (the walls, the true path in green and the
estimated one in red over the map), both trajectories in TUM format and ``summary.json``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.realtime.writers import write_json_atomic
from swarmslam.formats.map_io import write_map
from swarmslam.formats.png import write_png
from swarmslam.progress import Progress
from swarmslam.view.run_view import frame_of
from swarmslam.formats.tum import write_tum
from swarmslam_sim.exploration import FrontierExplorer


def run_exploration_demo(out_dir, world: str = "office", optimizer: str | None = None,
                         seed: int = 0, max_steps: int = 1500, coverage_goal: float = 0.9,
                         echo=print, config: SlamConfig | None = None, watch=None) -> dict:
    """``config``: the SLAM's configuration (default: the simulator's preset for the LiDAR);
    ``optimizer`` overrides its swarm method. ``watch``: a :class:`swarmslam.view.run_view.RunWatch`
    shown every step, with the true pose (closed at the end)."""
    try:
        return _explore(out_dir, world, optimizer, seed, max_steps, coverage_goal, echo, config,
                        watch)
    finally:
        if watch is not None:
            watch.close()


def _explore(out_dir, world, optimizer, seed, max_steps, coverage_goal, echo, config, watch):
    if config is not None and optimizer is not None:
        config = config.with_optimizer(optimizer)
    env = gym.make("swarmslam_sim:SwarmSlam-v0", world=world, optimizer=optimizer or "abc",
                   coverage_goal=coverage_goal, render_mode="rgb_array",
                   max_episode_steps=max_steps, slam_config=config)
    u = env.unwrapped
    optimizer = u.slam_config.matcher.swarm.optimizer
    t0 = time.perf_counter()
    obs, info = env.reset(seed=seed)
    echo(f"world {u.world.name}: {u.mappable_cells * u.cell_area:.0f} m² to map; "
         f"LiDAR {u.lidar.config.beams} beams at {u.lidar.config.rate_hz:g} Hz; SLAM with {optimizer}")
    policy = FrontierExplorer.for_env(env)
    errors, slam_ms = [], []
    progress = Progress(max_steps, "exploring")
    steps, end = 0, "time limit"
    started = time.perf_counter()
    while True:
        action = policy.act(info["estimated_pose"], u.map, info["in_contact"])
        obs, reward, terminated, truncated, info = env.step(action)
        steps += 1
        errors.append(info["pose_error"])
        slam_ms.append(u.slam_ms)
        if watch is not None and u.runtime is not None and u.runtime.last is not None:
            watch.tick(u.runtime, frame_of(u.runtime, u.runtime.last, u.runtime.scan.points,
                                           steps * u.dt, 1e-3 * u.slam_ms, info["true_pose"]))
        progress.update()
        if terminated:
            end = f"{coverage_goal:.0%} of the floor mapped"
            break
        if policy.done:
            end = "no frontier left"
            break
        if truncated:
            break
    progress.close()
    run_seconds = time.perf_counter() - started

    out = Path(out_dir)
    grid = u.slam.global_map()
    write_map(out / "map", grid)
    write_png(out / "trajectory.png", env.render())
    stamps = np.arange(len(u.true_path)) * u.dt
    write_tum(out / "trajectory_true.tum", stamps, np.array(u.true_path))
    write_tum(out / "trajectory_estimated.tum", stamps, np.array(u.estimated_path))
    odometry_drift = math.hypot(*(info["odometry"][:2] - info["true_pose"][:2]))
    summary = {
        "world": u.world.name, "optimizer": optimizer, "seed": seed, "steps": steps,
        "simulated_seconds": steps * u.dt, "wall_seconds": run_seconds,
        "total_seconds": time.perf_counter() - t0, "end": end,
        "coverage": info["coverage"], "collisions": info["collisions"],
        "pose_error_final_m": info["pose_error"], "pose_error_mean_m": float(np.mean(errors)),
        "pose_error_max_m": float(np.max(errors)), "heading_error_final_rad": info["heading_error"],
        "odometry_drift_final_m": odometry_drift, "nodes": info["slam_nodes"],
        "loop_closures": info["loop_closures"],
        "slam_ms_median": float(np.median(slam_ms)), "slam_ms_p99": float(np.percentile(slam_ms, 99)),
        "slam_status": info["slam_status"],
    }
    write_json_atomic(out / "summary.json", summary)
    env.close()

    echo(f"{steps} steps ({steps * u.dt:.0f} s simulated) in {run_seconds:.1f} s: {end}")
    echo(f"  coverage {info['coverage']:.1%}, collisions {info['collisions']}, "
         f"{info['slam_nodes']} nodes, {info['loop_closures']} loop closures")
    echo(f"  pose error: final {100 * info['pose_error']:.1f} cm, mean "
         f"{100 * summary['pose_error_mean_m']:.1f} cm, max {100 * summary['pose_error_max_m']:.1f} cm "
         f"(wheel odometry alone drifted {100 * odometry_drift:.1f} cm)")
    echo(f"  SLAM per step: {summary['slam_ms_median']:.1f} ms median, {summary['slam_ms_p99']:.1f} ms p99")
    echo(f"wrote {out}/map.pgm, map.yaml, map.png, trajectory.png (green: true path, red: "
         f"estimate), trajectory_true.tum, trajectory_estimated.tum, summary.json")
    return summary
