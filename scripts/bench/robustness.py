"""``swarmslam bench robustness``: whether the map holds on every seed, and on perturbed copies
of the given logs, which make new test cases without new data (docs/benchmarks.md).

Per log and per family of perturbations, every seed is replayed with the defaults and scored
by the log's relations; the benchmark reports the median, the worst and the spread (worst ÷
median) of eT, eR and the global eT (relations ≥ 300 s apart), and counts the **gross** runs:
a global eT or a p99 translational error above ``GROSS_RATIO`` × the median seed's, or an eT
above ``GROSS_ET``. A log scored in parts (fr-clinic: its local relations) is judged by its
scored part's eT.

The families (:data:`FAMILIES`), each a function of the log and the seed, so that each seed
is a different case:

* ``raw``: the log as it is;
* ``every-2nd``, ``every-3rd``: the scans thinned (a slower scanner or a faster robot);
* ``half-beams``: every second beam (a coarser scanner);
* ``odometry-drift``: odometry re-integrated from its steps with a seeded scale error (±3%)
  and heading drift (±1° per metre), as wheels of another size and a gyro's bias make;
* ``start-cut``: the first tenth of the log cut away (the map starts somewhere else);
* ``corridor``: not a given log but a simulated corridor survey, a new floor for each seed
  (``swarmslam simlog --site corridor --seed S``), scored against its true poses.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from swarmslam.bench.record import save_results
from swarmslam.bench.slam import LOGS, SCORED
from swarmslam.datasets import require
from swarmslam.evaluation.metrics import LOCAL_GAP, relation_errors
from swarmslam.formats.carmen import read_carmen, robotlaser1_line
from swarmslam.formats.relations import read_relations
from swarmslam.replay import replay_run
from swarmslam.runs import RunOptions
from swarmslam.runtime.pose import between, compose
from swarmslam.simlog import write_simlog
from swarmslam.view.plots import require_matplotlib, robustness_figure

GROSS_RATIO = 2.0  # a run's global eT or p99 error beyond this × the median seed's: gross
GROSS_ET = 0.10  # m: a run's eT beyond this: gross
SCALE_ERROR = 0.03  # odometry-drift: the largest scale error drawn
HEADING_DRIFT = math.radians(1.0)  # odometry-drift: the largest heading drift drawn, per metre
START_CUT = 0.1  # start-cut: the share of the log's scans cut away
FAMILIES = ("raw", "every-2nd", "every-3rd", "half-beams", "odometry-drift", "start-cut")
SIMULATED = "corridor"


def perturbed(lasers, family: str, seed: int) -> list:
    """``lasers`` (a log's scans, in time order) as ``family`` makes them for ``seed``."""
    if family == "raw":
        return list(lasers)
    if family in ("every-2nd", "every-3rd"):
        return list(lasers[:: 2 if family == "every-2nd" else 3])
    if family == "start-cut":
        return list(lasers[int(START_CUT * len(lasers)):])
    if family == "half-beams":
        out = []
        for r in lasers:
            out.append(type(r)(r.timestamp, r.ranges[::2].copy(), r.angles[::2].copy(),
                               r.pose, r.odometry, r.max_range, r.laser_offset, r.line))
        return out
    if family == "odometry-drift":
        rng = np.random.default_rng([seed, 97])
        scale = 1.0 + rng.uniform(-SCALE_ERROR, SCALE_ERROR)
        drift = rng.uniform(-HEADING_DRIFT, HEADING_DRIFT)
        out, pose = [], np.array(lasers[0].odometry, np.float64)
        for k, r in enumerate(lasers):
            if k:
                step = between(r.odometry, lasers[k - 1].odometry)
                metres = math.hypot(step[0], step[1])
                pose = compose(pose, np.array([scale * step[0], scale * step[1],
                                               step[2] + drift * metres]))
            out.append(type(r)(r.timestamp, r.ranges, r.angles, pose.copy(), pose.copy(),
                               r.max_range, r.laser_offset, r.line))
        return out
    raise ValueError(f"unknown family {family!r}; choose from {', '.join(FAMILIES)}")


def write_log(lasers, path: Path) -> Path:
    """Scans as a CARMEN log of ROBOTLASER1 lines (beam angles and mount as given; a beam
    with no return at the scan's no-return reading)."""
    with open(path, "w") as f:
        for r in lasers:
            ranges = np.where(np.isfinite(r.ranges), r.ranges, r.max_range)
            step = float(r.angles[1] - r.angles[0]) if len(r.angles) > 1 else 0.0
            f.write(robotlaser1_line(ranges, float(r.angles[0]), step, r.max_range, r.odometry,
                                     r.timestamp, laser_offset=r.laser_offset) + "\n")
    return path


def scored_part(log: str) -> str:
    """The eT a log is judged by: its scored part's (fr-clinic: local)."""
    return SCORED.get(log, ("",))[0]


def run_one(job) -> dict:
    """One replay of the benchmark: ``job`` = (log name, log path, relations path, family,
    seed, scratch folder, the folder its outputs are kept in or None). Its figures."""
    name, log_path, rel_path, family, seed, scratch, keep = job
    row = {"log": name, "family": family, "seed": seed}
    with tempfile.TemporaryDirectory(dir=scratch) as tmp:
        if family == SIMULATED:
            made = write_simlog(Path(tmp) / f"corridor-s{seed}.clf", "corridor", seed,
                                "sick-1", 10.0, "good")
            log_path, rel_path = made["log"], made["relations"]
        elif family != "raw":
            lasers = perturbed(read_carmen(log_path).lasers, family, seed)
            log_path = write_log(lasers, Path(tmp) / f"{name}-{family}.clf")
        relations = read_relations(rel_path)
        with contextlib.redirect_stderr(io.StringIO()):
            m, runtime = replay_run(
                log_path, rel_path, RunOptions(seed=seed), label=f"{name} {family} seed {seed}",
                out_dir=None if keep is None else Path(keep) / f"{name}-{family}-s{seed}")
    stamps, poses = runtime.slam.trajectory()
    used, e_t, _ = relation_errors(stamps, poses, relations)
    far = np.abs(relations.t2[used] - relations.t1[used]) >= LOCAL_GAP
    part = scored_part(name)
    row.update({"eT": m["eT"], "eR_deg": m["eR_deg"],
                "eT_scored": m.get(f"eT{part}", m["eT"]),
                "eT_global": float(np.mean(e_t[far])) if np.any(far) else None,
                "p99_m": float(np.percentile(e_t, 99)), "loops": m["loops_accepted"],
                "real_time_factor": m["real_time_factor"], "status": m["status"]})
    return row


def summarise(rows) -> dict:
    """Median, worst and spread of the figures over the seeds of one log and family, and
    which runs were gross (by seed)."""
    def spread(key):
        values = np.array([r[key] for r in rows if r[key] is not None], np.float64)
        if not len(values):
            return {}
        median = float(np.median(values))
        return {f"{key}_median": median, f"{key}_worst": float(values.max()),
                f"{key}_spread": float(values.max() / median) if median > 0 else None}

    out = {"runs": len(rows)}
    for key in ("eT", "eR_deg", "eT_scored", "eT_global", "p99_m"):
        out.update(spread(key))
    gross = []
    for r in rows:
        why = []
        if r["eT_scored"] > GROSS_ET:
            why.append(f"eT {r['eT_scored']:.3f} m")
        for key in ("eT_global", "p99_m"):
            median = out.get(f"{key}_median")
            if r[key] is not None and median and r[key] > GROSS_RATIO * median:
                why.append(f"{key} {r[key]:.3f} m > {GROSS_RATIO:g}× median {median:.3f}")
        if why:
            gross.append({"seed": r["seed"], "why": why})
    out["gross"] = gross
    return out


def bench_robustness(data_dir: Path | None, logs=tuple(LOGS), families=FAMILIES,
                     seeds=tuple(range(10)), jobs: int | None = None, json_path=None,
                     plots=None, keep=None, echo=print) -> dict:
    """Every (log, family, seed) replayed, ``jobs`` at a time (default: one per core), and
    summarised per log and family (see the module); ``plots``: a folder for the figure;
    ``keep``: a folder for each run's outputs (map, trajectory, graph: LOG-FAMILY-sSEED)."""
    if plots is not None:
        require_matplotlib()  # before the runs, not after them
    work = []
    for name in logs:
        if name == SIMULATED:
            work += [(name, None, None, SIMULATED, s) for s in seeds]
            continue
        log_file, rel_file = LOGS[name]
        log_path = require(data_dir / "radish" / log_file)
        rel_path = require(data_dir / "radish" / rel_file)
        work += [(name, log_path, rel_path, f, s) for f in families for s in seeds]
    results = {"benchmark": "robustness", "gross_ratio": GROSS_RATIO, "gross_eT": GROSS_ET,
               "seeds": list(seeds), "runs": [], "summary": {}}
    with tempfile.TemporaryDirectory(prefix="swarmslam-robustness-") as scratch, \
            ProcessPoolExecutor(max_workers=jobs or os.cpu_count() or 1) as pool:
        for k, row in enumerate(pool.map(run_one, [(*w, scratch, keep) for w in work])):
            results["runs"].append(row)
            echo(f"[{k + 1}/{len(work)}] {row['log']} {row['family']} seed {row['seed']}: "
                 f"eT {row['eT']:.4f} m, eR {row['eR_deg']:.3f}°, p99 {row['p99_m']:.3f} m")
    for name in logs:
        for family in ((SIMULATED,) if name == SIMULATED else families):
            rows = [r for r in results["runs"] if r["log"] == name and r["family"] == family]
            results["summary"][f"{name}/{family}"] = summarise(rows)
    echo(format_table(results["summary"]))
    if plots is not None:
        robustness_figure(plots, results["runs"], results["summary"])
    if json_path is not None:
        save_results(json_path, results)
    return results


def format_table(summary: dict) -> str:
    lines = [f"{'log/family':28} {'eT med':>8} {'worst':>8} {'spread':>6} {'eR med':>7} "
             f"{'worst':>6} {'glob med':>8} {'worst':>7} {'gross':>5}"]
    for key, s in summary.items():
        def f(name, width, digits):
            v = s.get(name)
            return f"{v:{width}.{digits}f}" if v is not None else " " * (width - 1) + "–"
        lines.append(f"{key:28} {f('eT_scored_median', 8, 4)} {f('eT_scored_worst', 8, 4)} "
                     f"{f('eT_scored_spread', 6, 2)} {f('eR_deg_median', 7, 3)} "
                     f"{f('eR_deg_worst', 6, 3)} {f('eT_global_median', 8, 3)} "
                     f"{f('eT_global_worst', 7, 3)} {len(s['gross']):5d}")
    return "\n".join(lines)
