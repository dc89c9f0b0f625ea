"""Sessions: the whole runtime state in one file, saved atomically, resumed exactly.

A session holds the configuration, the pose graph, every node's stored scan, the trajectory,
the matchers' random streams and rejection thresholds, the back end's queued work and the
statistics — enough that ``save → kill → resume`` continues the same map, and in the lockstep
schedule the same run bit for bit (the map itself is rebuilt from the nodes on demand).

Format: a NumPy ``.npz`` archive (uncompressed): one ``meta`` entry (JSON), the arrays, and a
``checksum`` (SHA-256 over the meta and every array's name, dtype, shape and bytes).

Saving writes a temp file beside the target, fsyncs it and renames it over the target, after
keeping the previous good session as ``<name>.prev``. A power cut mid-save leaves the old file;
a truncated or corrupt file (bad archive, checksum mismatch, missing entry) is refused on load
with :class:`SessionError` naming the file and the problem — and the ``.prev`` file, if any.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import typing
import zipfile
from pathlib import Path

import numpy as np

from runtime.writers import write_bytes_atomic

FORMAT = "swarmslam-session"
VERSION = 1


class SessionError(ValueError):
    """A session file that cannot be resumed."""


# ---------------------------------------------------------------------- configs ⇄ JSON
def config_to_dict(config) -> dict:
    return dataclasses.asdict(config)


def config_from_dict(cls, data: dict, where: str = "config"):
    """Rebuild a (nested) frozen config dataclass from :func:`config_to_dict`'s output."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise SessionError(f"{where}: unknown field(s) {sorted(unknown)} for {cls.__name__}")
    kwargs = {}
    for name, value in data.items():
        kind = hints.get(name)
        if dataclasses.is_dataclass(kind) and isinstance(value, dict):
            value = config_from_dict(kind, value, f"{where}.{name}")
        elif isinstance(value, list):
            value = tuple(value)
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise SessionError(f"{where}: {exc}") from None


# ---------------------------------------------------------------------- state ⇄ arrays
def _workspace_arrays(prefix: str, ws) -> dict:
    return {f"{prefix}.{name}": getattr(ws, name) for name in ws._fields}


def runtime_state(runtime) -> tuple[dict, dict]:
    """(meta, arrays) describing ``runtime`` completely."""
    slam, g = runtime.slam, runtime.slam.graph
    n, m, k = g.n_nodes, g.n_edges, slam.n_scans
    counts = slam.node_counts[:n]
    points = np.concatenate([slam.node_points[i, : counts[i]] for i in range(n)]) if n else \
        np.zeros((0, 2))
    arrays = {
        "graph.poses": g.poses[:n], "graph.stamps": g.stamps[:n], "graph.ij": g.ij[:m],
        "graph.z": g.z[:m], "graph.info": g.info[:m], "graph.kind": g.kind[:m],
        "nodes.counts": counts, "nodes.points": points, "nodes.cov": slam.node_cov[:n],
        "scans.node": slam.scan_node[:k], "scans.rel": slam.scan_rel[:k],
        "scans.stamp": slam.scan_stamp[:k],
        "slam.rel": slam.rel, "slam.motion": slam.motion, "slam.initial_pose": slam.initial_pose,
        "slam.last_odometry": slam.last_odometry,
        "stats.latency": runtime.stats.latency,
    }
    arrays.update(_workspace_arrays("matcher.ws", slam.matcher.optimizer.ws))
    arrays.update(_workspace_arrays("loop_matcher.ws", slam.loop_matcher.optimizer.ws))
    for key, value in runtime.back_end.state().items():
        arrays[f"back_end.{key}"] = value
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "seed": runtime.seed,
        "slam_config": config_to_dict(slam.config),
        "runtime_config": config_to_dict(runtime.config),
        "graph_revision": g.revision,
        "keyframe": slam.keyframe,
        "weak": slam.weak,
        "have_odometry": slam.have_odometry,
        "lost_matches": slam.lost_matches,
        "status": slam.status,
        "loops": [slam.loops.attempts, slam.loops.accepted, slam.loops.rejected_match,
                  slam.loops.rejected_consistency],
        "thresholds": [list(slam.matcher.threshold.state()),
                       list(slam.loop_matcher.threshold.state())],
        "front_end_cost": runtime.front_end_cost,
        "stats": {name: getattr(runtime.stats, name) for name in runtime.stats.SCALARS},
        "inbox": [runtime.inbox.received, runtime.inbox.stale, runtime.inbox.empty],
    }
    return meta, {key: np.ascontiguousarray(v) for key, v in arrays.items()}


def _checksum(meta_bytes: bytes, arrays: dict) -> str:
    h = hashlib.sha256(meta_bytes)
    for key in sorted(arrays):
        a = arrays[key]
        h.update(f"{key}|{a.dtype.str}|{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_session(path, runtime) -> Path:
    """Write ``runtime``'s state to ``path`` atomically; the previous file becomes ``.prev``."""
    path = Path(path)
    meta, arrays = runtime_state(runtime)
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


def read_session(path) -> tuple[dict, dict]:
    """(meta, arrays) from a session file, verified; :class:`SessionError` otherwise."""
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
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        raise refuse(f"not a readable session archive (truncated or corrupt): {exc}") from None
    for key in ("meta", "checksum"):
        if key not in data:
            raise refuse(f"missing entry {key!r}: not a SwarmSLAM session")
    meta_bytes = data.pop("meta").tobytes()
    stored = data.pop("checksum").tobytes().decode("ascii", "replace")
    try:
        meta = json.loads(meta_bytes)
    except ValueError as exc:
        raise refuse(f"meta is not valid JSON: {exc}") from None
    if meta.get("format") != FORMAT:
        raise refuse(f"format is {meta.get('format')!r}, expected {FORMAT!r}")
    if meta.get("version") != VERSION:
        raise refuse(f"session version {meta.get('version')} is not supported (this build "
                     f"reads version {VERSION})")
    if _checksum(meta_bytes, data) != stored:
        raise refuse("checksum mismatch: the file is corrupt")
    return meta, data


def load_session(path, clock=None):
    """A :class:`SlamRuntime` continuing the saved session."""
    import time

    from runtime.fixed_rate import RuntimeConfig, SlamRuntime
    from runtime.slam import SlamConfig

    meta, a = read_session(path)
    try:
        slam_config = config_from_dict(SlamConfig, meta["slam_config"], "slam_config")
        runtime_config = config_from_dict(RuntimeConfig, meta["runtime_config"], "runtime_config")
        runtime = SlamRuntime(slam_config, runtime_config, seed=meta["seed"],
                              initial_pose=a["slam.initial_pose"], clock=clock or time.perf_counter)
        _restore(runtime, meta, a)
    except KeyError as exc:
        raise SessionError(f"{path}: missing field {exc.args[0]!r}") from None
    except (ValueError, IndexError) as exc:
        raise SessionError(f"{path}: {exc}") from None
    return runtime


def _restore(runtime, meta: dict, a: dict) -> None:
    slam, g = runtime.slam, runtime.slam.graph
    n, m, k = len(a["graph.poses"]), len(a["graph.ij"]), len(a["scans.node"])
    c = slam.config
    for what, used, cap in (("nodes", n, g.max_nodes), ("edges", m, g.max_edges),
                            ("scans", k, c.max_scans)):
        if used > cap:
            raise ValueError(f"{used} {what} exceed the capacity {cap}")
    g.n_nodes, g.n_edges = n, m
    g.poses[:n], g.stamps[:n] = a["graph.poses"], a["graph.stamps"]
    g.ij[:m], g.z[:m], g.info[:m], g.kind[:m] = a["graph.ij"], a["graph.z"], a["graph.info"], \
        a["graph.kind"]
    g.revision = int(meta["graph_revision"])
    counts = a["nodes.counts"]
    if len(counts) != n or int(counts.sum()) != len(a["nodes.points"]):
        raise ValueError("node scan counts do not match the stored points")
    offsets = np.concatenate([[0], np.cumsum(counts)])
    for i in range(n):
        slam.node_points[i, : counts[i]] = a["nodes.points"][offsets[i] : offsets[i + 1]]
    slam.node_counts[:n] = counts
    slam.node_cov[:n] = a["nodes.cov"]
    slam.scan_node[:k], slam.scan_rel[:k], slam.scan_stamp[:k] = a["scans.node"], \
        a["scans.rel"], a["scans.stamp"]
    slam.n_scans = k
    slam.rel[:], slam.motion[:] = a["slam.rel"], a["slam.motion"]
    slam.last_odometry[:] = a["slam.last_odometry"]
    slam.have_odometry = bool(meta["have_odometry"])
    slam.keyframe = int(meta["keyframe"])
    slam.weak = bool(meta["weak"])
    slam.lost_matches = int(meta["lost_matches"])
    slam.status = str(meta["status"])
    loops = slam.loops
    loops.attempts, loops.accepted, loops.rejected_match, loops.rejected_consistency = \
        (int(v) for v in meta["loops"])
    slam.matcher.threshold.restore(meta["thresholds"][0])
    slam.loop_matcher.threshold.restore(meta["thresholds"][1])
    for prefix, matcher in (("matcher.ws", slam.matcher), ("loop_matcher.ws", slam.loop_matcher)):
        ws = matcher.optimizer.ws
        for name in ws._fields:
            getattr(ws, name)[...] = a[f"{prefix}.{name}"]
    if slam.keyframe >= 0:
        if not 0 <= slam.keyframe < n:
            raise ValueError(f"keyframe {slam.keyframe} is not a stored node")
        slam.rebuild_keyframe_reference()
    runtime.back_end.restore({key[len("back_end."):]: v for key, v in a.items()
                              if key.startswith("back_end.")})
    runtime.front_end_cost = float(meta["front_end_cost"])
    for name, value in meta["stats"].items():
        setattr(runtime.stats, name, value)
    runtime.stats.latency[:] = a["stats.latency"]
    runtime.inbox.received, runtime.inbox.stale, runtime.inbox.empty = meta["inbox"]
