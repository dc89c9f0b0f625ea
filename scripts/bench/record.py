"""What every benchmark's JSON records beside its figures (``meta``), so a figure can be traced
to the code, the machine and the conditions that made it: the commit (and whether its sources
had uncommitted changes), the date, the command line, the CPU model and core count, the
Python, numpy and numba versions, and whether another benchmark (or test run) shared the
machine while it ran — sampled every few seconds, since speed figures taken beside another
load are not comparable.

    watch = start_watch()            # when the benchmark starts
    ...
    save_results(path, results)      # results["meta"] filled in, written atomically
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import llvmlite.binding
import numba
import numpy as np

from swarmslam.runtime.realtime.writers import write_json_atomic

SAMPLE_SECONDS = 5.0  # how often other processes are looked for
# Command lines that mark another benchmark or test run (heavy, CPU-bound work).
OTHERS = (("swarmslam", "bench"), ("pytest",), ("swarmslam", "replay"), ("swarmslam", "sweep"))


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith(("model name", "hardware", "processor\t: arm")):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def cpu_target() -> str:
    """The CPU numba compiles the kernels for (LLVM's name: ``znver3``, ``znver4``, ...). Two
    machines alike to ``/proc/cpuinfo``'s model name ("AMD EPYC") can differ here, and with
    them the kernels' vector width and the figures' speed."""
    return llvmlite.binding.get_host_cpu_name()


# What a benchmark runs: a change elsewhere (its own results, the docs, the tests) leaves the
# figures as the commit's code makes them.
SOURCES = ("runtime", "hardware", "swarmslam_sim", "scripts", "worlds", "pyproject.toml")


def source_commit(root: Path | None = None) -> tuple[str | None, bool | None]:
    """The git commit of the sources that run, and whether they differ from it — the
    package folders and pyproject.toml, not the results or the docs (None, None when they
    are not a git checkout: an installed copy). ``root``: the checkout (default: this one)."""
    root = Path(__file__).resolve().parent.parent.parent if root is None else Path(root)
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                              text=True, timeout=10)
        if head.returncode != 0:
            return None, None
        status = subprocess.run(["git", "-C", str(root), "status", "--porcelain",
                                 "--untracked-files=no", "--", *SOURCES], capture_output=True,
                                text=True, timeout=30)
        return head.stdout.strip(), bool(status.stdout.strip())
    except (OSError, subprocess.TimeoutExpired):
        return None, None


def other_processes() -> list[str]:
    """Command lines of other benchmark or test processes running now (not this one, nor its
    parents or children)."""
    mine = {os.getpid(), os.getppid()}
    found = []
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else ():
        if not entry.name.isdigit() or int(entry.name) in mine:
            continue
        try:
            words = (entry / "cmdline").read_bytes().split(b"\0")
            if int((entry / "stat").read_text().split(")")[-1].split()[1]) == os.getpid():
                continue  # a child of this benchmark (a worker)
        except (OSError, ValueError, IndexError):
            continue
        line = " ".join(w.decode(errors="replace") for w in words if w)
        if any(all(word in line for word in marks) for marks in OTHERS):
            found.append(line[:200])
    return found


class Watch:
    """Samples the machine for other benchmark or test processes until stopped."""

    def __init__(self):
        self.started = time.time()
        self.seen: set[str] = set(other_processes())
        self.load = [os.getloadavg()[0]] if hasattr(os, "getloadavg") else []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.wait(SAMPLE_SECONDS):
            self.seen.update(other_processes())
            if hasattr(os, "getloadavg"):
                self.load.append(os.getloadavg()[0])

    def stop(self) -> dict:
        self._stop.set()
        self.seen.update(other_processes())
        return {"shared_machine": bool(self.seen), "others_seen": sorted(self.seen),
                "load_average_max": max(self.load) if self.load else None,
                "seconds": round(time.time() - self.started, 1)}


_watch: Watch | None = None


def start_watch() -> Watch:
    """Start (or restart) watching the machine for the benchmark about to run."""
    global _watch
    if _watch is not None:
        _watch.stop()
    _watch = Watch()
    return _watch


def meta(watch: Watch | None = None) -> dict:
    commit, dirty = source_commit()
    watch = watch or _watch
    conditions = watch.stop() if watch is not None else {"shared_machine": None}
    return {"commit": commit, "dirty": dirty,
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "command": " ".join(["swarmslam", *sys.argv[1:]])
            if Path(sys.argv[0]).name in ("swarmslam", "cli.py", "__main__.py")
            else " ".join(sys.argv),
            "cpu": cpu_model(), "cpu_target": cpu_target(), "cores": os.cpu_count(),
            "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
            else os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "platform": platform.platform(), **conditions}


def save_results(json_path, results: dict, watch: Watch | None = None) -> None:
    """``results`` with its ``meta`` (see the module), written atomically to ``json_path``."""
    results["meta"] = meta(watch)
    write_json_atomic(json_path, results)
