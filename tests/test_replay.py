"""``swarmslam replay``: what its timing covers (scripts/replay.py)."""

import json
import subprocess
import sys

from swarmslam.cli import main

PROBE = """
import json, sys
from swarmslam.replay import replay_run
from swarmslam.runtime.scan_matcher import align_kernel
from swarmslam.runtime.sparse_ldl import ldl_factor
from swarmslam.runtime.wide_loop_search import nodes_within
seen = {}
def before_scan(k, runtime):
    if k == 0:  # the clock has started; nothing of the log has been processed yet
        seen.update(matcher=len(align_kernel.signatures), solver=len(ldl_factor.signatures),
                    wide=len(nodes_within.signatures))
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
