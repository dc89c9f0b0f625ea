"""The embedded-style SLAM runtime: Alg. 4 at a fixed rate, every tick within its budget.

    runtime = SlamRuntime(SlamConfig(), RuntimeConfig(rate_hz=10))
    driver.on_scan = runtime.inbox.put_ranges      # any producer: driver thread, simulator, log
    runtime.run(stop_event)                        # or call runtime.tick() from your own loop

Each tick takes the newest complete scan (older ones were dropped and counted by the inbox),
runs the front end — Alg. 5's alignment and Alg. 6's node insertion — always, with the swarm's
evaluation budget scaled to the time the tick has, then gives the back end — Alg. 7's loop
search and Eq. 21's optimisation, in slices — whatever time is left. The tick's latency, and
whether it missed its deadline (the next tick's start), are recorded in :class:`RuntimeStats`.

Two schedules. ``budgeted`` (a robot, or ``bench runtime``) consults the clock as above.
``lockstep`` never does: every tick runs the whole back end, so a run is bit-for-bit repeatable
from its seed (the simulator, tests) and equal to :meth:`GraphSlam.step` scan by scan.

Memory: everything that grows with time has a capacity fixed at start-up — nodes, edges and
stored scans (``SlamConfig.max_nodes``/``max_edges``/``max_points``), trajectory poses
(``max_scans``), the loop-search queue (``RuntimeConfig.loop_queue``), and the map's cells per
side (``SlamConfig.map_cells``, at which it coarsens rather than grows). When one is reached
the runtime keeps localising and says so in ``status``. Sizing: README, "Sizing a runtime".
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from runtime.back_end import BackEnd
from runtime.g2o import write_g2o
from runtime.inbox import ScanInbox
from runtime.map_io import write_map
from runtime.scan import PointScan
from runtime.slam import GraphSlam, SlamConfig, StepResult
from runtime.tum import write_tum

SCHEDULES = ("budgeted", "lockstep")


@dataclass(frozen=True)
class RuntimeConfig:
    rate_hz: float = 10.0
    # Work allowed per tick; the rest of the period is the robot's (planner, drivers). The
    # deadline is the period itself.
    tick_budget: float = 0.015  # s
    schedule: str = "budgeted"
    # The swarm plans its evaluations for this share of the tick budget, and never drops
    # below min_evaluation_share of its configured budget (accuracy before punctuality).
    front_end_share: float = 0.6
    min_evaluation_share: float = 0.25
    loop_queue: int = 64  # nodes awaiting their loop search
    max_deferred_ticks: int = 10  # a back-end slice waits at most this long, then runs
    latency_window: int = 4096  # recent tick latencies kept for the median / p99
    # Back every buffer with memory at start-up (None: when the schedule is budgeted).
    commit_memory: bool | None = None

    def __post_init__(self):
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {self.rate_hz}")
        if not 0 < self.tick_budget <= 1.0 / self.rate_hz:
            raise ValueError(f"tick_budget must be in (0, period = {1 / self.rate_hz:g} s], "
                             f"got {self.tick_budget}")
        if not 0 < self.min_evaluation_share <= 1 or not 0 < self.front_end_share <= 1:
            raise ValueError("front_end_share and min_evaluation_share must be in (0, 1]")

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


class RuntimeStats:
    """Counters and a fixed window of recent tick latencies (nothing grows)."""

    def __init__(self, window: int):
        self.latency = np.zeros(window)
        self.ticks = 0  # all ticks
        self.scans = 0  # ticks that processed a scan
        self.deadline_misses = 0
        self.over_budget = 0
        self.max_latency = 0.0
        self.evaluation_share = 1.0  # the swarm's last budget share

    def record(self, latency: float, budget: float) -> None:
        self.latency[self.scans % self.latency.shape[0]] = latency
        self.scans += 1
        self.max_latency = max(self.max_latency, latency)
        if latency > budget:
            self.over_budget += 1

    def recent(self) -> np.ndarray:
        return self.latency[: min(self.scans, self.latency.shape[0])]

    def summary(self) -> dict:
        recent = self.recent()
        return {
            "ticks": self.ticks,
            "scans": self.scans,
            "deadline_misses": self.deadline_misses,
            "over_budget": self.over_budget,
            "latency_ms_median": float(1e3 * np.median(recent)) if len(recent) else 0.0,
            "latency_ms_p99": float(1e3 * np.percentile(recent, 99)) if len(recent) else 0.0,
            "latency_ms_max": 1e3 * self.max_latency,
            "evaluation_share": self.evaluation_share,
        }

    SCALARS = ("ticks", "scans", "deadline_misses", "over_budget", "max_latency",
               "evaluation_share")


def commit_memory(root, min_bytes: int = 1 << 16) -> int:
    """Write every large preallocated array reachable from ``root``, so the operating system
    backs it with memory now rather than page by page as the run first touches it (zeroed
    arrays are mapped lazily): the resident size is then fixed at start-up. Returns the
    bytes committed."""
    seen, stack, total = set(), [root], 0
    while stack:
        obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            if obj.nbytes >= min_bytes and obj.flags.writeable and obj.base is None:
                flat = obj.reshape(-1).view(np.uint8)
                flat[::4096] += 0  # one write per page (values kept)
                total += obj.nbytes
            continue
        if isinstance(obj, (list, tuple)):
            stack.extend(obj)
        elif hasattr(obj, "__dict__") and type(obj).__module__.startswith("runtime"):
            stack.extend(vars(obj).values())
    return total


class SlamRuntime:
    """One class for the simulator, the serial driver and log replay (see module doc)."""

    def __init__(self, slam_config: SlamConfig | None = None, config: RuntimeConfig | None = None,
                 seed: int = 0, initial_pose=None, clock=time.perf_counter):
        self.config = c = config or RuntimeConfig()
        self.slam = GraphSlam(slam_config, seed=seed, initial_pose=initial_pose)
        self.seed = seed
        self.clock = clock
        points = self.slam.config.max_points
        self.inbox = ScanInbox(points)
        self.back_end = BackEnd(self.slam, c.loop_queue, c.max_deferred_ticks)
        self.stats = RuntimeStats(c.latency_window)
        self.scan = PointScan(points)
        self.odometry = np.zeros(3)
        self.front_end_cost = 0.0  # s per tick at the full evaluation budget (running mean)
        self.last: StepResult | None = None
        # A robot commits its capacities now; a simulator making an env per episode need not.
        commit = c.commit_memory if c.commit_memory is not None else c.schedule == "budgeted"
        self.reserved_bytes = commit_memory(self) if commit else 0

    # ------------------------------------------------------------------ Alg. 4, one tick
    def tick(self, deadline: float | None = None) -> StepResult | None:
        """One period: the newest scan through the front end, then back-end slices in the
        time left. ``deadline`` defaults to one period after the tick starts."""
        c, stats = self.config, self.stats
        lockstep = c.schedule == "lockstep"
        start = 0.0 if lockstep else self.clock()
        stats.ticks += 1
        got, has_odometry, stamp = self.inbox.take(self.scan, self.odometry)  # newest scan
        result = None
        if got:
            share = 1.0 if lockstep else self._evaluation_share(start)
            result = self.slam.track(self.scan, self.odometry if has_odometry else None,
                                     stamp)  # front end: Alg. 5 + Alg. 6, always
            if not lockstep:
                self._learn_front_end_cost(self.clock() - start, share)
            if result.node_added and self.slam.graph.n_nodes > 1:
                self.back_end.enqueue(self.slam.keyframe)  # its Alg. 7, when time allows
        closed = self.slam.loops.accepted
        self.back_end.work(self.clock, None if lockstep else start + c.tick_budget)
        if result is not None and self.slam.loops.accepted > closed:
            result.loop_closed = True
            result.pose = self.slam.pose()  # the closure moved the keyframe
        if not lockstep:
            end = self.clock()
            if end > (start + c.period if deadline is None else deadline):
                stats.deadline_misses += 1
            if got:
                stats.record(end - start, c.tick_budget)
        elif got:
            stats.scans += 1
        self.last = result
        return result

    def warm_up(self, scans: int = 120) -> float:
        """Run every compiled path once — matching, node insertion, loop search, optimisation —
        on a synthetic loop through a throwaway runtime of this configuration, so that no
        kernel is compiled or loaded on the hot path (the first loop closure would otherwise
        cost a deadline or a few MB of resident memory mid-run). Returns the seconds taken."""
        from runtime.synthetic import LoopDrive

        t0 = time.perf_counter()
        c = self.slam.config  # the same kernels on small buffers
        c = replace(c, max_nodes=64, max_edges=256, max_scans=scans + 1,
                    matcher=replace(c.matcher, grid_cells=min(c.matcher.grid_cells, 320)))
        scratch = SlamRuntime(c, RuntimeConfig(schedule="lockstep"), seed=self.seed)
        drive = LoopDrive(self.seed, steps_per_lap=40)
        scan = PointScan(len(drive.angles))
        for k in range(scans):
            _, odometry, ranges = drive.next()
            scan.set_ranges(ranges, drive.angles, 0.05, drive.max_range)
            scratch.process(scan, odometry, float(k))
        if scratch.slam.loops.accepted == 0:
            raise RuntimeError("warm-up closed no loop: the loop-closure kernels stay cold")
        return time.perf_counter() - t0

    def process(self, scan: PointScan, odometry=None, stamp: float = 0.0) -> StepResult | None:
        """Hand over one scan and run a tick on it at once: log replay and the simulator."""
        self.inbox.put_points(scan.buffer, scan.count, stamp, odometry)
        return self.tick()

    def drain(self) -> int:
        """Finish all deferred back-end work now, however long it takes (end of a replay,
        before saving a map). Returns the slices run."""
        return self.back_end.work(self.clock, None)

    def run(self, stop: threading.Event, max_ticks: int | None = None, on_tick=None) -> None:
        """The fixed-rate loop: a tick every period until ``stop`` is set. A tick that overruns
        its deadline is counted; the schedule then skips to the next period boundary instead
        of bunching late ticks together."""
        period = self.config.period
        next_start = self.clock()
        done = 0
        while not stop.is_set() and (max_ticks is None or done < max_ticks):
            wait = next_start - self.clock()
            if wait > 0 and stop.wait(wait):
                break
            result = self.tick(deadline=next_start + period)
            done += 1
            if on_tick is not None:
                on_tick(self, result)
            next_start += period
            late = self.clock() - next_start
            if late > 0:
                next_start += period * (int(late / period) + 1)

    # ------------------------------------------------------------------ adaptive budget
    def _evaluation_share(self, start: float) -> float:
        """The swarm's budget for this tick: what fits in the front end's share of the tick
        budget at the measured cost, within [min_evaluation_share, 1]."""
        c = self.config
        available = start + c.front_end_share * c.tick_budget - self.clock()
        share = 1.0 if self.front_end_cost <= 0 else available / self.front_end_cost
        share = min(max(share, c.min_evaluation_share), 1.0)
        self.slam.matcher.set_evaluation_share(share)
        self.stats.evaluation_share = share
        return share

    def _learn_front_end_cost(self, took: float, share: float) -> None:
        full = took / share
        self.front_end_cost = full if self.front_end_cost <= 0 else \
            0.9 * self.front_end_cost + 0.1 * full

    # ------------------------------------------------------------------ results
    @property
    def status(self) -> str:
        if self.back_end.dropped:
            extra = (f"loop queue full: {self.back_end.dropped} loop searches dropped "
                     f"(raise RuntimeConfig.loop_queue or tick_budget)")
            return extra if self.slam.status == "ok" else f"{self.slam.status}; {extra}"
        return self.slam.status

    def pose(self) -> np.ndarray:
        return self.slam.pose()

    def global_map(self):
        return self.slam.global_map()

    def trajectory(self):
        return self.slam.trajectory()

    def write_results(self, out_dir) -> None:
        """The map (PGM + YAML for ROS map_server, PNG), the trajectory (TUM) and the pose
        graph (g2o) into ``out_dir``, each written atomically."""
        out = Path(out_dir)
        write_map(out / "map", self.global_map())
        write_tum(out / "trajectory.tum", *self.trajectory())
        write_g2o(out / "graph.g2o", self.slam.graph)

    def report(self) -> dict:
        """Statistics a person or a benchmark wants: rate, latency, misses, SLAM, capacity."""
        b, slam = self.back_end, self.slam
        out = self.stats.summary()
        out.update({
            "stale_scans": self.inbox.stale,
            "empty_scans": self.inbox.empty,
            "nodes": int(slam.graph.n_nodes),
            "edges": int(slam.graph.n_edges),
            "loops_accepted": slam.loops.accepted,
            "loop_searches": {"enqueued": b.enqueued, "done": b.searched, "pending": b.size
                              + (b.node >= 0), "dropped": b.dropped},
            "back_end_slices": {"select": int(b.slices[0]), "align": int(b.slices[1]),
                                "close": int(b.slices[2])},
            "deferred_ticks": b.deferred,
            "forced_slices": b.forced,
            "status": self.status,
        })
        return out

    # ------------------------------------------------------------------ sessions
    def save(self, path) -> None:
        """The whole state to one file, atomically (see :mod:`runtime.session`)."""
        from runtime.session import save_session

        save_session(path, self)

    @classmethod
    def resume(cls, path, clock=time.perf_counter) -> SlamRuntime:
        from runtime.session import load_session

        return load_session(path, clock=clock)
