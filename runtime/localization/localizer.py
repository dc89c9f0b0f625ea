"""Localization mode: find, confirm and track the robot's pose in a saved map that never
changes (docs/method.md §9).

    localizer = Localizer(config, saved)              # saved: a swarmslam.runtime.localization.map_tracking.SavedMap
    result = localizer.step(scan, odometry, stamp)    # a StepResult; pose NaN while unknown

1. searching — no pose (no prior was given, or it was lost): the global search
   (:mod:`swarmslam.runtime.localization.relocalization`, §8) places the scan, or lists the distinct poses that
   explain it about equally well;
2. confirming — every candidate is tracked (:class:`~swarmslam.runtime.localization.map_tracking.MapTracker`) back
   over the scans since the search began (by odometry, at most ``confirm_replay_scans``), then
   forward over the next, until its scans span ``confirm_seconds``; a candidate whose scans
   stop fitting is dropped, two that track into one place merge, and after the window a
   candidate missing the saved surfaces with many more points than the best one
   (``confirm_misses``) is dropped, and so is one absent from a second look's poses (the
   newest scan searched again; a list of ``max_hypotheses`` poses, maybe incomplete, drops
   none). One left → tracking; none → searching; several → they stay candidates until the
   scans tell them apart (a corridor);
3. tracking — Alg. 5 against the saved node scans nearest the pose; ``lost_scans`` poor
   matches in a row → searching.

The same :class:`~swarmslam.runtime.step_result.StepResult` as mapping comes back, so
:class:`~swarmslam.runtime.realtime.fixed_rate.SlamRuntime` runs either at its fixed rate. The saved map's arrays
are read-only: localization cannot change them.
"""

from __future__ import annotations

import math

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.front_end.tracker import TRAJECTORY_STATUS
from swarmslam.runtime.localization.map_tracking import MapTracker, SavedMap
from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.occupancy_grid import OccupancyGrid
from swarmslam.runtime.front_end.odometry_readings import OdometryReadings
from swarmslam.runtime.pose import between, compose, inverse
from swarmslam.runtime.localization.relocalization import Located, Relocalizer
from swarmslam.runtime.resources import check_memory
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import ScanMatcher
from swarmslam.runtime.step_result import StepResult

# Share of points off the saved surfaces any candidate may have beyond the best one's multiple
# (a nearly perfect best one then does not drop the other for a point or two).
CONFIRM_MISS_FLOOR = 0.003
# m, rad: candidates that tracked this near each other are one (the worse is dropped)
MERGE_DISTANCE = 0.2
MERGE_ANGLE = 0.05

SEARCHING, CONFIRMING, TRACKING = "searching", "confirming", "tracking"


class Localizer:
    """Localization in a :class:`SavedMap` (see module doc). ``initial_pose``: a prior (then
    tracking starts at once); None: the first scans are searched for."""

    def __init__(self, config: SlamConfig, saved: SavedMap, seed: int = 0, initial_pose=None):
        check_memory(config)  # before any buffer is allocated
        self.config, self.saved, self.seed = config, saved, seed
        self.relocalizer = Relocalizer(config, saved.poses, saved.nodes, saved.n_nodes, seed)
        self.matcher = ScanMatcher(config.matcher, seed=seed + 1)  # (as reset reseeds them)
        self.trackers = [MapTracker(saved, self.matcher, config)
                         for _ in range(config.relocalization.max_hypotheses)]
        self.n_candidates = 0  # trackers[:n_candidates] follow live hypotheses
        # the scans since the search began (a ring), for a new candidate to be tracked back over
        ring = config.relocalization.confirm_replay_scans + 1  # and the scan searched
        self.recent = NodeScans(ring, config.sensor.max_points)
        self.recent_stamps = np.zeros(ring)
        self.recent_motions = np.zeros((ring, 3))  # odometry's motion into each; NaN: none
        self.n_recent, self._next = 0, 0
        self._replayed = PointScan(config.sensor.max_points)
        # a search spread over ticks: its scan, and odometry's motion since that scan
        self._pending = None
        self._searched_scan = PointScan(config.sensor.max_points)
        self._carried = np.zeros(3)
        self.phase = SEARCHING
        self.confirm_until = self.found_at = 0.0
        self._searched = False  # this scan already
        n = config.capacity.max_scans
        self.stamps = np.zeros(n)
        self.poses = np.full((n, 3), np.nan)  # NaN: no committed pose at that scan
        self.n_scans = 0
        self.readings = OdometryReadings(config.front_end.stale_motion,
                                         config.front_end.periodic_odometry_ratio)
        self.last_stamp = math.nan  # the scan before's, for the sweep (docs/method.md §6.1)
        self.counts = {"searches": 0, "ambiguous_answers": 0, "empty_answers": 0,
                       "committed": 0, "lost": 0, "poor_matches": 0, "tracked_scans": 0,
                       "odometry_held": 0}
        self.fit_sum = 0.0  # over tracked scans
        self.trajectory_full = False
        if initial_pose is not None:
            self._commit_pose(np.asarray(initial_pose, np.float64))

    def reset(self, initial_pose=None, seed: int | None = None) -> None:
        """Forget the pose (and odometry): the next scan is searched for, or tracked from
        ``initial_pose``. The trajectory recorded so far stays. ``seed``: the swarms' random
        streams restart as a localizer made with that seed starts them (a benchmark's
        queries then do not depend on the ones before)."""
        self.phase, self.n_candidates, self.n_recent = SEARCHING, 0, 0
        self.readings.have = False
        self.last_stamp = math.nan
        self._pending = None
        if seed is not None:  # as the constructor seeds them
            self.relocalizer.matcher.optimizer.reseed(seed)
            self.matcher.optimizer.reseed(seed + 1)
        if initial_pose is not None:
            self._commit_pose(np.asarray(initial_pose, np.float64))

    def warm_up(self) -> None:
        """Run the search and the tracking kernels once on the saved map (a robot calls this
        before its first tick); the localizer's own state is left as it was."""
        scan = self.saved.nodes.load(0, PointScan(self.saved.nodes.max_points))
        self.relocalizer.relocalize(scan)
        scratch = MapTracker(self.saved, self.matcher, self.config)
        scratch.start(self.saved.poses[0])
        scratch.follow(scan, np.zeros(3))

    # ------------------------------------------------------------------ one scan
    def step(self, scan: PointScan, odometry=None, stamp: float = 0.0, clock=None,
             budget_end: float | None = None) -> StepResult:
        """One scan in the current phase (see module doc); ``clock`` times the tracking."""
        start = clock() if clock is not None else 0.0
        motion, news = self._odometry_step(odometry, stamp)
        stale = motion is not None and not news  # odometry's last reading again
        interval = stamp - self.last_stamp if stamp > self.last_stamp else 0.0  # (NaN: 0)
        self.last_stamp = stamp
        error = 0.0
        self._searched = False
        if self.phase == TRACKING:
            error = self._track(scan, motion, news, stale, interval)
        if self.phase != TRACKING:
            self._remember(scan, motion, stamp)
        if self.phase == CONFIRMING:
            self._confirm(scan, motion, news, stale, stamp, interval)
        if self.phase == SEARCHING and not self._searched:  # (a second look may have)
            self._search(scan, motion, stamp, clock, budget_end)
        took = clock() - start if clock is not None else 0.0
        self._record(stamp)
        return StepResult(self.pose(), False, False, error, took)

    def _track(self, scan, motion, news, stale, interval) -> float:
        tracker = self.trackers[0]
        fit = tracker.follow(scan, motion, news, stale, gate=True, interval=interval)
        self.counts["tracked_scans"] += 1
        self.fit_sum += fit
        if tracker.poor:
            self.counts["poor_matches"] += 1
        if tracker.held:
            self.counts["odometry_held"] += 1
        if tracker.poor >= self.config.localization.lost_scans:
            self.counts["lost"] += 1
            # the scans before were taken where the pose no longer fits: none is replayed
            self.phase, self.n_candidates, self.n_recent = SEARCHING, 0, 0
        return tracker.error

    def _remember(self, scan, motion, stamp) -> None:
        """Keep ``scan`` in the ring of scans since the search began."""
        k = self._next
        self.recent.store(k, scan)
        self.recent_stamps[k] = stamp
        self.recent_motions[k] = np.nan if motion is None else motion
        self._next = (k + 1) % len(self.recent_stamps)
        self.n_recent = min(self.n_recent + 1, len(self.recent_stamps))

    def _search(self, scan, motion, stamp, clock=None, budget_end=None) -> None:
        """The global search (§8); its candidates are confirmed over the scans around. Given
        a clock and a budget it is spread over ticks (docs/method.md §9): begun on ``scan``,
        gone on with in the next ticks until each one's budget is spent; its poses, found for
        the scan it began on, are then carried to the newest by odometry's motion since."""
        if self._pending is None:
            if clock is None or budget_end is None:  # at once (the lockstep schedule)
                poses = self._look(scan)
                if poses:
                    self._begin(poses, stamp)
                return
            self.counts["searches"] += 1
            self._searched_scan.buffer[: scan.count] = scan.buffer[: scan.count]
            self._searched_scan.count = scan.count
            self._pending = self.relocalizer.begin(self._searched_scan)
            self._carried[:] = 0.0
        elif motion is not None:  # (a reading the inbox dropped: no motion known)
            self._carried[:] = compose(self._carried, motion)
        self._searched = True
        if not self._pending.advance(clock, budget_end):
            return
        poses = self._poses(self._pending.answer)
        self._pending = None
        if poses:
            self._begin(tuple(compose(p, self._carried) for p in poses), stamp)

    def _look(self, scan) -> tuple:
        """The global search's poses for ``scan``, at once: one, several rivals, or none."""
        self.counts["searches"] += 1
        self._searched = True
        return self._poses(self.relocalizer.relocalize(scan))

    def _poses(self, answer) -> tuple:
        if isinstance(answer, Located):
            return (answer.pose,)
        self.counts["ambiguous_answers" if answer.poses else "empty_answers"] += 1
        return answer.poses

    def _begin(self, poses, stamp) -> None:
        """Confirm ``poses`` (the newest scan's candidates)."""
        for tracker, pose in zip(self.trackers, poses):
            tracker.start(pose)
        self.n_candidates = min(len(poses), len(self.trackers))
        self.phase = CONFIRMING
        self.found_at = stamp
        # a candidate found late is confirmed by the scans before it as well as after
        earliest = self._replay_backward(stamp)
        self.confirm_until = earliest + self.config.relocalization.confirm_seconds
        self._decide(None, stamp)

    def _replay_backward(self, stamp) -> float:
        """Every candidate (just started at the newest scan) followed back over the scans
        remembered before it, each predicted by the inverse of odometry's motion, until they
        span ``confirm_seconds`` or odometry is missing; a candidate that loses track on the
        way is dropped. Returns the earliest scan's stamp."""
        ring, confirm = len(self.recent_stamps), self.config.relocalization.confirm_seconds
        newest = (self._next - 1) % ring
        earliest, back = stamp, 0
        while back + 1 < self.n_recent and earliest > stamp - confirm:
            later = (newest - back) % ring
            if np.isnan(self.recent_motions[later, 0]):
                break
            back += 1
            earliest = self.recent_stamps[(newest - back) % ring]
        if back == 0:
            return stamp
        motion = self.recent_motions[newest]
        motion = motion if not np.isnan(motion[0]) else np.zeros(3)
        lost = set()
        for tracker in self.trackers[: self.n_candidates]:
            pose = tracker.pose.copy()
            for b in range(1, back + 1):
                k = (newest - b) % ring
                step = inverse(self.recent_motions[(k + 1) % ring])
                tracker.follow(self.recent.load(k, self._replayed), step, measure=True)
            if tracker.poor >= self.config.localization.lost_scans:
                lost.add(id(tracker))
            tracker.rewind(pose, motion)
        self._keep(lambda t: id(t) not in lost)
        if self.n_candidates == 0:
            self.phase = SEARCHING
        return earliest

    def _confirm(self, scan, motion, news, stale, stamp, interval) -> None:
        lc = self.config.localization
        for k in range(self.n_candidates):  # each gated: docs/method.md §9, "The odometry gate"
            self.trackers[k].follow(scan, motion, news, stale, gate=True, measure=True,
                                    interval=interval)
        # a candidate that lost track is dropped; two that tracked into one place are one
        dropped = self._duplicates()
        self._keep(lambda t: t.poor < lc.lost_scans and id(t) not in dropped)
        if self.n_candidates == 0:
            self.phase = SEARCHING
            return
        self._decide(scan, stamp)

    def _decide(self, scan, stamp) -> None:
        """Once the candidates' scans span the window: drop those missing the surfaces with
        many more points than the best, then look again (``scan``: the newest, searched
        again unless the candidates came from it); one left is committed."""
        if self.phase != CONFIRMING or stamp < self.confirm_until:
            return
        lc = self.config.localization
        if self.trackers[0].fits:  # (none with no window: confirm_seconds 0)
            # the fit saturates near 1 in a well-mapped place: the share of points off the
            # surfaces tells a wrong place (a rival seen from afar) from the right one
            best = 1.0 - max(t.mean_fit for t in self.trackers[: self.n_candidates])
            worst = min(lc.confirm_misses * best + CONFIRM_MISS_FLOOR, lc.confirm_max_miss,
                        1.0 - self.config.front_end.min_track_inliers)  # none fitting poorly
            self._keep(lambda t: 1.0 - t.mean_fit <= worst)
        if self.config.relocalization.confirm_look and stamp > self.found_at:
            # a second look, apart from the first: a candidate that tracked well into a
            # wrong place (a corridor's twin) is seldom where this scan is placed
            poses = self._look(scan)
            rc = self.config.relocalization  # one place to the search: not distinct (§8)
            near = {id(t) for t in self.trackers[: self.n_candidates]
                    if any(within(t.pose, p, rc.distinct_distance, rc.distinct_angle)
                           for p in poses)}
            if len(poses) == 1 and not near:
                self._begin(poses, stamp)  # located elsewhere: confirm that place instead
                return
            # rivals none of which is a candidate tell nothing; nor does a full list, which
            # may leave out rivals as good as those it holds (a corridor's many twins)
            if near and len(poses) < rc.max_hypotheses:
                self._keep(lambda t: id(t) in near)
        if self.n_candidates == 0:
            self.phase = SEARCHING
        elif self.n_candidates == 1 and (self.trackers[0].pinned or 1.0 - self.trackers[0]
                                         .mean_fit <= lc.corridor_max_miss):
            # (a place seen only as a corridor, fitting less than nearly perfectly, is not yet
            # a place: the candidate is followed on until a match pins it along the corridor
            # too — a wrong map's corridor never does)
            self._commit(0)

    def _keep(self, test) -> None:
        """Keep the candidates passing ``test`` (in order) at the front of the trackers."""
        kept = 0
        for k in range(self.n_candidates):
            tracker = self.trackers[k]
            if test(tracker):
                self.trackers[kept], self.trackers[k] = tracker, self.trackers[kept]
                kept += 1
        self.n_candidates = kept

    def _duplicates(self) -> set:
        """Candidates that tracked into the place of a better fitting one (within
        MERGE_DISTANCE and MERGE_ANGLE): ids to drop."""
        lc = self.config.localization
        trackers, dropped = self.trackers[: self.n_candidates], set()
        for i, a in enumerate(trackers):
            for b in trackers[i + 1 :]:
                if within(a.pose, b.pose, MERGE_DISTANCE, MERGE_ANGLE):
                    dropped.add(id(b) if a.mean_fit >= b.mean_fit else id(a))
        return dropped

    def _commit(self, k: int) -> None:
        self.trackers[0], self.trackers[k] = self.trackers[k], self.trackers[0]
        self.n_candidates = 1
        self.phase = TRACKING
        self.counts["committed"] += 1

    def _commit_pose(self, pose) -> None:
        self.trackers[0].start(pose)
        self._commit(0)

    def _odometry_step(self, odometry, stamp):
        """Odometry's motion at this scan and whether it is a new reading, or (None, False)
        without one (the trackers repeat their last motion; a reading the inbox dropped: the
        next starts odometry afresh, docs/runtime.md §7). A new reading's motion is added to
        the pose of the scan that brought the last new one, a stale one's to the last scan's
        (:mod:`swarmslam.runtime.front_end.odometry_readings`)."""
        step, news, _ = self.readings.read(odometry, stamp)
        return step, news

    def _record(self, stamp) -> None:
        k = self.n_scans
        if k >= len(self.stamps):
            self.trajectory_full = True
            return
        self.stamps[k] = stamp
        if self.phase == TRACKING:
            self.poses[k] = self.trackers[0].pose
        self.n_scans += 1

    # ------------------------------------------------------------------ what consumers read
    def pose(self) -> np.ndarray:
        """The committed pose in the map frame; NaN while searching or confirming."""
        if self.phase != TRACKING:
            return np.full(3, np.nan)
        return self.trackers[0].pose.copy()

    def candidates(self) -> np.ndarray:
        """The poses still in question (while confirming), or the committed one."""
        return np.array([t.pose for t in self.trackers[: self.n_candidates]]).reshape(-1, 3)

    def global_map(self) -> OccupancyGrid:
        """The saved map localization runs in, as an occupancy grid: the saved node scans
        drawn from their saved poses (what mapping's ``global_map`` gave when it was saved)."""
        s = self.saved
        return OccupancyGrid.of_nodes(s.poses, s.nodes, s.n_nodes, self.config.map)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and poses of the scans with a committed pose."""
        known = self.has_pose()
        return self.stamps[: self.n_scans][known], self.poses[: self.n_scans][known]

    def has_pose(self) -> np.ndarray:
        """Which recorded scans have a committed pose (a boolean mask)."""
        return ~np.isnan(self.poses[: self.n_scans, 0])

    def set_evaluation_share(self, share: float) -> None:
        """The runtime's swarm budget for this tick, shared by the candidates followed."""
        self.matcher.set_evaluation_share(share / max(self.n_candidates, 1))

    def run_back_end(self, clock=None, budget_end=None) -> bool:
        return False  # the saved graph is never optimised again

    def drain(self, clock=None) -> int:
        return 0

    @property
    def status(self) -> str:
        said = {TRACKING: "ok", SEARCHING: "localizing: searching the map",
                CONFIRMING: f"localizing: confirming {self.n_candidates} candidate pose(s)"}
        said = said[self.phase]
        if self.trajectory_full:
            said = TRAJECTORY_STATUS if said == "ok" else f"{said}; {TRAJECTORY_STATUS}"
        return said

    def report(self) -> dict:
        tracked = self.counts["tracked_scans"]
        return {"mode": "localization", "phase": self.phase, "saved_nodes": self.saved.n_nodes,
                **self.counts, "mean_fit": self.fit_sum / tracked if tracked else 0.0,
                "scans_without_pose": int(self.n_scans - self.has_pose().sum()),
                "status": self.status}


def within(a, b, distance: float, angle: float) -> bool:
    """Whether poses ``a`` and ``b`` lie within ``distance`` (m) and ``angle`` (rad) of each
    other."""
    d = between(a, b)
    return d[0] ** 2 + d[1] ** 2 <= distance ** 2 and abs(d[2]) <= angle
