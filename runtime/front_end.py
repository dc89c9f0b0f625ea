"""The front end (local SLAM): track each scan against the keyframe (Alg. 5) and insert nodes
(Alg. 6); docs/method.md §6.1.

    tracked = front_end.track(scan, odometry, stamp)   # → Tracking(pose, node_added, error)

Each scan is aligned with the newest node's scan, the keyframe, rather than with the previous
scan: the search starts from the last estimate moved by the odometry (or, with none, by the
last motion the scans showed), and matching every scan against the same keyframe keeps the
error between two nodes to one match instead of a sum of many. A match that lands too few
points on the keyframe's surfaces, or (with odometry) corrects odometry by more than the
odometry gate, has lost track: odometry stands in, or on scans alone the whole box is searched.
The trajectory — every scan's node, pose in that node's frame and odometry reading — is
recorded here; the scans between nodes are placed from it (docs/method.md §6.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarmslam.runtime.between_scans import (FIRST_READING, NEW_READING, NO_READING,
                                             STALE_READING, BetweenSmoothing, smooth_headings,
                                             smooth_positions)
from swarmslam.runtime.config import FrontEndConfig, SlamConfig
from swarmslam.runtime.degeneracy import Degeneracy
from swarmslam.runtime.loop_closure import propagate_covariance
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.odometry_readings import OdometryReadings
from swarmslam.runtime.odometry_scale import OdometryScale
from swarmslam.runtime.pose import between, compose, interpolate, wrap_angle
from swarmslam.runtime.pose_graph import ODOMETRY, PoseGraph, information_from_sigma
from swarmslam.runtime.scan import PointScan
from swarmslam.runtime.scan_matcher import MatchResult, ScanMatcher
from swarmslam.runtime.sweep_motion import SweepMotion

CAPACITY_STATUS = "capacity reached: localising against the last node, map frozen"
TRAJECTORY_STATUS = "trajectory capacity reached: poses no longer recorded"


def stale_turn_box(config: SlamConfig) -> np.ndarray:
    """The half-widths of a match's box after a stale reading: the guess window's, the
    heading's widened to ``stale_turn_window`` (a turn in place since the reading is not
    known)."""
    g = config.matcher.guess_window
    return np.array([g[0], g[1], max(g[2], config.front_end.stale_turn_window)])


@dataclass
class Tracking:
    pose: np.ndarray  # the scan's pose in the map frame
    node_added: bool
    node: int  # the keyframe after this scan (the new node if one was added)
    error: float  # λ of the alignment (0 for the first scan)


def contradicts_odometry(pose, guess, step, config: FrontEndConfig,
                         heading: bool = True, position: bool = True) -> bool:
    """The odometry gate (docs/method.md §6.1): ``pose`` (a match) corrects ``guess``
    (odometry's prediction, in the same frame; ``step`` the motion it predicted over) by more
    than odometry errs over that motion; ``heading``, ``position``: which of the two are
    judged."""
    if config.odometry_gate is None:
        return False
    gate, share = config.odometry_gate, config.odometry_gate_share
    correction = between(pose, guess)
    allowed = gate[0] + share[0] * math.hypot(step[0], step[1])
    return bool((position and math.hypot(correction[0], correction[1]) > allowed)
                or (heading and abs(correction[2]) > gate[1] + share[1] * abs(step[2])))


def scans_overrule(fit: float, predicted: float, stale: bool, config: FrontEndConfig) -> bool:
    """Whether a match fitting ``fit`` of its points on the keyframe's surfaces fits clearly
    better than odometry's prediction, which fits ``predicted`` (docs/method.md §6.1). Against
    a ``stale`` reading — odometry's last one again, which says nothing of the motion since —
    a gain above ``odometry_gate_fit`` suffices. A new reading is a measurement: the match must
    fit more than ``odometry_gate_explained`` of the points the prediction misses (both fits
    counted within ``odometry_gate_distance``). A fixed gain cannot tell a match that fits
    every point where the prediction misses a tenth (odometry a few degrees off in a turn)
    from one that fits two thirds where it fits half (a hall whose walls fit a slip either
    way)."""
    if stale:
        return fit - predicted > config.odometry_gate_fit
    return fit - predicted > config.odometry_gate_explained * (1.0 - predicted)


def _unbeatable(n: int, gain: float) -> int:
    """The least count ``k`` of ``n`` points whose share leaves no room for a share above it
    by more than ``gain``: ``1 − k/n > gain`` fails, as floating point computes it (``n + 1``
    when no count does). Shares only grow with counts, so any count from ``k`` on fails too."""
    k = max(int((1.0 - gain) * n) - 1, 0)
    while k <= n and 1.0 - k / n > gain:
        k += 1
    return k


class FrontEnd:
    def __init__(self, config: SlamConfig, graph: PoseGraph, nodes: NodeScans, seed: int = 0,
                 initial_pose=None):
        """``initial_pose``: the first scan's pose in the map frame (default: the origin)."""
        self.config = config
        self.graph, self.nodes = graph, nodes
        self.initial_pose = (np.zeros(3) if initial_pose is None
                             else np.array(initial_pose, dtype=np.float64))
        points = config.sensor.max_points
        submap_nodes = config.front_end.submap_nodes
        self.matcher = ScanMatcher(config.matcher, seed=seed)
        self._turn_window = stale_turn_box(config)  # a lost match's box after a stale reading
        self.reference = self.matcher.new_reference()
        self.sweep = SweepMotion(config.sensor, points)
        # The last scan's stamp, and the time since the one before: what the motion the sweep
        # is undistorted by was over.
        self.last_stamp = math.nan
        self.last_interval = math.nan
        self._node_scan = PointScan(points)
        self._submap = PointScan(points * submap_nodes)
        # The submap's nodes and the poses that placed them when it was built (the keyframe's
        # last): a loop closure moves the graph's poses, not the reference tracked against, and
        # a restored session rebuilds the reference the running one had.
        self._submap_nodes = np.zeros(submap_nodes, np.int64)
        self._submap_poses = np.zeros((submap_nodes, 3))
        self._n_submap = 0
        # work buffers of the moved points' test: a range image and a placement per node scan
        self._submap_images = np.zeros((submap_nodes, config.loop_closure.bearing_bins))
        self._submap_placed = np.zeros((submap_nodes, 4))
        # The trajectory: the node each scan was matched to, and its pose in that node's frame.
        n = config.capacity.max_scans
        self.scan_node = np.zeros(n, np.int64)
        self.scan_rel = np.zeros((n, 3))
        self.scan_stamp = np.zeros(n)
        # and what odometry read at it (its kind, and its pose for a new one): the scans
        # between nodes are smoothed with its motion (swarmslam.runtime.between_scans)
        self.scan_reading = np.zeros(n, np.int8)
        self.scan_odometry = np.zeros((n, 3))
        self._reading, self._reading_pose = NO_READING, np.zeros(3)  # the scan being tracked's
        self.n_scans = 0
        self.keyframe = -1
        self.rel = np.zeros(3)  # the current pose in the keyframe's frame
        self.motion = np.zeros(3)  # last motion between scans, for a scan-only prediction
        self.readings = OdometryReadings(config.front_end.stale_motion,
                                         config.front_end.periodic_odometry_ratio,
                                         config.front_end.period_restart_gaps)
        # The pose (in the keyframe's frame) of the scan that brought odometry's last new
        # reading: its motion is predicted from there (docs/method.md §6.1).
        self.odometry_rel = np.zeros(3)
        # Odometry's scale fitted to the matches that pin the motion; the translation the
        # keyframe's interval so far took from odometry along a degenerate axis (the next node
        # edge's odometry part); whether the match at odometry_rel pinned the motion, so that
        # the motion from it can be observed (docs/method.md §6.1, "Odometry's scale").
        c = config.front_end
        self.odometry_scale = OdometryScale(c.odometry_scale_prior_travel,
                                            c.odometry_scale_limits, c.odometry_scale_dead_zone)
        self.odometry_part = np.zeros(2)
        self._pinned_base = False
        self.weak = False  # a match since the last node was replaced by odometry
        self.lost_matches = 0
        self.overruled_odometry = 0  # matches the gate refused that the scans upheld
        self.stale = False  # the scan being tracked brought odometry's previous reading again
        self.rescued_matches = 0  # lost matches found again around the scans' own motion
        self.sought_matches = 0  # of those sought again, the compass search's from headings
        self.degenerate_matches = 0  # matches held to the prediction along a direction
        self.degeneracy = None  # the last match's (swarmslam.runtime.degeneracy), when measured
        # The scan tracked last, and its surfaces listed once a match was checked against it:
        # it holds each wall once where the keyframe's submap may hold one twice
        # (docs/method.md §6.1, "The previous scan"). Listed, not rendered: two matches are
        # read against it, and rendering its field cost up to a tenth of a replay (fr-clinic).
        self._previous = PointScan(points)
        self._previous_surfaces = self.matcher.new_surfaces(points)
        self._previous_listed = False
        self.disowned_matches = 0  # matches the previous scan called lost
        self.held_to_odometry = 0  # matches that gave way to the optimum nearer odometry
        # the trajectory's last estimates (between_scans.BetweenNoise), heading and position
        self.heading_noise = self.position_noise = None
        self.status = "ok"
        self.evaluations = 0  # by the last match (what a viewer plots)

    # ------------------------------------------------------------------ Alg. 5 + Alg. 6
    def track(self, scan: PointScan, odometry=None, stamp: float = 0.0) -> Tracking:
        """Align ``scan`` (robot frame) with the keyframe and add a node when the robot has
        moved far enough; ``odometry`` is the robot's odometry pose at the scan, if any."""
        if self.keyframe < 0:
            self._start(scan, odometry, stamp)
            return Tracking(self.graph.poses[0].copy(), True, 0, 0.0)
        base, step, news = self._prediction(odometry, stamp)
        self.stale = odometry is not None and not news  # the same reading as before
        guess = compose(base, step)
        # Alg. 5, each point turned to the stamp's heading (the sweep, docs/method.md §6.1)
        match, scan = self.sweep.align(self.matcher, scan, self.reference, guess, self.motion,
                                       self.last_interval, self.rel, stamp - self.last_stamp)
        self.evaluations = match.evaluations
        pose = match.pose
        if news:  # (a stale reading predicts no turn to weigh a match against)
            pose = self._nearer_odometry(scan, match, guess, step)
        pinned = pose is match.pose  # (not held to odometry's heading)
        self.degeneracy = None
        if self.config.front_end.degeneracy_ratio > 0:
            pose = self._constrained(scan, pose, guess)
            pinned = pinned and not self.degeneracy.degenerate
        # (after the slide along a degenerate axis is dropped: there the box's edge is no sign)
        inside = not self.matcher.at_box_edge(pose, self.config.front_end.window_margin)
        if self._lost(scan, pose, guess, step, odometry is not None, inside):
            pose = self._recover(scan, pose, guess, step, odometry is not None, inside,
                                 stamp - self.last_stamp)
            pinned = False
        elif self.degeneracy is not None and self.degeneracy.degenerate:
            self._note_odometry_part(guess)
        if news:
            self._observe_scale(pose, base, step, pinned)
        self.motion = between(pose, self.rel)
        self.rel = pose
        if news:
            self.odometry_rel[:] = pose
        node_added = self.insert_node(scan, stamp)  # Alg. 6
        self.last_interval = stamp - self.last_stamp
        self.last_stamp = stamp
        self._record(stamp)
        self._remember(scan)
        return Tracking(self.pose(), node_added, self.keyframe, match.error)

    def pose(self) -> np.ndarray:
        """The latest scan's pose in the map frame."""
        return compose(self.graph.poses[self.keyframe], self.rel)

    def insert_node(self, scan: PointScan, stamp: float) -> bool:
        """Alg. 6: a node (with an odometry edge from the keyframe) once the motion since the
        keyframe exceeds ``node_distance`` or ``node_angle``; it becomes the keyframe."""
        c = self.config.front_end
        if math.hypot(self.rel[0], self.rel[1]) <= c.node_distance and abs(self.rel[2]) <= c.node_angle:
            return False
        g = self.graph
        if g.n_nodes >= g.max_nodes or g.n_edges >= g.max_edges:
            self.status = CAPACITY_STATUS
            return False
        previous = self.keyframe
        info = self.information()
        if self.degeneracy is not None:  # the edge is the last match: weak where it slid
            info = self.degeneracy.information(info)
        z = self.rel.copy()  # odometry's part at the scale the graph's edges hold theirs
        z[:2] += (g.scale - 1.0) * self.odometry_part
        if self.weak:
            info = info / c.weak_information_factor
            self.weak = False
        node = g.add_node(compose(g.poses[previous], z), stamp)
        g.add_edge(previous, node, z, info, ODOMETRY, self.odometry_part)
        self.odometry_part[:] = 0.0
        g.scale_target = self.odometry_scale.scale
        cov = self.nodes.cov
        propagate_covariance(cov[previous], g.poses[previous], z, np.linalg.inv(info),
                             cov[node])
        self.nodes.store(node, scan)
        self.keyframe = node
        self.odometry_rel[:] = between(self.odometry_rel, self.rel)  # the new node's frame
        self.rel = np.zeros(3)
        self.rebuild_reference()
        return True

    def join(self, scan: PointScan, odometry, stamp: float, anchor: int, rel) -> bool:
        """A new session's first node: ``scan`` at ``rel`` in saved node ``anchor``'s frame,
        where localization placed and confirmed it (docs/method.md §9), joined to the anchor
        by an edge; mapping goes on from it. False when the capacity is reached."""
        g = self.graph
        if g.n_nodes >= g.max_nodes or g.n_edges >= g.max_edges:
            self.status = CAPACITY_STATUS
            return False
        rel = np.asarray(rel, np.float64)
        node = g.add_node(compose(g.poses[anchor], rel), stamp)
        info = self.information()
        g.add_edge(anchor, node, rel, info, ODOMETRY)
        cov = self.nodes.cov
        propagate_covariance(cov[anchor], g.poses[anchor], rel, np.linalg.inv(info), cov[node])
        self.nodes.store(node, scan)
        self.keyframe = node
        self.rel[:], self.motion[:] = 0.0, 0.0
        self.weak, self.readings.have = False, False
        self.last_stamp, self.last_interval = stamp, math.nan  # (not the saved session's)
        self._prediction(odometry, stamp)  # the new run's odometry starts here
        self.odometry_part[:] = 0.0
        self._pinned_base = True  # placed where localization confirmed it
        self.rebuild_reference()
        self._record(stamp)
        self._remember(scan)
        return True

    def rebuild_reference(self, placed: bool = False) -> None:
        """The keyframe's reference maps from the stored node scans, placed by the graph's
        poses — or, ``placed``, by the poses kept when it was last built (a restored session
        rebuilds exactly what the running one had)."""
        self.nodes.load(self.keyframe, self._node_scan)
        self.matcher.build_reference(self._submap_of(self.keyframe, placed), self.reference)

    def information(self, loop: bool = False) -> np.ndarray:
        """An edge's information matrix: fixed, from the front end's σ for a node edge and the
        loop closure's for a ``loop`` edge, or Eq. 20's I/σλ² for both (docs/method.md §4.2)."""
        if self.config.front_end.information == "paper":
            sigma = self.matcher.threshold.std
            return information_from_sigma(sigma if sigma > 0 else 1.0)
        c = self.config.loop_closure if loop else self.config.front_end
        return np.diag([1 / c.sigma_translation**2, 1 / c.sigma_translation**2,
                        1 / c.sigma_rotation**2])

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and optimised poses of every scan recorded (docs/method.md §6.2)."""
        n = self.n_scans
        node, rel, stamp = self.scan_node[:n], self.scan_rel[:n], self.scan_stamp[:n]
        step = self._node_steps()
        poses = self._place(node, rel, stamp, step)
        c = self.config.front_end
        if not n:
            return stamp.copy(), poses
        # the scans between nodes smoothed with odometry's motion, heading first (a position's
        # motion is read in the frame its heading gives), where the run shows it pays
        is_node = np.r_[True, node[1:] != node[:-1]]  # a node's first scan is its own
        smoothing = BetweenSmoothing(c.between_significance, c.between_gate, c.between_min_pairs)
        odometry, kind = self.scan_odometry[:n], self.scan_reading[:n]
        rel = rel.copy()
        if c.smooth_between_headings:
            headings, self.heading_noise = smooth_headings(node, rel, is_node, poses, odometry,
                                                           kind, step, smoothing)
            if headings is not None:
                rel[:, 2] = headings
                poses = self._place(node, rel, stamp, step)
        if c.smooth_between_positions:
            positions, self.position_noise = smooth_positions(node, rel, is_node, poses, odometry,
                                                              kind, step, smoothing,
                                                              self.graph.scale)
            if positions is not None:
                rel[:, :2] = positions
                poses = self._place(node, rel, stamp, step)
        return stamp.copy(), poses

    def _node_steps(self) -> np.ndarray:
        """Per node k, the edge that made node k + 1, in k's frame (NaN where none)."""
        g = self.graph
        ij, kind, z = g.ij[: g.n_edges], g.kind[: g.n_edges], g.z[: g.n_edges]
        made = (kind == ODOMETRY) & (ij[:, 1] == ij[:, 0] + 1)  # node k → k + 1 (Alg. 6)
        step = np.full((g.n_nodes, 3), np.nan)
        step[ij[made, 0]] = z[made]
        return step

    def _place(self, node, rel, stamp, step):
        """Each scan placed by the graph: from its node by its pose in the node's frame and,
        with ``spread_corrections``, blended with its place from the next node: a scan
        tracked from node k before node k + 1 was made is placed from k + 1 by that pose taken
        back along the edge that made k + 1, and the two blended by the scan's share of the
        time between the nodes. When the graph bends the chain between k and k + 1, the scans
        between them follow the bend instead of moving with k alone (docs/method.md §6.2)."""
        g = self.graph
        poses = compose(g.poses[node], rel)
        if not self.config.front_end.spread_corrections:
            return poses
        nxt = np.minimum(node + 1, g.n_nodes - 1)
        gap = g.stamps[nxt] - g.stamps[node]
        ok = (node + 1 < g.n_nodes) & ~np.isnan(step[node, 0]) & (gap > 0)
        if not np.any(ok):
            return poses
        k = node[ok]
        from_next = compose(g.poses[k + 1], between(rel[ok], step[k]))  # z⁻¹ ⊕ rel, from k + 1
        share = np.clip((stamp[ok] - g.stamps[k]) / gap[ok], 0.0, 1.0)
        poses[ok] = interpolate(poses[ok], from_next, share)
        return poses

    # ------------------------------------------------------------------ helpers
    def _start(self, scan, odometry, stamp):
        self.graph.add_node(self.initial_pose, stamp)
        self.nodes.store(0, scan)
        self.keyframe = 0
        self.last_stamp = stamp
        self.rebuild_reference()
        self._reading = NO_READING
        if odometry is not None:
            # odometry starts here
            self._note_reading(odometry, *self.readings.read(odometry, stamp))
            self.odometry_rel[:] = 0.0
            self._pinned_base = True  # the first node's own pose
        self._record(stamp)
        self._remember(scan)

    def _submap_of(self, node, placed: bool = False):
        """The newest node's scan, preceded by up to submap_nodes − 1 earlier node scans moved
        into its frame (oldest first, so surfaces join within each scan) by the graph's poses,
        or (``placed``) by those kept from the last build."""
        k = self.config.front_end.submap_nodes
        if k <= 1 or node == 0:
            return self._node_scan
        if not placed:
            first = max(node - k + 1, 0)
            self._n_submap = node + 1 - first
            for i in range(self._n_submap):  # (no temporary array: this runs at every node)
                self._submap_nodes[i] = first + i
            self._submap_poses[: self._n_submap] = self.graph.poses[first : node + 1]
        m = self._n_submap  # the kept poses are rows 0..m-1, the keyframe's the last
        c = self.config.front_end
        if c.drop_moved_points:
            return self.nodes.place_unmoved(self._submap_poses, self._submap_nodes[:m], m - 1,
                                            self._submap, c.track_inlier_distance,
                                            c.track_inlier_slope, self._submap_images,
                                            self._submap_placed)
        return self.nodes.place(self._submap_poses, self._submap_nodes[:m], m - 1,
                                self._submap, rows=range(m))

    def _inliers(self, scan, pose, distance: float | None = None) -> float:
        """The share of ``scan``'s points at ``pose`` within ``distance`` (default
        ``track_inlier_distance``), plus ``track_inlier_slope`` per m of range, of the
        keyframe's surfaces."""
        c = self.config.front_end
        if distance is None:
            distance = c.track_inlier_distance
        return self.matcher.inlier_fraction(scan, self.reference, pose, distance,
                                            c.track_inlier_slope)

    def _lost(self, scan, pose, guess, step, have_odometry: bool, inside: bool) -> bool:
        """The match has lost track: it is pressed against its search box's edge (the optimum
        lies beyond), too few of its points land on the keyframe's surfaces, it contradicts
        odometry (the gate) without :meth:`_overrules` odometry, or the previous scan
        :meth:`_disowns` it (docs/method.md §6.1)."""
        c = self.config.front_end
        if not inside:
            return True
        fit = self._inliers(scan, pose)
        if fit < c.min_track_inliers:
            return True
        if have_odometry and contradicts_odometry(pose, guess, step, c):
            if not self._overrules(scan, pose, fit, guess, step, inside):
                return True
            self.overruled_odometry += 1
        return have_odometry and self._disowns(scan, pose, guess)

    def _disowns(self, scan, pose, guess) -> bool:
        """The previous scan fits odometry's prediction ``guess`` (a new reading) clearly
        better than the match ``pose``: more than ``previous_scan_gain`` of the points better,
        the prediction fitting at least ``previous_scan_fit`` of them. A keyframe's submap
        whose node scans were placed a few degrees apart holds a wall twice, and a scan
        tracked against it fits either copy; the previous scan, moments old, holds the wall
        once (fr-clinic's halls: ±4° a scan, alternating; docs/method.md §6.1)."""
        c = self.config.front_end
        n = scan.count
        if self.stale or c.previous_scan_gain >= 1 or self._previous.count == 0 or n == 0:
            return False  # a stale reading predicts nothing to vouch for
        if not self._previous_listed:
            self.matcher.list_surfaces(self._previous, self._previous_surfaces)
            self._previous_listed = True
        # (the previous scan's pose in the keyframe's frame is self.rel until this scan's is set)
        # The match first: the prediction fits at most every point, so a match fitting
        # ``unbeatable`` of them cannot be disowned and its count stops there. The verdict is
        # the one both counts in full give, in about half the reads (most matches fit 0.9+).
        unbeatable = _unbeatable(n, c.previous_scan_gain)
        matched = self.matcher.surface_inliers(
            scan, self._previous_surfaces, between(pose, self.rel), c.track_inlier_distance,
            c.track_inlier_slope, stop=unbeatable)
        if matched >= unbeatable:
            return False
        fit = matched / n
        predicted = self.matcher.surface_inliers(
            scan, self._previous_surfaces, between(guess, self.rel), c.track_inlier_distance,
            c.track_inlier_slope) / n
        if predicted >= c.previous_scan_fit and predicted - fit > c.previous_scan_gain:
            self.disowned_matches += 1
            return True
        return False

    def _remember(self, scan: PointScan) -> None:
        """Keep ``scan`` as the previous scan (at most ``sensor.max_points`` of it, as a node
        keeps); its surfaces are listed when first needed."""
        n = min(scan.count, self._previous.capacity)
        self._previous.buffer[:n] = scan.buffer[:n]
        self._previous.count = n
        self._previous_listed = False

    def _overrules(self, scan, pose, fit: float, guess, step, inside: bool,
                   stale: bool | None = None) -> bool:
        """A match (``fit``: its share of points on the keyframe's surfaces) is trusted over
        odometry's prediction ``guess`` when it is an optimum inside its search box, not one
        pressed against its edge, fits, and fits clearly better than the prediction does
        (:func:`scans_overrule`) — unless it moves a new reading's position alone, its heading
        within the gate's fixed part (``odometry_gate``'s angle), from a prediction that
        itself tracks (fits ``min_track_inliers``): that match may have slid along a corridor,
        and odometry's position errs little between scans unless its heading does; a
        prediction that would count as lost is no place to slide from (docs/method.md §6.1).
        A stale reading is never held to more than a new one: a match the plain gain refuses
        is judged as against a new reading (a turn started facing a near wall: the prediction
        fits 0.9 of the points, so no gain above 0.1 can be). ``stale``: judge as after a
        stale reading (default: whether this scan's reading is)."""
        c = self.config.front_end
        if not inside or fit < c.min_track_inliers:
            return False
        if stale is None:
            stale = self.stale
        if stale and scans_overrule(fit, self._inliers(scan, guess), True, c):
            return True
        # "alone": the heading within the gate's own part, not its share of the turn: a match
        # turning a fast turn's prediction by 20° is no slide along a corridor, and odometry's
        # position, composed along its heading, is off with it (docs/method.md §6.1)
        if (contradicts_odometry(pose, guess, step, c, heading=False)
                and abs(float(between(pose, guess)[2])) <= c.odometry_gate[1]
                and self._inliers(scan, guess) >= c.min_track_inliers):
            return False
        # a narrower band than a lost match's tells two poses a few degrees apart
        fit, predicted = (self._inliers(scan, p, c.odometry_gate_distance) for p in (pose, guess))
        return scans_overrule(fit, predicted, False, c)

    def _nearer_odometry(self, scan, match, guess, step):
        """Of two optima of the scan cost, the one nearer odometry's heading: a ``match``
        turning the prediction ``guess`` (a new reading) by more than σ
        (``odometry_heading_sigma`` plus ``odometry_gate_share``'s heading share of the turn
        ``step`` predicted) is weighed against the optimum the compass search settles in from
        the prediction, each by its λ plus ``odometry_heading_weight``·(its turn from the
        prediction / σ)². A submap holding a wall twice fits a scan at either copy about
        equally; odometry, which saw no such turn, tells them apart (fr-clinic's halls: ±2–5°
        a scan where odometry drove straight; docs/method.md §6.1). A match that fits clearly
        better, odometry's lag in a fast turn, outweighs the prior."""
        c = self.config.front_end
        turn = float(wrap_angle(match.pose[2] - guess[2]))
        sigma = c.odometry_heading_sigma + c.odometry_gate_share[1] * abs(float(step[2]))
        if c.odometry_heading_weight <= 0 or abs(turn) <= sigma:
            return match.pose
        settled = self.matcher.settle(scan, self.reference, self._at_prediction(guess))
        held = float(wrap_angle(settled.pose[2] - guess[2]))
        weight = c.odometry_heading_weight
        if settled.error + weight * (held / sigma) ** 2 < match.error + weight * (turn / sigma) ** 2:
            self.held_to_odometry += 1
            return settled.pose
        return match.pose

    def _at_prediction(self, guess) -> MatchResult:
        """Odometry's prediction as a match to settle from (its λ is the settling's to find)."""
        return MatchResult(pose=np.asarray(guess, dtype=np.float64), error=math.inf,
                           scan_error=math.inf, used_map=False, iterations=0, evaluations=0)

    def _constrained(self, scan, pose, guess):
        """The match where the scan pins it, the prediction where it does not
        (swarmslam.runtime.degeneracy; docs/method.md §6.1); the next node's edge is weak along it."""
        c = self.config.front_end
        h = self.matcher.curvature(scan, self.reference, pose, c.curvature_step)
        self.degeneracy = Degeneracy(h, c.degeneracy_ratio, c.degenerate_information)
        if self.degeneracy.degenerate:
            self.degenerate_matches += 1
        return self.degeneracy.remap(pose, guess)

    def _recover(self, scan, pose, guess, step, have_odometry: bool, inside: bool,
                 interval: float):
        """The guided match ``pose`` lost track. With odometry, the match is sought again
        around the motion the scans showed last, continued (after a stale reading, over a
        heading window as wide as ``stale_turn_window``), and, when ``pose`` pressed against
        its box's edge (not ``inside``), around ``pose`` itself: the optimum lay beyond the
        box. Odometry that lags the scans and then catches up in a burst (MIT-CSAIL's turns)
        predicts tens of degrees off, and so may the scans' last motion when a turn starts or
        stops (the simulated robot's turns at 2 rad/s, read every 0.8 s: docs/method.md §6.1).
        The better fitting of the matches that fit the scans, and clearly better than
        odometry's prediction, stands; otherwise the prediction stands in (the next node's
        edge weakened): a match that merely fits as well may be shifted along a corridor
        (ACES: eT 0.048 → 0.092 m from one such recovery). When none stands and the reading
        lags its scan (it came again, after more than a scan, or at a period of its own), one
        more match spans every heading the robot can have turned to (:meth:`_turned_search`).
        On scans alone, search the whole box without a guess — the swarm's strength — and
        keep the better fitting of the two."""
        self.lost_matches += 1
        if have_odometry:
            # (a stale reading says nothing of a turn in place since: 2 rad/s for a scan at
            # 4.7 Hz is 24°, beyond the guess window; the scans' last motion may not show it)
            window = self._turn_window if self.stale else None
            # around the lost match too when it pressed against its box: the optimum lay beyond
            priors = (compose(self.rel, self.motion),) + (() if inside else (pose,))
            best, degeneracy = self._best_overruling(scan, priors, window, guess, step)
            # (a reading taken some time before its scan says nothing of a pivot since)
            if best is None and (self.stale or self.readings.reading_scans > 1
                                 or self.readings.period() > 0):
                best, degeneracy = self._turned_search(scan, guess, step, interval, priors,
                                                       window)
            if best is not None:
                self.degeneracy = degeneracy  # (the next node's edge is weak where it slid)
                self.rescued_matches += 1
                return best
            self.weak = True
            return guess
        wide = self.matcher.align_scans(scan, self.reference, None).pose
        return max((pose, wide), key=lambda p: self._inliers(scan, p))

    def _turned_search(self, scan, guess, step, interval: float, searched, window):
        """One match over every heading the robot can have turned to since the last scan, at
        ``pivot_search_rate`` for ``interval`` s either side of that scan's heading, at the
        prediction's position. It stands if it overrules the prediction as after a stale
        reading (:meth:`_best_overruling`) and turns beyond every box searched before (around
        ``guess`` and each of ``searched``, their half-widths ``window``, None: the guess
        window's): within them, the searches there found the scans' optimum, and a wider box
        finds a poorer one in a scan of few surfaces. At 2 Hz a pivot at 2 rad/s turns 57° a
        scan: its first scan lies beyond the box around every prediction when the reading
        lags the turn (docs/method.md §6.1, "Recovery")."""
        c = self.config.front_end
        if c.pivot_search_rate <= 0 or not math.isfinite(interval) or interval <= 0:
            return None, None
        prior = np.array(guess, dtype=np.float64)
        prior[2] = self.rel[2]
        g = self.config.matcher.guess_window
        # (wide enough to hold the prediction's own box too)
        half = max(min(c.pivot_search_rate * interval, math.pi),
                   abs(float(wrap_angle(guess[2] - self.rel[2]))) + g[2])
        self.matcher.keep_stream()
        kept = self.degeneracy, self.degenerate_matches
        # (no heading search here: over every heading a building's right angles offer wrong
        # basins the fine field scores lower, docs/experiments/2026-11-30-recovery-headings.md)
        found = self._best_overruling(scan, (prior,), np.array([g[0], g[1], half]), guess, step,
                                      stale=True, seek=False)
        turn = float((g if window is None else window)[2])
        if found[0] is None or any(abs(float(wrap_angle(found[0][2] - p[2]))) <= turn
                                   for p in (guess, *searched)):
            # nothing kept: the run goes on as without the search
            self.matcher.rewind_stream()
            self.degeneracy, self.degenerate_matches = kept
            return None, None
        return found

    def _sought_match(self, scan, prior, window, seek: bool = True) -> np.ndarray:
        """A lost match sought again around ``prior`` (a box of half-widths ``window``, None:
        the guess window): Alg. 5's, or the compass search's settled from headings
        ``recovery_heading_step`` apart across the same box where it fits clearly better (λ
        below ``recovery_seek_ratio`` of Alg. 5's). The swarm finds its basin on the coarse
        field, which people crowding a pivot can mislead; the fine field tells the turn
        (docs/method.md §6.1, "Recovery"). ``seek`` False: Alg. 5's alone."""
        c = self.config.front_end
        match = self.matcher.align_scans(scan, self.reference, prior, window)
        if seek and c.recovery_heading_step > 0:
            sought = self.matcher.seek_headings(scan, self.reference, c.recovery_heading_step)
            if sought.error < c.recovery_seek_ratio * match.error:
                self.sought_matches += 1
                return sought.pose
        return match.pose

    def _best_overruling(self, scan, priors, window, guess, step, stale=None, seek=True):
        """Of the matches sought around each of ``priors`` (boxes of half-widths ``window``,
        None: the guess window; :meth:`_sought_match`, by ``seek``), the best fitting that
        overrules odometry's prediction ``guess`` (:meth:`_overrules`, judged as after a
        ``stale`` reading if given): ``(match, degeneracy)``, the match None when none does."""
        c = self.config.front_end
        best, best_fit, degeneracy = None, -1.0, None
        for prior in priors:
            match = self._sought_match(scan, prior, window, seek)
            inside_box = not self.matcher.at_box_edge(match, c.window_margin)
            if c.degeneracy_ratio > 0:  # along a degenerate axis, odometry's position stands
                match = self._constrained(scan, match, guess)
                inside_box = not self.matcher.at_box_edge(
                    self.degeneracy.remap(match, prior), c.window_margin)
            fit = self._inliers(scan, match)
            if fit > best_fit and self._overrules(scan, match, fit, guess, step, inside_box,
                                                  stale):
                best, best_fit, degeneracy = match, fit, self.degeneracy
        return best, degeneracy

    def _note_odometry_part(self, guess) -> None:
        """A match that took odometry's prediction ``guess`` along its degenerate axis: the
        step from the last scan's pose the prediction gave there adds to the next node edge's
        odometry part (docs/method.md §6.1, "Odometry's scale")."""
        if not self.config.front_end.calibrate_odometry_scale or self._reading == NO_READING:
            return  # (on scans alone the prediction is the scans' own motion)
        axis = self.degeneracy.axis
        along = float(axis[0] * (guess[0] - self.rel[0]) + axis[1] * (guess[1] - self.rel[1]))
        self.odometry_part += along * axis

    def _observe_scale(self, pose, base, step, pinned: bool) -> None:
        """A new reading's scan: the motion from the scan that brought the last new reading
        (``base``) to ``pose`` against odometry's ``step`` over it, where both matches pinned
        the motion."""
        if pinned and self._pinned_base and self.config.front_end.calibrate_odometry_scale:
            self.odometry_scale.observe(between(pose, base), step)
        self._pinned_base = pinned

    def _prediction(self, odometry, stamp):
        """Where the scan's predicted pose starts (in the keyframe's frame), the motion added
        to it, and whether odometry brought a new reading: a new reading's motion from the
        scan that brought the last new one, a stale one's from the last scan
        (:mod:`swarmslam.runtime.odometry_readings`). Without odometry: the last motion the
        scans showed, continued (docs/method.md §6.1)."""
        step, news, first = self.readings.read(odometry, stamp)
        self._note_reading(odometry, step, news, first)
        if step is None:  # scans only, or a reading the inbox dropped
            return self.rel, self.motion, False
        if not news:
            return self.rel, step, False
        if first:  # odometry starts here
            self.odometry_rel[:] = self.rel
        return self.odometry_rel, step, True

    def _note_reading(self, odometry, step, news, first) -> None:
        """What odometry read at the scan being tracked, for the trajectory."""
        if step is None:
            self._reading = NO_READING
        elif not news:
            self._reading = STALE_READING
        else:
            self._reading = FIRST_READING if first else NEW_READING
            self._reading_pose[:] = odometry

    def _record(self, stamp):
        k = self.n_scans
        if k >= self.scan_node.shape[0]:
            self.status = TRAJECTORY_STATUS
            return
        self.scan_node[k] = self.keyframe
        self.scan_rel[k] = self.rel
        self.scan_stamp[k] = stamp
        self.scan_reading[k] = self._reading
        self.scan_odometry[k] = self._reading_pose
        self.n_scans += 1

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        k = self.n_scans
        return {"matcher": self.matcher.state(), "scan_node": self.scan_node[:k].copy(),
                "scan_rel": self.scan_rel[:k].copy(), "scan_stamp": self.scan_stamp[:k].copy(),
                "scan_reading": self.scan_reading[:k].copy(),
                "scan_odometry": self.scan_odometry[:k].copy(),
                "initial_pose": self.initial_pose.copy(), "rel": self.rel.copy(),
                "motion": self.motion.copy(), "keyframe": self.keyframe,
                "weak": self.weak, "lost_matches": self.lost_matches,
                "degenerate_matches": self.degenerate_matches, "status": self.status,
                "submap_nodes": self._submap_nodes[: self._n_submap].copy(),
                "submap_poses": self._submap_poses[: self._n_submap].copy(),
                "odometry_rel": self.odometry_rel.copy(), **self.readings.state(),
                "odometry_scale": self.odometry_scale.travel.copy(),
                "odometry_part": self.odometry_part.copy(), "pinned_base": self._pinned_base,
                "last_stamp": self.last_stamp, "last_interval": self.last_interval,
                "previous_points": self._previous.points.copy()}

    def restore(self, state: dict) -> None:
        """The state :meth:`state` gave, over a front end of the same configuration built on
        the restored graph and node scans."""
        k = len(state["scan_node"])
        if k > self.scan_node.shape[0]:
            raise ValueError(f"{k} scans exceed the trajectory capacity {self.scan_node.shape[0]}")
        n = self.graph.n_nodes
        if k and (state["scan_node"].min() < 0 or state["scan_node"].max() >= n):
            raise ValueError("the trajectory refers to nodes that do not exist")
        self.matcher.restore(state["matcher"])
        self.scan_node[:k], self.scan_rel[:k] = state["scan_node"], state["scan_rel"]
        self.scan_stamp[:k] = state["scan_stamp"]
        # (saved before odometry's pose was recorded per scan, its heading alone or nothing:
        # none read, none smoothed)
        if "scan_odometry" in state:
            reading = np.asarray(state.get("scan_reading", np.zeros(k, np.int8)))
            odometry = np.asarray(state["scan_odometry"], np.float64)
        else:
            reading, odometry = np.zeros(k, np.int8), np.zeros((k, 3))
        if (reading.shape != (k,) or odometry.shape != (k, 3) or not np.all(np.isfinite(odometry))
                or np.any((reading < NO_READING) | (reading > FIRST_READING))):
            raise ValueError("the trajectory's odometry readings are not one per scan, each "
                             "a known kind with a finite pose")
        self.scan_reading[:k], self.scan_odometry[:k] = reading, odometry
        self.n_scans = k
        self.initial_pose[:] = state["initial_pose"]
        self.rel[:], self.motion[:] = state["rel"], state["motion"]
        self.readings.restore(state)
        self.weak = bool(state["weak"])
        self.lost_matches, self.status = int(state["lost_matches"]), str(state["status"])
        self.degenerate_matches = int(state["degenerate_matches"])
        self.keyframe = int(state["keyframe"])
        # a session saved before stale readings were told apart predicts from its last scan
        self.odometry_rel[:] = state.get("odometry_rel", self.rel)
        # (saved before odometry's scale was fitted: the fit starts afresh)
        if "odometry_scale" in state:
            self.odometry_scale.restore(state["odometry_scale"])
        part = np.asarray(state.get("odometry_part", np.zeros(2)), np.float64)
        if part.shape != (2,) or not np.all(np.isfinite(part)):
            raise ValueError("the keyframe's odometry part is not two finite numbers")
        self.odometry_part[:] = part
        self._pinned_base = bool(state.get("pinned_base", False))
        # (saved before the sweep was undistorted: the trajectory's last stamp; no motion's
        # interval, so the next scan's first pass leaves its sweep as it came)
        self.last_stamp = float(state.get("last_stamp", self.scan_stamp[k - 1] if k else math.nan))
        self.last_interval = float(state.get("last_interval", math.nan))
        if self.keyframe >= 0 and not 0 <= self.keyframe < n:
            raise ValueError(f"keyframe {self.keyframe} is not a stored node")
        members = state.get("submap_nodes", np.zeros(0, np.int64))
        poses = state.get("submap_poses", np.zeros((0, 3)))
        if (len(members) > self._submap_nodes.shape[0] or poses.shape != (len(members), 3)
                or np.any(members < 0) or np.any(members >= n)
                or (len(members) and members[-1] != self.keyframe)
                or not np.all(np.isfinite(poses))):
            raise ValueError("the keyframe's submap is not one this front end builds "
                             "(another submap_nodes?)")
        previous = state.get("previous_points", np.zeros((0, 2)))  # (none: saved before it)
        if (previous.ndim != 2 or previous.shape[1] != 2
                or len(previous) > self._previous.capacity or not np.all(np.isfinite(previous))):
            raise ValueError("the previous scan's points do not fit this front end")
        self._previous.buffer[: len(previous)] = previous
        self._previous.count, self._previous_listed = len(previous), False
        self._n_submap = len(members)
        self._submap_nodes[: self._n_submap] = members
        self._submap_poses[: self._n_submap] = poses
        if self.keyframe >= 0:
            # a session saved before the submap was kept (or of one scan) places it by the graph
            self.rebuild_reference(placed=self._n_submap > 0)
