"""``swarmslam bench runtime``: the fixed-rate runtime on a raw log, and a soak run.

Three passes over ``radish/intel.clf.gz`` (``--log`` another of the radish logs; one core,
budgeted schedule unless said):

1. *max speed*: every scan, one tick each, back to back, the collector held as the robot's
   loop holds it — per-tick latency median/p99/max,
   deadline misses at 10 Hz, peak RSS and RSS growth after warm-up, accuracy against the
   relations, beside the unsliced (lockstep) replay of the same log;
2. *traced*: the first scans again under tracemalloc — traced bytes per tick after warm-up;
3. *recorded rate*: a producer thread hands scans over at their logged times and the loop
   ticks at 10 Hz on the wall clock, for ``realtime_minutes`` of the log (45 min in all),
   the log's pauses (gaps over :data:`LOG_PAUSE`) cut out.

``--soak MINUTES`` instead drives the runtime for that long on simulated scans
(:class:`swarmslam.runtime.realtime.warm_up.LoopDrive`), sampling RSS and traced memory each minute.
Targets (:data:`TARGETS`): 0 misses, p99 ≤ 20 ms, RSS growth ≤ 1 MiB; 0 traced bytes per tick.
"""

from __future__ import annotations

import gc
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.warm_up import LoopDrive
from swarmslam.formats.carmen import read_carmen
from swarmslam.datasets import require
from swarmslam.evaluation.metrics import kummerle
from swarmslam.view.plots import latency_histograms, lines_plot, require_matplotlib
from swarmslam.progress import Progress
from swarmslam.formats.relations import read_relations
from swarmslam.replay import replay, robot_frame_scan
from swarmslam.runs import RunOptions
from swarmslam.view.run_view import RunWatch, frame_of
from swarmslam.bench.record import save_results

WARM_UP = 1000  # scans before RSS and traced memory are taken as the baseline
TARGETS = {"p99_ms": 20.0, "rss_growth_mib": 1.0, "misses": 0}  # (also docs/results.md's)
LOG_PAUSE = 10.0  # s between scans beyond which the recorded-rate pass takes the log as paused


def rss_kib() -> tuple[int, int]:
    """(current, peak) resident set size of this process, KiB (Linux /proc)."""
    fields = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                fields[key] = int(value.split()[0])
    return fields.get("VmRSS", 0), fields.get("VmHWM", 0)


def robot_frame_scans(log, sensor):
    """Each laser record's points in the robot frame (valid within ``sensor``'s ranges), as
    (points, count, odometry, stamp)."""
    out = []
    scan = PointScan(max(len(r.ranges) for r in log.lasers))
    for r in log.lasers:
        pts = robot_frame_scan(r, scan, sensor).points.copy()
        out.append((pts, len(pts), np.asarray(r.odometry, dtype=np.float64), r.timestamp))
    return out


def max_speed(scans, relations, config, echo, seed: int = 0) -> dict:
    runtime = SlamRuntime(config, seed=seed)
    runtime_config = config.runtime
    warm = runtime.warm_up()
    latency = np.zeros(len(scans))
    rss_after_warm_up = 0
    progress = Progress(len(scans), "runtime max speed")
    clock = time.perf_counter
    start = clock()
    with runtime.collector_held():  # as in the robot's loop (SlamRuntime.run)
        for k, (pts, n, odometry, stamp) in enumerate(scans):
            runtime.inbox.put_points(pts, n, stamp, odometry)
            t0 = clock()
            runtime.tick()
            latency[k] = clock() - t0
            if k == WARM_UP:
                rss_after_warm_up = rss_kib()[0]
            progress.update(note=f"nodes {runtime.slam.n_nodes}")
    runtime.drain()
    progress.close()
    wall = clock() - start
    rss_end, rss_peak = rss_kib()
    stamps, poses = runtime.trajectory()
    report = runtime.report()
    out = {
        "scans": len(scans),
        "wall_seconds": wall,
        "real_time_factor": (scans[-1][3] - scans[0][3]) / wall,
        "latency_ms_median": float(1e3 * np.median(latency)),
        "latency_ms_p99": float(1e3 * np.percentile(latency, 99)),
        "latency_ms_max": float(1e3 * latency.max()),
        "deadline_misses_10hz": int(np.sum(latency > runtime_config.period)),
        "over_budget_ticks": int(np.sum(latency > runtime_config.tick_budget)),
        "rss_mib_peak": rss_peak / 1024,
        "rss_mib_committed_at_start": runtime.reserved_bytes / 2**20,
        "allocator_pinned": runtime.allocator_pinned,
        "warm_up_seconds": warm,
        "rss_mib_growth_after_warm_up": (rss_end - rss_after_warm_up) / 1024,
        "runtime": report,
    }
    out.update(kummerle(stamps, poses, relations))
    return out, 1e3 * latency


def traced(scans, config, ticks) -> dict:
    """Traced memory growth per tick after warm-up, in two consecutive windows (tracemalloc
    slows Python: run apart from the timed pass). A per-tick leak grows alike in both. The
    runtime warms up first, as every pass does: a kernel first met after the warm-up scans
    (the wide loop search's, on Intel after scan 1,000) would otherwise count numba's loading
    of its machine code as growth."""
    runtime = SlamRuntime(config)
    runtime.warm_up()

    def run(chunk):
        for pts, n, odometry, stamp in chunk:
            runtime.inbox.put_points(pts, n, stamp, odometry)
            runtime.tick()
        gc.collect()
        return tracemalloc.get_traced_memory()[0]

    half = ticks // 2
    tracemalloc.start()
    try:
        start = run(scans[:WARM_UP])
        middle = run(scans[WARM_UP : WARM_UP + half])
        end = run(scans[WARM_UP + half : WARM_UP + 2 * half])
    finally:
        tracemalloc.stop()
    windows = [middle - start, end - middle]
    return {"ticks": 2 * half, "traced_bytes_growth": windows[0] + windows[1],
            "traced_bytes_per_tick": (windows[0] + windows[1]) / max(2 * half, 1),
            "windows_bytes": windows, "nodes": int(runtime.slam.n_nodes)}


def recording_times(stamps, pause: float = LOG_PAUSE) -> np.ndarray:
    """Each scan's time since the first, with every gap between scans longer than ``pause``
    cut to nothing: a pause in the logging is not replayed (fr-clinic's second scan comes
    163 s after its first, and 595 s of its 4,820 are such gaps)."""
    gaps = np.diff(np.asarray(stamps, dtype=np.float64), prepend=stamps[0])
    gaps[gaps > pause] = 0.0
    return np.cumsum(gaps)


def recorded_rate(scans, config, minutes: float, echo) -> dict:
    """Scans handed over at their logged times by a producer thread, the log's pauses cut
    out (:func:`recording_times`); ticks on the wall clock."""
    times = recording_times([s[3] for s in scans])
    chosen = [(s, t) for s, t in zip(scans, times) if t <= 60.0 * minutes]
    runtime = SlamRuntime(config)
    runtime.warm_up()
    stop = threading.Event()
    latencies = []

    def produce():
        start = time.perf_counter()
        for (pts, n, odometry, stamp), due in chosen:
            wait = due - (time.perf_counter() - start)
            if wait > 0 and stop.wait(wait):
                return
            runtime.inbox.put_points(pts, n, stamp, odometry)
        stop.wait(0.5)  # let the last scan be taken
        stop.set()

    def on_tick(rt, result):
        latencies.append(rt.stats.last_latency if result is not None else 0.0)

    producer = threading.Thread(target=produce, daemon=True)
    producer.start()
    runtime.run(stop, on_tick=on_tick)
    producer.join()
    lat = np.array([v for v in latencies if v > 0]) if latencies else np.zeros(1)
    report = runtime.report()
    return {
        "minutes": minutes,
        "scans_offered": len(chosen),
        "ticks": report["ticks"],
        "scans_processed": report["scans"],
        "stale_scans": report["stale_scans"],
        "deadline_misses": report["deadline_misses"],
        "latency_ms_median": float(1e3 * np.median(lat)),
        "latency_ms_p99": float(1e3 * np.percentile(lat, 99)),
        "latency_ms_max": float(1e3 * lat.max()),
    }, 1e3 * lat


def view_overhead(scans, config, n: int) -> tuple[dict, dict]:
    """Tick latency with a view attached (a rerun recording and an MCAP file, as ``--record``
    and ``--mcap`` write them) against none: two runtimes ticked alternately on the same
    scans, so both see the same machine at the same moments."""
    scans = scans[:n]
    plain, watched = SlamRuntime(config), SlamRuntime(config)
    plain.warm_up()
    watched.warm_up()
    off, on, view = np.zeros(len(scans)), np.zeros(len(scans)), np.zeros(len(scans))
    clock = time.perf_counter
    progress = Progress(len(scans), "runtime with and without a view")
    with tempfile.TemporaryDirectory(prefix="swarmslam-view-") as tmp:
        watch = RunWatch(record=Path(tmp) / "run.rrd", mcap=Path(tmp) / "run.mcap")
        try:
            for k, (pts, count, odometry, stamp) in enumerate(scans):
                for runtime, latency in ((plain, off), (watched, on)):
                    runtime.inbox.put_points(pts, count, stamp, odometry)
                    t0 = clock()
                    result = runtime.tick()
                    latency[k] = clock() - t0
                if result is not None:
                    t0 = clock()
                    watch.tick(watched, frame_of(watched, result, pts[:count], stamp, on[k]))
                    view[k] = clock() - t0
                progress.update()
        finally:
            watch.close()
            progress.close()
        sizes = {p.name: p.stat().st_size for p in Path(tmp).iterdir()}
    p99_off, p99_on = (float(1e3 * np.percentile(v, 99)) for v in (off, on))
    return {
        "scans": len(scans),
        "latency_ms_p99_without_view": p99_off, "latency_ms_p99_with_view": p99_on,
        "p99_ratio": p99_on / p99_off,
        "latency_ms_median_without_view": float(1e3 * np.median(off)),
        "latency_ms_median_with_view": float(1e3 * np.median(on)),
        "view_ms_median": float(1e3 * np.median(view)), "view_ms_p99":
            float(1e3 * np.percentile(view, 99)),
        "recording_bytes": sizes,
    }, {"without a view": 1e3 * off, "with a view": 1e3 * on}


def bench_runtime(data_dir: Path, optimizer="abc", realtime_minutes=2.0, traced_ticks=6000,
                  limit=None, json_path=None, echo=print, config=None, plots=None,
                  view_scans: int = 4000, log: str = "intel", seed: int = 0) -> dict:
    """``config``: the SLAM's configuration (default: the defaults), run budgeted.
    ``view_scans``: scans ticked with and without a view (0: skip); ``plots``: a folder for
    the latency histograms (PNG); ``log``: the radish log's name; ``seed``: the max-speed
    pass's and the unsliced replay's."""
    if plots:
        require_matplotlib()
    log_path = require(Path(data_dir) / "radish" / f"{log}.clf.gz")
    rel_path = require(Path(data_dir) / "radish" / f"{log}.relations")
    log = read_carmen(log_path)
    if limit:
        log.lasers = log.lasers[:limit]
    relations = read_relations(rel_path)
    config = override(config or SlamConfig(), {"matcher.swarm.optimizer": optimizer,
                                               "runtime.schedule": "budgeted",
                                               "capacity.max_scans": len(log.lasers) + 1})
    scans = robot_frame_scans(log, config.sensor)
    rc = config.runtime
    result = {"benchmark": "runtime", "log": str(log_path), "optimizer": optimizer, "seed": seed,
              "runtime_config": {"rate_hz": rc.rate_hz, "tick_budget_s": rc.tick_budget}}
    result["max_speed"], latency = max_speed(scans, relations, config, echo, seed)
    latencies = {"max speed": latency}
    unsliced = replay(log_path, rel_path, RunOptions(config, optimizer, seed), limit=limit,
                      label="unsliced")
    result["unsliced"] = {k: unsliced[k] for k in ("eT", "eT_std", "eR_deg", "eR_std",
                                                   "loops_accepted", "latency_ms_p99")}
    result["traced"] = traced(scans, config, traced_ticks)
    if realtime_minutes > 0:
        result["recorded_rate"], latencies["recorded rate"] = recorded_rate(
            scans, config, realtime_minutes, echo)
    if view_scans > 0:
        result["view"], by_view = view_overhead(scans, config, view_scans)
    echo(format_runtime(result))
    if plots:
        budget = 1e3 * rc.tick_budget
        latency_histograms(plots, latencies, budget, "runtime-latency")
        if view_scans > 0:
            latency_histograms(plots, by_view, budget, "runtime-view")
    if json_path:
        save_results(json_path, result)
    return result


def format_runtime(r) -> str:
    f, u, t = r["max_speed"], r["unsliced"], r["traced"]
    lines = [
        f"{Path(r['log']).name} through the fixed-rate runtime ({r['optimizer']}, seed "
        f"{r.get('seed', 0)}, 10 Hz, tick budget "
        f"{1e3 * r['runtime_config']['tick_budget_s']:.0f} ms)",
        f"  max speed: {f['scans']} scans in {f['wall_seconds']:.1f} s "
        f"({f['real_time_factor']:.1f}x real time)",
        f"    latency ms: median {f['latency_ms_median']:.2f}  p99 {f['latency_ms_p99']:.2f}  "
        f"max {f['latency_ms_max']:.1f}   (target p99 <= {TARGETS['p99_ms']:.0f})",
        f"    deadline misses at 10 Hz: {f['deadline_misses_10hz']}   (target "
        f"{TARGETS['misses']}); over the "
        f"{1e3 * r['runtime_config']['tick_budget_s']:.0f} ms budget: {f['over_budget_ticks']}",
        f"    loop searches: {f['runtime']['loop_searches']['done']} done, "
        f"{f['runtime']['loop_searches']['dropped']} dropped from a full queue; back-end "
        f"slices {f['runtime']['back_end_slices']}, forced {f['runtime']['forced_slices']}",
        f"    RSS: peak {f['rss_mib_peak']:.1f} MiB ({f['rss_mib_committed_at_start']:.0f} MiB of "
        f"capacity committed at start-up), growth after warm-up "
        f"{f['rss_mib_growth_after_warm_up']:.2f} MiB   (target <= "
        f"{TARGETS['rss_growth_mib']:.0f} MiB)",
        f"    accuracy: eT {f['eT']:.4f} m  eR {f['eR_deg']:.3f} deg; unsliced replay "
        f"eT {u['eT']:.4f} m  eR {u['eR_deg']:.3f} deg",
        f"  traced: {t['traced_bytes_growth']} B over {t['ticks']} ticks = "
        f"{t['traced_bytes_per_tick']:.2f} B/tick (windows: {t['windows_bytes'][0]} B, then "
        f"{t['windows_bytes'][1]} B)   (target 0)",
    ]
    if "recorded_rate" in r:
        q = r["recorded_rate"]
        lines.append(
            f"  recorded rate ({q['minutes']:g} min of log): {q['scans_processed']}/"
            f"{q['scans_offered']} scans, {q['stale_scans']} stale, {q['deadline_misses']} "
            f"misses, latency ms median {q['latency_ms_median']:.2f} p99 "
            f"{q['latency_ms_p99']:.2f} max {q['latency_ms_max']:.1f}")
    if "view" in r:
        v = r["view"]
        lines.append(f"  with a view (rerun + MCAP recording), {v['scans']} scans: p99 "
                     f"{v['latency_ms_p99_with_view']:.2f} ms vs {v['latency_ms_p99_without_view']:.2f}"
                     f" without ({v['p99_ratio']:.2f}x; target <= 1.10); the view's own work "
                     f"{v['view_ms_median']:.2f} ms median, {v['view_ms_p99']:.2f} ms p99 per tick")
    return "\n".join(lines)


def bench_soak(minutes: float, json_path=None, echo=print, seed=0, plots=None) -> dict:
    """The runtime for ``minutes`` of wall time on simulated scans, back to back; ``plots``:
    a folder for the memory samples (PNG)."""
    if plots:
        require_matplotlib()
    drive = LoopDrive(seed)
    config = override(SlamConfig(), {"capacity.max_nodes": 2000, "capacity.max_edges": 8000,
                                     "capacity.max_scans": 1_000_000})
    runtime = SlamRuntime(config, seed=seed)
    runtime.warm_up()
    scan = PointScan(len(drive.angles))
    samples = []
    latency_max = 0.0
    end = time.perf_counter() + 60.0 * minutes
    next_sample = time.perf_counter()
    tracemalloc.start()
    k = 0
    try:
        while time.perf_counter() < end:
            _, odometry, ranges = drive.next()
            scan.set_ranges(ranges, drive.angles, 0.05, drive.max_range)
            t0 = time.perf_counter()
            runtime.process(scan, odometry, 0.18 * k)
            latency_max = max(latency_max, time.perf_counter() - t0)
            k += 1
            if time.perf_counter() >= next_sample:
                gc.collect()
                samples.append({"tick": k, "rss_mib": rss_kib()[0] / 1024,
                                "traced_kib": tracemalloc.get_traced_memory()[0] / 1024,
                                "nodes": int(runtime.slam.n_nodes)})
                echo(f"soak: {samples[-1]}")
                next_sample += 60.0
    finally:
        tracemalloc.stop()
    report = runtime.report()
    first = samples[1] if len(samples) > 1 else samples[0]
    result = {"benchmark": "runtime-soak", "minutes": minutes, "ticks": k, "samples": samples,
              "rss_mib_growth_after_first_minute": samples[-1]["rss_mib"] - first["rss_mib"],
              "traced_kib_growth_after_first_minute": samples[-1]["traced_kib"]
              - first["traced_kib"],
              "latency_ms_max": 1e3 * latency_max, "runtime": report}
    echo(f"soak {minutes:g} min: {k} ticks; RSS growth after the first minute "
         f"{result['rss_mib_growth_after_first_minute']:.2f} MiB, traced "
         f"{result['traced_kib_growth_after_first_minute']:.1f} KiB; p99 "
         f"{report['latency_ms_p99']:.1f} ms; status {report['status']}")
    if plots:
        ticks = [x["tick"] for x in samples]
        lines_plot(plots, "runtime-soak", f"soak, {minutes:g} min", "ticks",
                   {"RSS (MiB)": (ticks, [x["rss_mib"] for x in samples]),
                    "traced by tracemalloc (KiB)": (ticks, [x["traced_kib"] for x in samples])})
    if json_path:
        save_results(json_path, result)
    return result
