"""Graph SLAM with swarm scan matching: Alg. 4 as a front end and a back end joined by a thin
glue (docs/method.md §6).

    slam = GraphSlam(SlamConfig())
    for scan, odometry in stream:
        result = slam.step(scan, odometry)    # odometry optional, as in the paper
    grid = slam.global_map()

:class:`~runtime.front_end.FrontEnd` tracks each scan against the keyframe (Alg. 5) and
inserts nodes (Alg. 6); :class:`~runtime.back_end.BackEnd` seeks a loop closure for each new
node (Alg. 7) and re-optimises the graph (Eq. 21). Both work on one pose graph and one store of
node scans. Capacities (nodes, edges, points per stored scan, trajectory length) are fixed at
start-up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.back_end import BackEnd
from runtime.config import SlamConfig
from runtime.front_end import FrontEnd
from runtime.node_scans import NodeScans
from runtime.occupancy_grid import OccupancyGrid
from runtime.pose_graph import PoseGraph
from runtime.scan import PointScan


@dataclass
class StepResult:
    pose: np.ndarray  # the scan's pose in the map frame, after this step's back-end work
    node_added: bool
    loop_closed: bool  # a loop closure was kept during this step
    error: float  # λ of the front end's alignment
    front_end_seconds: float = 0.0  # measured only when a clock is given


class GraphSlam:
    def __init__(self, config: SlamConfig | None = None, seed: int = 0, initial_pose=None):
        """``initial_pose``: the first scan's pose in the map frame (default: the origin, so
        the first scan's frame is the map's; a simulator or a robot that knows where it starts
        passes that pose)."""
        self.config = c = config or SlamConfig()
        self.graph = PoseGraph(c.capacity.max_nodes, c.capacity.max_edges)
        self.nodes = NodeScans(c.capacity.max_nodes, c.sensor.max_points)
        self.front_end = FrontEnd(c, self.graph, self.nodes, seed, initial_pose)
        self.back_end = BackEnd(c, self.graph, self.nodes, self.front_end.information, seed + 1)

    # ------------------------------------------------------------------ Alg. 4
    def step(self, scan: PointScan, odometry=None, stamp: float = 0.0, clock=None,
             budget_end: float | None = None) -> StepResult:
        """One scan through Alg. 4: the front end, then the back end's loop search for a new
        node. Without ``budget_end`` the back end does all its pending work now (the lockstep
        schedule); with it, only the slices that fit before then (``clock`` reads the time)."""
        start = clock() if clock is not None else 0.0
        tracked = self.front_end.track(scan, odometry, stamp)  # Alg. 5 + Alg. 6
        took = clock() - start if clock is not None else 0.0
        if tracked.node_added and tracked.node > 0:
            self.back_end.enqueue(tracked.node)  # Alg. 7 for the new node
        closed = self.run_back_end(clock, budget_end)
        pose = self.pose() if closed else tracked.pose
        return StepResult(pose, tracked.node_added, closed, tracked.error, took)

    def run_back_end(self, clock=None, budget_end: float | None = None) -> bool:
        """Back-end slices (all pending work when ``budget_end`` is None); True if a loop
        closure was kept."""
        revision = self.back_end.revision
        self.back_end.work(clock, budget_end)
        return self.back_end.revision != revision

    # ------------------------------------------------------------------ what consumers read
    def pose(self) -> np.ndarray:
        """The latest scan's pose in the map frame."""
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
        return self.back_end.loops.accepted

    @property
    def status(self) -> str:
        said = [s for s in (self.front_end.status, self.back_end.status) if s != "ok"]
        return "; ".join(said) if said else "ok"

    def draw_map(self, grid: OccupancyGrid, max_range: float | None = None) -> OccupancyGrid:
        """Draw every node's scan from its optimised pose into ``grid`` (added to what is in
        it)."""
        reach = self.config.map.max_range if max_range is None else max_range
        for k in range(self.graph.n_nodes):
            grid.integrate(self.graph.poses[k], self.node_scan(k), reach)
        return grid

    def global_map(self) -> OccupancyGrid:
        """An occupancy grid covering the node poses and their scans within the map's reach."""
        m, g = self.config.map, self.graph
        corners = self.nodes.extent_points(g.poses, g.n_nodes, m.max_range)
        grid = OccupancyGrid.covering(corners, m.resolution, m.margin, m.max_cells)
        return self.draw_map(grid)

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
