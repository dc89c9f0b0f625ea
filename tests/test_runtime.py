"""The fixed-rate runtime: lockstep = GraphSlam.step, sliced back end under deadline pressure,
capacities, sessions (save → kill → resume, corrupt files), and no memory growth per tick."""

import gc
import json
import os
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from swarmslam.runtime.realtime import allocator
from swarmslam.runtime.back_end.slices import CLOSE
from swarmslam.runtime.config import (
    MatcherConfig,
    RuntimeConfig,
    SensorConfig,
    SlamConfig,
    SwarmConfig,
    override,
    to_dict,
)
from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
from swarmslam.runtime.realtime.inbox import ScanInbox
from swarmslam.runtime.pose import between, compose
from swarmslam.runtime.pose_graph import LOOP
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime import session
from swarmslam.runtime.realtime.session import SessionError, read_session, write_session
from swarmslam.runtime.slam import GraphSlam
from swarmslam.runtime.realtime.warm_up import LoopDrive

from old_sessions import as_early_version_6, as_version_6, as_version_7, as_version_8
from source_layout import copy_installed_layout

# A small swarm budget keeps the long runs quick; the code paths are the same at any budget.
# LoopDrive's scanner reaches 12 m ("no return" reads 12).
QUICK = SlamConfig(sensor=SensorConfig(max_range=12.0),
                   matcher=MatcherConfig(swarm=SwarmConfig(max_evaluations=400),
                                         refine_evaluations=100))


def with_runtime(config, **fields):
    """``config`` with a runtime section of these fields (the rest default)."""
    return replace(config, runtime=RuntimeConfig(**fields))


LOCKSTEP = with_runtime(QUICK, schedule="lockstep")


def recorded_drive(steps, seed=0):
    """``steps`` of a LoopDrive, recorded once, as (truth, odometry, ranges) lists."""
    drive = LoopDrive(seed)
    out = [drive.next() for _ in range(steps)]
    return drive.angles, out


def feed(runtime, angles, records, first=0):
    scan = PointScan(len(angles))
    results = []
    for k, (_, odometry, ranges) in enumerate(records):
        scan.set_ranges(ranges, angles, 0.05, 12.0)
        results.append(runtime.process(scan, odometry, float(first + k)))
    return results


def truth_in_map(records):
    truth = np.array([r[0] for r in records])
    return between(truth, truth[0])


def test_lockstep_runtime_is_graph_slam_step_scan_by_scan():
    angles, records = recorded_drive(120)
    runtime = SlamRuntime(LOCKSTEP, seed=5)
    slam = GraphSlam(QUICK, seed=5)
    scan = PointScan(len(angles))
    for k, (_, odometry, ranges) in enumerate(records):
        scan.set_ranges(ranges, angles, 0.05, 12.0)
        a = runtime.process(scan, odometry, float(k))
        b = slam.step(scan, odometry, float(k))
        assert np.array_equal(a.pose, b.pose), k
        assert (a.node_added, a.loop_closed) == (b.node_added, b.loop_closed), k
    assert slam.loops_closed >= 1
    n = slam.graph.n_nodes
    assert np.array_equal(runtime.slam.graph.poses[:n], slam.graph.poses[:n])


def test_inbox_keeps_the_newest_scan_and_counts_the_stale_ones():
    runtime = SlamRuntime(LOCKSTEP)
    angles, records = recorded_drive(3)
    for k, (_, odometry, ranges) in enumerate(records):
        runtime.inbox.put_ranges(angles=angles, ranges=ranges, stamp=float(k), odometry=odometry)
    runtime.tick()
    assert runtime.inbox.stale == 2
    assert runtime.slam.front_end.scans.stamp[0] == 2.0  # the newest one was taken
    assert runtime.tick() is None  # nothing new: an idle tick
    assert runtime.stats.ticks == 2 and runtime.stats.scans == 1
    empty = np.full(len(angles), np.inf)
    assert not runtime.inbox.put_ranges(angles=angles, ranges=empty, stamp=3.0, odometry=None)
    assert runtime.inbox.empty == 1 and runtime.tick() is None


def test_inbox_counts_the_scans_it_cuts_to_max_points():
    """A scan with more usable points than `sensor.max_points` keeps its first ones and is
    counted (a live scanner faster than its preset); beams with no return do not count
    towards it."""
    inbox = ScanInbox(10, 0.1, 8.0)
    angles = np.linspace(-1.0, 1.0, 15)
    ranges = np.full(15, 2.0)
    assert inbox.put_ranges(angles=angles, ranges=ranges, stamp=0.0) and inbox.cut == 1
    assert inbox.take(PointScan(10), np.zeros(3))[0] and inbox.cut == 1
    ranges[:5] = np.inf  # 10 usable: all kept
    assert inbox.put_ranges(angles=angles, ranges=ranges, stamp=1.0) and inbox.cut == 1
    points = np.c_[np.cos(angles), np.sin(angles)]
    assert inbox.put_points(points, 15, stamp=2.0) and inbox.cut == 2
    points[:5] = np.nan
    assert inbox.put_points(points, 15, stamp=3.0) and inbox.cut == 2
    assert "2 scans' points beyond sensor.max_points" in inbox.skipped()
    restored = ScanInbox(10)
    restored.restore(inbox.state())
    assert restored.cut == 2


def test_slow_matcher_defers_back_end_work_which_completes_later():
    angles, records = recorded_drive(240)
    runtime = SlamRuntime(with_runtime(QUICK, rate_hz=10, tick_budget=0.02), seed=1)
    align = runtime.slam.front_end.matcher.align_into
    slow = {"on": False}

    def slow_align(*args):
        if slow["on"]:
            time.sleep(0.12)  # beyond the 0.1 s period
        return align(*args)

    runtime.slam.front_end.matcher.align_into = slow_align
    feed(runtime, angles, records[:120])
    searched_before = runtime.slam.back_end.counts.searched
    slow["on"] = True
    feed(runtime, angles, records[120:160], first=120)
    during = runtime.report()
    slow["on"] = False
    feed(runtime, angles, records[160:], first=160)
    idle = 0
    while runtime.slam.back_end.pending() and idle < 200:  # idle ticks: the back end catches up
        runtime.tick()
        idle += 1
    report = runtime.report()
    assert during["deadline_misses"] >= 40  # every slow tick missed its deadline, counted
    assert during["deferred_ticks"] > 0  # ... and the back end waited for time
    assert during["evaluation_share"] == pytest.approx(0.25)  # the swarm was cut to its floor
    assert runtime.slam.back_end.counts.searched > searched_before
    assert report["loop_searches"]["pending"] == 0  # nothing left behind ...
    assert report["loop_searches"]["done"] == report["loop_searches"]["enqueued"]  # ... or lost
    assert report["loop_searches"]["dropped"] == 0
    assert report["loops_accepted"] >= 5
    _, poses = runtime.trajectory()
    err = np.hypot(*(poses[:, :2] - truth_in_map(records)[:, :2]).T)
    assert err.max() < 0.3, err.max()


def test_budgeted_ticks_stay_near_their_budget_when_the_swarm_must_shrink():
    angles, records = recorded_drive(60)
    runtime = SlamRuntime(with_runtime(QUICK, tick_budget=0.0005))
    feed(runtime, angles, records)
    # Half a millisecond cannot hold a full match: the swarm ran at its floor share.
    assert runtime.stats.evaluation_share == pytest.approx(0.25)
    assert runtime.slam.front_end.matcher.settings[8] == 100  # S_MAX_EVALS: a quarter of 400


def test_capacities_reached_keep_localising_and_say_so():
    angles, records = recorded_drive(200)
    config = override(LOCKSTEP, {"capacity.max_nodes": 12, "capacity.max_edges": 30,
                                 "capacity.max_scans": 150})
    runtime = SlamRuntime(config)
    results = feed(runtime, angles, records)
    assert runtime.slam.graph.n_nodes == 12
    assert runtime.slam.front_end.scans.n == 150
    assert "capacity reached" in runtime.status
    # the pose is still tracked against the last node after the graph froze
    truth = truth_in_map(records)
    poses = np.array([r.pose for r in results])
    err = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    assert err[-50:].max() < 0.3, err[-50:].max()


def test_a_full_loop_queue_drops_the_oldest_search_and_says_so():
    angles, records = recorded_drive(120)
    runtime = SlamRuntime(with_runtime(QUICK, loop_queue=2, tick_budget=0.0005,
                                               max_deferred_ticks=1000))
    feed(runtime, angles, records)
    assert runtime.slam.back_end.counts.dropped > 0
    assert "loop queue full" in runtime.status


def test_a_wide_loop_search_is_spread_over_slices_in_the_budgeted_schedule():
    """Budgeted, a wide search runs as many WIDE slices (docs/runtime.md §3), each a part of
    its grid or of its branch and bound, and every search still ends; in lockstep it is one."""
    angles, records = recorded_drive(160)
    wide = {"loop_closure.wide_search.after": 1, "loop_closure.wide_search.min_gap": 1,
            "loop_closure.wide_search.radius": 4.0, "loop_closure.wide_search.slice_cells": 500,
            "loop_closure.wide_search.slice_blocks": 20}
    counts = {}
    for schedule in ("lockstep", "budgeted"):
        runtime = SlamRuntime(override(with_runtime(QUICK, schedule=schedule), wide), seed=2)
        feed(runtime, angles, records)
        runtime.drain()
        back = runtime.slam.back_end
        counts[schedule] = (int(back.slices[3]), back.wide.searches)
        report = runtime.report()["loop_searches"]
        assert report["pending"] == 0 and report["done"] == report["enqueued"]
        assert back.wide.searches > 0 and runtime.slam.loops_closed > 0
    slices, searches = counts["lockstep"]
    # one slice per search (one that finds no old node within reach ends before rendering)
    assert searches <= slices <= 1.1 * searches + 1, counts
    slices, searches = counts["budgeted"]
    assert slices > 10 * searches, counts


def test_after_a_wide_search_that_fits_nowhere_the_next_nodes_are_not_searched_widely():
    """A wide search that finds no pose where the scan fits says the robot is on new ground;
    the ``wide_search.spacing`` − 1 nodes after it see much the same and are not searched widely. A
    search that fitted the scan somewhere (a rival, no second look yet) is followed at the
    next node, as without the rule (docs/method.md §5, "after a long drift")."""
    angles, records = recorded_drive(160)
    wide = {"loop_closure.wide_search.after": 1, "loop_closure.wide_search.min_gap": 1,
            "loop_closure.wide_search.radius": 4.0}
    searched = {}
    for spacing in (1, 4):
        runtime = SlamRuntime(override(LOCKSTEP, {**wide, "loop_closure.wide_search.spacing": spacing}),
                              seed=2)
        back = runtime.slam.back_end
        log = searched[spacing] = []
        search = back.wide.search

        def recorded(poses, nodes, node, since=0, sliced=False, search=search, log=log):
            proposal = yield from search(poses, nodes, node, since, sliced)
            log.append((node, back.wide.fitted))
            return proposal

        back.wide.search = recorded
        feed(runtime, angles, records)
        runtime.drain()
    spaced = searched[4]
    gaps = [(b[0] - a[0], a[1]) for a, b in zip(spaced, spaced[1:])]
    assert any(fitted == 0 for _, fitted in gaps) and any(fitted > 0 for _, fitted in gaps)
    assert all(gap >= 4 for gap, fitted in gaps if fitted == 0), gaps
    assert any(gap < 4 for gap, fitted in gaps if fitted > 0), gaps
    assert len(spaced) < len(searched[1])
    assert any(b[0] - a[0] < 4 and a[1] == 0 for a, b in zip(searched[1], searched[1][1:]))


# ---------------------------------------------------------------------- sessions
RUN_AND_DIE = textwrap.dedent(
    """
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    from test_runtime import LOCKSTEP, QUICK, feed, recorded_drive
    from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
    angles, records = recorded_drive({steps})
    runtime = SlamRuntime(LOCKSTEP, seed=7)
    feed(runtime, angles, records[:{cut}])
    runtime.save({path!r})
    feed(runtime, angles, records[{cut}:{cut} + 5], first={cut})  # work after the save is lost
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_save_kill_resume_continues_the_same_run(tmp_path):
    steps, cut = 160, 90
    path = tmp_path / "robot.session"
    code = RUN_AND_DIE.format(tests=os.path.dirname(__file__), steps=steps, cut=cut,
                              path=str(path))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=os.path.dirname(os.path.dirname(__file__)), timeout=600)
    assert done.returncode == -9, done.stderr  # killed, not exited
    resumed = SlamRuntime.resume(path)
    angles, records = recorded_drive(steps)
    feed(resumed, angles, records[cut:], first=cut)
    whole = SlamRuntime(LOCKSTEP, seed=7)
    feed(whole, angles, records)
    a, b = resumed.slam.graph, whole.slam.graph
    assert a.n_nodes == b.n_nodes and a.n_edges == b.n_edges
    assert np.array_equal(a.poses[: a.n_nodes], b.poses[: b.n_nodes])
    assert np.array_equal(a.ij[: a.n_edges], b.ij[: b.n_edges])
    assert np.array_equal(resumed.trajectory()[1], whole.trajectory()[1])
    assert resumed.slam.loops_closed == whole.slam.loops_closed >= 1


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    angles, records = recorded_drive(50)
    runtime = SlamRuntime(LOCKSTEP)
    feed(runtime, angles, records)
    path = tmp_path_factory.mktemp("session") / "good.session"
    runtime.save(path)
    return runtime, path


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty"])
def test_corrupt_session_files_are_refused_naming_the_file(saved, tmp_path, damage):
    _, good = saved
    data = good.read_bytes()
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":  # one bit inside an array's bytes: only the checksum can tell
        i = data.index(b"graph.poses") + 400
        data = data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:]
    elif damage == "garbage":
        data = b"not a session at all\n" * 10
    else:
        data = b""
    bad = tmp_path / "bad.session"
    bad.write_bytes(data)
    with pytest.raises(SessionError, match="bad.session"):
        SlamRuntime.resume(bad)


def test_a_session_whose_tracking_submap_is_not_its_own_is_refused(saved, tmp_path):
    runtime, _ = saved
    state = runtime.state()
    front = state["slam"]["front_end"]
    assert len(front["submap_nodes"]) == 3  # the default tracks against three node scans
    front["submap_nodes"] = front["submap_nodes"] - 1  # not ending at the keyframe
    bad = tmp_path / "foreign.session"
    write_session(bad, state)
    with pytest.raises(SessionError, match="submap"):
        SlamRuntime.resume(bad)


def test_a_session_keeps_the_scan_the_next_match_is_checked_against(saved, tmp_path):
    """The front end checks each match against the scan tracked before it (docs/method.md
    §6.1): a resumed session has that scan, and refuses one that is not a scan's points."""
    runtime, path = saved
    kept = runtime.state()["slam"]["front_end"]["previous_points"]
    assert kept.shape[0] > 100 and kept.shape[1] == 2
    resumed = SlamRuntime.resume(path).state()["slam"]["front_end"]["previous_points"]
    assert np.array_equal(resumed, kept)
    state = runtime.state()
    state["slam"]["front_end"]["previous_points"][3, 1] = np.nan
    bad = tmp_path / "nan.session"
    write_session(bad, state)
    with pytest.raises(SessionError, match="previous scan"):
        SlamRuntime.resume(bad)


def _counted(runtime) -> dict:
    """Every tally a run's report holds (none of its timings)."""
    r = runtime.report()
    keys = ("tracking", "loops", "loop_searches", "back_end_slices", "wide_searches",
            "deferred_ticks", "forced_slices", "stale_scans", "empty_scans", "cut_scans")
    return {k: r[k] for k in keys}


def test_a_resumed_run_keeps_every_count(saved, tmp_path):
    """Every tally is saved whole: after --resume the report counts on from where the saved
    run stood, the front end's five rule counts as well (they once reset to zero)."""
    runtime, _ = saved
    slam = runtime.slam
    for k, counts in enumerate((slam.front_end.counts, slam.back_end.loops.counts,
                                slam.back_end.counts)):
        for j, name in enumerate(vars(counts)):
            setattr(counts, name, 100 * (k + 1) + j + 1)  # each a value of its own
    path = tmp_path / "counted.session"
    runtime.save(path)
    resumed = SlamRuntime.resume(path)
    assert _counted(resumed) == _counted(runtime)
    assert resumed.report()["tracking"]["held_to_odometry"] == 107
    state = runtime.state()
    state["slam"]["front_end"]["counts"]["sought_matches"] = -1
    bad = tmp_path / "negative.session"
    write_session(bad, state)
    with pytest.raises(SessionError, match="sought_matches"):
        SlamRuntime.resume(bad)
    state["slam"]["front_end"]["counts"]["sought_matches"] = 3
    del state["slam"]["back_end"]["counts"]["dropped"]
    write_session(bad, state)
    with pytest.raises(SessionError, match="SearchCounts"):
        SlamRuntime.resume(bad)


def test_a_version_6_session_resumes_through_its_migration(saved, tmp_path, monkeypatch):
    """A session an older build wrote (version 6: its tallies flat, five front-end counts not
    kept) is read through the migration: the same map and trajectory, the counts it kept, the
    others from zero. A version with no migration is refused by number."""
    runtime, _ = saved
    old = as_version_6(runtime.state())
    path = tmp_path / "v6.session"
    monkeypatch.setattr(session, "VERSION", 6)
    write_session(path, old)
    monkeypatch.undo()
    resumed = SlamRuntime.resume(path)
    assert np.array_equal(resumed.slam.node_poses(), runtime.slam.node_poses())
    assert np.array_equal(resumed.trajectory()[1], runtime.trajectory()[1])
    counts = resumed.slam.front_end.counts
    assert counts.lost_matches == runtime.slam.front_end.counts.lost_matches
    assert counts.sought_matches == counts.disowned_matches == 0
    assert vars(resumed.slam.back_end.loops.counts) == vars(runtime.slam.back_end.loops.counts)
    early = tmp_path / "early-v6.session"  # before every rule whose state came later
    monkeypatch.setattr(session, "VERSION", 6)
    write_session(early, as_early_version_6(runtime.state()))
    monkeypatch.undo()
    resumed = SlamRuntime.resume(early)
    assert np.array_equal(resumed.slam.node_poses(), runtime.slam.node_poses())
    assert resumed.slam.front_end.readings.period() == 0 and resumed.inbox.cut == 0
    assert resumed.slam.graph.scale == 1.0
    monkeypatch.setattr(session, "VERSION", 5)
    write_session(path, old)
    monkeypatch.undo()
    with pytest.raises(SessionError, match="version 5 is not supported"):
        SlamRuntime.resume(path)


def test_a_version_7_session_with_the_flat_configuration_resumes_as_it_was(saved, tmp_path,
                                                                           monkeypatch):
    """Version 7 saved the configuration in its flat names (``odometry_gate_share``,
    ``wide_after`` = 0 for off, the fixed internals as fields): the migration reads it as this
    version's tree, the same configuration, and the run resumes on the same map."""
    runtime, _ = saved
    changed = override(runtime.config, {"loop_closure.wide_search.enabled": False,
                                        "front_end.odometry_gate.share": (0.25, 0.3)})
    state = runtime.state()
    state["config"] = to_dict(changed)
    old = as_version_7(state)
    assert old["config"]["loop_closure"]["wide_after"] == 0
    assert tuple(old["config"]["front_end"]["odometry_gate_share"]) == (0.25, 0.3)
    path = tmp_path / "v7.session"
    monkeypatch.setattr(session, "VERSION", 7)
    write_session(path, old)
    monkeypatch.undo()
    resumed = SlamRuntime.resume(path)
    assert resumed.config == changed
    assert np.array_equal(resumed.slam.node_poses(), runtime.slam.node_poses())


def test_a_version_8_session_remembers_its_one_strained_loop_as_the_newest_of_a_group(
        saved, tmp_path, monkeypatch):
    """Version 8 remembered one loop refused for its own error; the migration makes it the
    newest row of the group's memory, the others empty, and the run resumes on the same map."""
    runtime, _ = saved
    state = runtime.state()
    be = state["slam"]["back_end"]
    be["strained"][0] = [3.0, 7.0, 0.5, -0.25, 0.125]
    be["strained_info"][0] = 4.0 * np.eye(3)
    old = as_version_8(state)
    assert np.shape(old["slam"]["back_end"]["strained"]) == (5,)
    path = tmp_path / "v8.session"
    monkeypatch.setattr(session, "VERSION", 8)
    write_session(path, old)
    monkeypatch.undo()
    resumed = SlamRuntime.resume(path)
    memory = resumed.slam.back_end.closure.memory
    assert list(memory.strained[0]) == [3.0, 7.0, 0.5, -0.25, 0.125]
    assert np.all(memory.strained[1:, :2] == -1.0)
    assert np.array_equal(memory.strained_info[0], 4.0 * np.eye(3))
    assert np.array_equal(resumed.slam.node_poses(), runtime.slam.node_poses())


def test_each_save_keeps_the_previous_good_session(saved, tmp_path):
    runtime, _ = saved
    path = tmp_path / "s.session"
    runtime.save(path)
    first = path.read_bytes()
    runtime.slam.front_end.counts.lost_matches += 1  # any change
    runtime.save(path)
    assert (tmp_path / "s.session.prev").read_bytes() == first
    # The current file is damaged (say, by a card fault): refused, pointing to the .prev one.
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(SessionError, match=r"previous session is at .*s\.session\.prev"):
        SlamRuntime.resume(path)
    assert SlamRuntime.resume(tmp_path / "s.session.prev").slam.front_end.counts.lost_matches == \
        runtime.slam.front_end.counts.lost_matches - 1


def test_an_interrupted_save_leaves_the_previous_file_intact(saved, tmp_path, monkeypatch):
    runtime, _ = saved
    path = tmp_path / "s.session"
    runtime.save(path)
    before = path.read_bytes()

    def power_cut(fd, *args):
        raise KeyboardInterrupt  # the write dies half-way

    monkeypatch.setattr(os, "fsync", power_cut)
    with pytest.raises(KeyboardInterrupt):
        write_session(path, runtime.state())
    assert path.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    read_session(path)  # still valid


# ---------------------------------------------------------------------- memory
SOAK_PROBE = textwrap.dedent(
    """
    import gc, json, sys, tracemalloc
    import numpy as np
    sys.path.insert(0, {tests!r})
    from test_runtime import QUICK, recorded_drive, with_runtime
    from swarmslam.runtime.config import override
    from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
    from swarmslam.runtime.pose import between, compose
    from swarmslam.runtime.matching.scan import PointScan

    angles, records = recorded_drive(80)  # one lap, driven again and again
    config = override(QUICK, {{"capacity.max_nodes": 500, "capacity.max_edges": 2500,
                              "capacity.max_scans": 20000}})
    runtime = SlamRuntime(with_runtime(config, tick_budget=0.05))
    runtime.warm_up()
    scans = []
    for _, _, ranges in records:
        s = PointScan(len(angles))
        s.set_ranges(ranges, angles, 0.05, 12.0)
        scans.append(s)
    motions = [between(records[k][0], records[k - 1][0]) for k in range(80)]
    odometry = np.array(records[0][0])
    noise = np.random.default_rng(0).normal(0.0, 1.0, (80, 3)) * (0.02, 0.02, 0.01)

    def drive(first, count):
        for k in range(first, first + count):
            if k:
                odometry[:] = compose(odometry, motions[k % 80] + noise[k % 80])
            runtime.process(scans[k % 80], odometry, float(k))

    tracemalloc.start()
    drive(0, 2000)
    warm = runtime.report()
    gc.collect()
    before = tracemalloc.get_traced_memory()[0]
    drive(2000, 10_000)
    gc.collect()
    after = tracemalloc.get_traced_memory()[0]
    print(json.dumps({{"warm": warm, "end": runtime.report(), "growth": after - before}}))
    """
)


def test_no_traced_memory_growth_over_ten_thousand_ticks_after_warm_up():
    """10⁴ budgeted ticks after a warm-up in which the graph grew to its node capacity
    (matching, node insertion, loop search, optimisation, capacity reached): traced memory at
    tick boundaries must not grow with the ticks.

    Any object kept per tick would add ≥ 24 B each tick (≥ 240 kB here); the bound is a tenth
    of that. What is measured (2–10 kB over five runs) are 50–60 B blocks allocated inside
    numba's and numpy's C calls, at a rate that falls over the process's life."""
    result = probe(SOAK_PROBE)
    warm, end = result["warm"], result["end"]
    assert warm["nodes"] == 500 and warm["loops_accepted"] > 20
    assert "capacity reached" in end["status"] and end["scans"] == 12_000
    assert result["growth"] <= 24_000, f"traced memory grew {result['growth']} B over 10⁴ ticks"


GROWTH_PROBE = textwrap.dedent(
    """
    import gc, json, sys, tracemalloc
    sys.path.insert(0, {tests!r})
    from test_runtime import LOCKSTEP, recorded_drive
    from swarmslam.runtime.config import override
    from swarmslam.runtime.realtime.fixed_rate import SlamRuntime
    from swarmslam.runtime.matching.scan import PointScan

    angles, records = recorded_drive(80)
    runtime = SlamRuntime(override(LOCKSTEP, {{"capacity.max_nodes": 600,
                                              "capacity.max_edges": 3000}}))
    runtime.warm_up()
    scan = PointScan(len(angles))

    def drive(first, count):
        for k in range(first, first + count):
            _, odometry, ranges = records[k % 80]
            scan.set_ranges(ranges, angles, 0.05, 12.0)
            runtime.process(scan, odometry, float(k))

    tracemalloc.start()
    drive(0, 400)
    gc.collect()
    nodes, before = runtime.slam.graph.n_nodes, tracemalloc.get_traced_memory()[0]
    drive(400, 500)
    gc.collect()
    after = tracemalloc.get_traced_memory()[0]
    print(json.dumps({{"added": runtime.slam.graph.n_nodes - nodes, "growth": after - before,
                      "loops": runtime.slam.loops_closed}}))
    """
)


def probe(template: str) -> dict:
    """Run a measurement in a fresh interpreter, as a robot's process would be (what other
    tests left in this one would be measured too)."""
    code = template.format(tests=os.path.dirname(__file__))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=os.path.dirname(os.path.dirname(__file__)), timeout=900)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_graph_growth_allocates_nothing_that_stays():
    """Node insertion, loop search and optimisation work in preallocated buffers."""
    result = probe(GROWTH_PROBE)
    assert result["added"] >= 150 and result["loops"] > 20
    # Before the capacity buffers, the sparsity pattern alone grew by ~400 B per node, and the
    # qdldl solver's scipy round trips kept more; now it is the C-call residue above (37–57 B
    # per node over four runs).
    assert result["growth"] < 150 * result["added"], result


KEPT_PROBE = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    sys.path.insert(0, {tests!r})
    from test_runtime import QUICK, with_runtime
    from swarmslam.bench.runtime import rss_kib
    from swarmslam.runtime.realtime.fixed_rate import SlamRuntime

    def rss_mib():
        return rss_kib()[0] / 1024

    def kept_after_free():
        big = np.ones(2**21)  # 16 MiB freed: glibc raises its thresholds past 1 MiB
        del big
        before = rss_mib()
        blocks = [np.ones(2**17) for _ in range(20)]  # 20 blocks of 1 MiB, then freed
        del blocks
        return rss_mib() - before

    plain = SlamRuntime(with_runtime(QUICK, schedule="lockstep"))
    unpinned = kept_after_free()
    robot = SlamRuntime(with_runtime(QUICK, schedule="budgeted"))
    print(json.dumps({{"pinned": [plain.allocator_pinned, robot.allocator_pinned],
                      "kept_unpinned": unpinned, "kept_pinned": kept_after_free()}}))
    """
)


@pytest.mark.skipif(allocator.glibc() is None, reason="mallopt's thresholds are glibc's")
def test_a_robots_runtime_gives_back_what_it_frees_after_a_large_block():
    """A runtime that commits its memory pins glibc's thresholds: blocks freed after one large
    block was freed go back to the system instead of staying resident (docs/runtime.md §4).
    The same process shows what happens unpinned first; a simulator's runtime pins nothing."""
    result = probe(KEPT_PROBE)
    assert result["pinned"] == [False, True]
    assert result["kept_unpinned"] > 15, result  # the phenomenon, on this C library
    assert result["kept_pinned"] < 2, result


def test_run_ticks_at_its_rate_and_stops_on_request():
    angles, records = recorded_drive(5)
    runtime = SlamRuntime(with_runtime(QUICK, rate_hz=50, tick_budget=0.015))
    stop = threading.Event()
    seen = []

    def on_tick(rt, result):
        seen.append(time.perf_counter())
        if len(seen) < len(records):
            _, odometry, ranges = records[len(seen)]
            rt.inbox.put_ranges(angles=angles, ranges=ranges, stamp=float(len(seen)), odometry=odometry)
        if len(seen) == 25:
            stop.set()

    runtime.inbox.put_ranges(angles=angles, ranges=records[0][2], stamp=0.0, odometry=records[0][1])
    runtime.run(stop, on_tick=on_tick)
    assert len(seen) == 25
    assert runtime.stats.scans == 5
    gaps = np.diff(seen)
    assert np.median(gaps) == pytest.approx(0.02, abs=0.008)


def test_autosave_waits_for_the_first_scan_then_saves(tmp_path):
    """A silent scanner (the wrong model, a dead port) must not replace the session file
    already there with an empty map; once scans come, the session is saved as it grows."""
    angles, records = recorded_drive(5)
    path = tmp_path / "session.npz"
    path.write_bytes(b"yesterday's session")
    runtime = SlamRuntime(with_runtime(QUICK, rate_hz=50, autosave_seconds=0.02))
    runtime.run(threading.Event(), max_ticks=15, autosave=path)
    runtime.autosave.wait()
    assert path.read_bytes() == b"yesterday's session" and runtime.autosave.saves == 0
    for k, (_, odometry, ranges) in enumerate(records):
        runtime.inbox.put_ranges(angles=angles, ranges=ranges, stamp=float(k), odometry=odometry)
        runtime.run(threading.Event(), max_ticks=3, autosave=path)
    runtime.autosave.wait()
    assert runtime.autosave.saves >= 1 and not runtime.autosave.error
    assert isinstance(read_session(path), dict)  # a whole session, verified


def test_a_robots_loop_keeps_what_lived_before_it_out_of_the_collector_until_it_ends():
    """While a committing runtime's loop runs, the objects alive when it began are frozen
    (no full collection walks them); when it ends they are handed back. A simulator's
    runtime, which commits nothing, leaves the collector alone."""
    angles, records = recorded_drive(3)
    gc.collect()
    assert gc.get_freeze_count() == 0
    for schedule, frozen in (("budgeted", True), ("lockstep", False)):
        runtime = SlamRuntime(with_runtime(QUICK, rate_hz=50, schedule=schedule))
        stop, during = threading.Event(), []

        def on_tick(rt, result):
            during.append(gc.get_freeze_count())
            if len(during) == 3:
                stop.set()

        runtime.inbox.put_ranges(angles=angles, ranges=records[0][2], stamp=0.0,
                                 odometry=records[0][1])
        runtime.run(stop, on_tick=on_tick)
        assert (min(during) > 1000) == frozen, (schedule, during)
        assert gc.get_freeze_count() == 0


def test_the_hand_off_cannot_swap_angles_and_ranges():
    """The driver calls back with (angles, ranges, stamp): a positional hand-over would take
    them in some order silently; keywords only make a wrong wiring fail at once."""
    runtime = SlamRuntime(LOCKSTEP)
    angles, records = recorded_drive(1)
    with pytest.raises(TypeError):
        runtime.inbox.put_ranges(angles, records[0][2], 0.0)
    assert runtime.inbox.put_ranges(angles=angles, ranges=records[0][2], stamp=0.0)



def test_the_same_seed_gives_the_same_run_compiled_or_loaded_from_the_cache(tmp_path):
    """A replay in a fresh copy of the sources (every kernel compiled in the process, cached
    beside them), then the same replay again (every kernel loaded from that cache): the
    trajectories must match bit for bit. With reassociation allowed in the objective's sum
    they did not (docs/runtime.md §6)."""
    copy = copy_installed_layout(tmp_path / "src")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(copy)  # ahead of the installed package

    def cli(*args):
        done = subprocess.run([sys.executable, "-m", "swarmslam.cli", *args], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr

    log = tmp_path / "b.clf"
    cli("simlog", str(log), "--site", "building", "--scanner", "sick-1", "--rate", "5",
        "--seconds", "300", "--odometry", "noisy")
    cli("replay", str(log), "--out", str(tmp_path / "cold"))
    assert any(copy.rglob("*.nbi"))  # the first run compiled and cached
    cli("replay", str(log), "--out", str(tmp_path / "warm"))
    cold = (tmp_path / "cold" / "trajectory.tum").read_bytes()
    assert cold == (tmp_path / "warm" / "trajectory.tum").read_bytes()


def test_the_budgeted_runtime_commits_its_buffers_at_start_up():
    """Every large preallocated array of the core is written once at start-up (so the
    resident size does not grow as buffers fill): the node scans, the reference grids, the
    factor. The walk finds the core's objects by their installed package name."""
    small = override(SlamConfig(), {"capacity.max_nodes": 200, "capacity.max_edges": 800,
                                    "capacity.max_scans": 1000})
    budgeted = SlamRuntime(small)
    slam = budgeted.slam
    grids = slam.front_end.reference.field.nbytes + slam.back_end.alignment.reference.field.nbytes
    assert budgeted.reserved_bytes >= slam.nodes.points.nbytes + grids
    lockstep = SlamRuntime(override(small, {"runtime.schedule": "lockstep"}))
    assert lockstep.reserved_bytes == 0  # the simulator's schedule: nothing committed


@pytest.fixture(scope="module")
def mapped():
    """A lockstep run around the loop: its state, and a closure the back end can try (the
    drive's first node seen from its last, as the graph has it, nudged)."""
    angles, records = recorded_drive(120)
    slam = GraphSlam(QUICK, seed=5)
    scan = PointScan(len(angles))
    for k, (_, odometry, ranges) in enumerate(records):
        scan.set_ranges(ranges, angles, 0.05, 12.0)
        slam.step(scan, odometry, float(k))
    g = slam.graph
    z = between(g.poses[g.n_nodes - 1], g.poses[1]) + np.array([0.05, -0.03, 0.01])
    return slam.state(), z


def trial_ready(mapped, z_offset=(0.0, 0.0, 0.0)):
    """A back end restored from ``mapped`` with the closure aligned (``z`` moved by
    ``z_offset``), and its candidate and node."""
    state, z = mapped
    slam = GraphSlam(QUICK, seed=5)
    slam.restore(state)
    back = slam.back_end
    back.z[:] = z + np.asarray(z_offset)
    back.z_info[:] = slam.front_end.information(loop=True)
    return slam, back, 1, slam.graph.n_nodes - 1


def add_node_as_front_end(graph, step):
    """What the front end does at a new node: placed by the newest node's pose and an edge."""
    node = graph.add_node(compose(graph.poses[graph.n_nodes - 1], step))
    graph.add_edge(node - 1, node, step, np.eye(3))
    return node


def test_a_closure_on_trial_is_optimised_a_step_per_slice_while_the_front_end_adds_nodes(mapped):
    """Budgeted, a CLOSE optimises a copy of the graph one Gauss–Newton step per slice
    (docs/runtime.md §3): the graph itself holds no trial edge between slices, the nodes the
    front end adds meanwhile stay where it put them relative to their predecessor, and the
    closure kept gives the old nodes the poses an atomic one gives."""
    slam, back, candidate, node = trial_ready(mapped)
    assert back.close_loop(candidate, node, back.z)
    g = slam.graph
    atomic, n = g.poses[: g.n_nodes].copy(), g.n_nodes
    assert g.kind[g.n_edges - 1] == LOOP

    slam, back, candidate, node = trial_ready(mapped)
    g = slam.graph
    edges, before = g.n_edges, g.poses[:n].copy()
    steps = back.closure.steps(candidate, node, back.z, back.z_info, False)
    next(steps)  # the first step: more are to come
    assert g.n_edges == edges and np.array_equal(g.poses[:n], before)
    step = np.array([0.3, 0.02, 0.05])
    added = [add_node_as_front_end(g, step) for _ in range(2)]
    with pytest.raises(StopIteration) as stop:
        while True:
            next(steps)
    assert stop.value.value == candidate  # kept: the edge's old end
    assert np.array_equal(g.poses[:n], atomic[:n])  # the same solve, only later
    assert tuple(g.ij[g.n_edges - 1]) == (candidate, node) and g.kind[g.n_edges - 1] == LOOP
    assert g.n_edges == edges + 3  # two node edges, then the loop edge
    moved = between(g.poses[n - 1], before[n - 1])
    assert np.linalg.norm(moved[:2]) > 1e-3  # the closure moved the newest old node ...
    for k in added:  # ... and its successors with it
        assert np.allclose(between(g.poses[k], g.poses[k - 1]), step, atol=1e-12)


def test_a_closure_refused_after_its_slices_leaves_the_graph_as_the_front_end_left_it(mapped):
    slam, back, candidate, node = trial_ready(mapped, z_offset=(3.0, -2.0, 0.8))
    g = slam.graph
    steps = back.closure.steps(candidate, node, back.z, back.z_info, False)
    next(steps)
    add_node_as_front_end(g, np.array([0.3, 0.0, 0.0]))
    edges, before = g.n_edges, g.poses[: g.n_nodes].copy()
    rejected = back.loops.counts.rejected_consistency
    with pytest.raises(StopIteration) as stop:
        while True:
            next(steps)
    assert stop.value.value == -1 and back.loops.counts.rejected_consistency == rejected + 1
    assert g.n_edges == edges and np.array_equal(g.poses[: g.n_nodes], before)


def test_a_session_saved_during_a_trial_resumes_it_from_the_start(mapped):
    """The saved graph has no trial edge; the restored back end runs the CLOSE again and keeps
    the same closure with the same poses."""
    slam, back, candidate, node = trial_ready(mapped)
    back.candidates[0], back.n_candidates, back.next_candidate = candidate, 1, 0
    back.node, back.phase = node, CLOSE
    edges = slam.graph.n_edges
    back._run_slice(CLOSE, sliced=True)
    assert back._closing is not None and back.phase == CLOSE  # under way
    state = slam.state()
    assert len(state["graph"]["ij"]) == edges
    back.work(None, None)
    expected = slam.graph.poses[: slam.graph.n_nodes].copy()
    resumed = GraphSlam(QUICK, seed=5)
    resumed.restore(state)
    resumed.back_end.work(None, None)
    g = resumed.graph
    assert g.n_edges == edges + 1 and g.kind[edges] == LOOP
    assert np.array_equal(g.poses[: g.n_nodes], expected)
