"""The front end (local SLAM): track each scan against the keyframe (Alg. 5) and insert nodes
(Alg. 6); docs/method.md §6.1.

    tracked = front_end.track(scan, odometry, stamp)   # → Tracking(pose, node_added, error)

Each scan is aligned with the newest node's scan, the keyframe, rather than with the previous
scan: the search starts from the last estimate moved by the odometry (or, with none, by the
last motion the scans showed), and matching every scan against the same keyframe keeps the
error between two nodes to one match instead of a sum of many. The steps of
:meth:`FrontEnd.track` are components: the prediction (:class:`OdometryReadings`), the
alignment (:class:`SweepMotion` around the matcher), the heading prior and the odometry gate
(:mod:`swarmslam.runtime.front_end.odometry_gate`), the degeneracy check
(:mod:`swarmslam.runtime.matching.degeneracy`), recovery (:mod:`swarmslam.runtime.front_end.recovery`) and the
node insertion. The trajectory (:mod:`swarmslam.runtime.front_end.scan_trajectory`) records every scan;
the scans between nodes are placed from it (docs/method.md §6.2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from swarmslam.runtime.front_end.between_scans import (FIRST_READING, NEW_READING, NO_READING,
                                             STALE_READING)
from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.matching.degeneracy import DegeneracyCheck
from swarmslam.runtime.front_end.keyframe_submap import KeyframeSubmap
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.front_end.odometry_gate import OdometryGate, Prediction, TrackingCounts
from swarmslam.runtime.front_end.odometry_readings import OdometryReadings
from swarmslam.runtime.front_end.odometry_scale import OdometryCalibration
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.pose_graph import (ODOMETRY, PoseGraph, information_from_sigma,
                                           propagate_covariance)
from swarmslam.runtime.front_end.recovery import Recovery
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import BOX_MARGIN, ScanMatcher
from swarmslam.runtime.front_end.scan_trajectory import ScanTrajectory
from swarmslam.runtime.tallies import restore_counts
from swarmslam.runtime.matching.sweep_motion import SweepMotion

CAPACITY_STATUS = "capacity reached: localising against the last node, map frozen"
TRAJECTORY_STATUS = "trajectory capacity reached: poses no longer recorded"
# The next node edge's information is divided by this after a lost match: σ three times its
# own, the edge holding what recovery found, not a tracked match.
WEAK_INFORMATION_FACTOR = 9.0
# On scans alone, the last motion is continued over at most this many of the intervals it was
# made in: a scan or two dropped in between are bridged, but past a longer gap (a port that
# vanished, a stalled driver) the robot's motion is no longer known from its last scans.
CONTINUED_INTERVALS = 3.0


@dataclass
class Tracking:
    pose: np.ndarray  # the scan's pose in the map frame
    node_added: bool
    node: int  # the keyframe after this scan (the new node if one was added)
    error: float  # λ of the alignment (0 for the first scan)


class FrontEnd:
    def __init__(self, config: SlamConfig, graph: PoseGraph, nodes: NodeScans, seed: int = 0,
                 initial_pose=None):
        """``initial_pose``: the first scan's pose in the map frame (default: the origin)."""
        self.config = config
        c = config.front_end
        self.graph, self.nodes = graph, nodes
        self.initial_pose = (np.zeros(3) if initial_pose is None
                             else np.array(initial_pose, dtype=np.float64))
        self.counts = TrackingCounts()
        self.matcher = ScanMatcher(config.matcher, seed=seed)
        self.reference = self.matcher.new_reference()
        self.submap = KeyframeSubmap(config, graph, nodes, self.matcher, self.reference)
        self.sweep = SweepMotion(config.sensor, config.sensor.max_points)
        self.readings = OdometryReadings(c.stale_motion, c.periodic_odometry_ratio)
        self.gate = OdometryGate(c, self.matcher, self.reference, config.sensor.max_points,
                                 self.counts)
        self.degeneracy = DegeneracyCheck(c, self.matcher, self.reference, self.counts)
        self.recovery = Recovery(config, self.matcher, self.reference, self.gate,
                                 self.degeneracy, self.readings, self.counts)
        self.calibration = OdometryCalibration(c)
        self.scans = ScanTrajectory(c, config.capacity.max_scans)
        self.keyframe = -1
        self.rel = np.zeros(3)  # the current pose in the keyframe's frame
        self.motion = np.zeros(3)  # last motion between scans, for a scan-only prediction
        self._continued_motion = np.zeros(3)  # it, over the time since the last scan
        # The pose (in the keyframe's frame) of the scan that brought odometry's last new
        # reading: its motion is predicted from there (docs/method.md §6.1).
        self.odometry_rel = np.zeros(3)
        # The last scan's stamp, and the time since the one before: what the motion the sweep
        # is undistorted by was over.
        self.last_stamp = math.nan
        self.last_interval = math.nan
        self._reading, self._reading_pose = NO_READING, np.zeros(3)  # the scan being tracked's
        self._predicted = Prediction(self.rel, self.motion, self.rel, self.motion, False, False,
                                     math.nan)
        self.weak = False  # a match since the last node was replaced by odometry
        self.status = "ok"
        self.evaluations = 0  # by the last match (what a viewer plots)

    # ------------------------------------------------------------------ Alg. 5 + Alg. 6
    def track(self, scan: PointScan, odometry=None, stamp: float = 0.0) -> Tracking:
        """Align ``scan`` (robot frame) with the keyframe and add a node when the robot has
        moved far enough; ``odometry`` is the robot's odometry pose at the scan, if any."""
        if self.keyframe < 0:
            self._start(scan, odometry, stamp)
            return Tracking(self.graph.poses[0].copy(), True, 0, 0.0)
        predicted, base, news = self._predict(odometry, stamp)
        # Alg. 5, each point turned to the stamp's heading (the sweep, docs/method.md §6.1)
        match, scan = self.sweep.align(self.matcher, scan, self.reference, predicted.guess,
                                       self.motion, self.last_interval, self.rel,
                                       predicted.interval)
        self.evaluations = match.evaluations
        pose = match.pose
        if news:  # (a stale reading predicts no turn to weigh a match against)
            pose = self.gate.heading_prior(scan, match, predicted)
        pinned = pose is match.pose  # (not held to odometry's heading)
        self.degeneracy.last = None
        if self.config.front_end.degeneracy_ratio > 0:
            pose = self.degeneracy.constrain(scan, pose, predicted.guess)
            pinned = pinned and not self.degeneracy.last.degenerate
        # (after the slide along a degenerate axis is dropped: there the box's edge is no sign)
        inside = not self.matcher.at_box_edge(pose, BOX_MARGIN)
        if self.gate.lost(scan, pose, predicted, inside):
            pose, weak = self.recovery.recover(scan, pose, predicted, inside)
            self.weak = self.weak or weak
            pinned = False
        elif (self.degeneracy.last is not None and self.degeneracy.last.degenerate
              and self._reading != NO_READING):  # (on scans alone it is the scans' own motion)
            self.calibration.note_part(self.degeneracy.last.axis, predicted.guess, self.rel)
        if news:
            self.calibration.observe(pose, base, predicted.step, pinned)
        self.motion = between(pose, self.rel)
        self.rel = pose
        if news:
            self.odometry_rel[:] = pose
        node_added = self.insert_node(scan, stamp)  # Alg. 6
        self.last_interval = stamp - self.last_stamp
        self.last_stamp = stamp
        self._record(stamp)
        self.gate.previous.remember(scan)
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
        if self.degeneracy.last is not None:  # the edge is the last match: weak where it slid
            info = self.degeneracy.last.information(info)
        part = self.calibration.part
        z = self.rel.copy()  # odometry's part at the scale the graph's edges hold theirs
        z[:2] += (g.scale - 1.0) * part
        if self.weak:
            info = info / WEAK_INFORMATION_FACTOR
            self.weak = False
        node = g.add_node(compose(g.poses[previous], z), stamp)
        g.add_edge(previous, node, z, info, ODOMETRY, part)
        part[:] = 0.0
        g.scale_target = self.calibration.fit.scale
        cov = self.nodes.cov
        propagate_covariance(cov[previous], g.poses[previous], z, np.linalg.inv(info),
                             cov[node])
        self.nodes.store(node, scan)
        self.keyframe = node
        self.odometry_rel[:] = between(self.odometry_rel, self.rel)  # the new node's frame
        self.rel = np.zeros(3)
        self.submap.rebuild(node)
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
        self._predict(odometry, stamp)  # the new run's odometry starts here
        self.calibration.part[:] = 0.0
        self.calibration.pinned_base = True  # placed where localization confirmed it
        self.submap.rebuild(node)
        self._record(stamp)
        self.gate.previous.remember(scan)
        return True

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
        return self.scans.placed(self.graph)

    # ------------------------------------------------------------------ helpers
    def _start(self, scan, odometry, stamp):
        self.graph.add_node(self.initial_pose, stamp)
        self.nodes.store(0, scan)
        self.keyframe = 0
        self.last_stamp = stamp
        self.submap.rebuild(0)
        self._reading = NO_READING
        if odometry is not None:
            # odometry starts here
            self._note_reading(odometry, *self.readings.read(odometry, stamp))
            self.odometry_rel[:] = 0.0
            self.calibration.pinned_base = True  # the first node's own pose
        self._record(stamp)
        self.gate.previous.remember(scan)

    def _predict(self, odometry, stamp):
        """The scan's :class:`Prediction` (in the keyframe's frame), where it starts from, and
        whether odometry brought a new reading: a new reading's motion from the scan that
        brought the last new one, a stale one's from the last scan
        (:mod:`swarmslam.runtime.front_end.odometry_readings`). Without odometry: the last motion the
        scans showed, continued (docs/method.md §6.1)."""
        step, news, first = self.readings.read(odometry, stamp)
        self._note_reading(odometry, step, news, first)
        if step is None:  # scans only, or a reading the inbox dropped
            base, step, news = self.rel, self._continued(stamp - self.last_stamp), False
        elif not news:
            base = self.rel
        else:
            if first:  # odometry starts here
                self.odometry_rel[:] = self.rel
            base = self.odometry_rel
        p = self._predicted
        p.guess, p.step, p.last, p.motion = compose(base, step), step, self.rel, self.motion
        p.odometry = odometry is not None
        p.stale = p.odometry and not news  # the same reading as before
        p.interval = stamp - self.last_stamp
        return p, base, news

    def _continued(self, interval: float) -> np.ndarray:
        """The last motion the scans showed, continued over ``interval`` s (at most
        ``CONTINUED_INTERVALS`` of the one it was made in) at the rate it was made: after a gap
        in the scans, or in a burst of scans queued behind one, the same motion per scan would
        carry the pose away."""
        if not (self.last_interval > 0 and interval >= 0):  # (NaN: no rate known yet)
            return self.motion
        ratio = min(interval / self.last_interval, CONTINUED_INTERVALS)
        np.multiply(self.motion, ratio, out=self._continued_motion)
        return self._continued_motion

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
        if not self.scans.record(self.keyframe, self.rel, stamp, self._reading,
                                 self._reading_pose):
            self.status = TRAJECTORY_STATUS

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {"matcher": self.matcher.state(), **self.scans.state(),
                "initial_pose": self.initial_pose.copy(), "rel": self.rel.copy(),
                "motion": self.motion.copy(), "keyframe": self.keyframe,
                "weak": self.weak, "counts": asdict(self.counts), "status": self.status,
                **self.submap.state(), "odometry_rel": self.odometry_rel.copy(),
                **self.readings.state(), **self.calibration.state(),
                "last_stamp": self.last_stamp, "last_interval": self.last_interval,
                "previous_points": self.gate.previous.state()}

    def restore(self, state: dict) -> None:
        """The state :meth:`state` gave, over a front end of the same configuration built on
        the restored graph and node scans."""
        n = self.graph.n_nodes
        self.scans.restore(state, n)
        self.matcher.restore(state["matcher"])
        self.initial_pose[:] = state["initial_pose"]
        self.rel[:], self.motion[:] = state["rel"], state["motion"]
        self.readings.restore(state)
        self.weak = bool(state["weak"])
        self.status = str(state["status"])
        restore_counts(self.counts, state["counts"])
        self.keyframe = int(state["keyframe"])
        self.odometry_rel[:] = state["odometry_rel"]
        self.calibration.restore(state)
        self.last_stamp = float(state["last_stamp"])
        self.last_interval = float(state["last_interval"])
        if self.keyframe >= 0 and not 0 <= self.keyframe < n:
            raise ValueError(f"keyframe {self.keyframe} is not a stored node")
        self.gate.previous.restore(state["previous_points"])
        self.submap.restore(state, self.keyframe)
