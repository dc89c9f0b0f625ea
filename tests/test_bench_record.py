"""Every benchmark JSON says what made it (swarmslam.bench.record): commit, date, command,
machine, versions, and whether another benchmark shared the machine."""

import json
import os
import re
import signal
import subprocess
import sys

from swarmslam.bench.record import Watch, other_processes, save_results


def test_the_json_records_the_code_the_machine_and_the_conditions(tmp_path):
    path = tmp_path / "bench.json"
    save_results(path, {"benchmark": "x", "figure": 1.5}, Watch())
    data = json.loads(path.read_text())
    assert data["figure"] == 1.5
    meta = data["meta"]
    assert re.fullmatch(r"[0-9a-f]{40}", meta["commit"]) and isinstance(meta["dirty"], bool)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", meta["date"])
    assert meta["cpu"] and meta["cores"] >= 1 and meta["cores_usable"] >= 1
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
