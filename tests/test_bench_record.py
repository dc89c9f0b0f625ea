"""Every benchmark JSON says what made it (swarmslam.bench.record): commit, date, command,
machine, versions, and whether another benchmark shared the machine."""

import json
import os
import re
import signal
import subprocess
import sys

from swarmslam.bench.record import Watch, other_processes, save_results, source_commit


def test_the_json_records_the_code_the_machine_and_the_conditions(tmp_path):
    path = tmp_path / "bench.json"
    save_results(path, {"benchmark": "x", "figure": 1.5}, Watch())
    data = json.loads(path.read_text())
    assert data["figure"] == 1.5
    meta = data["meta"]
    assert re.fullmatch(r"[0-9a-f]{40}", meta["commit"]) and isinstance(meta["dirty"], bool)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", meta["date"])
    assert meta["cpu"] and meta["cores"] >= 1 and meta["cores_usable"] >= 1
    # the CPU the kernels were compiled for, as LLVM names it (a model name may not tell)
    assert re.fullmatch(r"[a-z][a-z0-9_.-]*", meta["cpu_target"])
    assert meta["python"].count(".") == 2 and meta["numba"] and meta["numpy"]
    assert meta["command"] and isinstance(meta["shared_machine"], bool)


def test_another_benchmark_running_beside_it_is_seen():
    """(Started through a shell that exits at once: a process of this one's own — a worker —
    is not another benchmark.)"""
    started = subprocess.run(["sh", "-c", f"'{sys.executable}' -c 'import time; "
                              "time.sleep(30)' swarmslam bench slam >/dev/null 2>&1 & echo $!"],
                             capture_output=True, text=True, check=True)
    pid = int(started.stdout)
    try:
        assert any("swarmslam bench slam" in line for line in other_processes())
        assert Watch().stop()["shared_machine"] is True
    finally:
        os.kill(pid, signal.SIGKILL)


def test_uncommitted_changes_count_only_in_the_sources(tmp_path):
    """A benchmark's own results or the docs changed since the commit leave its figures the
    commit's; a changed source file does not."""
    def git(*args):
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True)

    for name in ("runtime/core.py", "bench-results/slam.json", "docs/method.md"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text("1\n")
    git("init", "-q")
    git("add", "-A")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "x")
    commit, dirty = source_commit(tmp_path)
    assert re.fullmatch(r"[0-9a-f]{40}", commit) and dirty is False
    (tmp_path / "bench-results/slam.json").write_text("2\n")
    (tmp_path / "docs/method.md").write_text("2\n")
    assert source_commit(tmp_path) == (commit, False)
    (tmp_path / "runtime/core.py").write_text("2\n")
    assert source_commit(tmp_path) == (commit, True)
    assert source_commit(tmp_path / "runtime" / "nowhere") == (None, None)
