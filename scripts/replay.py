"""``swarmslam replay LOG``: the SLAM over a recorded log — CARMEN, or a ROS 1 / ROS 2 bag —
scored if relations are given.

Writes to ``out_dir`` (atomically): the map (PGM + YAML for ROS map_server, and PNG), the
trajectory of every scan (TUM), the pose graph (g2o), the session (``session.npz``: localize
in it with ``--localize``, extend it with ``--resume``) and ``metrics.json``.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import fields

import numpy as np

from swarmslam.runtime.config import ConfigError, SensorConfig, SlamConfig, override
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.pose import compose
from swarmslam.runtime.matching.scan import PointScan, ranges_to_points
from swarmslam.runtime.realtime.writers import write_json_atomic
from swarmslam.formats.logs import BagOptions, read_log
from swarmslam.evaluation.metrics import kummerle, match_relations
from swarmslam.outputs import (check_input_kept, check_writable, output_set, report_beside,
                               write_results)
from swarmslam.evaluation.odometry_check import odometry_seen
from swarmslam.progress import Progress
from swarmslam.formats.relations import read_relations
from swarmslam.view.run_view import frame_of
from swarmslam.formats.tum import write_tum
from swarmslam.runs import RunOptions, open_runtime


def _largest(section, name: str):
    """The largest value the configuration takes in ``section``'s field ``name``."""
    return next(f.metadata["le"] for f in fields(section) if f.name == name)


def node_bound(lasers, config: SlamConfig | None, odometry: bool) -> int:
    """The most nodes a replay of ``lasers`` can make: one per scan; with odometry, no more
    than twice what odometry's path and turn make in `node_distance` and `node_angle` (a
    node is made once the motion since the last exceeds one of them; odometry's path errs
    by a few percent)."""
    most = len(lasers) + 1
    readings = np.array([r.odometry for r in lasers], dtype=np.float64).reshape(-1, 3)
    if not odometry or not np.all(np.isfinite(readings)):
        return most
    steps = np.diff(readings, axis=0)
    path = float(np.hypot(steps[:, 0], steps[:, 1]).sum())
    turn = float(np.abs(np.remainder(steps[:, 2] + math.pi, 2 * math.pi) - math.pi).sum())
    fe = (config or SlamConfig()).front_end
    return min(most, 2 * math.ceil(path / fe.node_distance + turn / fe.node_angle) + 2)


def replay_config(config: SlamConfig | None = None, scans: int = 0,
                  schedule: str = "lockstep", nodes: int = 0, beams: int = 0) -> SlamConfig:
    """``config`` (default: the defaults) for a replay: the trajectory sized for the log's
    ``scans``, each stored scan for its largest scan's ``beams`` where
    the configuration holds fewer points (the runtime keeps a scan's first
    ``sensor.max_points`` points: a 360° scanner's last sector would be lost), and the
    runtime's ``schedule`` (lockstep: the whole back end every tick, bit for bit
    repeatable).

    In lockstep the pose graph is sized for the log's ``nodes`` too (:func:`node_bound`),
    its edges in the configuration's proportion, where the configuration holds fewer. A
    robot's capacities are fixed before it knows how long it will run (docs/runtime.md §4),
    and at capacity the map freezes (Intel at 800 nodes: eT 4.8 m); a log's length is known
    before its replay starts. The budgeted schedule replays as the robot runs, with the
    configuration's capacities (it commits them to memory at start-up)."""
    config = config or SlamConfig()
    changes = {"capacity.max_scans": max(config.capacity.max_scans, scans),
               "runtime.schedule": schedule}
    if beams > config.sensor.max_points:
        changes["sensor.max_points"] = min(beams, _largest(config.sensor, "max_points"))
    cap = config.capacity
    if schedule == "lockstep" and nodes > cap.max_nodes:
        nodes = min(nodes, _largest(cap, "max_nodes"))
        changes["capacity.max_nodes"] = nodes
        changes["capacity.max_edges"] = min(_largest(cap, "max_edges"), max(
            cap.max_edges, math.ceil(cap.max_edges / cap.max_nodes * nodes)))
    return override(config, changes)


def bag_sweep(lasers, config: SlamConfig | None, warn=print) -> SlamConfig | None:
    """``config`` with the sweep a bag's scans state: a ROS LaserScan gives the time between
    its beams (``time_increment``) and is stamped at its first ray (REP: the header's stamp),
    so a log whose scans give it runs with their median sweep (``time_increment`` × (beams −
    1)), stamped at its start, whatever the configuration said of the sweep
    (docs/method.md §6.1, "The sweep"). A log whose scans give none (a CARMEN log, a bag
    without it): ``config`` as it was. A sweep beyond ``sensor.sweep_seconds``' bound, or a
    ``time_increment`` not a number ≥ 0, is warned of by name and not used."""
    usable = [r for r in lasers if math.isfinite(r.time_increment) and r.time_increment >= 0.0]
    if len(usable) < len(lasers):
        warn(f"{len(lasers) - len(usable)} scans' time_increment is not a number ≥ 0: their "
             "sweep is not used")
    timed = [r.time_increment * (len(r.ranges) - 1) for r in usable if r.time_increment > 0.0]
    if not timed:
        return config
    sweep = float(np.median(timed))
    try:
        swept = override(config or SlamConfig(), {"sensor.sweep_seconds": sweep,
                                                  "sensor.sweep_stamp": 0.0})
    except ConfigError as error:  # beyond the field's bounds
        warn(f"the scans' time_increment makes a sweep of {sweep:.3g} s ({error}): not used")
        return config
    warn(f"the scans sweep for {sweep:.4g} s (their time_increment), stamped at the first "
         "beam: each scan's turn over it is undone")
    return swept


def robot_frame_scan(record, scan: PointScan, sensor: SensorConfig) -> PointScan:
    """A laser record's valid points, moved from the laser's frame into the robot's (none when
    no beam returned: the runtime refuses and counts such a scan). Valid within the
    ``sensor``'s ranges as well as the log's own no-return reading, as the runtime's inbox
    takes a live scanner's: fr-clinic's ROBOTLASER1 lines state 81.9 m and hold 5,849
    readings of 81.83 m, beyond its SICK LMS's 80 m (docs/formats.md §6)."""
    scan.count = ranges_to_points(record.ranges, record.angles, sensor.min_range,
                                  min(record.max_range, sensor.max_range), scan.buffer,
                                  scan.sweep)
    if scan.count and np.any(record.laser_offset):
        n = scan.count
        pts = compose(record.laser_offset, np.c_[scan.buffer[:n], np.zeros(n)])
        scan.buffer[:n] = pts[:, :2]
    return scan


def scored(stamps, poses, relations) -> dict:
    """:func:`kummerle`'s figures, or none and why when no relation's ends both have a pose
    (the scans they name were all refused): the run's outputs are kept either way."""
    try:
        return kummerle(stamps, poses, relations)
    except ValueError as exc:
        return {"relations_used": 0, "relations_total": len(relations),
                "relations_note": str(exc)}


def input_report(log, runtime: SlamRuntime) -> dict:
    """What of the log could not be used: records the reader skipped (by field) and scans
    the runtime refused, and the share of all records they make."""
    skipped = sum(log.skipped.values())
    refused = runtime.inbox.empty + runtime.inbox.bad_stamps
    total = len(log.lasers) + skipped
    report = {"records_skipped": dict(log.skipped), "scans_refused": refused,
              "unusable_share": (skipped + refused) / total if total else 1.0}
    if log.stopped:  # a damaged file: read up to its damage, the rest lost
        report["read_stopped"] = log.stopped
    return report


MOSTLY_UNUSABLE = 0.5  # a run whose records were more than this share unusable is not ok
NO_USABLE_SCAN = "no usable scan"  # a run's status starting so: it wrote nothing


def writes_outputs(metrics: dict) -> bool:
    """Whether a run leaves an output set: not when no scan was usable (an empty map must not
    replace what the output folder held)."""
    return not metrics["status"].startswith(NO_USABLE_SCAN)


def run_status(status: str, log, runtime: SlamRuntime) -> str:
    """The runtime's status, preceded by what makes the run not ok: most of its input
    unusable, no scan used at all, or a damaged file read only up to its damage."""
    report = input_report(log, runtime)
    said = []
    if report["scans_refused"] == len(log.lasers):
        said.append(f"{NO_USABLE_SCAN}: every scan was refused")
    elif report["unusable_share"] > MOSTLY_UNUSABLE:
        said.append(f"mostly unusable input: {report['unusable_share']:.0%} of the records "
                    f"skipped or refused")
    if log.stopped:
        said.append(f"damaged input, the rest of it lost: {log.stopped}")
    if status != "ok":
        said.append(status)
    return "; ".join(said) if said else "ok"


def log_seconds(lasers) -> float:
    """The time the scans span, from their finite timestamps (a bad one is skipped)."""
    stamps = np.array([r.timestamp for r in lasers], dtype=np.float64)
    stamps = stamps[np.isfinite(stamps)]
    return float(stamps.max() - stamps.min()) if len(stamps) else 0.0


def replay(log_path, relations_path=None, options: RunOptions | None = None, *,
           odometry: bool = True, out_dir=None, limit=None, start: int = 0,
           bag: BagOptions | None = None, label: str = "replay", watch=None) -> dict:
    """Every scan of the log through :class:`SlamRuntime`, one tick each, as fast as it goes,
    started as ``options`` say (:class:`swarmslam.runs.RunOptions`: new, localized in a
    session or resuming one; default: a new run, seed 0). A replay's schedule is lockstep
    unless ``options`` say otherwise (the whole back end every tick, as ``GraphSlam.step``:
    bit for bit repeatable); ``budgeted`` slices it as on a robot.

    A localized replay's outputs are the trajectory and ``localization.json`` (the session's
    map is not changed); a resumed one extends the session's map from wherever the log
    starts in it (multi-session mapping). ``odometry``: False replays the scans alone.
    ``start``: the first scan replayed; ``limit``: how many. ``watch``: a
    :class:`swarmslam.view.run_view.RunWatch` shown every tick (closed at the end)."""
    return replay_run(log_path, relations_path, options, odometry=odometry, out_dir=out_dir,
                      limit=limit, start=start, bag=bag, label=label, watch=watch)[0]


def replay_run(log_path, relations_path=None, options: RunOptions | None = None, *,
               odometry: bool = True, out_dir=None, limit=None, start: int = 0,
               bag: BagOptions | None = None, label: str = "replay", watch=None,
               before_scan=None):
    """:func:`replay`, returning ``(metrics, runtime)``; ``before_scan(k, runtime)`` is called
    before scan ``k`` is processed (benchmarks use it to follow the run)."""
    try:
        return _replay_run(log_path, relations_path, options or RunOptions(), odometry,
                           out_dir, limit, start, bag, label, watch, before_scan)
    finally:
        if watch is not None:
            watch.close()


def _replay_run(log_path, relations_path, options: RunOptions, odometry, out_dir, limit, start,
                bag, label, watch, before_scan):
    if out_dir is not None:
        check_writable(out_dir)  # before the run, not after it
        if options.localize:
            check_input_kept(out_dir, options.localize, "the session")
    log = read_log(log_path, bag, warn=lambda text: print(text, file=sys.stderr))
    if log.skipped:
        print(f"{log_path}: skipped {sum(log.skipped.values())} records ("
              + ", ".join(f"{n} with a bad {f}" for f, n in log.skipped.items()) + "): "
              + "; ".join(log.skipped_examples), file=sys.stderr)
    relations = read_relations(relations_path) if relations_path else None
    lasers = log.lasers[start : start + limit if limit else None]
    if not lasers:
        raise ValueError(f"{log_path}: no laser scans from scan {start}")
    if relations is not None:  # before the run, not after it: relations of another log
        matched = int(match_relations([r.timestamp for r in lasers], relations)[2].sum())
        if matched == 0:
            raise ValueError(f"{relations_path}: none of its {len(relations)} relations has "
                             f"both ends at scans of {log_path} (within 0.1 ms) — the "
                             f"relations of another log?")
    schedule = options.schedule or "lockstep"
    beams = max(len(r.ranges) for r in lasers)
    config = None
    if options.session is None:  # (a session's configuration is its own)
        config = bag_sweep(lasers, options.config, warn=lambda text: print(
            f"{log_path}: {text}", file=sys.stderr))
        config = replay_config(config, len(lasers), schedule,
                               node_bound(lasers, config, odometry), beams)
    runtime = open_runtime(options, config, {"runtime.schedule": schedule}, scans=len(lasers))
    config = runtime.config
    slam = runtime.slam
    # Every kernel compiled or loaded before the clock starts, as a robot warms up before its
    # first tick: the real-time factor is the run's, not the compiler's (after a checkout that
    # changed a source, numba compiles every kernel afresh: docs/runtime.md §8).
    warm_up_seconds = runtime.warm_up()
    scan = PointScan(beams)
    latencies = np.zeros(len(lasers))
    progress = Progress(len(lasers), label)
    start_time = time.perf_counter()
    for k, record in enumerate(lasers):
        robot_frame_scan(record, scan, config.sensor)
        if before_scan is not None:
            before_scan(k, runtime)
        t0 = time.perf_counter()
        result = runtime.process(scan, record.odometry if odometry else None, record.timestamp)
        latencies[k] = time.perf_counter() - t0
        if watch is not None and result is not None:
            watch.tick(runtime, frame_of(runtime, result, scan.points, record.timestamp,
                                         latencies[k]))
        progress.update(note=runtime.status if runtime.localizing else
                        f"nodes {slam.n_nodes} loops {slam.loops_closed}")
    runtime.drain()  # deferred loop searches finish, as on the robot's next ticks
    progress.close()
    wall = time.perf_counter() - start_time
    data_seconds = log_seconds(lasers)
    timing = {
        "warm_up_seconds": warm_up_seconds,
        "wall_seconds": wall,
        "data_seconds": data_seconds,
        "real_time_factor": data_seconds / wall if wall > 0 else float("inf"),
        "latency_ms_median": float(1e3 * np.median(latencies)),
        "latency_ms_p99": float(1e3 * np.percentile(latencies, 99)),
    }
    if runtime.localizing:
        return localization_results(runtime, log, log_path, options.localize, lasers, odometry,
                                    timing, relations, out_dir), runtime
    stamps, poses = slam.trajectory()
    metrics = {
        "log": str(log_path),
        **input_report(log, runtime),
        "optimizer": config.matcher.swarm.optimizer,
        "odometry": bool(odometry),
        "scans": len(lasers),
        "nodes": int(slam.graph.n_nodes),
        "edges": int(slam.graph.n_edges),
        "loops_accepted": slam.loops_closed,
        "odometry_seen": odometry_seen(slam.front_end, poses),
        **timing,
        "status": run_status(runtime.status, log, runtime),
        "runtime": runtime.report(),
    }
    if relations is not None:
        metrics.update(scored(stamps, poses, relations))
    if out_dir is not None and not writes_outputs(metrics):
        report_beside(out_dir, metrics)
    elif out_dir is not None:
        with output_set(out_dir) as stage:  # swapped in whole (scripts/outputs.py)
            write_results(slam, stage)
            runtime.save(stage / "session.npz")  # map once, localize or resume later
            write_json_atomic(stage / "metrics.json", metrics)
    return metrics, runtime


def localization_results(runtime: SlamRuntime, log, log_path, session_path, lasers, odometry,
                         timing: dict, relations, out_dir) -> dict:
    """A localization replay's metrics, and its outputs: the trajectory (TUM) and
    ``localization.json``."""
    stamps, poses = runtime.trajectory()
    metrics = {"log": str(log_path), "session": str(session_path), "odometry": bool(odometry),
               "scans": len(lasers), "scans_with_pose": len(stamps), **timing,
               **input_report(log, runtime), "status": run_status(runtime.status, log, runtime),
               "runtime": runtime.report(),
               "saved_map_sha256": runtime.slam.saved.digest()}
    if relations is not None:
        metrics.update(scored(stamps, poses, relations))
    if out_dir is not None and not writes_outputs(metrics):
        report_beside(out_dir, metrics)
    elif out_dir is not None:
        with output_set(out_dir) as stage:
            write_tum(stage / "trajectory.tum", stamps, poses)
            write_json_atomic(stage / "localization.json", metrics)
    return metrics
