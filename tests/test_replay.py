"""``swarmslam replay``: what its timing covers (scripts/replay.py)."""

import json
import math
import subprocess
import sys

import numpy as np

from swarmslam.cli import main
from swarmslam.replay import node_bound, replay_config, replay_run
from swarmslam.runs import RunOptions
from swarmslam.runtime.config import SlamConfig, override

PROBE = """
import json, sys
from swarmslam.replay import replay_run
from swarmslam.runtime.matching.scan_matcher import align_kernel, global_stage, local_stages
from swarmslam.runtime.back_end.sparse_ldl import ldl_factor
from swarmslam.runtime.back_end.wide_loop_search import nodes_within
seen = {}
def before_scan(k, runtime):
    if k == 0:  # the clock has started; nothing of the log has been processed yet
        seen.update(matcher=len(align_kernel.signatures), solver=len(ldl_factor.signatures),
                    wide=len(nodes_within.signatures), loop=len(global_stage.signatures),
                    loop_local=len(local_stages.signatures))
metrics, _ = replay_run(sys.argv[1], limit=30, before_scan=before_scan)
print(json.dumps({"seen": seen, "warm_up_seconds": metrics.get("warm_up_seconds", 0.0)}))
"""


def test_the_kernels_are_warm_before_the_replay_clock_starts(tmp_path):
    """A replay's real-time factor is the run's, not the compiler's: in a fresh process,
    where numba compiles or loads each kernel at its first call, the matcher's, the graph
    solver's and the wide loop search's kernels have run before the first scan is timed — as
    a robot's runtime warms up before its first tick (docs/runtime.md §6)."""
    log = tmp_path / "s.clf"
    assert main(["simlog", str(log), "--scanner", "sick-1", "--rate", "5",
                 "--seconds", "8"]) == 0
    out = subprocess.run([sys.executable, "-c", PROBE, str(log)], capture_output=True,
                         text=True, check=True).stdout
    report = json.loads(out.strip().splitlines()[-1])
    assert all(n >= 1 for n in report["seen"].values()), report
    assert report["warm_up_seconds"] > 0


def test_a_replay_sizes_the_pose_graph_for_the_log_in_lockstep(tmp_path):
    """A log's length is known before its replay starts: in lockstep the graph holds a node per
    scan at most, whatever the configuration's capacity, so a long log never freezes its map.
    The budgeted schedule replays as the robot runs, within the configuration's capacities."""
    log = tmp_path / "s.clf"
    assert main(["simlog", str(log), "--scanner", "sick-1", "--rate", "5",
                 "--seconds", "12"]) == 0
    small = override(SlamConfig(), {"capacity.max_nodes": 3, "capacity.max_edges": 12})
    sized = replay_config(small, scans=60, nodes=61)
    assert (sized.capacity.max_nodes, sized.capacity.max_edges) == (61, 244)
    assert replay_config(small, scans=60, schedule="budgeted", nodes=61).capacity == small.capacity
    assert replay_config(None, scans=60, nodes=61).capacity == SlamConfig().capacity  # room
    metrics, _ = replay_run(log, options=RunOptions(small), label="lockstep")
    assert metrics["status"] == "ok" and metrics["nodes"] > 3
    metrics, _ = replay_run(log, options=RunOptions(small, schedule="budgeted"),
                            label="budgeted")
    assert metrics["nodes"] == 3 and metrics["status"].startswith("capacity reached")


def test_a_replays_node_bound_holds_what_odometry_allows():
    """A node needs `node_distance` of path or `node_angle` of turn since the last: a robot
    that drives 10 m and turns a full circle makes no more than 20 + 13 nodes (the bound
    doubles that); scans only, or odometry missing, bound it by the scans."""

    class Record:
        def __init__(self, odometry):
            self.odometry = np.asarray(odometry, dtype=np.float64)

    drive = [Record((0.1 * k, 0.0, 0.0)) for k in range(101)]  # 10 m in 100 steps
    turn = [Record((10.0, 0.0, math.remainder(k * math.pi / 50, 2 * math.pi)))
            for k in range(1, 101)]  # a full circle, wrapping at ±π
    lasers = drive + turn
    assert node_bound(lasers, None, True) == 2 * math.ceil(20 + 2 * math.pi / 0.5) + 2
    assert node_bound(lasers, None, False) == len(lasers) + 1
    lasers[5] = Record((math.nan, 0.0, 0.0))
    assert node_bound(lasers, None, True) == len(lasers) + 1
    assert node_bound(drive[:3], None, True) == 4  # never more than a node per scan


def test_a_replay_keeps_every_beam_of_a_scanner_larger_than_the_configuration(tmp_path):
    """The runtime keeps a scan's first `sensor.max_points` points: a 720-beam scanner read
    with a configuration for 400 would lose the last 44% of each sweep. A replay sizes the
    stored scans for the log's largest scan instead."""
    log = tmp_path / "a2.clf"
    assert main(["simlog", str(log), "--scanner", "rplidar-a2", "--rate", "5",
                 "--seconds", "4"]) == 0
    small = override(SlamConfig(), {"sensor.max_points": 400})
    _, runtime = replay_run(log, options=RunOptions(small), label="a2")
    assert runtime.config.sensor.max_points == 720
    nodes = runtime.slam.nodes
    assert nodes.counts[: runtime.slam.graph.n_nodes].max() > 400


def test_the_warm_up_compiles_the_inboxs_count_of_a_cut_scan():
    """A scan cut to `sensor.max_points` is counted by two compiled kernels that no warm-up
    scan reaches: the warm-up runs them itself, so the first cut scan of a live run compiles
    nothing (in a fresh process, as a robot starts)."""
    probe = ("from swarmslam.runtime.realtime.fixed_rate import SlamRuntime\n"
             "from swarmslam.runtime.matching.scan import usable_beams, usable_points\n"
             "SlamRuntime().warm_up()\n"
             "print(len(usable_beams.signatures), len(usable_points.signatures))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout
    assert out.split()[-2:] == ["1", "2"]
