"""``swarmslam bench matcher``: swarm scan matching on keyframe logs with no initial guess.

For every consecutive pair of a CARMEN keyframe log, the current scan is matched against the
previous one with each optimizer, starting from nothing (the search box centred on zero
motion). The logged poses are the reference, never input. Measured in the same run, on the
same pairs: the paper's own form of the matcher (Eq. 14, no budget) and point-to-point ICP with
a scipy k-d tree, the local baseline.
"""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import numpy as np

from swarmslam.runtime.config import SensorConfig
from swarmslam.runtime.pose import between
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import MatcherConfig, ScanMatcher
from swarmslam.formats.carmen import read_carmen
from swarmslam.datasets import require
from swarmslam.evaluation.icp import icp
from swarmslam.evaluation.metrics import is_failure, pair_errors, relative_errors
from swarmslam.view.plots import matcher_errors, require_matplotlib
from swarmslam.progress import Progress
from swarmslam.bench.record import save_results
from swarmslam.replay import robot_frame_scan

DATASETS = {"intel": "intel-corrected.log.gz", "aces": "aces-corrected.log.gz"}
EQ24_PAIRS = 50


def load_pairs(path: Path, limit: int | None = None):
    """Scans (as point buffers) and reference relative poses of consecutive keyframes."""
    log = read_carmen(require(path))
    sensor = SensorConfig()  # the logs' SICK LMS, as the SLAM takes it
    scans = [robot_frame_scan(r, PointScan(len(r.ranges)), sensor) for r in log.lasers]
    poses = log.scan_poses()
    truth = between(poses[1:], poses[:-1])  # pose k+1 in the frame of pose k
    n = len(truth) if limit is None else min(limit, len(truth))
    return scans[: n + 1], truth[:n]


def summarise(estimates, truth, times_s, eq24_idx, extra=None) -> dict:
    e_t, e_r = relative_errors(estimates, truth)
    times_ms = 1e3 * np.asarray(times_s)
    out = {
        "pairs": int(len(truth)),
        "fail_rate": float(np.mean(is_failure(e_t, e_r))),
        "eT": float(np.mean(e_t)),
        "eT_std": float(np.std(e_t)),
        "eR": float(np.mean(e_r)),
        "eR_std": float(np.std(e_r)),
        "eT_median": float(np.median(e_t)),
        "eq24": pair_errors(np.asarray(estimates)[eq24_idx], truth[eq24_idx]),
        "ms_median": float(np.median(times_ms)),
        "ms_p99": float(np.percentile(times_ms, 99)),
    }
    out.update(extra or {})
    return out


def run_swarm(scans, truth, config: MatcherConfig, seed: int, label: str):
    """Match every pair; time reference rendering + alignment together, as a match costs."""
    matcher = ScanMatcher(config, seed=seed)
    reference = matcher.new_reference()
    t0 = time.perf_counter()  # the first call compiles, or loads the numba cache
    matcher.align_scans(scans[1], matcher.build_reference(scans[0], reference))
    first_call = time.perf_counter() - t0
    matcher = ScanMatcher(config, seed=seed)  # a fresh threshold for the measured run
    estimates = np.zeros((len(truth), 3))
    times, builds, evaluations, fallback = [], [], [], 0
    progress = Progress(len(truth), label)
    for k in range(len(truth)):
        t0 = time.perf_counter()
        matcher.build_reference(scans[k], reference)
        t1 = time.perf_counter()
        r = matcher.align_scans(scans[k + 1], reference)
        times.append(time.perf_counter() - t0)
        builds.append(t1 - t0)
        estimates[k] = r.pose
        evaluations.append(r.evaluations)
        fallback += r.used_map
        progress.update()
    progress.close()
    return estimates, times, {
        "first_call_s": first_call,
        "build_ms_median": float(1e3 * np.median(builds)),  # reference field(s), within ms
        "evaluations_median": float(np.median(evaluations)),
        "fallback_rate": fallback / len(truth),
    }


def run_icp(scans, truth, label: str):
    estimates = np.zeros((len(truth), 3))
    times, iterations = [], []
    progress = Progress(len(truth), label)
    for k in range(len(truth)):
        t0 = time.perf_counter()
        pose, it = icp(scans[k].points, scans[k + 1].points)
        times.append(time.perf_counter() - t0)
        estimates[k] = pose
        iterations.append(it)
        progress.update()
    progress.close()
    return estimates, times, {"iterations_median": float(np.median(iterations))}


def bench_matcher(data_dir: Path, optimizers=("abc", "pso", "fa"), datasets=tuple(DATASETS),
                  paper=True, limit=None, seed=0, json_path=None, echo=print,
                  plots=None) -> dict:
    """``plots``: a folder for each log's error distributions per matcher (PNG)."""
    if plots:
        require_matplotlib()
    results = {
        "benchmark": "matcher",
        "machine": {"python": platform.python_version(), "cpu": platform.processor(),
                    "cores": os.cpu_count()},
        "config": {"default": repr(MatcherConfig()), "paper": repr(MatcherConfig.paper())},
        "seed": seed,
        "datasets": {},
    }
    for name in datasets:
        scans, truth = load_pairs(Path(data_dir) / "corrected" / DATASETS[name], limit)
        eq24_idx = np.sort(np.random.default_rng(0).choice(len(truth), min(EQ24_PAIRS, len(truth)),
                                                           replace=False))
        rows, errors = {}, {}
        variants = [(opt, MatcherConfig.for_optimizer(opt)) for opt in optimizers]
        if paper:
            variants += [(f"{opt}-paper", MatcherConfig.paper(opt)) for opt in optimizers]
        for label, config in variants:
            est, times, extra = run_swarm(scans, truth, config, seed, f"{name} {label}")
            rows[label] = summarise(est, truth, times, eq24_idx, extra)
            errors[label] = relative_errors(est, truth)
        est, times, extra = run_icp(scans, truth, f"{name} icp")
        rows["icp"] = summarise(est, truth, times, eq24_idx, extra)
        errors["icp"] = relative_errors(est, truth)
        results["datasets"][name] = rows
        if plots:
            matcher_errors(plots, name, errors)
        echo(format_table(name, rows))
    if json_path:
        save_results(json_path, results)
    return results


def format_table(name: str, rows: dict) -> str:
    head = (f"{name:<6} {'method':<10} {'fail':>6} {'eT m':>7} {'±':>6} {'eR rad':>7} "
            f"{'ex':>6} {'ey':>6} {'eθ':>6} {'ms med':>7} {'ms p99':>7}")
    lines = [head, "-" * len(head)]
    for label, r in rows.items():
        q = r["eq24"]
        lines.append(
            f"{'':<6} {label:<10} {100 * r['fail_rate']:5.1f}% {r['eT']:7.4f} {r['eT_std']:6.3f} "
            f"{r['eR']:7.4f} {q['ex']:6.3f} {q['ey']:6.3f} {q['etheta']:6.3f} "
            f"{r['ms_median']:7.2f} {r['ms_p99']:7.2f}"
        )
    return "\n".join(lines)
