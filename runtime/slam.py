"""Graph SLAM with swarm scan matching: Alg. 4 as a front end and a back end joined by a thin
glue (docs/method.md §6).

    slam = GraphSlam(SlamConfig())
    for scan, odometry in stream:
        result = slam.step(scan, odometry)    # odometry optional, as in the paper
    grid = slam.global_map()

:class:`~swarmslam.runtime.front_end.tracker.FrontEnd` tracks each scan against the keyframe (Alg. 5) and
inserts nodes (Alg. 6); :class:`~swarmslam.runtime.back_end.slices.BackEnd` seeks a loop closure for each new
node (Alg. 7) and re-optimises the graph (Eq. 21). Both work on one pose graph and one store of
node scans. Capacities (nodes, edges, points per stored scan, trajectory length) are fixed at
start-up.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from swarmslam.runtime.back_end.slices import SLICE_NAMES, BackEnd
from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.front_end.tracker import FrontEnd
from swarmslam.runtime.localization.localizer import TRACKING, Localizer
from swarmslam.runtime.localization.map_tracking import SavedMap
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.occupancy_grid import OccupancyGrid
from swarmslam.runtime.pose import between
from swarmslam.runtime.pose_graph import PoseGraph
from swarmslam.runtime.resources import check_memory
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.step_result import StepResult


def screen(odometry, stamp: float) -> None:
    """Raise ValueError unless ``stamp`` and ``odometry`` (x, y, θ, or None) are finite."""
    if not math.isfinite(stamp):
        raise ValueError(f"a scan's stamp must be finite, got {stamp}")
    if odometry is not None and not (math.isfinite(odometry[0]) and math.isfinite(odometry[1])
                                     and math.isfinite(odometry[2])):
        raise ValueError(f"odometry must be finite (None for a scan without it), got "
                         f"{tuple(float(v) for v in odometry)}")


class GraphSlam:
    def __init__(self, config: SlamConfig | None = None, seed: int = 0, initial_pose=None):
        """``initial_pose``: the first scan's pose in the map frame (default: the origin, so
        the first scan's frame is the map's; a simulator or a robot that knows where it starts
        passes that pose)."""
        self.config = c = config or SlamConfig()
        check_memory(c)  # before any buffer is allocated
        self.graph = PoseGraph(c.capacity.max_nodes, c.capacity.max_edges)
        self.nodes = NodeScans(c.capacity.max_nodes, c.sensor.max_points)
        self.front_end = FrontEnd(c, self.graph, self.nodes, seed, initial_pose)
        self.back_end = BackEnd(c, self.graph, self.nodes, self.front_end.information, seed + 1)
        self.locator: Localizer | None = None  # set by rejoin()

    # ------------------------------------------------------------------ Alg. 4
    def step(self, scan: PointScan, odometry=None, stamp: float = 0.0, clock=None,
             budget_end: float | None = None) -> StepResult:
        """One scan through Alg. 4: the front end, then the back end's loop search for a new
        node. Without ``budget_end`` the back end does all its pending work now (the lockstep
        schedule); with it, only the slices that fit before then (``clock`` reads the time).
        A stamp or an odometry reading that is not finite is refused (ValueError), as the
        runtime's inbox refuses it: nothing non-finite reaches the kernels or the trajectory."""
        screen(odometry, stamp)
        if self.locator is not None:  # a resumed session, started at an unknown place
            return self._rejoin(scan, odometry, stamp, clock, budget_end)
        start = clock() if clock is not None else 0.0
        tracked = self.front_end.track(scan, odometry, stamp)  # Alg. 5 + Alg. 6
        took = clock() - start if clock is not None else 0.0
        if tracked.node_added and tracked.node > 0:
            self.back_end.enqueue(tracked.node)  # Alg. 7 for the new node
        closed = self.run_back_end(clock, budget_end)
        pose = self.pose() if closed else tracked.pose
        return StepResult(pose, tracked.node_added, closed, tracked.error, took)

    def rejoin(self, seed: int = 0) -> None:
        """Multi-session mapping (docs/method.md §9): the next scans are first localized in the
        map so far (searched for, then confirmed); the first confirmed pose becomes a node
        joined to the nearest saved one, and mapping goes on from there."""
        saved = SavedMap(self.graph.poses, self.nodes, self.graph.n_nodes)
        self.locator = Localizer(self.config, saved, seed)

    def _rejoin(self, scan, odometry, stamp, clock, budget_end) -> StepResult:
        # with a clock and a budget its global search is spread over ticks (docs/method.md §9)
        located = self.locator.step(scan, odometry, stamp, clock, budget_end)
        if self.locator.phase != TRACKING:
            return located  # no pose yet: nothing is added to the map
        tracker = self.locator.trackers[0]
        anchor = tracker.anchored()  # (a pose committed before any scan was followed has none)
        rel = between(tracker.pose, self.graph.poses[anchor])
        joined = self.front_end.join(scan, odometry, stamp, anchor, rel)
        self.locator = None
        if joined:
            self.back_end.enqueue(self.front_end.keyframe)  # Alg. 7 for the new node
        closed = self.run_back_end(clock, budget_end)
        return StepResult(self.pose(), joined, closed, located.error, located.front_end_seconds)

    def run_back_end(self, clock=None, budget_end: float | None = None) -> bool:
        """Back-end slices (all pending work when ``budget_end`` is None); True if a loop
        closure was kept."""
        revision = self.back_end.revision
        self.back_end.work(clock, budget_end)
        return self.back_end.revision != revision

    # ------------------------------------------------------------------ what consumers read
    def pose(self) -> np.ndarray:
        """The latest scan's pose in the map frame (NaN while a resumed session is localized)."""
        if self.locator is not None:
            return self.locator.pose()
        return self.front_end.pose()

    @property
    def keyframe(self) -> int:
        return self.front_end.keyframe

    @property
    def n_nodes(self) -> int:
        return self.graph.n_nodes

    def node_pose(self, node: int) -> np.ndarray:
        """Node ``node``'s optimised pose (a view)."""
        return self.graph.poses[node]

    def node_poses(self) -> np.ndarray:
        """Every node's optimised pose, ``(n_nodes, 3)`` (a view)."""
        return self.graph.poses[: self.graph.n_nodes]

    def node_scan(self, node: int) -> np.ndarray:
        """Node ``node``'s stored scan points in its own frame (a view)."""
        return self.nodes.scan_points(node)

    @property
    def revision(self) -> int:
        """Changes whenever the optimised node poses change (a loop closure was kept): a
        consumer's map drawn from the nodes is stale when this differs from when it drew."""
        return self.back_end.revision

    @property
    def loops_closed(self) -> int:
        return self.back_end.loops.counts.accepted

    @property
    def status(self) -> str:
        parts = (self.front_end.status, self.back_end.status,
                 "ok" if self.locator is None else self.locator.status)
        said = [s for s in parts if s != "ok"]
        dropped = self.back_end.counts.dropped
        if dropped:
            said.append(f"loop queue full: {dropped} loop searches dropped "
                        f"(raise runtime.loop_queue or runtime.tick_budget)")
        return "; ".join(said) if said else "ok"

    def set_evaluation_share(self, share: float) -> None:
        """The swarm's budget for the next scans, a share (0–1] of the configured one."""
        self.front_end.matcher.set_evaluation_share(share)
        if self.locator is not None:
            self.locator.set_evaluation_share(share)

    def drain(self, clock) -> int:
        """All deferred back-end work now, however long it takes; the slices run."""
        return self.back_end.work(clock, None)

    def report(self) -> dict:
        """The graph, the front end's and the loop search's tallies and the back end's
        slicing, for a run's report."""
        b, g = self.back_end, self.graph
        q = b.counts
        return {
            "nodes": int(g.n_nodes),
            "edges": int(g.n_edges),
            "loops_accepted": self.loops_closed,
            "tracking": asdict(self.front_end.counts),
            "loops": asdict(b.loops.counts),
            "loop_searches": {"enqueued": q.enqueued, "done": q.searched,
                              "pending": b.queue.size + (b.node >= 0), "dropped": q.dropped},
            "back_end_slices": {name: int(v) for name, v in zip(SLICE_NAMES, b.slices)},
            "wide_searches": b.wide.counts(),
            "deferred_ticks": q.deferred,
            "forced_slices": q.forced,
        }

    def draw_map(self, grid: OccupancyGrid, max_range: float | None = None) -> OccupancyGrid:
        """Draw every node's scan from its optimised pose into ``grid`` (added to what is in
        it)."""
        reach = self.config.map.max_range if max_range is None else max_range
        return grid.draw_nodes(self.graph.poses, self.nodes, self.graph.n_nodes, reach)

    def global_map(self) -> OccupancyGrid:
        """An occupancy grid covering the node poses and their scans within the map's reach."""
        g = self.graph
        return OccupancyGrid.of_nodes(g.poses, self.nodes, g.n_nodes, self.config.map)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and optimised poses of every scan recorded."""
        return self.front_end.trajectory()

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {"graph": self.graph.state(), "nodes": self.nodes.state(self.graph.n_nodes),
                "front_end": self.front_end.state(), "back_end": self.back_end.state()}

    def restore(self, state: dict) -> None:
        """The state :meth:`state` gave, into a GraphSlam of the same configuration."""
        self.graph.restore(state["graph"])
        if len(state["nodes"]["counts"]) != self.graph.n_nodes:
            raise ValueError("node scans do not match the graph's nodes")
        self.nodes.restore(state["nodes"])
        self.front_end.restore(state["front_end"])
        self.back_end.restore(state["back_end"])
