"""What a SLAM run leaves behind, each file written atomically: the map (PGM + YAML for ROS
map_server, and PNG), the trajectory of every scan (TUM, for ``evo``) and the pose graph
(g2o). docs/formats.md describes each.

A run's files are one *output set*: :func:`output_set` writes them into a staging folder beside
the output folder and swaps it in whole, so an interrupted write (SIGTERM, Ctrl-C, a full disk)
leaves the previous set as it was — never half new, half old — and a stale staging folder
(a killed writer) is cleaned up at the next run.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from pathlib import Path

from swarmslam.runtime.slam import GraphSlam
from swarmslam.g2o import write_g2o
from swarmslam.map_io import write_map
from swarmslam.tum import write_tum

STALE_SECONDS = 300.0  # a temp file untouched this long lost its writer
RESULT_FILES = ("map.pgm", "map.yaml", "map.png", "trajectory.tum", "graph.g2o")


def write_results(slam: GraphSlam, out_dir) -> None:
    """The map, the trajectory and the pose graph of ``slam`` into ``out_dir``."""
    out = Path(out_dir)
    write_map(out / "map", slam.global_map())
    write_tum(out / "trajectory.tum", *slam.trajectory())
    write_g2o(out / "graph.g2o", slam.graph)


def _staging(out: Path, kind: str, pid: int) -> Path:
    return out.parent / f".{out.name}.{kind}-{pid}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale(out_dir) -> list[Path]:
    """Remove what killed writers left beside ``out_dir`` (their staging folders, and temp
    files in it), putting back a previous set a swap was interrupted in. Returns what went."""
    out = Path(out_dir)
    gone: list[Path] = []
    if not out.parent.is_dir():
        return gone
    for entry in out.parent.glob(f".{out.name}.*-*"):
        kind, _, pid = entry.name[len(out.name) + 2:].rpartition("-")
        if kind not in ("staging", "old") or not pid.isdigit() or _alive(int(pid)):
            continue
        if kind == "old" and not out.exists():
            os.replace(entry, out)  # the swap stopped between its two renames
            continue
        shutil.rmtree(entry, ignore_errors=True)
        gone.append(entry)
    if out.is_dir():  # an atomic write's temp file whose writer was killed: untouched for
        now = time.time()  # minutes (a live write renames within seconds)
        for tmp in out.glob(".*.tmp"):
            with contextlib.suppress(OSError):
                if now - tmp.stat().st_mtime > STALE_SECONDS:
                    tmp.unlink()
                    gone.append(tmp)
    return gone


@contextlib.contextmanager
def output_set(out_dir):
    """``with output_set(out) as stage:`` write every file into ``stage``; on leaving the
    block the set replaces ``out`` whole (files already in ``out`` that the set does not
    rewrite are kept, as hard links). On an exception the staging folder is dropped and
    ``out`` stays as it was."""
    out = Path(out_dir)
    clean_stale(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = _staging(out, "staging", os.getpid())
    shutil.rmtree(stage, ignore_errors=True)
    if out.is_dir():  # start from the previous set: what is rewritten replaces a link
        shutil.copytree(out, stage, copy_function=_link_or_copy, symlinks=True)
    else:
        stage.mkdir()
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old = _staging(out, "old", os.getpid())
    if out.exists():
        os.replace(out, old)
    os.replace(stage, out)
    shutil.rmtree(old, ignore_errors=True)


def _link_or_copy(source, target) -> None:
    """A hard link (free), or a copy where the file system has none (FAT, some shares)."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def check_writable(out_dir) -> None:
    """Refuse an output folder that cannot be written, before any long work."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    parent = out if out.is_dir() else next((p for p in out.parents if p.exists()), Path("."))
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"--out {out}: {parent} is not writable")
