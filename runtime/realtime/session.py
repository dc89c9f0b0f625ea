"""Sessions: a runtime's state in one file, saved atomically, read back verified.

The codec knows nothing of what it stores: a *state* is a nested dict whose leaves are numpy
arrays or JSON values (numbers, strings, lists), as every stateful component's ``state()``
returns it and its ``restore()`` takes it back, reading required keys only
(:meth:`swarmslam.runtime.realtime.fixed_rate.SlamRuntime.state`). docs/formats.md §4 has the layout.
The session's history is here alone: a file of an older version is brought to this one by the
chain of :data:`MIGRATIONS`, each the one place that knows what changed.

Format: a NumPy ``.npz`` archive (uncompressed): one ``meta`` entry (JSON: the format, its
version and the state's JSON leaves), one entry per array leaf named by its dotted path, and a
``checksum`` (SHA-256 over the meta and every array's name, dtype, shape and bytes).

Saving writes a temp file beside the target, fsyncs it and renames it over the target, after
keeping the previous good session as ``<name>.prev``. A power cut mid-save leaves the old file;
a truncated or corrupt file (bad archive, checksum mismatch, missing entry) is refused on read
with :class:`SessionError` naming the file and the problem — and the ``.prev`` file, if any.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import threading
from pathlib import Path

import numpy as np

from swarmslam.runtime.back_end.loop_closure import VerdictMemory
from swarmslam.runtime.config import upgrade_names
from swarmslam.runtime.front_end.odometry_scale import BINS as SCALE_BINS
from swarmslam.runtime.realtime.writers import write_bytes_atomic

FORMAT = "swarmslam-session"
# 9: the loops refused for their own error remembered as a group; 8: the configuration nested
# by component; 7: every component's state complete, its tallies saved whole; 6: the swarm's
# stall rule (its run scalars grew); 5: the wide search's recent corrections; 4: the back end's
# wide loop search; 3: loop edges carry their own information. A component whose state changes
# raises the version and adds the migration from the one before (MIGRATIONS); restore() then
# reads required keys only.
VERSION = 9
ARRAY = "__array__"  # marks, in the meta, a leaf stored as an archive entry


class SessionError(ValueError):
    """A session file that cannot be resumed."""


def _from_6(state: dict) -> dict:
    """Version 6 → 7. Fields a version-6 session may lack, from sessions saved before their
    rule, take the value that rule started from; the tallies move into their dataclasses."""
    slam = state["slam"]
    fe, be, graph = slam["front_end"], slam["back_end"], slam["graph"]
    k, m = len(fe["scan_node"]), len(graph["ij"])
    if "scan_odometry" not in fe:  # odometry's pose not yet recorded per scan: none read
        fe.pop("scan_odometry_heading", None)
        fe["scan_reading"], fe["scan_odometry"] = np.zeros(k, np.int8), np.zeros((k, 3))
    fe.setdefault("scan_reading", np.zeros(k, np.int8))
    fe.setdefault("odometry_rel", np.asarray(fe["rel"], np.float64).copy())
    fe.setdefault("odometry_scale", np.zeros(SCALE_BINS))  # the fit starts afresh
    fe.setdefault("odometry_part", np.zeros(2))
    fe.setdefault("pinned_base", False)
    # before the sweep was undistorted: the trajectory's last stamp, no motion's interval
    fe.setdefault("last_stamp", float(fe["scan_stamp"][-1]) if k else math.nan)
    fe.setdefault("last_interval", math.nan)
    fe.setdefault("submap_nodes", np.zeros(0, np.int64))  # placed by the graph
    fe.setdefault("submap_poses", np.zeros((0, 3)))
    fe.setdefault("previous_points", np.zeros((0, 2)))
    for key, value in (("stale_scans", 0), ("reading_scans", 0), ("reading_step", np.zeros(3)),
                       ("readings_rate", np.zeros(3))):
        fe.setdefault(key, value)
    for key in ("stamp", "arrival", "scan_time", "scan_intervals", "period_time", "period_scans",
                "periods", "fewest", "long_gaps", "lag"):  # the period not yet kept: none known
        fe.setdefault(f"readings_{key}", math.nan if key in ("stamp", "arrival") else 0)
    counts = {"lost_matches": fe.pop("lost_matches"),
              "degenerate_matches": fe.pop("degenerate_matches")}
    fe["counts"] = {"overruled_odometry": 0, "rescued_matches": 0, "sought_matches": 0,
                    "disowned_matches": 0, "held_to_odometry": 0, **counts}
    attempts, accepted, rejected_match, rejected_consistency = be["loops"]
    be["loops"] = {"attempts": attempts, "accepted": accepted,
                   "rejected_match": rejected_match,
                   "rejected_consistency": rejected_consistency,
                   **{key: be.pop(key, 0) for key in ("agreed", "given_up", "reanchored")}}
    be["counts"] = {key: be.pop(key) for key in ("enqueued", "searched", "dropped", "deferred",
                                                 "forced")}
    for key, value in (("failed", np.zeros(0, np.int64)), ("failed_node", -1),
                       ("failed_revision", -1), ("wide_from", 0),
                       ("rise_refused", np.array([-1.0, -1.0, 0.0, 0.0, 0.0])),
                       ("strained", np.array([-1.0, -1.0, 0.0, 0.0, 0.0])),
                       ("strained_info", np.zeros((3, 3)))):
        be.setdefault(key, value)
    # before odometry's scale: no edge took a part, and the scale is 1
    graph.setdefault("odometry_part", np.zeros((m, 2)))
    graph.setdefault("scale", np.ones(2))
    for key in ("bad_stamps", "odometry_non_finite", "odometry_jumps", "odometry_out_of_range",
                "cut"):
        state["inbox"].setdefault(key, 0)
    return state


def _from_7(state: dict) -> dict:
    """Version 7 → 8. The saved configuration in this version's names: moved fields in their
    component's section, sentinels as ``enabled``, fixed ones dropped (config.upgrade_names)."""
    state["config"] = upgrade_names(state["config"])
    return state


def _from_8(state: dict) -> dict:
    """Version 8 → 9. The one loop remembered as refused for its own error becomes the newest
    row of the group's memory, the rows before it empty."""
    be = state["slam"]["back_end"]
    strained, info = VerdictMemory.none_strained()
    strained[0], info[0] = be["strained"], be["strained_info"]
    be["strained"], be["strained_info"] = strained, info
    return state


MIGRATIONS = {6: _from_6, 7: _from_7, 8: _from_8}  # version → the function that brings its state to the next


def migrate(state: dict, version: int) -> dict:
    """A runtime's state saved at ``version``, brought to :data:`VERSION` through the chain of
    :data:`MIGRATIONS`; KeyError names a field the saved version should have held."""
    while version < VERSION:
        state = MIGRATIONS[version](state)
        version += 1
    return state


def encode(state: dict) -> tuple[dict, dict]:
    """(JSON tree with array leaves replaced by markers, {dotted path: array})."""
    arrays: dict = {}

    def walk(node, path):
        if isinstance(node, dict):
            return {key: walk(value, f"{path}.{key}" if path else key)
                    for key, value in node.items()}
        if isinstance(node, np.ndarray):
            arrays[path] = np.ascontiguousarray(node)
            return ARRAY
        if isinstance(node, np.generic):
            return node.item()
        if isinstance(node, (list, tuple)):
            return [walk(v, path) for v in node]
        return node

    return walk(state, ""), arrays


def decode(tree: dict, arrays: dict) -> dict:
    """The state :func:`encode` took apart."""

    def walk(node, path):
        if isinstance(node, dict):
            return {key: walk(value, f"{path}.{key}" if path else key)
                    for key, value in node.items()}
        if node == ARRAY:
            if path not in arrays:
                raise KeyError(path)
            return arrays[path]
        return node

    return walk(tree, "")


def _checksum(meta_bytes: bytes, arrays: dict) -> str:
    h = hashlib.sha256(meta_bytes)
    for key in sorted(arrays):
        a = arrays[key]
        h.update(f"{key}|{a.dtype.str}|{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def write_session(path, state: dict) -> Path:
    """Write ``state`` to ``path`` atomically; the previous file becomes ``.prev``."""
    path = Path(path)
    tree, arrays = encode(state)
    meta = {"format": FORMAT, "version": VERSION, "state": tree}
    meta_bytes = json.dumps(meta, sort_keys=True).encode()
    buffer = io.BytesIO()
    np.savez(buffer, meta=np.frombuffer(meta_bytes, np.uint8),
             checksum=np.frombuffer(_checksum(meta_bytes, arrays).encode(), np.uint8), **arrays)
    if path.exists():  # keep the last good session; ``path`` itself never goes missing
        previous = path.with_name(path.name + ".prev")
        link = path.with_name(f".{path.name}.prev.tmp")
        link.unlink(missing_ok=True)
        os.link(path, link)
        os.replace(link, previous)
    return write_bytes_atomic(path, buffer.getvalue())


def read_session(path) -> dict:
    """The state in a session file, verified; :class:`SessionError` otherwise."""
    path = Path(path)

    def refuse(problem: str):
        previous = path.with_name(path.name + ".prev")
        hint = f"; the previous session is at {previous}" if previous.exists() else ""
        return SessionError(f"{path}: {problem}{hint}")

    if not path.exists():
        raise FileNotFoundError(f"session file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as archive:
            data = {key: archive[key] for key in archive.files}
    except Exception as exc:  # noqa: BLE001 — a damaged archive fails deep in zipfile or
        # NumPy's header parser with whatever it meets (BadZipFile, EOFError, OSError,
        # ValueError; a flipped header byte: NotImplementedError for an unknown compression,
        # tokenize.TokenError): every one means the same to the user
        raise refuse(f"not a readable session archive (truncated or corrupt): "
                     f"{type(exc).__name__}: {exc}") from None
    for key in ("meta", "checksum"):
        if key not in data:
            raise refuse(f"missing entry {key!r}: not a SwarmSLAM session")
    meta_bytes = data.pop("meta").tobytes()
    stored = data.pop("checksum").tobytes().decode("ascii", "replace")
    try:
        meta = json.loads(meta_bytes)
    except ValueError as exc:
        raise refuse(f"meta is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else None
        raise refuse(f"format is {got!r}, expected {FORMAT!r}")
    version = meta.get("version")
    if version != VERSION and version not in MIGRATIONS:
        readable = ", ".join(str(v) for v in (*sorted(MIGRATIONS), VERSION))
        raise refuse(f"session version {version} is not supported (this build reads versions "
                     f"{readable})")
    if _checksum(meta_bytes, data) != stored:
        raise refuse("checksum mismatch: the file is corrupt")
    try:
        return migrate(decode(meta["state"], data), version)
    except KeyError as exc:
        raise refuse(f"missing entry {exc.args[0]!r}") from None


class Autosave:
    """A session written every ``interval`` seconds while a run goes on, so that a power cut
    or a SIGKILL loses at most that much (docs/runtime.md §5). The state is taken on the
    caller's thread (a consistent copy); a thread of its own encodes and writes it, so the
    loop only pays for the copy. A write still running when the next is due skips that one."""

    def __init__(self, path, interval: float, clock):
        self.path, self.interval, self.clock = Path(path), float(interval), clock
        self.due = clock() + self.interval
        self.saves = 0
        self.error = ""  # the last write's failure, if any (the run goes on)
        self._thread: threading.Thread | None = None

    def maybe(self, state_of) -> bool:
        """Start a write of ``state_of()`` if one is due and none is running."""
        if self.interval <= 0 or self.clock() < self.due:
            return False
        self.due = self.clock() + self.interval
        if self._thread is not None and self._thread.is_alive():
            return False
        state = state_of()
        self._thread = threading.Thread(target=self._write, args=(state,),
                                        name="session-autosave", daemon=True)
        self._thread.start()
        return True

    def _write(self, state) -> None:
        try:
            write_session(self.path, state)
            self.saves += 1
        except Exception as exc:  # noqa: BLE001 — a full disk or anything else: said in the
            self.error = f"autosave to {self.path} failed: {exc}"  # report; the run goes on

    def wait(self) -> None:
        """Let a write in progress finish (before the final save)."""
        if self._thread is not None:
            self._thread.join()
