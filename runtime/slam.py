"""Graph SLAM with swarm scan matching: the whole loop of Alg. 4 (method.md §6).

    slam = GraphSlam(SlamConfig())
    for scan, odometry in stream:
        pose = slam.step(scan, odometry)      # odometry optional, as in the paper
    grid = slam.global_map()

Each scan is aligned (Alg. 5) with the scan of the newest node, its keyframe, rather than with
the previous scan: the search starts from the last estimate moved by the odometry (or, with
none, by the last motion the scans showed), and matching every scan against the same keyframe
keeps the error between two nodes to one match instead of a sum of many. Nodes are added by
Alg. 6, loops sought by Alg. 7 at each new node, and the graph re-optimised when one closes.
Capacities (nodes, edges, points per stored scan, trajectory length) are fixed at start-up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from runtime.graph_optimizer import GaussNewton
from runtime.loop_closure import (
    LoopCloser,
    LoopClosureConfig,
    propagate_covariance,
    relative_guess,
)
from runtime.occupancy_grid import OccupancyGrid
from runtime.pose import between, compose, place_points_nb
from runtime.pose_graph import LOOP, ODOMETRY, PoseGraph, information_from_sigma
from runtime.scan import PointScan
from runtime.scan_matcher import MatcherConfig, ScanMatcher
from runtime.sparse_ldl import FactorCapacityError


@dataclass(frozen=True)
class SlamConfig:
    matcher: MatcherConfig = field(default_factory=MatcherConfig)
    # Alg. 6: a node when the motion since the last one exceeds either.
    node_distance: float = 0.5  # m
    node_angle: float = 0.5  # rad
    # Edge information. "fixed": diag(1/σt², 1/σt², 1/σθ²) with the values below; "paper":
    # Eq. 20, I/σλ², with σλ the matcher's running deviation (unitless: it weighs metres and
    # radians alike and scales χ² by λ's units, so the χ² gates lose their meaning).
    information: str = "fixed"
    sigma_translation: float = 0.05  # m
    sigma_rotation: float = 0.02  # rad
    loop_closure: LoopClosureConfig = field(default_factory=LoopClosureConfig)
    loop_window: tuple[float, float, float] = (2.0, 2.0, 0.5)  # search box around the graph
    # Tracking: a match with fewer inliers than this (points within 0.2 m of the keyframe's
    # surfaces) has lost track: with odometry its prediction stands in and the next node's
    # edge carries 1/weak_information_factor of the information; on scans alone the match is
    # retried over the whole search box.
    min_track_inliers: float = 0.5
    weak_information_factor: float = 9.0
    # With odometry, a match that corrects the odometry's prediction by more than
    # odometry_gate[0] + odometry_gate_share[0]·(odometry's step) in translation, or
    # odometry_gate[1] + odometry_gate_share[1]·|its rotation| in heading, has lost track too:
    # between two scans odometry errs by far less, while a keyframe match that has drifted
    # with shrinking overlap pulls a few degrees per scan towards the keyframe (Intel, turning
    # on the spot: 49° lost over 16 scans). None: no gate.
    odometry_gate: tuple[float, float] | None = (0.15, math.radians(5.0))
    odometry_gate_share: tuple[float, float] = (0.2, 0.35)
    max_nodes: int = 5000
    max_edges: int = 20000
    max_points: int = 1440  # per stored scan
    max_scans: int = 100000  # trajectory length kept (poses per scan)
    # The keyframe reference is built from the last submap_nodes node scans, placed in the
    # newest node's frame by the graph (1: the newest node's scan alone).
    submap_nodes: int = 1
    map_resolution: float = 0.05
    map_max_range: float = 30.0


@dataclass
class StepResult:
    pose: np.ndarray  # the scan's pose in the world (the first scan's frame)
    node_added: bool
    loop_closed: bool
    error: float  # λ of the alignment


class GraphSlam:
    def __init__(self, config: SlamConfig | None = None, seed: int = 0, initial_pose=None):
        """``initial_pose``: the first scan's pose in the map frame (default: the origin, so
        the first scan's frame is the map's; a simulator or a robot that knows where it starts
        passes that pose)."""
        self.config = c = config or SlamConfig()
        self.initial_pose = np.zeros(3) if initial_pose is None else np.array(initial_pose, dtype=np.float64)
        if c.information not in ("fixed", "paper"):
            raise ValueError(f"information must be 'fixed' or 'paper', got {c.information!r}")
        self.matcher = ScanMatcher(c.matcher, seed=seed)
        self.loop_matcher = ScanMatcher(replace(c.matcher, guess_window=c.loop_window), seed=seed + 1)
        self.graph = PoseGraph(c.max_nodes, c.max_edges)
        self.optimizer = GaussNewton(self.graph)
        self.loops = LoopCloser(c.loop_closure)
        self.keyframe_reference = self.matcher.new_reference()
        self.loop_reference = self.loop_matcher.new_reference()
        self.node_points = np.zeros((c.max_nodes, c.max_points, 2))
        self.node_counts = np.zeros(c.max_nodes, np.int64)
        self.node_cov = np.zeros((c.max_nodes, 3, 3))
        self._loop_scan = PointScan(c.max_points)
        self._node_scan = PointScan(c.max_points)
        self._saved_poses = np.zeros((c.max_nodes, 3))
        self._submap = PointScan(c.max_points * max(c.submap_nodes, 1))
        self._loop_submap = PointScan(c.max_points * (2 * c.loop_closure.submap_nodes + 1))
        # Per-scan trajectory: the node a scan was matched to, and its pose in that node's frame.
        self.scan_node = np.zeros(c.max_scans, np.int64)
        self.scan_rel = np.zeros((c.max_scans, 3))
        self.scan_stamp = np.zeros(c.max_scans)
        self.n_scans = 0
        self.keyframe = -1
        self.rel = np.zeros(3)  # the current pose in the keyframe's frame
        self.motion = np.zeros(3)  # last motion between scans, for a scan-only prediction
        self.last_odometry = np.zeros(3)  # odometry at the previous scan (a copy)
        self.have_odometry = False
        self.weak = False  # a match since the last node was replaced by odometry
        self.lost_matches = 0
        self.status = "ok"

    # ------------------------------------------------------------------ Alg. 4
    def step(self, scan: PointScan, odometry=None, stamp: float = 0.0) -> StepResult:
        """Process one scan (points in the robot frame); ``odometry`` is the robot's odometry
        pose at the scan, if any. Returns the scan's estimated pose. The whole of Alg. 4 at
        once; :class:`runtime.fixed_rate.SlamRuntime` runs the same parts sliced across ticks."""
        result = self.track(scan, odometry, stamp)  # Alg. 5 + Alg. 6
        if result.node_added and self.seek_loop_closure(self.keyframe):  # Alg. 7
            result.loop_closed = True
            result.pose = self.pose()
        return result

    def track(self, scan: PointScan, odometry=None, stamp: float = 0.0) -> StepResult:
        """The front end: align the scan with the keyframe (Alg. 5) and add a node when the
        robot has moved far enough (Alg. 6). Loop closure is left to the caller."""
        if self.keyframe < 0:
            self._start(scan, odometry, stamp)
            return StepResult(self.graph.poses[0].copy(), True, False, 0.0)
        step = self._predicted_motion(odometry)
        guess = compose(self.rel, step)
        match = self.matcher.align_scans(scan, self.keyframe_reference, guess)  # Alg. 5
        pose = match.pose
        if (self._inliers(scan, pose) < self.config.min_track_inliers
                or (odometry is not None and self._contradicts_odometry(pose, guess, step))):
            pose = self._recover(scan, pose, guess, odometry is not None)
        self.motion = between(pose, self.rel)
        self.rel = pose
        node_added = self.update_graph(scan, stamp)  # Alg. 6
        self._record(stamp)
        return StepResult(self.pose(), node_added, False, match.error)

    def pose(self) -> np.ndarray:
        return compose(self.graph.poses[self.keyframe], self.rel)

    # ------------------------------------------------------------------ Alg. 6
    def update_graph(self, scan: PointScan, stamp: float) -> bool:
        c = self.config
        if math.hypot(self.rel[0], self.rel[1]) <= c.node_distance and abs(self.rel[2]) <= c.node_angle:
            return False
        g = self.graph
        if g.n_nodes >= g.max_nodes or g.n_edges >= g.max_edges:
            self.status = "capacity reached: localising against the last node, map frozen"
            return False
        previous = self.keyframe
        node = g.add_node(compose(g.poses[previous], self.rel), stamp)
        info = self._information()
        if self.weak:
            info = info / self.config.weak_information_factor
            self.weak = False
        g.add_edge(previous, node, self.rel, info, ODOMETRY)
        propagate_covariance(self.node_cov[previous], g.poses[previous], self.rel,
                             np.linalg.inv(info), self.node_cov[node])
        self._store_scan(node, scan)
        self.keyframe = node
        self.rel = np.zeros(3)
        self.rebuild_keyframe_reference()
        return True

    def rebuild_keyframe_reference(self) -> None:
        """The keyframe's reference maps, from the stored node scans (so that a resumed
        session rebuilds exactly what the running one had)."""
        self._load_scan(self.keyframe, self._node_scan)
        self.matcher.build_reference(self._submap_of(self.keyframe, self._node_scan),
                                     self.keyframe_reference)

    # ------------------------------------------------------------------ Alg. 7
    def seek_loop_closure(self, node: int) -> bool:
        """Alg. 7 for ``node``: align it with up to ``max_attempts`` gated candidates and keep
        the first closure that passes the consistency test."""
        for candidate in self.loop_candidates(node)[: self.loops.config.max_attempts]:
            if self.edges_full():
                return False
            z = self.align_loop(candidate, node)
            if z is not None and self.close_loop(candidate, node, z):
                return True
        return False

    def loop_candidates(self, node: int) -> list[int]:
        """Alg. 7, steps 1–2: nearby nodes inside the 95% ellipse, closest first."""
        return self.loops.candidates(self.graph, self.node_cov, node)

    def align_loop(self, candidate: int, node: int):
        """Alg. 7, step 3a: ``node``'s pose in ``candidate``'s frame by Alg. 5 against the
        submap around the candidate, or None when too few of its points land on its surfaces."""
        loops, scan = self.loops, self._loop_scan
        loops.attempts += 1
        k = loops.config.submap_nodes
        last = min(candidate + k, node - loops.config.exclude_recent)  # never the node's neighbours
        nodes = range(max(candidate - k, 0), max(last, candidate) + 1)
        submap = self._place_scans(nodes, candidate, self._loop_submap)
        reference = self.loop_matcher.build_reference(submap, self.loop_reference)
        self._load_scan(node, scan)
        match = self.loop_matcher.align_scans(scan, reference, relative_guess(self.graph, candidate, node))
        if self.loop_matcher.inlier_fraction(scan, reference, match.pose,
                                             loops.config.inlier_distance) < loops.config.min_inliers:
            loops.rejected_match += 1
            return None
        return match.pose

    def close_loop(self, candidate: int, node: int, z) -> bool:
        """Alg. 7, step 3b: add the loop edge, re-optimise (Eq. 21), and keep the edge only if
        the graph stays consistent; otherwise remove it and restore the poses."""
        g, loops = self.graph, self.loops
        if self.edges_full():
            return False
        total_before = g.chi2()
        saved = self._saved_poses[: g.n_nodes]
        saved[:] = g.poses[: g.n_nodes]
        edge = g.add_edge(candidate, node, z, self._information(), LOOP)
        try:
            self.optimize_graph()
        except FactorCapacityError as exc:  # the graph as it was; localising goes on
            g.remove_last_edge()
            g.poses[: g.n_nodes] = saved
            self.status = f"capacity reached: {exc}"
            return False
        if loops.consistent(g, edge, total_before):
            loops.accepted += 1
            return True
        g.remove_last_edge()
        g.poses[: g.n_nodes] = saved
        loops.rejected_consistency += 1
        return False

    def edges_full(self) -> bool:
        """True (and said in the status) once the edge capacity leaves no room for a loop."""
        if self.graph.n_edges < self.graph.max_edges:
            return False
        self.status = "capacity reached: no more loop closures"
        return True

    def optimize_graph(self):
        return self.optimizer.optimize()

    # ------------------------------------------------------------------ on halt
    def global_map(self) -> OccupancyGrid:
        """Occupancy grid from the optimised node poses and their stored scans."""
        c, g = self.config, self.graph
        n = g.n_nodes
        corners = [g.poses[:n, :2]]
        for k in range(n):
            pts = self.node_points[k, : self.node_counts[k]]
            near = pts[np.hypot(pts[:, 0], pts[:, 1]) <= c.map_max_range]
            if len(near):
                corners.append(compose(g.poses[k], np.c_[near, np.zeros(len(near))])[:, :2])
        grid = OccupancyGrid.covering(np.vstack(corners), c.map_resolution)
        for k in range(n):
            grid.integrate(g.poses[k], self.node_points[k, : self.node_counts[k]], c.map_max_range)
        return grid

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and optimised poses of every scan recorded."""
        n = self.n_scans
        poses = compose(self.graph.poses[self.scan_node[:n]], self.scan_rel[:n])
        return self.scan_stamp[:n].copy(), poses

    # ------------------------------------------------------------------ helpers
    def _start(self, scan, odometry, stamp):
        self.graph.add_node(self.initial_pose, stamp)
        self._store_scan(0, scan)
        self.keyframe = 0
        self.rebuild_keyframe_reference()
        if odometry is not None:
            self.last_odometry[:] = odometry
            self.have_odometry = True
        self._record(stamp)

    def _submap_of(self, node, scan):
        """The newest node's scan, preceded by up to submap_nodes − 1 earlier node scans moved
        into its frame (oldest first, so surfaces join within each scan)."""
        k = self.config.submap_nodes
        if k <= 1 or node == 0:
            return scan
        return self._place_scans(range(max(node - k + 1, 0), node + 1), node, self._submap)

    def _place_scans(self, nodes, frame: int, out: PointScan) -> PointScan:
        """The stored scans of ``nodes``, one after another, in node ``frame``'s frame as the
        graph places them (each scan's points stay together, so surfaces join within it)."""
        n = 0
        for other in nodes:
            n = place_points_nb(self.graph.poses, other, frame, self.node_points[other],
                                self.node_counts[other], out.buffer, n)
        out.count = n
        return out

    def _inliers(self, scan, pose) -> float:
        return self.matcher.inlier_fraction(scan, self.keyframe_reference, pose, 0.2)

    def _contradicts_odometry(self, pose, guess, step) -> bool:
        gate = self.config.odometry_gate
        if gate is None:
            return False
        share = self.config.odometry_gate_share
        correction = between(pose, guess)
        return bool(math.hypot(correction[0], correction[1]) > gate[0] + share[0] * math.hypot(step[0], step[1])
                    or abs(correction[2]) > gate[1] + share[1] * abs(step[2]))

    def _recover(self, scan, pose, guess, have_odometry: bool):
        """The guided match lost track. With odometry, its prediction stands in (the next
        node's edge weakened): a wide search can lock onto a shifted pose along a corridor
        (ACES: eT 0.048 → 0.092 m from one such recovery). On scans alone, search the whole box
        without a guess — the swarm's strength — and keep the better fitting of the two."""
        self.lost_matches += 1
        if have_odometry:
            self.weak = True
            return guess
        wide = self.matcher.align_scans(scan, self.keyframe_reference, None).pose
        return max((pose, wide), key=lambda p: self._inliers(scan, p))

    def _predicted_motion(self, odometry):
        if odometry is None:
            return self.motion  # scans only: assume the last motion continues
        odometry = np.asarray(odometry, dtype=np.float64)
        delta = between(odometry, self.last_odometry) if self.have_odometry else np.zeros(3)
        self.last_odometry[:] = odometry  # copied: callers may reuse their array
        self.have_odometry = True
        return delta

    def _information(self) -> np.ndarray:
        c = self.config
        if c.information == "paper":
            sigma = self.matcher.threshold.std
            return information_from_sigma(sigma if sigma > 0 else 1.0)
        return np.diag([1 / c.sigma_translation**2, 1 / c.sigma_translation**2,
                        1 / c.sigma_rotation**2])

    def _store_scan(self, node, scan):
        n = min(scan.count, self.config.max_points)
        self.node_points[node, :n] = scan.buffer[:n]
        self.node_counts[node] = n

    def _load_scan(self, node, scan):
        n = self.node_counts[node]
        scan.buffer[:n] = self.node_points[node, :n]
        scan.count = n

    def _record(self, stamp):
        k = self.n_scans
        if k >= self.scan_node.shape[0]:
            self.status = "trajectory capacity reached: poses no longer recorded"
            return
        self.scan_node[k] = self.keyframe
        self.scan_rel[k] = self.rel
        self.scan_stamp[k] = stamp
        self.n_scans += 1

