"""A loop candidate's alignment (Alg. 7, step 3a; docs/method.md §5): the new node's scan
matched against the submap around the candidate, and the tests a loop match must pass.

    z = alignment.align(candidate, node)        # node's pose in candidate's frame, or None
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.matching.degeneracy import Degeneracy
from swarmslam.runtime.back_end.loop_closure import LoopCloser, relative_guess, visibility
from swarmslam.runtime.node_scans import BEARING_BINS, NodeScans
from swarmslam.runtime.pose_graph import PoseGraph
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import (BOX_MARGIN, CURVATURE_STEP, INLIER_SLOPE,
                                                     ScanMatcher, beyond_margin)
from swarmslam.runtime.back_end.wide_loop_search import WideLoopSearch

# The largest share of the points the submap's scans saw that may lie in space they saw through
# for a loop match accepted by overlap (a few stray points: glass, a person).
MAX_VIOLATIONS = 0.03


class LoopAlignment:
    def __init__(self, config: SlamConfig, graph: PoseGraph, nodes: NodeScans, loops: LoopCloser,
                 wide: WideLoopSearch, information, z_info: np.ndarray, seed: int = 0):
        """``information(loop=True)``: a new loop edge's information matrix (the front end's);
        ``z_info``: where the aligned match's information is written."""
        lc = config.loop_closure
        self.config = config
        self.graph, self.nodes, self.loops, self.wide = graph, nodes, loops, wide
        self.information, self.z_info = information, z_info
        # a loop's guess is the graph's estimate, never trusted as a prediction
        self.matcher = ScanMatcher(replace(config.matcher, guess_window=lc.search_window,
                                           predict_first=0.0),
                                   seed=seed)
        self.reference = self.matcher.new_reference()
        points = config.sensor.max_points
        self._scan = PointScan(points)
        self.submap = PointScan(points * (2 * lc.submap_nodes + 1))
        self._members = np.zeros(2 * lc.submap_nodes + 1, np.int64)  # the submap's nodes
        self._image = np.zeros(BEARING_BINS)
        self._state = np.zeros(points, np.int64)
        self._seen = np.zeros(2, np.int64)
        self._window = np.zeros(3)

    def align(self, candidate: int, node: int, guess=None, window=None):
        """``node``'s pose in ``candidate``'s frame by Alg. 5 against the submap around the
        candidate, in a box around ``guess`` (default: the graph's estimate) of half-widths
        ``window`` (default: :meth:`LoopCloser.window`), or None when the match ends at the
        edge of its box, or the submap's surfaces hold too few of its points and its scans saw
        too little of where the match puts them, or saw through too many.

        The submap: the candidate's scan and ``submap_nodes`` either side. A ``guess`` given is
        a wide search's proposal: the submap is then the old nodes nearest to where it puts
        ``node`` (the map the proposal was found in) and the submap tests are left to the
        search's own (docs/method.md §5, step 5)."""
        loops = self.loops
        c = loops.config
        loops.counts.attempts += 1
        members = self._members
        proposal = guess is not None
        if not proposal:
            first, last = loops.submap_span(candidate, node)
            n_members = last - first + 1
            for k in range(n_members):
                members[k] = first + k
        else:
            n_members = self.wide.members(self.graph.poses, node, candidate, guess, members)
        submap = self.nodes.place(self.graph.poses, members[:n_members], candidate, self.submap)
        scan = self.nodes.load(node, self._scan)
        if not proposal:
            guess = relative_guess(self.graph, candidate, node)
        if window is None:
            window = loops.window(self.graph, self.nodes.cov, candidate, node, self._window)
        # the fine field only for a global stage that ended inside the box
        match = self.matcher.align_inside(scan, submap, self.reference, guess, window,
                                          BOX_MARGIN)
        if match is None or beyond_margin(match.pose, guess, window, BOX_MARGIN):
            loops.counts.rejected_match += 1  # at or beyond the box
            return None
        pose, reference = match.pose, self.reference
        self.z_info[:] = self.information(loop=True)
        ratio = self.config.front_end.degeneracy_ratio
        if ratio > 0:  # along a corridor the guess stands in, the edge weak there
            fc = self.config.front_end
            h = self.matcher.curvature(scan, reference, pose, CURVATURE_STEP)
            degeneracy = Degeneracy(h, ratio, fc.degenerate_information)
            pose = degeneracy.remap(pose, guess)
            # An ordinary search's guess is the graph's own estimate: along the axis the edge
            # repeats it rather than measuring it, and would pin the drift it holds; the floor
            # frees it (docs/method.md §5, step 3).
            share = None if proposal else c.degenerate_information
            self.z_info[:] = degeneracy.information(self.z_info, share)
        if proposal:
            return pose  # the wide search's own tests stand (wide_loop_search.py)
        return self._submap_agrees(scan, reference, pose, candidate, members, n_members)

    def _submap_agrees(self, scan, reference, pose, candidate, members, n_members):
        """The ordinary loop match's tests: inliers on the submap, or what its scans saw."""
        loops = self.loops
        c = loops.config
        inliers = self.matcher.inlier_fraction(scan, reference, pose, c.inlier_distance,
                                               INLIER_SLOPE)
        seen = self._seen  # both tests always run: one cost per attempt, every kernel warm
        visibility(self.nodes.points, self.nodes.counts, self.graph.poses, members, n_members,
                   candidate, scan.buffer, scan.count, float(pose[0]), float(pose[1]),
                   float(pose[2]), c.inlier_distance, INLIER_SLOPE, self._image, self._state,
                   seen)
        on, through = int(seen[0]), int(seen[1])
        if inliers >= c.min_inliers or (on >= c.min_overlap * scan.count
                                        and through <= MAX_VIOLATIONS * (on + through)):
            return pose
        loops.counts.rejected_match += 1
        return None
