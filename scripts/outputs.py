"""What a SLAM run leaves behind, each file written atomically: the map (PGM + YAML for ROS
map_server, and PNG), the trajectory of every scan (TUM, for ``evo``) and the pose graph
(g2o). docs/formats.md describes each.

A run's files are one *output set*: :func:`output_set` writes them into a staging folder beside
the output folder and swaps it in whole, so an interrupted write (SIGTERM, Ctrl-C, a full disk)
leaves the previous set as it was — never half new, half old, nor an old file of the previous
set beside the new ones — and a stale staging folder (a killed writer) is cleaned up at the
next run.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import stat
import tempfile
import time
from pathlib import Path

from swarmslam.runtime.realtime.writers import write_json_atomic, write_text_atomic
from swarmslam.runtime.slam import GraphSlam
from swarmslam.formats.g2o import write_g2o
from swarmslam.formats.map_io import write_map
from swarmslam.formats.tum import write_tum

STALE_SECONDS = 300.0  # a temp file untouched this long lost its writer
RESULT_FILES = ("map.pgm", "map.yaml", "map.png", "trajectory.tum", "graph.g2o")


def write_results(slam: GraphSlam, out_dir) -> None:
    """The map, the trajectory and the pose graph of ``slam`` into ``out_dir``."""
    out = Path(out_dir)
    write_map(out / "map", slam.global_map())
    write_tum(out / "trajectory.tum", *slam.trajectory())
    write_g2o(out / "graph.g2o", slam.graph)


MANIFEST = ".swarmslam-outputs"  # in an output folder: the names its last set wrote


def _target(out_dir) -> Path:
    """The folder a set goes to, absolute; a symbolic link is followed (the link stays, its
    target is written)."""
    return Path(out_dir).resolve()


def _staging(out: Path, kind: str, pid: int) -> Path:
    # a short name whatever the output folder's (a 250-character one must not fail at the end)
    tag = hashlib.sha1(out.name.encode("utf-8", "surrogateescape")).hexdigest()[:12]
    return out.parent / f".swarmslam-{tag}.{kind}-{pid}"


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
    out = _target(out_dir)
    gone: list[Path] = []
    if not out.parent.is_dir():
        return gone
    prefix = _staging(out, "", 0).name[: -len(".-0")]
    for entry in out.parent.glob(f"{prefix}.*-*"):
        kind, _, pid = entry.name[len(prefix) + 1:].rpartition("-")
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


def _previous_set(out: Path) -> set[str]:
    """The names the last set written into ``out`` made (none known: none)."""
    with contextlib.suppress(OSError):
        return set((out / MANIFEST).read_text(encoding="utf-8").split("\n")) - {""}
    return set()


def _in_place(out: Path) -> bool:
    """``out`` holds this process's working folder (``--out .``): it cannot be swapped (the
    process, and the shell it came from, would be left in a deleted folder)."""
    cwd = Path.cwd().resolve()
    return out == cwd or out in cwd.parents


@contextlib.contextmanager
def output_set(out_dir):
    """``with output_set(out) as stage:`` write every file into ``stage``; on leaving the
    block the set replaces ``out``'s previous set whole: what that set wrote and this one
    does not is gone (no old map beside a new trajectory), the user's own files stay. The new
    folder keeps the old one's group and permissions. On an exception the staging folder is
    dropped and ``out`` stays as it was. A symbolic link is followed; ``out`` holding the
    working folder is written file by file instead of swapped."""
    out = _target(out_dir)
    clean_stale(out)
    out.mkdir(parents=True, exist_ok=True)
    stage = _staging(out, "staging", os.getpid())
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir()
    previous = _previous_set(out)
    # (a file being written into ``out`` meanwhile — a recording — is carried over too, as a
    # hard link its writer's rename then finds)
    keep = [p for p in out.iterdir() if p.name not in previous and p.name != MANIFEST]
    try:
        _copy_folder_mode(out, stage)
        yield stage
        written = sorted(p.name for p in stage.iterdir())
        (stage / MANIFEST).write_text("\n".join(written) + "\n", encoding="utf-8")
        if _in_place(out):
            _install_file_by_file(stage, out, previous - set(written))
            return
        keep += [p for p in out.iterdir() if p.name.endswith(".tmp") and p not in keep]
        for path in keep:  # the user's own files, as hard links (free)
            target = stage / path.name
            if path.is_dir() and not path.is_symlink():
                shutil.copytree(path, target, copy_function=_link_or_copy, symlinks=True)
            elif not target.exists():
                _link_or_copy(path, target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old = _staging(out, "old", os.getpid())
    os.replace(out, old)
    os.replace(stage, out)
    shutil.rmtree(old, ignore_errors=True)


def _install_file_by_file(stage: Path, out: Path, dropped) -> None:
    """Each file of ``stage`` renamed into ``out`` (each rename atomic), then what the last
    set wrote and this one did not removed."""
    try:
        for path in stage.iterdir():
            if path.name != MANIFEST:
                os.replace(path, out / path.name)
        for name in dropped:
            with contextlib.suppress(FileNotFoundError):
                (out / name).unlink()
        os.replace(stage / MANIFEST, out / MANIFEST)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _copy_folder_mode(source: Path, target: Path) -> None:
    """``target`` gets ``source``'s permissions and group (a shared, group-owned output
    folder stays one)."""
    st = source.stat()
    os.chmod(target, stat.S_IMODE(st.st_mode))
    if target.stat().st_gid != st.st_gid:
        with contextlib.suppress(PermissionError):
            os.chown(target, -1, st.st_gid)


def _link_or_copy(source, target) -> None:
    """A hard link (free), or a copy where the file system has none (FAT, some shares)."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def check_writable(out_dir) -> None:
    """Refuse an output folder that cannot be written, before any long work: not a folder,
    a name the file system cannot hold, or no right to write it (or, to swap it in whole,
    the folder it is in)."""
    given = Path(out_dir)
    absolute = Path(os.path.abspath(given))
    existing = next((p for p in absolute.parents if p.exists()), Path("/"))
    limit = os.pathconf(existing, "PC_NAME_MAX") if hasattr(os, "pathconf") else 255
    too_long = [part for part in absolute.relative_to(existing).parts
                if len(part.encode("utf-8", "surrogateescape")) > limit]
    if too_long:
        raise ValueError(f"--out {given}: the name {too_long[0][:40]}... is longer than the "
                         f"file system allows ({limit} bytes)")
    out = _target(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {given}: exists and is not a folder")
    existing = next((p for p in (out, *out.parents) if p.exists()), Path("/"))
    needs = existing if existing != out or _in_place(out) else out.parent
    try:  # tried, not asked: os.access says yes to root, and to /proc and /sys
        probe, name = tempfile.mkstemp(prefix=".swarmslam-probe-", dir=needs)
        os.close(probe)
        os.unlink(name)
    except OSError as exc:
        raise ValueError(f"--out {given}: {needs} is not writable ({exc.strerror})") from None


UNUSABLE_REPORT = "unusable-run.json"  # a run that wrote no set: its report, beside the set


def report_beside(out_dir, report: dict) -> Path:
    """A run that left no output set (nothing usable came in): its ``report`` written into
    ``out_dir`` beside the set there, which stays as it was; named in the set's manifest, so
    that the next set replaces it with the rest."""
    out = _target(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = write_json_atomic(out / UNUSABLE_REPORT, report)
    names = _previous_set(out)
    if UNUSABLE_REPORT not in names:
        write_text_atomic(out / MANIFEST, "\n".join(sorted(names | {UNUSABLE_REPORT})) + "\n")
    return path


def check_input_kept(out_dir, path, what: str) -> None:
    """Refuse, before any long work, a run whose output set would drop its own input ``path``
    (``what`` it is): a file an earlier set wrote into ``out_dir`` that this run's set does
    not write again, as a localized run's session and map."""
    source = Path(path).resolve()
    out = _target(out_dir)
    if source.parent == out and source.name in _previous_set(out):
        raise ValueError(f"--out {out_dir}: {what} {path} is part of the output set there, "
                         f"which this run's outputs replace (its map and session would be "
                         f"gone); give another --out")
