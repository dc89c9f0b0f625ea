"""``swarmslam bench posegraph``: Gauss–Newton on the g2o benchmark graphs (χ² and time).

Published with g2o's error convention and the first pose fixed: INTEL χ² 215.830 (g2o 12 ms,
GTSAM 87 ms), M3500 χ² 137.913 (g2o 95 ms, GTSAM 240 ms) on this machine class.
"""

from __future__ import annotations

import time
from pathlib import Path

from swarmslam.runtime.back_end.graph_optimizer import GaussNewton
from swarmslam.datasets import require
from swarmslam.formats.g2o import read_g2o
from swarmslam.view.plots import bars, require_matplotlib
from swarmslam.bench.record import save_results

GRAPHS = {
    "INTEL": ("input_INTEL_g2o.g2o", 215.830, 12.0),
    "M3500": ("input_M3500_g2o.g2o", 137.913, 95.0),
}


def bench_posegraph(data_dir: Path, repeats: int = 5, json_path=None, echo=print,
                    plots=None) -> dict:
    """``plots``: a folder for the time per graph beside g2o's (PNG)."""
    if plots:
        require_matplotlib()
    results = {"benchmark": "posegraph", "graphs": {}}
    lines = [f"{'graph':<6} {'chi2':>11} {'g2o chi2':>9} {'ms median':>9} {'g2o ms':>7} "
             f"{'ratio':>6} {'iters':>5} {'first ms':>8}"]
    for name, (file, chi2_ref, ms_ref) in GRAPHS.items():
        path = require(Path(data_dir) / "posegraphs" / file)
        times, report = [], None
        for _ in range(repeats + 1):  # the first run includes compilation / cache load
            graph, _ = read_g2o(path)
            t0 = time.perf_counter()
            report = GaussNewton(graph).optimize()
            times.append(1e3 * (time.perf_counter() - t0))
        ms = sorted(times[1:])[len(times[1:]) // 2]
        results["graphs"][name] = {
            "chi2": report.chi2, "chi2_g2o": chi2_ref, "chi2_initial": report.chi2_initial,
            "iterations": report.iterations, "ms_median": ms, "ms_runs": times[1:],
            "first_run_ms": times[0], "g2o_ms": ms_ref, "time_ratio_to_g2o": ms / ms_ref,
            "solver": report.solver,
        }
        lines.append(f"{name:<6} {report.chi2:11.3f} {chi2_ref:9.3f} {ms:9.1f} {ms_ref:7.1f} "
                     f"{ms / ms_ref:6.2f} {report.iterations:5d} {times[0]:8.1f}")
    echo("\n".join(lines))
    if plots:
        g = results["graphs"]
        bars(plots, "posegraph", "Gauss-Newton to convergence", "ms (log)",
             {"ours (median)": {k: v["ms_median"] for k, v in g.items()},
              "g2o (published)": {k: v["g2o_ms"] for k, v in g.items()}}, log=True)
    if json_path:
        save_results(json_path, results)
    return results
