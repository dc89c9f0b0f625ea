"""One pose followed through a saved map: Alg. 5 against the saved node scans nearest it
(docs/method.md §9).

    tracker = MapTracker(saved, matcher, config)
    tracker.start(pose)
    fit = tracker.follow(scan, step, news, stale, interval=dt)  # share of points on the map

The reference is the ``localization.submap_nodes`` saved node scans nearest the pose (heading
counted as distance, since a scan sees what its node faced), placed in the nearest one's
frame — the anchor. It is rebuilt only when another node becomes nearer than the anchor by
``REANCHOR_DISTANCE``, so, as in the front end, most scans match a reference built earlier.
A match that fits poorly is replaced by the prediction (the scan may be blocked by people or
furniture the map does not have); ``lost_scans`` such matches in a row mean the pose is lost.
With ``gate`` (a committed pose, or a candidate being confirmed), a match that odometry
contradicts is refused too, as the front end refuses one, but for at most ``max_held_scans``
scans in a row (:meth:`MapTracker._gated`). A rotating scanner's sweep is undone as the
front end undoes it (docs/method.md §6.1, "The sweep"), given the time since the scan before.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
from numba import njit

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.matching.degeneracy import Degeneracy
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.front_end.odometry_gate import contradicts_odometry
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.front_end.recovery import stale_turn_box
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import CURVATURE_STEP, INLIER_SLOPE, ScanMatcher
from swarmslam.runtime.matching.sweep_motion import SweepMotion


@njit(cache=True)
def node_distance2(poses, m, x, y, theta, heading_weight):
    """Squared distance from ``(x, y, theta)`` to node ``m``, the heading difference ×
    ``heading_weight`` counted as distance."""
    d = (theta - poses[m, 2] + math.pi) % (2.0 * math.pi) - math.pi
    return (poses[m, 0] - x) ** 2 + (poses[m, 1] - y) ** 2 + (heading_weight * d) ** 2


@njit(cache=True)
def nearest_nodes(poses, n, x, y, theta, heading_weight, out, out_d2):
    """The ``len(out)`` nodes of ``poses[:n]`` nearest ``(x, y, theta)`` (heading difference
    × ``heading_weight`` counted as distance), nearest first, into ``out`` / ``out_d2``.
    Returns how many."""
    k = 0
    size = out.shape[0]
    for m in range(n):
        d2 = node_distance2(poses, m, x, y, theta, heading_weight)
        if k == size and d2 >= out_d2[k - 1]:
            continue
        if k < size:
            k += 1
        q = k - 1
        while q > 0 and out_d2[q - 1] > d2:
            out[q], out_d2[q] = out[q - 1], out_d2[q - 1]
            q -= 1
        out[q], out_d2[q] = m, d2
    return k


class SavedMap:
    """A saved session's node poses and node scans, read-only (the map localization uses)."""

    def __init__(self, poses, nodes: NodeScans, n_nodes: int):
        if n_nodes < 1:
            raise ValueError("the saved map has no nodes")
        self.poses = np.array(poses[:n_nodes], dtype=np.float64)
        self.nodes = NodeScans(n_nodes, nodes.max_points)
        self.nodes.points[:] = nodes.points[:n_nodes]
        self.nodes.counts[:] = nodes.counts[:n_nodes]
        self.nodes.cov[:] = nodes.cov[:n_nodes]
        self.n_nodes = n_nodes
        for a in (self.poses, self.nodes.points, self.nodes.counts, self.nodes.cov):
            a.flags.writeable = False  # a write anywhere is an error, not a changed map

    @classmethod
    def from_state(cls, slam_state: dict, max_points: int) -> SavedMap:
        """From a :meth:`swarmslam.runtime.slam.GraphSlam.state` (a session's ``slam`` entry)."""
        poses = np.asarray(slam_state["graph"]["poses"], dtype=np.float64)
        n = len(poses)
        if poses.ndim != 2 or poses.shape[1] != 3:
            raise ValueError(f"node poses have shape {poses.shape}, expected (n, 3)")
        if not np.all(np.isfinite(poses)):
            raise ValueError("the graph holds non-finite poses")
        nodes = NodeScans(max(n, 1), max_points)
        nodes.restore(slam_state["nodes"])
        if len(slam_state["nodes"]["counts"]) != n:
            raise ValueError("node scans do not match the graph's nodes")
        return cls(poses, nodes, n)

    def digest(self) -> str:
        """SHA-256 of the poses and scans (equal before and after a run: nothing changed)."""
        h = hashlib.sha256()
        for a in (self.poses, self.nodes.points, self.nodes.counts):
            h.update(a.tobytes())
        return h.hexdigest()


# A confirmation's pinned matches are judged by the front end's degeneracy ratio, or this
# when that test is off (0): a corridor is not a place.
MIN_PINNED_RATIO = 0.12
# m per rad: a saved node's heading difference counts as this much distance when the nearest
# are chosen (a scan sees what its node faced)
HEADING_WEIGHT = 2.0
# m: the reference is rebuilt once a saved node is this much nearer than its anchor (most scans
# then match a reference built earlier, as in the front end)
REANCHOR_DISTANCE = 0.3


class MapTracker:
    """One pose hypothesis tracked in a :class:`SavedMap` (see module doc)."""

    def __init__(self, saved: SavedMap, matcher: ScanMatcher, config: SlamConfig):
        self.saved, self.matcher, self.config = saved, matcher, config
        k = config.localization.submap_nodes
        self.reference = matcher.new_reference()
        self._submap = PointScan(saved.nodes.max_points * k)
        self._near = np.zeros(min(k, saved.n_nodes), np.int64)
        self._near_d2 = np.zeros(len(self._near))
        self.pose = np.zeros(3)  # in the map frame
        self.motion = np.zeros(3)  # the last scan-to-scan motion, for a scan-only prediction
        # the pose of the scan that brought odometry's last new reading (if one did since the
        # start): the next new reading's motion is added to it (docs/method.md §6.1)
        self.odometry_pose = np.zeros(3)
        self.odometry_pose_known = False
        self.last_interval = 0.0  # s from the scan before the last to the last (0: unknown)
        self.sweep = SweepMotion(config.sensor, config.sensor.max_points)
        self._turn_window = stale_turn_box(config)  # the box after a stale reading
        self.anchor = -1
        self.poor = 0  # poor matches in a row
        self.followed = False  # the pose came from a match, not from a search or a rewind
        self.held = False  # the last match was refused by the odometry gate
        self.n_held = 0  # matches refused in a row
        self.unfixed = np.zeros(3)  # odometry's path since the last match kept (m, 0, 0)
        self.fit_sum, self.fits = 0.0, 0  # since start()
        self.pinned = 0  # matches measured since start() that pinned every direction
        self.error = 0.0  # λ of the last match

    def start(self, pose) -> None:
        self._restart(pose, 0.0)
        self.fit_sum, self.fits = 0.0, 0
        self.pinned = 0

    def rewind(self, pose, motion) -> None:
        """Back at ``pose``, the scan :meth:`start` began at, after following earlier scans
        backward: their fits count, the rest starts afresh (``motion``: the last scan-to-scan
        motion going forward)."""
        self._restart(pose, motion)

    def _restart(self, pose, motion) -> None:
        """At ``pose``, not yet tracked: no reference, no poor match, nothing held."""
        self.pose[:] = pose
        self.motion[:] = motion
        self.odometry_pose_known = False
        self.last_interval = 0.0
        self.anchor = -1
        self.poor, self.n_held = 0, 0
        self.followed = self.held = False
        self.unfixed[:] = 0.0

    @property
    def mean_fit(self) -> float:
        return self.fit_sum / self.fits if self.fits else 0.0

    def follow(self, scan: PointScan, step=None, news: bool = False, stale: bool = False,
               gate: bool = False, measure: bool = False, interval: float = 0.0) -> float:
        """Alg. 5 for ``scan`` from the pose moved by ``step``: odometry's motion, from the
        pose of the scan that brought its last new reading if it is a new one (``news``; the
        last scan's when none came since this pose was started), else from the last scan's
        (:mod:`swarmslam.runtime.front_end.odometry_readings`); None: the last motion again. A
        ``stale`` reading (the last one again) widens the heading's search to
        ``recovery.stale_turn_window``. With ``gate``, a match odometry contradicts is
        refused (:meth:`_gated`); with ``measure``, a match that pins every direction (not
        degenerate, docs/method.md §6.1) is counted in ``pinned``. ``interval``: s since the
        scan followed before (0: not known, or scans followed backward), over which the robot's
        turn is undone from the scan's sweep. Returns the fit (inlier share) of the pose
        taken."""
        c = self.config.front_end
        news = news and step is not None
        # the last pose is a match kept: not searched for, given, rewound to, or odometry's
        # standing in (a few degrees off in a turn)
        kept = self.followed and not self.held and self.poor == 0
        base = self.odometry_pose if news and self.odometry_pose_known else self.pose
        predicted = compose(base, self.motion if step is None else step)
        self._reanchor(predicted)
        origin = self.saved.poses[self.anchor]
        guess = between(predicted, origin)
        # The turn over the sweep is the match's from the last pose, if that was a match kept
        # (another would put its own error into every point).
        interval = interval if kept else 0.0
        # (a stale reading says nothing of a turn in place since: 23° a scan in a pivot is
        # beyond the guess window, and odometry's next reading comes only after it)
        window = self._turn_window if stale else None
        match, scan = self.sweep.align(self.matcher, scan, self.reference, guess, self.motion,
                                       self.last_interval, between(self.pose, origin), interval,
                                       window)
        pose = match.pose
        self.held = False
        if gate and step is not None and self.followed:
            pose = self._gated(pose, guess, step)
        fit = self.matcher.inlier_fraction(scan, self.reference, pose,
                                           c.track_inlier_distance, INLIER_SLOPE)
        if measure and fit >= c.min_track_inliers:
            h = self.matcher.curvature(scan, self.reference, pose, CURVATURE_STEP)
            self.pinned += not Degeneracy(h, max(c.degeneracy_ratio, MIN_PINNED_RATIO),
                                          c.degenerate_information).degenerate
        if fit < c.min_track_inliers:
            self.poor += 1
            pose = guess  # the prediction stands in, as in the front end
        else:
            self.poor = 0
        pose = compose(origin, pose)
        self.followed = True
        self.last_interval = interval if not self.held and self.poor == 0 else 0.0
        self.motion[:] = between(pose, self.pose)
        self.pose[:] = pose
        if news:
            self.odometry_pose[:] = pose
            self.odometry_pose_known = True
        self.fit_sum += fit
        self.fits += 1
        self.error = match.error
        return fit

    def _gated(self, pose, guess, step):
        """The match, or odometry's prediction if the match places the scan farther from it
        than odometry errs (the front end's odometry gate, docs/method.md §9): a match that
        fits can still slide, along a corridor or onto a wall drawn twice (most of a metre from a
        pose a millimetre off). Position only: on a fast turn odometry's heading can be a scan
        out of step, and walls pin a match's heading. What the
        gate allows grows with odometry's motion since the last match kept, and at most
        ``max_held_scans`` matches in a row are refused: after a creep of small steps the
        match that brings the pose back is a large correction too."""
        self.unfixed[0] += math.hypot(step[0], step[1])
        self.held = (self.n_held < self.config.localization.max_held_scans
                     and contradicts_odometry(pose, guess, self.unfixed, self.config.front_end,
                                              heading=False))
        if not self.held:
            self.n_held = 0
            self.unfixed[:] = 0.0
            return pose
        self.n_held += 1
        return guess

    def anchored(self) -> int:
        """The saved node the pose is tracked from, chosen now if none is yet (a pose
        committed before it followed a scan)."""
        if self.anchor < 0:
            self._reanchor(self.pose)
        return self.anchor

    def _reanchor(self, pose) -> None:
        lc = self.config.localization
        n = nearest_nodes(self.saved.poses, self.saved.n_nodes, pose[0], pose[1], pose[2],
                          HEADING_WEIGHT, self._near, self._near_d2)
        if self.anchor >= 0:
            held = math.sqrt(node_distance2(self.saved.poses, self.anchor, pose[0], pose[1],
                                            pose[2], HEADING_WEIGHT))
            if math.sqrt(self._near_d2[0]) + REANCHOR_DISTANCE >= held:
                return
        self.anchor = int(self._near[0])
        self._near[:n].sort()  # oldest first, so surfaces join within each scan
        submap = self.saved.nodes.place(self.saved.poses, self._near[:n], self.anchor,
                                        self._submap)
        self.matcher.build_reference(submap, self.reference)
