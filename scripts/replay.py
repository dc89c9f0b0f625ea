"""``swarmslam replay LOG``: the SLAM over a recorded CARMEN log, scored if relations are given.

Writes to ``out_dir`` (atomically): the map (PGM + YAML for ROS map_server, and PNG), the
trajectory of every scan (TUM), the pose graph (g2o), the session (``session.npz``: localize
in it with ``--localize``, extend it with ``--resume``) and ``metrics.json``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from runtime.config import SlamConfig, override
from runtime.fixed_rate import SlamRuntime
from runtime.pose import compose
from runtime.scan import PointScan
from runtime.writers import write_json_atomic
from scripts.carmen import read_carmen
from scripts.metrics import kummerle
from scripts.outputs import write_results
from scripts.progress import Progress
from scripts.relations import read_relations


def replay_config(config: SlamConfig | None = None, optimizer: str | None = None,
                  scans: int = 0, schedule: str = "lockstep") -> SlamConfig:
    """``config`` (default: the defaults) for a replay: ``optimizer`` if given, the trajectory
    sized for the log's ``scans``, and the runtime's ``schedule`` (lockstep: the whole back
    end every tick, bit for bit repeatable)."""
    config = config or SlamConfig()
    changes = {"capacity.max_scans": max(config.capacity.max_scans, scans),
               "runtime.schedule": schedule}
    if optimizer is not None:
        changes["matcher.swarm.optimizer"] = optimizer
    return override(config, changes)


def robot_frame_scan(record, scan: PointScan) -> PointScan:
    """A laser record's valid points, moved from the laser's frame into the robot's."""
    scan.set_ranges(record.ranges, record.angles, 0.0, record.max_range)
    if np.any(record.laser_offset):
        n = scan.count
        pts = compose(record.laser_offset, np.c_[scan.buffer[:n], np.zeros(n)])
        scan.buffer[:n] = pts[:, :2]
    return scan


def replay(log_path, relations_path=None, optimizer: str | None = None, odometry=True,
           out_dir=None, limit=None, seed=0, config: SlamConfig | None = None, label="replay",
           echo=print, schedule: str = "lockstep") -> dict:
    """Every scan of the log through :class:`SlamRuntime`, one tick each, as fast as it goes.
    The default schedule is lockstep (the whole back end every tick, as ``GraphSlam.step``);
    ``budgeted`` slices it as on a robot. ``optimizer`` overrides ``config``'s."""
    return replay_run(log_path, relations_path, optimizer, odometry, out_dir, limit, seed,
                      config, label, schedule)[0]


def replay_run(log_path, relations_path=None, optimizer: str | None = None, odometry=True,
               out_dir=None, limit=None, seed=0, config: SlamConfig | None = None,
               label="replay", schedule: str = "lockstep", before_scan=None):
    """:func:`replay`, returning ``(metrics, runtime)``; ``before_scan(k, runtime)`` is called
    before scan ``k`` is processed (benchmarks use it to follow the run)."""
    log = read_carmen(log_path)
    relations = read_relations(relations_path) if relations_path else None
    lasers = log.lasers[:limit] if limit else log.lasers
    config = replay_config(config, optimizer, len(lasers), schedule)
    runtime = SlamRuntime(config, seed=seed)
    slam = runtime.slam
    scan = PointScan(max(len(r.ranges) for r in lasers))
    latencies = np.zeros(len(lasers))
    progress = Progress(len(lasers), label)
    start = time.perf_counter()
    for k, record in enumerate(lasers):
        robot_frame_scan(record, scan)
        if before_scan is not None:
            before_scan(k, runtime)
        t0 = time.perf_counter()
        runtime.process(scan, record.odometry if odometry else None, record.timestamp)
        latencies[k] = time.perf_counter() - t0
        progress.update(note=f"nodes {slam.n_nodes} loops {slam.loops_closed}")
    runtime.drain()  # deferred loop searches finish, as on the robot's next ticks
    progress.close()
    wall = time.perf_counter() - start
    stamps, poses = slam.trajectory()
    data_seconds = float(lasers[-1].timestamp - lasers[0].timestamp)
    metrics = {
        "log": str(log_path),
        "optimizer": config.matcher.swarm.optimizer,
        "odometry": bool(odometry),
        "scans": len(lasers),
        "nodes": int(slam.graph.n_nodes),
        "edges": int(slam.graph.n_edges),
        "loops_accepted": slam.loops_closed,
        "loops_rejected_match": slam.back_end.loops.rejected_match,
        "loops_rejected_consistency": slam.back_end.loops.rejected_consistency,
        "matches_recovered": slam.front_end.lost_matches,
        "matches_degenerate": slam.front_end.degenerate_matches,
        "wall_seconds": wall,
        "data_seconds": data_seconds,
        "real_time_factor": data_seconds / wall if wall > 0 else float("inf"),
        "latency_ms_median": float(1e3 * np.median(latencies)),
        "latency_ms_p99": float(1e3 * np.percentile(latencies, 99)),
        "status": runtime.status,
        "runtime": runtime.report(),
    }
    if relations is not None:
        metrics.update(kummerle(stamps, poses, relations))
    if out_dir is not None:
        write_results(slam, out_dir)
        runtime.save(Path(out_dir) / "session.npz")  # map once, localize or resume later
        write_json_atomic(Path(out_dir) / "metrics.json", metrics)
    return metrics, runtime
