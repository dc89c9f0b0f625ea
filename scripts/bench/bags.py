"""``swarmslam bench bags``: what reading a ROS bag costs beside the replay it feeds, and
whether a converted log replays as the CARMEN original.

Per log: converted to each bag format (ROS 1, ROS 2 sqlite3, MCAP) in a temporary folder; each
bag read as ``replay`` reads it (the best of ``repeats`` reads, after one untimed read that
warms the disk cache and the type store); the CARMEN log and the MCAP bag replayed (seed 0,
defaults), their trajectories compared bit for bit. Target: a read costs at most 10% of the
replay's wall time.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from swarmslam.formats.bags import FORMATS
from swarmslam.bench.record import save_results
from swarmslam.bench.slam import LOGS
from swarmslam.convert import convert
from swarmslam.datasets import require
from swarmslam.formats.logs import read_log
from swarmslam.replay import replay_run

TARGET_SHARE = 0.10  # a bag's read, as a share of the replay's wall time
SUFFIX = {"ros1": ".bag", "sqlite3": "", "mcap": ".mcap"}


def _read_seconds(path, repeats: int) -> float:
    read_log(path)  # untimed: the disk cache and rosbags' type store warmed
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        read_log(path)
        best = min(best, time.perf_counter() - t0)
    return best


def bench_bags(logs: dict, repeats: int = 3, json_path=None, echo=print) -> dict:
    """``logs``: name → CARMEN log (with :func:`dataset_logs`, the given Radish logs)."""
    results = {"benchmark": "bags", "target_read_share": TARGET_SHARE, "logs": {}}
    lines = [f"{'log':<7} {'format':<8} {'read s':>7} {'replay s':>8} {'share':>6} target"]
    for name, log in logs.items():
        with tempfile.TemporaryDirectory(prefix="swarmslam-bench-bags-") as tmp:
            bags = {fmt: Path(tmp) / f"{name}{SUFFIX[fmt]}" for fmt in FORMATS}
            for fmt, path in bags.items():
                convert(log, path, fmt)
            carmen_metrics, carmen_runtime = replay_run(log, label=f"{name} (CARMEN)")
            bag_metrics, bag_runtime = replay_run(bags["mcap"], label=f"{name} (MCAP)")
            same = all(np.array_equal(a, b, equal_nan=True) for a, b in
                       zip(carmen_runtime.trajectory(), bag_runtime.trajectory()))
            wall = carmen_metrics["wall_seconds"]
            entry = {"scans": carmen_metrics["scans"], "replay_wall_seconds": wall,
                     "trajectory_identical": same, "formats": {}}
            for fmt, path in bags.items():
                seconds = _read_seconds(path, repeats)
                share = seconds / wall
                entry["formats"][fmt] = {"read_seconds": seconds, "share_of_replay": share,
                                         "target_met": share <= TARGET_SHARE}
                lines.append(f"{name:<7} {fmt:<8} {seconds:7.2f} {wall:8.1f} {share:6.1%} "
                             f"{'met' if share <= TARGET_SHARE else 'MISSED'}")
            carmen_seconds = _read_seconds(log, repeats)
            entry["carmen_read_seconds"] = carmen_seconds
            lines.append(f"{name:<7} {'carmen':<8} {carmen_seconds:7.2f} {wall:8.1f} "
                         f"{carmen_seconds / wall:6.1%}")
            lines.append(f"{name:<7} the MCAP bag's trajectory is the CARMEN log's, bit for "
                         f"bit: {'yes' if same else 'NO'}")
            results["logs"][name] = entry
    echo("\n".join(lines))
    if json_path:
        save_results(json_path, results)
    return results


def dataset_logs(data_dir: Path, names) -> dict:
    """The given Radish logs by ``bench slam``'s names."""
    return {name: require(Path(data_dir) / "radish" / LOGS[name][0]) for name in names}
