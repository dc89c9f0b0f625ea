"""``swarmslam bench slam``: the SLAM on the raw Intel and ACES3 logs, scored with their
Kümmerle relations, per optimizer, with and without odometry, beside published systems."""

from __future__ import annotations

from pathlib import Path

from runtime.writers import write_json_atomic
from scripts.datasets import require
from scripts.replay import replay

LOGS = {"intel": ("intel.clf.gz", "intel.relations"), "aces": ("aces.clf.gz", "aces.relations")}
# Hess et al. 2016 (Table II) and Kümmerle et al. 2009, same metric (shared/datasets/README).
PUBLISHED = {
    "intel": {"Cartographer": (0.0229, 0.0239, 0.453, 1.335),
              "Graph mapping": (0.031, 0.026, 1.3, 4.7),
              "RBPF (GMapping, 50 particles)": (0.070, 0.083, None, None),
              "scan matching only": (0.220, 0.296, None, None)},
    "aces": {"Cartographer": (0.0375, 0.0426, 0.373, 0.469),
             "Graph mapping": (0.044, 0.044, 0.4, 0.4),
             "RBPF (GMapping, 50 particles)": (0.060, 0.049, None, None),
             "scan matching only": (0.173, 0.614, None, None)},
}


def bench_slam(data_dir: Path, optimizers=("abc", "pso", "fa"), logs=tuple(LOGS),
               modes=(True, False), limit=None, out_dir=None, json_path=None, echo=print,
               config=None):
    """``config``: the SLAM's configuration (default: the defaults); each run sets its
    optimizer."""
    results = {"benchmark": "slam", "runs": []}
    for name in logs:
        log, rel = LOGS[name]
        log_path = require(Path(data_dir) / "radish" / log)
        rel_path = require(Path(data_dir) / "radish" / rel)
        rows = []
        for optimizer in optimizers:
            for odometry in modes:
                label = f"{name} {optimizer} {'odom' if odometry else 'scans'}"
                run_out = None if out_dir is None else Path(out_dir) / label.replace(" ", "-")
                m = replay(log_path, rel_path, optimizer, odometry, run_out, limit, label=label,
                           config=config)
                m["dataset"] = name
                results["runs"].append(m)
                rows.append((f"{optimizer} {'+odometry' if odometry else 'scans only'}", m))
        echo(format_table(name, rows))
    if json_path:
        write_json_atomic(json_path, results)
    return results


def format_table(name, rows) -> str:
    head = (f"{name:<6} {'system':<30} {'eT m':>7} {'± m':>7} {'eR deg':>7} {'± deg':>7} "
            f"{'x real time':>11} {'p99 ms':>7} {'loops':>5}")
    lines = [head, "-" * len(head)]
    for label, m in rows:
        lines.append(f"{'':<6} {label:<30} {m['eT']:7.4f} {m['eT_std']:7.4f} {m['eR_deg']:7.3f} "
                     f"{m['eR_std']:7.3f} {m['real_time_factor']:11.1f} "
                     f"{m['latency_ms_p99']:7.1f} {m['loops_accepted']:5d}")
    for system, (et, et_s, er, er_s) in PUBLISHED[name].items():
        f = (lambda v, w: f"{v:{w}.4f}" if v is not None else f"{'—':>{w}}")
        g = (lambda v, w: f"{v:{w}.3f}" if v is not None else f"{'—':>{w}}")
        lines.append(f"{'':<6} {system + ' (published)':<30} {f(et, 7)} {f(et_s, 7)} "
                     f"{g(er, 7)} {g(er_s, 7)}")
    return "\n".join(lines)
