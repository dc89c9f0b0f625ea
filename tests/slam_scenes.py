"""Scenes the SLAM tests share: a simulated loop driven with noisy odometry, a hall with a wall
held twice, drifted and wrongly closed chains, corridors with stale odometry or people, a
room tracked for a few scans."""

import numpy as np

from swarmslam.runtime.config import SlamConfig, override
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.pose import between, compose, wrap_angle
from swarmslam.runtime.pose_graph import LOOP
from swarmslam.runtime.realtime.warm_up import loop_path, room_world, scan_at
from swarmslam.runtime.slam import GraphSlam


ANGLES = np.deg2rad(np.arange(-180, 180, 1.0))


def run(steps=100, laps=1.25, odometry_noise=(0.02, 0.02, 0.01), seed=0, config=None,
        initial_pose=None):
    """Drive 1¼ laps of the demo loop: the second pass over the start closes a loop."""
    truth = loop_path(int(steps / laps))
    truth = np.vstack([truth] * 2)[:steps]
    world = room_world(seed, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=truth)
    rng = np.random.default_rng(seed)
    slam = GraphSlam(config or SlamConfig(), seed=seed, initial_pose=initial_pose)
    odom = truth[0].copy()
    scan = PointScan(len(ANGLES))
    for k in range(steps):
        if k:  # noisy wheel odometry, integrated
            odom = compose(odom, between(truth[k], truth[k - 1]) + rng.normal(0, odometry_noise))
        scan.set_ranges(scan_at(world, truth[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, odom, stamp=float(k))
    # The SLAM's world frame is the first scan's: express the truth in it.
    return slam, between(truth, truth[0]), odom


def glitch_run(config, glitch_at=20, glitch_turn_deg=12.0):
    """Drive part of the demo loop with exact odometry; one scan is taken as if the robot had
    turned ``glitch_turn_deg`` more than it did (what a match that lost track reports)."""
    path = loop_path(80)[:30]
    world = room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path)
    slam = GraphSlam(config, seed=0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        seen = compose(path[k], [0.0, 0.0, np.radians(glitch_turn_deg)]) if k == glitch_at else path[k]
        scan.set_ranges(scan_at(world, seen, ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, path[k], float(k)).pose[2])
    truth = between(path, path[0])
    return slam, np.degrees(np.abs(wrap_angle(np.array(headings) - truth[:, 2])))


def heading_errors(config, world, path, reading, interval):
    """A run along ``path`` in ``world``, scans ``interval`` s apart, the odometry reading at
    scan k ``reading(k)``: the SLAM, and each scan's heading error (°) against the path's."""
    truth = between(path, path[0])
    slam = GraphSlam(config, seed=0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, reading(k), interval * k).pose[2])
    return slam, np.degrees(np.abs(wrap_angle(np.array(headings) - truth[:, 2])))


def hall_with_a_wall_held_twice(config, seed):
    """A hall 3 m wide with a door every 3 m, driven straight at 0.1 m a scan with exact
    odometry; once the third node is made, the node before it is turned 4.5° in the graph
    and the keyframe's submap rebuilt: it holds both walls twice, 4.5° apart (fr-clinic's
    halls after a node was placed off). The heading error of every later scan (°). The
    moved points' test is off: the copy's points in front of the walls the other node scans
    saw lie in their free space, and with them left out no seed goes more than 0.25° wrong
    even with both rules off (docs/method.md §6.1, "Moved points"). The rules tested here
    are for the copies nothing saw through."""
    walls = [[x, y, x + 2.2, y] for y in (-1.5, 1.5) for x in np.arange(-3.0, 30.0, 3.0)]
    world = np.array(walls + [[-3.0, -1.5, -3.0, 1.5]])
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(40)])
    slam = GraphSlam(override(config, {"front_end.drop_moved_points": False}), seed=seed)
    fe = slam.front_end
    rng = np.random.default_rng(seed)
    scan = PointScan(len(ANGLES))
    errors = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        heading = slam.step(scan, path[k], float(k)).pose[2]
        if errors or fe.keyframe >= 2:
            errors.append(abs(np.degrees(wrap_angle(heading))))
        if len(errors) == 1:
            slam.graph.poses[fe.keyframe - 1, 2] += np.radians(4.5)
            fe.submap.rebuild(fe.keyframe)
    return fe, np.array(errors[1:])


def worst_without_and_with(without, with_rule, counter):
    """The hall with a wall held twice on seeds 0–3, under a configuration without a rule and
    one with it: each seed's worst heading error (°) under both, and how often the rule acted
    (the front end's ``counter``), which must be never without it."""
    worst_without, worst_with, acted = [], [], 0
    for seed in range(4):
        fe, errors = hall_with_a_wall_held_twice(without, seed)
        assert getattr(fe.counts, counter) == 0
        worst_without.append(errors.max())
        fe, errors = hall_with_a_wall_held_twice(with_rule, seed)
        acted += getattr(fe.counts, counter)
        worst_with.append(errors.max())
    return worst_without, worst_with, acted


def drifted_chain(config, n=60, step=0.5, stretch=1.05):
    """A GraphSlam whose graph is a straight chain of ``n`` nodes with odometry 5% long (1.5 m
    of drift), and its back end ready to close loops measured by the truth."""
    slam = GraphSlam(config, seed=0)
    g, back = slam.graph, slam.back_end
    info = slam.front_end.information()
    for k in range(n):
        g.add_node([k * step * stretch, 0.0, 0.0], float(k))
        if k:
            g.add_edge(k - 1, k, [step * stretch, 0.0, 0.0], info)
    back.z_info[:] = slam.front_end.information(loop=True)
    return slam, back, np.array([(n - 2) * step, 0.0, 0.0])


def chain_with_wrong_loops(config, n=60, step=0.5, turn=0.003):
    """A GraphSlam whose graph is a chain of ``n`` nodes along a straight line, its odometry
    turning ``turn`` rad a step (2.2 m to the side after 55 nodes), and loops from nodes 0, 1
    and 2 to nodes 50, 51 and 52 kept where the drifted chain put them (a corner's L matched
    onto the other L, agreeing with the drift)."""
    slam = GraphSlam(config, seed=0)
    g, back = slam.graph, slam.back_end
    info = slam.front_end.information()
    z = np.array([step, 0.0, turn])
    g.add_node([0.0, 0.0, 0.0], 0.0)
    for k in range(1, n):
        g.add_node(compose(g.poses[k - 1], z), float(k))
        g.add_edge(k - 1, k, z, info)
    for k in range(3):
        g.add_edge(k, 50 + k, between(g.poses[50 + k], g.poses[k]),
                   slam.front_end.information(loop=True), LOOP)
    back.z_info[:] = slam.front_end.information(loop=True)
    return slam, back


def corridor_with_stale_odometry(config, period=4):
    """A plain corridor 2 m wide and 40 m long, driven straight at 0.1 m a scan with exact
    odometry read every ``period`` scans (the same reading in between, as a robot whose
    odometry comes less often than its scans logs it). The error (m) of each scan's motion
    from the one before, on the trajectory."""
    world = np.array([[-2.0, y, 38.0, y] for y in (-1.0, 1.0)])
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(60)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k - k % period], float(k))
    _, poses = slam.trajectory()
    steps = between(poses[1:], poses[:-1])  # each scan in the frame of the one before
    return slam.front_end, np.hypot(steps[:, 0] - 0.1, steps[:, 1])


def corridor_with_people(config, n=60):
    """A plain corridor 2 m wide, its ends out of reach of a scanner that sees 180° ahead
    (a SICK's view), driven at 0.1 m a scan with exact odometry; a person 0.4 m wide walks
    towards the robot at 0.15 m a scan, 0.45 m to its left (another starts 8 m further on
    once one has passed). The error (m) of each scan's position along the corridor."""
    walls = np.array([[-20.0, y, 40.0, y] for y in (-1.0, 1.0)])
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(n)])
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    angles = np.deg2rad(np.arange(-90.0, 90.5, 1.0))
    scan = PointScan(len(angles))
    for k in range(n):
        x = 6.0 - 0.15 * k + (8.0 if 6.0 - 0.15 * k < path[k, 0] + 0.5 else 0.0)
        person = np.array([[x - 0.2, 0.25, x + 0.2, 0.25], [x + 0.2, 0.25, x + 0.2, 0.65],
                           [x + 0.2, 0.65, x - 0.2, 0.65], [x - 0.2, 0.65, x - 0.2, 0.25]])
        world = np.vstack([walls, person])
        scan.set_ranges(scan_at(world, path[k], angles, 12.0, 0.01, rng), angles, 0.05, 12.0)
        slam.step(scan, path[k], float(k))
    _, poses = slam.trajectory()
    return np.abs(poses[:, 0] - path[:, 0])


def pivot_facing_a_near_wall(config):
    """A corridor 2 m wide ending in a wall; the robot drives up to 0.6 m from it, then turns
    on the spot 8° a scan, its odometry (exact) read every fourth scan and stale in between.
    The heading error (°) of each scan."""
    world = np.array([[-2.0, -1.0, 38.0, -1.0], [-2.0, 1.0, 38.0, 1.0], [2.5, -1.0, 2.5, 1.0]])
    turn = np.radians(8.0)
    path = np.array([[0.1 * k, 0.0, 0.0] for k in range(20)]
                    + [[1.9, 0.0, turn * k] for k in range(1, 9)] + [[1.9, 0.0, 8 * turn]] * 6)
    slam = GraphSlam(config, seed=0)
    rng = np.random.default_rng(0)
    scan = PointScan(len(ANGLES))
    headings = []
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01, rng), ANGLES, 0.05, 12.0)
        headings.append(slam.step(scan, path[k - k % 4], float(k)).pose[2])
    return np.degrees(np.abs(wrap_angle(np.array(headings) - path[:, 2])))


def tracked_in_a_room():
    """A SLAM that tracked twelve scans of a room's loop with exact odometry: its front end,
    the last scan and that scan's pose in its keyframe's frame."""
    path = loop_path(80)[:12]
    return _tracked(room_world(0, size=(12.0, 9.0), boxes=14, walls=0, keep_clear=path), path)


def tracked_in_a_corridor():
    """:func:`tracked_in_a_room` down a plain corridor 2 m wide, 0.1 m a scan: every pose
    along it fits a scan as well as another."""
    world = np.array([[-20.0, y, 40.0, y] for y in (-1.0, 1.0)])
    return _tracked(world, np.array([[0.1 * k, 0.0, 0.0] for k in range(12)]))


def _tracked(world, path):
    slam = GraphSlam(SlamConfig(), seed=0)
    scan = PointScan(len(ANGLES))
    for k in range(len(path)):
        scan.set_ranges(scan_at(world, path[k], ANGLES, 12.0, 0.01), ANGLES, 0.05, 12.0)
        slam.step(scan, path[k], float(k))
    return slam.front_end, scan, slam.front_end.rel.copy()
