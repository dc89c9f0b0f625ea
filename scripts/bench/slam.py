"""``swarmslam bench slam``: the SLAM on the raw Intel, ACES3, fr-clinic, MIT-CSAIL and FR079 logs,
scored with their Kümmerle relations, per optimizer, with and without odometry, over seeds
(mean and worst), beside published systems. fr-clinic is scored apart on local relations
(endpoints less than 300 s apart) and global ones, as its published figures are. Every log's
short relations (< 10 s apart) are reported apart with their tail (median, p99, max, the count
above 5°): the front end's gross heading failures, which a mean hides. Each log's relations are
audited against its own scans once (swarmslam.evaluation.relations_audit, docs/method.md §7.1), and every
run's short relations are scored again over those the scans do not contradict, with the count
of those above 10° — the failures that are the SLAM's, not the reference's."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarmslam.datasets import require
from swarmslam.evaluation.metrics import LOCAL_GAP, relation_errors
from swarmslam.view.plots import require_matplotlib, slam_errors_over_time, slam_summary
from swarmslam.formats.relations import read_relations
from swarmslam.evaluation.relations_audit import audit_log, fits_of_gross_failures, short_tail_apart
from swarmslam.replay import replay_run
from swarmslam.runs import RunOptions
from swarmslam.bench.record import save_results

LOGS = {"intel": ("intel.clf.gz", "intel.relations"), "aces": ("aces.clf.gz", "aces.relations"),
        "clinic": ("fr-clinic.clf.gz", "fr-clinic.relations"),
        "mit": ("mit-csail.clf.gz", "mit-csail.relations"),
        "fr079": ("fr079.clf.gz", "fr079.relations")}
# Hess et al. 2016 (Table II) and Kümmerle et al. 2009, same metric (shared/datasets/README):
# (eT, ± m, eR, ± deg) per system; for fr-clinic per part, local and global.
PUBLISHED = {
    "intel": {"Cartographer": (0.0229, 0.0239, 0.453, 1.335),
              "Graph mapping": (0.031, 0.026, 1.3, 4.7),
              "RBPF (GMapping, 50 particles)": (0.070, 0.083, None, None),
              "scan matching only": (0.220, 0.296, None, None)},
    "aces": {"Cartographer": (0.0375, 0.0426, 0.373, 0.469),
             "Graph mapping": (0.044, 0.044, 0.4, 0.4),
             "RBPF (GMapping, 50 particles)": (0.060, 0.049, None, None),
             "scan matching only": (0.173, 0.614, None, None)},
    "clinic": {"Cartographer, local": (0.1078, 0.1943, 0.747, 2.047),
               "Graph mapping, local": (0.143, 0.180, 0.9, 2.2),
               "Cartographer, global": (5.2242, 6.6230, 3.341, 4.797),
               "Graph mapping, global": (11.6, 11.9, 6.3, 6.2)},
    "mit": {"Cartographer": (0.0319, 0.0363, 0.369, 0.365)},
    "fr079": {"Cartographer": (0.0452, 0.0354, 0.538, 0.718),
              "Graph mapping": (0.056, 0.042, 0.6, 0.6),
              "RBPF (GMapping, 50 particles)": (0.061, 0.044, None, None),
              "scan matching only": (0.258, 0.427, None, None)},
}
# The figures a run is judged by per log: the whole relation set, or fr-clinic's two parts.
SCORED = {"intel": ("",), "aces": ("",), "clinic": ("_local", "_global"), "mit": ("",),
          "fr079": ("",)}
# The short relations' figures, averaged over seeds (and their worst seed's).
SHORT = ("eT_short", "eR_short_deg", "eR_short_median_deg", "eR_short_p99_deg",
         "eR_short_max_deg", "eR_short_over_5deg")
# ... and over the short relations the log's scans do not contradict (the audit's).
AUDITED = ("eR_short_confirmed_deg", "eR_short_confirmed_p99_deg", "eR_short_over_10deg",
           "eR_short_over_10deg_confirmed")


def bench_slam(data_dir: Path, optimizers=("abc", "pso", "fa"), logs=tuple(LOGS),
               modes=(True, False), limit=None, out_dir=None, json_path=None, echo=print,
               config=None, seeds=(0, 1, 2, 3, 4), plots=None):
    """``config``: the SLAM's configuration (default: the defaults); each run sets its
    optimizer. Every (log, optimizer, input) runs once per seed; the table gives the mean
    over seeds and the worst seed. ``plots``: a folder for each run's relation errors over
    time and each log's summary (PNG)."""
    if plots:
        require_matplotlib()
    results = {"benchmark": "slam", "seeds": list(seeds), "runs": [], "summary": [],
               "audits": {}}
    for name in logs:
        log, rel = LOGS[name]
        log_path = require(Path(data_dir) / "radish" / log)
        rel_path = require(Path(data_dir) / "radish" / rel)
        relations = read_relations(rel_path)
        audit, scans, scan_stamps, odometry_at_scans = audit_log(log_path, relations,
                                                                 label=f"audit {name}")
        results["audits"][name] = audit.summary(relations)
        rows = []
        for optimizer in optimizers:
            for odometry in modes:
                runs = []
                for seed in seeds:
                    label = f"{name} {optimizer} {'odom' if odometry else 'scans'} seed {seed}"
                    run_out = None if out_dir is None else Path(out_dir) / label.replace(" ", "-")
                    m, runtime = replay_run(log_path, rel_path,
                                            RunOptions(config, optimizer, seed),
                                            odometry=odometry, out_dir=run_out, limit=limit,
                                            label=label)
                    if plots:
                        plot_run(plots, label, runtime, relations)
                    m.update(audited_tail(runtime, relations, audit, scans, scan_stamps,
                                          odometry_at_scans))
                    m.update(dataset=name, seed=seed)
                    results["runs"].append(m)
                    runs.append(m)
                summary = summarise(name, optimizer, odometry, runs)
                results["summary"].append(summary)
                rows.append(summary)
        echo(format_table(name, rows))
    if plots:
        slam_summary(plots, results["summary"], PUBLISHED)
        echo(f"plots in {plots}")
    if json_path:
        save_results(json_path, results)
    return results


def audited_tail(runtime, relations, audit, scans, scan_stamps, odometry=None) -> dict:
    """The run's short relations scored apart over those the scans do not contradict
    (swarmslam.evaluation.relations_audit.short_tail_apart), each gross failure listed with the fit of
    its scans placed by the relation, by the run and by ``odometry`` (the pose it gave with
    each scan; ``fits_of_gross_failures``); empty when no relation lies within the run (a
    ``--limit`` run)."""
    stamps, poses = runtime.trajectory()
    try:
        short = short_tail_apart(stamps, poses, relations, audit)
    except ValueError:  # no relation has both ends in the trajectory
        return {}
    fits_of_gross_failures(short, scans, scan_stamps, stamps, poses, odometry)
    return short


def plot_run(out_dir, label, runtime, relations) -> None:
    """The run's relation errors against the time of each relation's first scan."""
    stamps, poses = runtime.trajectory()
    ok, e_t, e_r = relation_errors(stamps, poses, relations)
    t1, t2 = relations.t1[ok], relations.t2[ok]
    slam_errors_over_time(out_dir, label, t1 - stamps[0], e_t, e_r,
                          np.abs(t2 - t1) < LOCAL_GAP)


def summarise(name, optimizer, odometry, runs) -> dict:
    """Mean over seeds and the worst seed of each scored figure, and the slowest real time."""
    out = {"dataset": name, "optimizer": optimizer, "odometry": bool(odometry),
           "seeds": [m["seed"] for m in runs],
           "real_time_factor_min": min(m["real_time_factor"] for m in runs),
           "latency_ms_p99_max": max(m["latency_ms_p99"] for m in runs),
           "loops_accepted_mean": float(np.mean([m["loops_accepted"] for m in runs]))}
    keys = [f"{k}{part}{unit}" for part in SCORED[name] for k, unit in (("eT", ""),
                                                                         ("eR", "_deg"))]
    for key in (*keys, *SHORT, *AUDITED):
        values = [m[key] for m in runs if key in m]
        if values:
            out[f"{key}_mean"] = float(np.mean(values))
            out[f"{key}_worst"] = float(np.max(values))
    return out


def format_table(name, rows) -> str:
    parts = SCORED[name]
    cols = "".join(f" {'eT' + p + ' m':>14} {'worst':>7} {'eR' + p + ' °':>13} {'worst':>7}"
                   for p in parts)
    head = (f"{name:<6} {'system':<30}{cols} {'x real time':>11} {'p99 ms':>7} {'loops':>6}"
            f"   short (< 10 s): {'eR °':>6} {'median':>6} {'p99':>6} {'max':>6} {'> 5°':>5}"
            f"   not contradicted: {'eR °':>6} {'p99':>6} {'> 10°':>5}")
    lines = [head, "-" * len(head)]
    for r in rows:
        label = f"{r['optimizer']} {'+odometry' if r['odometry'] else 'scans only'}"
        figures = "".join(f" {r[f'eT{p}_mean']:14.4f} {r[f'eT{p}_worst']:7.4f} "
                          f"{r[f'eR{p}_deg_mean']:13.3f} {r[f'eR{p}_deg_worst']:7.3f}"
                          for p in parts)
        short = "".join(f" {r.get(f'{k}_mean', float('nan')):6.2f}" for k in SHORT[1:5])
        audited = "".join(f" {r.get(f'{k}_mean', float('nan')):{w}.{d}f}"
                          for k, w, d in zip(AUDITED[:2] + AUDITED[3:], (6, 6, 5), (2, 2, 1)))
        lines.append(f"{'':<6} {label:<30}{figures} {r['real_time_factor_min']:11.1f} "
                     f"{r['latency_ms_p99_max']:7.1f} {r['loops_accepted_mean']:6.1f}"
                     f"{'':18}{short} {r.get('eR_short_over_5deg_mean', float('nan')):5.1f}"
                     f"{'':21}{audited}")
    def f(v, w, d):
        return f"{v:{w}.{d}f}" if v is not None else f"{'—':>{w}}"

    for system, (et, et_s, er, er_s) in PUBLISHED[name].items():
        lines.append(f"{'':<6} {system + ' (published)':<30} {f(et, 14, 4)} {f(et_s, 7, 4)} "
                     f"{f(er, 13, 3)} {f(er_s, 7, 3)}  (mean, std)")
    return "\n".join(lines)
