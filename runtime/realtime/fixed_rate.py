"""The embedded-style SLAM runtime: Alg. 4 at a fixed rate, every tick within its budget
(docs/runtime.md §1).

    runtime = SlamRuntime(preset("rplidar-a1"))
    runtime.warm_up()                      # every kernel compiled before the first tick
    driver.on_scan = lambda angles, ranges, stamp: runtime.inbox.put_ranges(
        angles=angles, ranges=ranges, stamp=stamp)   # keyword-only: never swapped
    runtime.run(stop_event)                # or call runtime.tick() from your own loop

Each tick takes the newest complete scan (older ones were dropped and counted by the inbox),
runs the front end — Alg. 5's alignment and Alg. 6's node insertion — always, with the swarm's
evaluation budget scaled to the time the tick has, then gives the back end — Alg. 7's loop
search and Eq. 21's optimisation, in slices — whatever time is left. The tick's latency, and
whether it missed its deadline (the next tick's start), are recorded in :class:`RuntimeStats`.

Two schedules (``runtime.schedule``). ``budgeted`` (a robot, or ``bench runtime``) consults the
clock as above. ``lockstep`` never does: every tick runs the whole back end, so a run is
bit-for-bit repeatable from its seed (the simulator, replay, tests) and equal to
:meth:`GraphSlam.step` scan by scan.

Memory: everything that grows with time has a capacity fixed at start-up — nodes, edges and
stored scans (``capacity.max_nodes``/``max_edges``, ``sensor.max_points``), trajectory poses
(``capacity.max_scans``), the loop-search queue (``runtime.loop_queue``); the map is rendered
on demand, at most ``map.max_cells`` a side. When one is reached the runtime keeps localising
and says so in ``status``. Sizing: docs/runtime.md §4.
"""

from __future__ import annotations

import contextlib
import gc
import threading
import time
from dataclasses import replace

import numpy as np

from swarmslam.runtime.realtime import session
from swarmslam.runtime.realtime.allocator import pin_malloc_thresholds
from swarmslam.runtime.config import SensorConfig, SlamConfig, from_dict, override, to_dict
from swarmslam.runtime.realtime.inbox import ScanInbox, real_array
from swarmslam.runtime.localization.localizer import Localizer
from swarmslam.runtime.localization.map_tracking import SavedMap
from swarmslam.runtime.pose_graph import add_scaled
from swarmslam.runtime.matching.scan import PointScan, usable_beams, usable_points
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.step_result import StepResult
from swarmslam.runtime.realtime.warm_up import LoopDrive

PAGE = 4096  # bytes: commit_memory writes one byte per page
# bytes: with commit_memory, glibc's mmap threshold is pinned here and its trim threshold at
# twice it, so that freed memory goes back to the system
MALLOC_MMAP_THRESHOLD = 131_072
WARM_UP_SCANS = 120  # synthetic scans the warm-up runs: every kernel and path compiled once
# The front end's evaluation budget tracks its measured cost: the newest tick weighs this much
# in the running cost, and the budget never drops below this share of the configured one.
FRONT_END_COST_SMOOTHING = 0.1
MIN_EVALUATION_SHARE = 0.25
# The core's objects, in any of its rooms, hold its buffers; GraphSlam lives at the core's top,
# so its package is the prefix of every room's module.
RUNTIME_PACKAGE = GraphSlam.__module__.rpartition(".")[0] + "."


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

    @property
    def last_latency(self) -> float:
        """The latest recorded tick's latency (s); 0 before any."""
        return float(self.latency[(self.scans - 1) % self.latency.shape[0]]) if self.scans else 0.0

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

    def state(self) -> dict:
        return {"latency": self.latency.copy(), **{k: getattr(self, k) for k in self.SCALARS}}

    def restore(self, state: dict) -> None:
        if state["latency"].shape != self.latency.shape:
            raise ValueError(f"latency window {state['latency'].shape[0]} differs from "
                             f"{self.latency.shape[0]}")
        self.latency[:] = state["latency"]
        for name in self.SCALARS:
            setattr(self, name, type(getattr(self, name))(state[name]))


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
                flat[::PAGE] += 0  # one write per page (values kept)
                total += obj.nbytes
            continue
        if isinstance(obj, (list, tuple)):
            stack.extend(obj)
        elif hasattr(obj, "__dict__") and type(obj).__module__.startswith(RUNTIME_PACKAGE):
            stack.extend(vars(obj).values())
    return total


def merged_sensor(saved: SensorConfig, now: SensorConfig) -> SensorConfig:
    """The sensor section to resume a session with when the scanner differs from the one it
    was recorded with: the new scanner's ranges and name, and room for the larger of the two
    scans (a smaller buffer would cut every new rotation short; the stored node scans must
    fit too)."""
    return replace(now, max_points=max(saved.max_points, now.max_points))


class SlamRuntime:
    """One class for the simulator, the serial driver and log replay (see module doc)."""

    def __init__(self, config: SlamConfig | None = None, seed: int = 0, initial_pose=None,
                 clock=time.perf_counter, saved_map: SavedMap | None = None):
        """``saved_map``: localization mode — track in that map, never changing it
        (:class:`swarmslam.runtime.localization.localizer.Localizer`; ``initial_pose`` None: search for it)."""
        self.config = config or SlamConfig()
        rc = self.config.runtime
        self.slam = (GraphSlam(self.config, seed=seed, initial_pose=initial_pose)
                     if saved_map is None else
                     Localizer(self.config, saved_map, seed=seed, initial_pose=initial_pose))
        self.seed = seed
        self.clock = clock
        sensor = self.config.sensor
        self.inbox = ScanInbox(sensor.max_points, sensor.min_range, sensor.max_range,
                               self.config.input)
        self.stats = RuntimeStats(rc.latency_window)
        self.scan = PointScan(sensor.max_points)
        self.odometry = np.zeros(3)
        self.front_end_cost = 0.0  # s per tick at the full evaluation budget (running mean)
        self.last: StepResult | None = None
        self.session_note = ""  # what resuming a session had to change, for the user
        self.autosave: session.Autosave | None = None  # set by run(autosave=...)
        # A robot commits its capacities now; a simulator making an env per episode need not.
        commit = rc.commit_memory if rc.commit_memory is not None else rc.schedule == "budgeted"
        self.committed = bool(commit)
        self.reserved_bytes = commit_memory(self) if commit else 0
        # and keeps what it frees from staying resident (runtime/realtime/allocator.py)
        self.allocator_pinned = bool(commit and pin_malloc_thresholds(MALLOC_MMAP_THRESHOLD))

    # ------------------------------------------------------------------ Alg. 4, one tick
    def tick(self, deadline: float | None = None) -> StepResult | None:
        """One period: the newest scan through the front end, then back-end slices in the
        time left. ``deadline`` defaults to one period after the tick starts."""
        rc, stats = self.config.runtime, self.stats
        lockstep = rc.schedule == "lockstep"
        clock = None if lockstep else self.clock
        start = 0.0 if lockstep else self.clock()
        budget_end = None if lockstep else start + rc.tick_budget
        stats.ticks += 1
        got, has_odometry, stamp = self.inbox.take(self.scan, self.odometry)  # newest scan
        result = None
        if got:
            share = 1.0 if lockstep else self._evaluation_share(start)
            result = self.slam.step(self.scan, self.odometry if has_odometry else None, stamp,
                                    clock, budget_end)  # front end always, back end in the rest
            if not lockstep:
                self._learn_front_end_cost(result.front_end_seconds, share)
        else:
            self.slam.run_back_end(clock, budget_end)
        if not lockstep:
            end = self.clock()
            if end > (start + rc.period if deadline is None else deadline):
                stats.deadline_misses += 1
            if got:
                stats.record(end - start, rc.tick_budget)
        elif got:
            stats.scans += 1
        self.last = result
        return result

    def warm_up(self) -> float:
        """Run every compiled path once — matching, node insertion, loop search, optimisation —
        on a synthetic loop (:class:`swarmslam.runtime.realtime.warm_up.LoopDrive`) through a throwaway runtime of
        this configuration, so that no kernel is compiled or loaded on the hot path (the first
        loop closure would otherwise cost a deadline or a few MB of resident memory mid-run).
        Returns the seconds taken."""
        t0 = time.perf_counter()
        c, scans = self.config, WARM_UP_SCANS
        scratch_config = override(c, {  # the same kernels on small buffers
            "capacity.max_nodes": 64, "capacity.max_edges": 256, "capacity.max_scans": scans + 1,
            "matcher.grid_cells": min(c.matcher.grid_cells, 320),
            # the wide loop search on every node whose ordinary search fails, on a small grid
            "loop_closure.wide_search.after": 1, "loop_closure.wide_search.min_gap": 1,
            "loop_closure.wide_search.radius": 2.0})
        scratch_config = replace(scratch_config, runtime=replace(
            c.runtime, schedule="lockstep", commit_memory=False))
        scratch = SlamRuntime(scratch_config, seed=self.seed)
        drive = LoopDrive(self.seed, steps_per_lap=40)
        scan = PointScan(len(drive.angles))
        for k in range(scans):
            _, odometry, ranges = drive.next()
            scan.set_ranges(ranges, drive.angles, 0.05, drive.max_range)
            scratch.process(scan, odometry, float(k))
        # what the inbox counts a scan cut to max_points by, which no scan here reaches
        usable_beams(ranges, drive.angles, 0.05, drive.max_range)
        usable_points(scan.buffer, scan.count, scan.sweep)
        usable_points(scan.buffer, scan.count, None)
        # odometry's scale brought into a trial, which a drive too short to fit one may not do
        graph = scratch.slam.graph
        add_scaled(graph.z, graph.odometry_part, 0.0, 0, 0)
        if scratch.slam.loops_closed == 0:
            raise RuntimeError("warm-up closed no loop: the loop-closure kernels stay cold")
        if scratch.slam.back_end.wide.searches == 0:
            raise RuntimeError("warm-up ran no wide loop search: its kernels stay cold")
        if self.localizing:  # the global search and map tracking too
            self.slam.warm_up()
        return time.perf_counter() - t0

    def process(self, scan, odometry=None, stamp: float = 0.0) -> StepResult | None:
        """Hand over one scan and run a tick on it at once: log replay and the simulator.
        ``scan``: a :class:`PointScan`, or an (N, 2) array of points (robot frame, m);
        ``odometry``: the robot's (x, y, θ) at the scan, if known."""
        if isinstance(scan, PointScan):
            self.inbox.put_points(scan.buffer, scan.count, stamp, odometry, scan.sweep)
        else:
            points = real_array("scan", scan, 2)
            self.inbox.put_points(points, points.shape[0], stamp, odometry)
        return self.tick()

    def drain(self) -> int:
        """Finish all deferred back-end work now, however long it takes (end of a replay,
        before saving a map). Returns the slices run."""
        return self.slam.drain(self.clock)

    def run(self, stop: threading.Event, max_ticks: int | None = None, on_tick=None,
            autosave=None) -> None:
        """The fixed-rate loop: a tick every period until ``stop`` is set. A tick that overruns
        its deadline is counted; the schedule then skips to the next period boundary instead
        of bunching late ticks together. ``autosave``: a session file written every
        ``runtime.autosave_seconds`` (:class:`swarmslam.runtime.realtime.session.Autosave`) while mapping."""
        period = self.config.runtime.period
        saver = None
        if autosave is not None and not self.localizing:
            saver = session.Autosave(autosave, self.config.runtime.autosave_seconds, self.clock)
        self.autosave = saver
        with self.collector_held():
            self._loop(stop, period, max_ticks, on_tick, saver)

    @contextlib.contextmanager
    def collector_held(self):
        """While a committing runtime ticks (:meth:`run`), what was alive before is kept out of
        the garbage collector's full passes, which otherwise walk every module and dispatcher
        (one stalls a tick by tens of ms); it is handed back at the end (docs/runtime.md
        §4). A runtime that commits nothing, or a hold already in place, leaves it alone."""
        frozen = self.committed and gc.get_freeze_count() == 0
        if frozen:
            gc.collect()
            gc.freeze()
        try:
            yield
        finally:
            if frozen:
                gc.unfreeze()

    def _loop(self, stop, period, max_ticks, on_tick, saver) -> None:
        next_start = self.clock()
        done = 0
        while not stop.is_set() and (max_ticks is None or done < max_ticks):
            wait = next_start - self.clock()
            if wait > 0 and stop.wait(wait):
                break
            result = self.tick(deadline=next_start + period)
            done += 1
            # between ticks, in the time left of this period; not before the first scan (a
            # silent scanner's empty map must not replace the session file already there)
            if saver is not None and self.stats.scans:
                saver.maybe(self.state)
            if on_tick is not None:
                on_tick(self, result)
            next_start += period
            late = self.clock() - next_start
            if late > 0:
                next_start += period * (int(late / period) + 1)

    # ------------------------------------------------------------------ adaptive budget
    def _evaluation_share(self, start: float) -> float:
        """The swarm's budget for this tick: what fits in the front end's share of the tick
        budget at the measured cost, within [MIN_EVALUATION_SHARE, 1]."""
        rc = self.config.runtime
        available = start + rc.front_end_share * rc.tick_budget - self.clock()
        share = 1.0 if self.front_end_cost <= 0 else available / self.front_end_cost
        share = min(max(share, MIN_EVALUATION_SHARE), 1.0)
        self.slam.set_evaluation_share(share)
        self.stats.evaluation_share = share
        return share

    def _learn_front_end_cost(self, took: float, share: float) -> None:
        full = took / share
        a = FRONT_END_COST_SMOOTHING
        self.front_end_cost = full if self.front_end_cost <= 0 else \
            (1.0 - a) * self.front_end_cost + a * full

    # ------------------------------------------------------------------ results
    @property
    def status(self) -> str:
        return self.slam.status

    def pose(self) -> np.ndarray:
        return self.slam.pose()

    def global_map(self):
        return self.slam.global_map()

    def trajectory(self):
        return self.slam.trajectory()

    def report(self) -> dict:
        """Statistics a person or a benchmark wants: rate, latency, misses, SLAM, capacity."""
        out = self.stats.summary()
        out.update({**self.inbox.counts(), **self.slam.report(), "status": self.status})
        if self.autosave is not None:
            out.update({"autosaves": self.autosave.saves,
                        "autosave_error": self.autosave.error})
        return out

    # ------------------------------------------------------------------ sessions
    def state(self) -> dict:
        """Everything needed to continue this run (see :mod:`swarmslam.runtime.realtime.session`)."""
        return {"config": to_dict(self.config), "seed": self.seed, "slam": self.slam.state(),
                "stats": self.stats.state(), "inbox": self.inbox.state(),
                "front_end_cost": self.front_end_cost}

    def restore(self, state: dict) -> None:
        self.slam.restore(state["slam"])
        self.stats.restore(state["stats"])
        self.inbox.restore(state["inbox"])
        self.front_end_cost = float(state["front_end_cost"])

    @property
    def localizing(self) -> bool:
        """Localization mode: the map is a saved one and stays as it was."""
        return isinstance(self.slam, Localizer)

    def save(self, path) -> None:
        """The whole state to one file, atomically (see :mod:`swarmslam.runtime.realtime.session`)."""
        if self.localizing:
            raise ValueError("a localization run changes no session: its map is read-only "
                             "(save the trajectory instead)")
        session.write_session(path, self.state())

    @classmethod
    def resume(cls, path, clock=time.perf_counter, anywhere: bool = False,
               changes: dict | None = None, more_scans: int = 0,
               sensor: SensorConfig | None = None) -> SlamRuntime:
        """A runtime continuing the session saved at ``path``. ``anywhere``: the new run may
        start at any place in the saved map — it is localized first, then joined to the graph
        (multi-session mapping, :meth:`GraphSlam.rejoin`). ``changes``: configuration
        overrides (dotted keys). ``more_scans``: the trajectory keeps the saved scans' poses and
        this many more (its capacity grows if need be). ``sensor``: the scanner the run reads
        now, if it may differ from the session's (see :func:`merged_sensor`)."""

        def build(state, config):
            kept = len(state["slam"]["front_end"]["scan_node"]) + more_scans
            if kept > config.capacity.max_scans:
                config = override(config, {"capacity.max_scans": kept})
            runtime = cls(config, seed=int(state["seed"]), clock=clock)
            runtime.restore(state)  # the initial pose too
            if anywhere:
                runtime.slam.rejoin(runtime.seed)
            return runtime

        return cls._from_session(path, build, changes, sensor)

    @classmethod
    def localize(cls, path, initial_pose=None, clock=time.perf_counter,
                 changes: dict | None = None, sensor: SensorConfig | None = None
                 ) -> SlamRuntime:
        """Localization mode in the map saved at ``path`` (read, never written): from
        ``initial_pose`` if known, else the global search finds it. ``sensor``: as in
        :meth:`resume`."""

        def build(state, config):
            saved = SavedMap.from_state(state["slam"], config.sensor.max_points)
            return cls(config, seed=int(state["seed"]), initial_pose=initial_pose, clock=clock,
                       saved_map=saved)

        return cls._from_session(path, build, changes, sensor)

    @staticmethod
    def _from_session(path, build, changes, sensor=None):
        state = session.read_session(path)
        try:
            config = from_dict(state["config"])
            config = override(config, changes) if changes else config
            note = ""
            if sensor is not None and sensor != config.sensor:
                merged = merged_sensor(config.sensor, sensor)
                note = (f"the session was recorded with {config.sensor.name} "
                        f"({config.sensor.max_points} points per scan); re-sized for "
                        f"{sensor.name}: {merged.max_points} points, ranges "
                        f"{merged.min_range:g}–{merged.max_range:g} m")
                config = replace(config, sensor=merged)
            runtime = build(state, config)
            runtime.session_note = note
            return runtime
        except KeyError as exc:
            raise session.SessionError(f"{path}: missing field {exc.args[0]!r}") from None
        except (ValueError, IndexError, TypeError) as exc:
            raise session.SessionError(f"{path}: {exc}") from None
