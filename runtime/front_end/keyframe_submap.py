"""The keyframe's submap: the scan the front end tracks against (docs/method.md §6.1).

The newest node's scan, preceded by up to ``submap_nodes`` − 1 earlier node scans moved into its
frame by the graph's poses (oldest first, so surfaces join within each scan). The nodes and the
poses that placed them are kept when it is built: a loop closure moves the graph's poses, not
the reference tracked against, and a restored session rebuilds the reference the running one
had.
"""

from __future__ import annotations

import numpy as np

from swarmslam.runtime.config import SlamConfig
from swarmslam.runtime.node_scans import BEARING_BINS, NodeScans
from swarmslam.runtime.pose_graph import PoseGraph
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.matching.scan_matcher import INLIER_SLOPE, ScanMatcher


class KeyframeSubmap:
    def __init__(self, config: SlamConfig, graph: PoseGraph, nodes: NodeScans,
                 matcher: ScanMatcher, reference):
        """``reference``: the matcher's reference this submap is built into."""
        self.config = config.front_end
        self.graph, self.nodes, self.matcher, self.reference = graph, nodes, matcher, reference
        points, k = config.sensor.max_points, config.front_end.submap_nodes
        self._node_scan = PointScan(points)
        self.scan = PointScan(points * k)
        self.members = np.zeros(k, np.int64)
        self.poses = np.zeros((k, 3))
        self.n = 0
        # work buffers of the moved points' test: a range image and a placement per node scan
        self._images = np.zeros((k, BEARING_BINS))
        self._placed = np.zeros((k, 4))

    def rebuild(self, keyframe: int, placed: bool = False) -> None:
        """The reference from the stored node scans, placed by the graph's poses, or
        (``placed``) by the poses kept when it was last built."""
        self.nodes.load(keyframe, self._node_scan)
        self.matcher.build_reference(self._of(keyframe, placed), self.reference)

    def _of(self, node: int, placed: bool) -> PointScan:
        c = self.config
        k = c.submap_nodes
        if k <= 1 or node == 0:
            return self._node_scan
        if not placed:
            first = max(node - k + 1, 0)
            self.n = node + 1 - first
            for i in range(self.n):  # (no temporary array: this runs at every node)
                self.members[i] = first + i
            self.poses[: self.n] = self.graph.poses[first : node + 1]
        m = self.n  # the kept poses are rows 0..m-1, the keyframe's the last
        if c.drop_moved_points:
            return self.nodes.place_unmoved(self.poses, self.members[:m], m - 1, self.scan,
                                            c.track_inlier_distance, INLIER_SLOPE,
                                            self._images, self._placed)
        return self.nodes.place(self.poses, self.members[:m], m - 1, self.scan, rows=range(m))

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {"submap_nodes": self.members[: self.n].copy(),
                "submap_poses": self.poses[: self.n].copy()}

    def restore(self, state: dict, keyframe: int) -> None:
        """The submap :meth:`state` gave, for ``keyframe`` of the restored graph; its reference
        rebuilt."""
        n = self.graph.n_nodes
        members, poses = state["submap_nodes"], state["submap_poses"]
        if (len(members) > self.members.shape[0] or poses.shape != (len(members), 3)
                or np.any(members < 0) or np.any(members >= n)
                or (len(members) and members[-1] != keyframe)
                or not np.all(np.isfinite(poses))):
            raise ValueError("the keyframe's submap is not one this front end builds "
                             "(another submap_nodes?)")
        self.n = len(members)
        self.members[: self.n] = members
        self.poses[: self.n] = poses
        if keyframe >= 0:
            # (a submap of the keyframe's scan alone keeps no poses: it is placed by the graph)
            self.rebuild(keyframe, placed=self.n > 0)
