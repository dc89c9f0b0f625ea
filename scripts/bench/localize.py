"""``swarmslam bench localize``: global relocalization on the Intel, ACES3 and fr-clinic logs.

Per log: the map of the whole log (a mapping replay, ABC with odometry, seed 0; its session is
kept in ``maps_dir`` and reused while the defaults and the code it was mapped with are today's;
the search and tracking always run with today's
:data:`swarmslam.runtime.config.SESSION_SECTIONS`), then single
scans drawn at seeded random times are relocalized with no prior. An answer is a success within
0.3 m and 5° of the mapping run's optimised pose of that scan, wrong otherwise; "ambiguous" is
neither. Then the same queries confirmed: localization mode started there with no prior, its
candidates tracked over the next ``confirm_seconds`` of scans, judged at the last of them. Then
localization-mode tracking over the log's second half on the budgeted schedule
(:func:`tracking`).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import swarmslam.formats.carmen
import swarmslam.replay
import swarmslam.runtime
from swarmslam.runtime.config import (
    SESSION_SECTIONS,
    ConfigError,
    SlamConfig,
    from_toml,
    session_settings,
    to_toml,
)
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.localization.localizer import TRACKING
from swarmslam.runtime.pose import between
from swarmslam.runtime.localization.relocalization import Ambiguous, Located
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.writers import write_text_atomic
from swarmslam.bench.slam import LOGS
from swarmslam.formats.carmen import read_carmen
from swarmslam.datasets import require
from swarmslam.view.plots import bars, latency_histograms, require_matplotlib
from swarmslam.progress import Progress
from swarmslam.replay import replay, robot_frame_scan
from swarmslam.bench.record import save_results

SUCCESS_DISTANCE = 0.3  # m
MEDIAN_MS_TARGET = 100.0  # a one-scan query's median time (also docs/results.md's)
SUCCESS_ANGLE = math.radians(5.0)


def judge(answer, truth) -> str:
    """``success``, ``wrong`` or ``ambiguous``."""
    if not isinstance(answer, Located):
        return "ambiguous"
    e = between(answer.pose, truth)
    close = math.hypot(e[0], e[1]) <= SUCCESS_DISTANCE and abs(e[2]) <= SUCCESS_ANGLE
    return "success" if close else "wrong"


MADE_BY = "made-by.toml"  # beside a kept session: the defaults its mapping run had
MADE_BY_CODE = "made-by.code"  # ... and the digest of the code that ran it (mapping_code)


def todays_search() -> dict:
    """Today's defaults of the sections a saved session may change (search and tracking): a
    kept map is scored with them, not with those saved in it."""
    return session_settings(SlamConfig())


def mapping_code() -> str:
    """A digest of the code a mapping replay runs: the SLAM core's sources, the log reader's
    and the replay's. A field added to the configuration reads an older file with today's
    default, so the defaults alone cannot tell a map made before the field existed."""
    digest = hashlib.sha256()
    core = Path(swarmslam.runtime.__file__).parent
    sources = sorted(core.rglob("*.py")) + [Path(swarmslam.formats.carmen.__file__),
                                            Path(swarmslam.replay.__file__)]
    for path in sources:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def _mapped_as_today(made_by: Path) -> bool:
    """Whether the defaults written in ``made_by`` map as today's do (the sections of the
    search and tracking aside: :func:`todays_search` replaces them), by today's code."""
    try:
        kept = from_toml(made_by.read_text(encoding="utf-8"), source=str(made_by))
        code = (made_by.parent / MADE_BY_CODE).read_text(encoding="utf-8").strip()
    except (OSError, ConfigError):
        return False
    today = SlamConfig()
    same = replace(kept, **{t: getattr(today, t) for t in SESSION_SECTIONS}) == today
    return same and code == mapping_code()


def mapping_session(name: str, log_path: Path, maps_dir: Path, echo=print) -> Path:
    """The session of the whole log's mapping run, made once per ``maps_dir`` and made again
    when the mapping defaults or the code have changed since (a kept map of other defaults
    would be scored as today's without a word)."""
    out = Path(maps_dir) / name
    session, made_by = out / "session.npz", out / MADE_BY
    if session.exists() and made_by.exists() and _mapped_as_today(made_by):
        return session
    if session.exists():
        echo(f"{name}: the map kept in {out} was made with other defaults or code: mapping "
             "again")
    else:
        echo(f"{name}: mapping the whole log first (kept in {out})")
    replay(log_path, out_dir=out, label=f"{name} mapping")
    write_text_atomic(made_by, to_toml(SlamConfig(), comments=False))
    write_text_atomic(out / MADE_BY_CODE, mapping_code() + "\n")
    return session


def bench_log(name: str, log_path: Path, session: Path, queries: int, seed: int,
              echo=print) -> dict:
    runtime = SlamRuntime.localize(session, changes=todays_search())
    localizer = runtime.slam
    relocalizer = localizer.relocalizer
    _, truth = SlamRuntime.resume(session).trajectory()
    lasers = read_carmen(log_path).lasers
    confirm = relocalizer.config.confirm_seconds
    stamps = np.array([r.timestamp for r in lasers])
    last = int(np.searchsorted(stamps, stamps[-1] - confirm, side="right")) - 1
    picks = np.random.default_rng(seed).integers(0, max(last, 1), size=queries)
    scan = PointScan(max(len(r.ranges) for r in lasers))
    localizer.warm_up()  # compiled before timing
    single, confirmed, seconds, seconds_confirmed = [], [], [], []
    progress = Progress(queries, f"{name} relocalize")
    for k in picks:
        k = int(k)
        robot_frame_scan(lasers[k], scan, localizer.config.sensor)
        localizer.reset(seed=localizer.seed)  # each query as on a fresh start
        t = time.perf_counter()
        answer = relocalizer.relocalize(scan)
        seconds.append(time.perf_counter() - t)
        single.append(judge(answer, truth[k]))
        # the first scan at or past the window's end: there the candidates are judged
        end = min(int(np.searchsorted(stamps, stamps[k] + confirm, side="left")), len(stamps) - 1)
        t = time.perf_counter()
        answer = confirm_from(localizer, lasers, k, end, scan)
        seconds_confirmed.append(time.perf_counter() - t)
        confirmed.append(judge(answer, truth[end]))
        progress.update(note=f"{single.count('success')} found, {single.count('wrong')} wrong; "
                             f"confirmed {confirmed.count('success')} found, "
                             f"{confirmed.count('wrong')} wrong")
    progress.close()

    def rate(outcomes, what):
        return outcomes.count(what) / len(outcomes)

    ms, ms_c = 1e3 * np.array(seconds), 1e3 * np.array(seconds_confirmed)
    return {
        "dataset": name, "queries": queries, "nodes": int(localizer.saved.n_nodes),
        "map_cells": list(relocalizer.place.shape),
        "success_rate": rate(single, "success"), "wrong_rate": rate(single, "wrong"),
        "ambiguous_rate": rate(single, "ambiguous"),
        "success_rate_confirmed": rate(confirmed, "success"),
        "wrong_rate_confirmed": rate(confirmed, "wrong"),
        "ambiguous_rate_confirmed": rate(confirmed, "ambiguous"),
        "ms_median": float(np.median(ms)), "ms_p99": float(np.percentile(ms, 99)),
        "ms_median_confirmed": float(np.median(ms_c)),
        "ms_p99_confirmed": float(np.percentile(ms_c, 99)),
        "ms_per_query": [round(float(v), 3) for v in ms],
        **tracking(name, lasers, session, truth, echo),
    }


def confirm_from(localizer, lasers, first: int, last: int, scan: PointScan):
    """Localization mode started with no prior at scan ``first``: the search, then its
    candidates tracked over the scans to ``last`` (docs/method.md §9). Judged at ``last``: a
    committed pose is the answer; candidates still in question are "ambiguous". The swarms'
    streams restart from the localizer's seed, as on a fresh start."""
    localizer.reset(seed=localizer.seed)
    for m in range(first, last + 1):
        localizer.step(robot_frame_scan(lasers[m], scan, localizer.config.sensor),
                       lasers[m].odometry, lasers[m].timestamp)
    if localizer.phase != TRACKING:
        return Ambiguous(tuple(localizer.candidates()), (), localizer.status)
    return Located(localizer.pose(), 1.0)


def tracking(name: str, lasers, session: Path, truth, echo=print) -> dict:
    """Localization mode over the log's second half on the budgeted schedule, ticks back to
    back, started at the mapping run's pose of its first scan: error against the mapping
    run, ms per tick, deadline misses at the configured rate, and whether the session file
    and the map in memory are unchanged afterwards."""
    before = sha256_file(session)
    half = len(lasers) // 2
    runtime = SlamRuntime.localize(session, initial_pose=truth[half],
                                   changes={**todays_search(), "runtime.schedule": "budgeted"})
    digest = runtime.slam.saved.digest()
    runtime.warm_up()
    scan = PointScan(max(len(r.ranges) for r in lasers))
    progress = Progress(len(lasers) - half, f"{name} tracking")
    for record in lasers[half:]:
        runtime.process(robot_frame_scan(record, scan, runtime.config.sensor), record.odometry,
                        record.timestamp)
        progress.update(note=runtime.status)
    progress.close()
    _, poses = runtime.slam.trajectory()
    known = runtime.slam.has_pose()
    e = between(poses, truth[half:][known])
    distance = np.hypot(e[:, 0], e[:, 1])
    report = runtime.report()
    return {
        "tracking_scans": len(lasers) - half,
        "tracking_scans_with_pose": int(known.sum()),
        "tracking_error_m": float(np.mean(distance)),
        "tracking_error_m_median": float(np.median(distance)),
        "tracking_error_m_p99": float(np.percentile(distance, 99)),
        "tracking_error_m_max": float(np.max(distance)),
        "tracking_error_deg": float(np.degrees(np.mean(np.abs(e[:, 2])))),
        "tracking_lost": report["lost"],
        "tracking_odometry_held": report["odometry_held"],
        "tracking_ms_median": report["latency_ms_median"],
        "tracking_ms_p99": report["latency_ms_p99"],
        "tracking_deadline_misses": report["deadline_misses"],
        "map_unchanged": bool(sha256_file(session) == before
                              and runtime.slam.saved.digest() == digest),
    }


def sha256_file(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def bench_localize(data_dir: Path, logs=("intel", "aces", "clinic"), queries: int = 200, seed: int = 0,
                   maps_dir=None, json_path=None, echo=print, plots=None) -> dict:
    """``plots``: a folder for the outcomes per log and the query times (PNG)."""
    if plots:
        require_matplotlib()
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
             f"{row['wrong_rate_confirmed']:.1%} wrong; tracking: {row['tracking_error_m']:.3f} m "
             f"mean error ({row['tracking_error_m_p99']:.2f} m p99, "
             f"{row['tracking_error_m_max']:.2f} m max), {row['tracking_ms_p99']:.1f} ms p99, "
             f"{row['tracking_deadline_misses']} misses, map unchanged: {row['map_unchanged']}")
        if json_path:
            save_results(json_path, results)
    if plots:
        plot_localize(plots, results["logs"])
    return results


def plot_localize(out_dir, rows) -> None:
    """Outcome shares per log (one scan and confirmed) and the time per one-scan query."""
    shares = {what: {f"{r['dataset']}\n{part or 'one scan'}":
                     r[f"{what}_rate{'_confirmed' if part else ''}"]
                     for r in rows for part in ("", "confirmed")}
              for what in ("success", "ambiguous", "wrong")}
    bars(out_dir, "localize-outcomes", "global relocalization, no prior", "share of queries",
         shares, stacked=True)
    latency_histograms(out_dir, {r["dataset"]: r["ms_per_query"] for r in rows},
                       MEDIAN_MS_TARGET,
                       "localize-ms", "target median", "ms per one-scan query", "queries")
