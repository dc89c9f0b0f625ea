import numpy as np

from swarmslam.runtime.node_scans import NodeScans
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.matching.scan import PointScan

BEARINGS = np.radians(np.arange(-30.0, 30.5, 1.0))


def _scan_of(pose, wall_x=5.0, blobs=()):
    """What a scanner at ``pose`` (map frame, facing +x) sees of a wall across ``x = wall_x``
    and of round blobs ``(x, y)`` 0.15 m wide in front of it: the nearest return per bearing,
    in the scanner's frame."""
    ranges = (wall_x - pose[0]) / np.cos(BEARINGS)
    for bx, by in blobs:
        rel = between(np.array([bx, by, 0.0]), np.asarray(pose, float))
        d = np.hypot(rel[0], rel[1])
        hit = np.abs(np.arctan2(rel[1], rel[0]) - BEARINGS) < 0.15 / d
        ranges = np.where(hit, np.minimum(ranges, d), ranges)
    return np.c_[ranges * np.cos(BEARINGS), ranges * np.sin(BEARINGS)]


def _placed(poses, scans, drop):
    nodes = NodeScans(len(poses), 100)
    for k, points in enumerate(scans):
        scan = PointScan(100)
        scan.buffer[: len(points)] = points
        scan.count = len(points)
        nodes.store(k, scan)
    out = PointScan(100 * len(poses))
    ids = np.arange(len(poses))
    poses = np.asarray(poses, float)
    if drop:
        m = len(poses)
        nodes.place_unmoved(poses, ids, m - 1, out, 0.2, 0.01, np.zeros((m, 720)),
                            np.zeros((m, 4)))
    else:
        nodes.place(poses, ids, len(poses) - 1, out)
    return compose(poses[-1], np.c_[out.buffer[: out.count], np.zeros(out.count)])[:, :2]


def _near(points, x, y, d=0.2):
    return int(np.sum(np.hypot(points[:, 0] - x, points[:, 1] - y) < d))


def test_a_point_another_node_scan_saw_through_is_left_out_of_the_reference():
    """A person stood 2 m ahead of the first node; the second node, 0.5 m on, saw the wall
    behind where they stood: the person's returns are left out, every wall point stays."""
    poses = [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]]
    scans = [_scan_of(poses[0], blobs=[(2.0, 0.0)]), _scan_of(poses[1])]
    kept = _placed(poses, scans, drop=True)
    every = _placed(poses, scans, drop=False)
    assert _near(every, 2.0, 0.0) >= 3
    assert _near(kept, 2.0, 0.0) == 0
    assert len(every) - len(kept) == _near(every, 2.0, 0.0)  # nothing else left out


def test_a_point_hidden_from_the_other_node_scans_or_seen_by_one_of_them_stays():
    """No evidence, no verdict: a pillar in front of the second node hid the place, so the
    person stays; and a person seen by one node scan stays though another saw through them
    (something still there, or a view the other got wrong)."""
    poses = [[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]]
    hidden = [_scan_of(poses[0], blobs=[(2.0, 0.0)]), _scan_of(poses[1], blobs=[(1.0, 0.0)])]
    assert _near(_placed(poses, hidden, drop=True), 2.0, 0.0) >= 3
    poses3 = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]]
    disputed = [_scan_of(poses3[0], blobs=[(2.0, 0.0)]), _scan_of(poses3[1], blobs=[(2.0, 0.0)]),
                _scan_of(poses3[2])]
    kept = _placed(poses3, disputed, drop=True)
    assert _near(kept, 2.0, 0.0) >= 6  # both scans' returns from the person
