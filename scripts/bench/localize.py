"""``swarmslam bench localize``: global relocalization on the Intel, ACES3 and fr-clinic logs.

Per log: the map of the whole log (a mapping replay, ABC with odometry, seed 0; its session is
kept in ``maps_dir`` and reused), then single scans drawn at seeded random times are
relocalized with no prior. An answer is a success within 0.3 m and 5° of the mapping run's
optimised pose of that scan, wrong otherwise; "ambiguous" is neither. Then the same queries
confirmed: the scans of the next ``confirm_seconds`` merged by the log's odometry between them
and relocalized as one, judged at the last of them.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from runtime.fixed_rate import SlamRuntime
from runtime.pose import between
from runtime.relocalization import Located, Relocalizer
from runtime.scan import PointScan
from runtime.writers import write_json_atomic
from scripts.bench.slam import LOGS
from scripts.carmen import read_carmen
from scripts.datasets import require
from scripts.progress import Progress
from scripts.replay import replay, robot_frame_scan

SUCCESS_DISTANCE = 0.3  # m
SUCCESS_ANGLE = math.radians(5.0)


def judge(answer, truth) -> str:
    """``success``, ``wrong`` or ``ambiguous``."""
    if not isinstance(answer, Located):
        return "ambiguous"
    e = between(answer.pose, truth)
    close = math.hypot(e[0], e[1]) <= SUCCESS_DISTANCE and abs(e[2]) <= SUCCESS_ANGLE
    return "success" if close else "wrong"


def mapping_session(name: str, log_path: Path, maps_dir: Path, echo=print) -> Path:
    """The session of the whole log's mapping run, made once per ``maps_dir``."""
    out = Path(maps_dir) / name
    session = out / "session.npz"
    if not session.exists():
        echo(f"{name}: mapping the whole log first (kept in {out})")
        replay(log_path, out_dir=out, label=f"{name} mapping")
    return session


def bench_log(name: str, log_path: Path, session: Path, queries: int, seed: int,
              echo=print) -> dict:
    runtime = SlamRuntime.resume(session)
    slam = runtime.slam
    t0 = time.perf_counter()
    relocalizer = Relocalizer(runtime.config, slam.graph.poses, slam.nodes, slam.n_nodes)
    build = time.perf_counter() - t0
    _, truth = slam.trajectory()
    lasers = read_carmen(log_path).lasers
    confirm = relocalizer.config.confirm_seconds
    stamps = np.array([r.timestamp for r in lasers])
    last = int(np.searchsorted(stamps, stamps[-1] - confirm, side="right")) - 1
    picks = np.random.default_rng(seed).integers(0, max(last, 1), size=queries)
    scan = PointScan(max(len(r.ranges) for r in lasers))
    relocalizer.relocalize(robot_frame_scan(lasers[0], scan))  # compiled before timing
    single, confirmed, seconds, seconds_confirmed = [], [], [], []
    progress = Progress(queries, f"{name} relocalize")
    for k in picks:
        k = int(k)
        robot_frame_scan(lasers[k], scan)
        t = time.perf_counter()
        answer = relocalizer.relocalize(scan)
        seconds.append(time.perf_counter() - t)
        single.append(judge(answer, truth[k]))
        end = int(np.searchsorted(stamps, stamps[k] + confirm, side="right")) - 1
        window = range(k, end + 1)
        scans = [robot_frame_scan(lasers[m], PointScan(len(lasers[m].ranges))) for m in window]
        motions = [between(lasers[m].odometry, lasers[end].odometry) for m in window]
        t = time.perf_counter()
        answer = relocalizer.relocalize_merged(scans, motions)
        seconds_confirmed.append(time.perf_counter() - t)
        confirmed.append(judge(answer, truth[end]))
        progress.update(note=f"{single.count('success')} found, {single.count('wrong')} wrong")
    progress.close()

    def rate(outcomes, what):
        return outcomes.count(what) / len(outcomes)

    ms, ms_c = 1e3 * np.array(seconds), 1e3 * np.array(seconds_confirmed)
    return {
        "dataset": name, "queries": queries, "nodes": int(slam.n_nodes),
        "map_cells": list(relocalizer.place.shape), "build_seconds": build,
        "success_rate": rate(single, "success"), "wrong_rate": rate(single, "wrong"),
        "ambiguous_rate": rate(single, "ambiguous"),
        "success_rate_confirmed": rate(confirmed, "success"),
        "wrong_rate_confirmed": rate(confirmed, "wrong"),
        "ambiguous_rate_confirmed": rate(confirmed, "ambiguous"),
        "ms_median": float(np.median(ms)), "ms_p99": float(np.percentile(ms, 99)),
        "ms_median_confirmed": float(np.median(ms_c)),
        "ms_p99_confirmed": float(np.percentile(ms_c, 99)),
    }


def bench_localize(data_dir: Path, logs=tuple(LOGS), queries: int = 200, seed: int = 0,
                   maps_dir=None, json_path=None, echo=print) -> dict:
    maps_dir = Path(maps_dir or "swarmslam-maps")
    results = {"benchmark": "localize", "seed": seed, "queries": queries,
               "success": {"distance_m": SUCCESS_DISTANCE, "angle_deg": 5.0}, "logs": []}
    for name in logs:
        log, _ = LOGS[name]
        log_path = require(Path(data_dir) / "radish" / log)
        session = mapping_session(name, log_path, maps_dir, echo)
        row = bench_log(name, log_path, session, queries, seed, echo)
        results["logs"].append(row)
        echo(f"{name}: one scan: {row['success_rate']:.1%} found, {row['wrong_rate']:.1%} wrong, "
             f"{row['ambiguous_rate']:.1%} ambiguous, {row['ms_median']:.0f} ms median / "
             f"{row['ms_p99']:.0f} ms p99; confirmed: {row['success_rate_confirmed']:.1%} found, "
             f"{row['wrong_rate_confirmed']:.1%} wrong")
        if json_path:
            write_json_atomic(json_path, results)
    return results
