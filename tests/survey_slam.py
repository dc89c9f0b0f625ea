"""A simulated survey driven through the SLAM, for the tests that score a run against its truth."""

import numpy as np

from swarmslam.runtime.pose import between
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.slam import GraphSlam


def slam_over(survey, config, seed: int = 0) -> GraphSlam:
    """``survey``'s scans and odometry through a ``GraphSlam`` of ``config``, in order."""
    slam = GraphSlam(config, seed=seed)
    scan = PointScan(len(survey.angles))
    for t, odo, ranges in zip(survey.stamps, survey.odometry, survey.ranges):
        scan.set_ranges(ranges, survey.angles, 0.05, survey.lidar.max_range)
        slam.step(scan, odo, float(t))
    return slam


def node_steps(slam, survey):
    """Each node step of the graph, and the true one (the new node in the old one's frame)."""
    g = slam.graph
    k = np.searchsorted(survey.stamps, g.stamps[: g.n_nodes])
    est = between(g.poses[1 : g.n_nodes], g.poses[: g.n_nodes - 1])
    ref = between(survey.true_poses[k[1:]], survey.true_poses[k[:-1]])
    return est, ref
