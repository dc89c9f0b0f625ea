"""``swarmslam simlog OUT.clf``: a CARMEN log from a simulated survey, with Kümmerle relations
computed from the true poses (docs/formats.md §7).

Writes ``OUT.clf`` (``FLASER`` for a 180° scanner, ``ROBOTLASER1`` otherwise, with ``ODOM``
lines; or ``OUT.clf.gz``), ``OUT.relations``, ``OUT.truth.tum`` (the true pose of every scan)
and ``OUT.world`` (the floor). Relations are sampled as Kümmerle et al. did for the public
logs: short ones along the path (0.5–3 s apart, about one a second) and long ones across
revisits (at least ``long_gap`` seconds apart and within ``long_radius`` of each other).
"""

from __future__ import annotations

import gzip
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarmslam.runtime.pose import between
from swarmslam.runtime.realtime.writers import write_bytes_atomic, write_text_atomic
from swarmslam.formats.carmen import flaser_line, odom_line, robotlaser1_line
from swarmslam.formats.relations import relations_text
from swarmslam.formats.tum import tum_lines
from swarmslam_sim.survey import Effects, Survey, Turning, run_survey, site
from swarmslam_sim.world import save_world


@dataclass(frozen=True)
class RelationSampling:
    short_every: float = 1.0  # s between the first scans of two short relations
    short_span: tuple[float, float] = (0.5, 3.0)  # s, a short relation's length (uniform)
    long_every: float = 2.0  # s between scans that look for a revisit
    long_gap: float = 60.0  # s: a revisit is at least this much later
    long_radius: float = 1.5  # m between the two true positions of a revisit


def sample_relations(stamps, poses, rng: np.random.Generator,
                     sampling: RelationSampling = RelationSampling()):
    """Index pairs ``(i, j)``, short ones first, and their true relative poses
    ``poses[j] ⊖ poses[i]``."""
    stamps, poses = np.asarray(stamps, float), np.asarray(poses, float)
    n = len(stamps)
    dt = float(np.median(np.diff(stamps))) if n > 1 else 1.0
    pairs = []
    step = max(1, round(sampling.short_every / dt))
    for i in range(0, n, step):
        j = i + max(1, round(rng.uniform(*sampling.short_span) / dt))
        if j < n:
            pairs.append((i, j))
    step = max(1, round(sampling.long_every / dt))
    for i in range(0, n, step):
        near = np.hypot(*(poses[:, :2] - poses[i, :2]).T) <= sampling.long_radius
        later = np.nonzero((stamps - stamps[i] >= sampling.long_gap) & near)[0]
        if len(later):
            pairs.append((i, int(rng.choice(later))))
    ij = np.array(pairs, np.int64).reshape(-1, 2)
    return ij, between(poses[ij[:, 1]], poses[ij[:, 0]])


def log_text(survey: Survey, fmt: str = "auto") -> str:
    """The survey as CARMEN lines: per scan an ``ODOM`` line and the laser line."""
    half_turn = survey.lidar.fov <= math.pi + 1e-9
    if fmt == "auto":
        fmt = "flaser" if half_turn and survey.lidar.beams in (181, 361) else "robotlaser1"
    if fmt == "flaser" and not (half_turn and survey.lidar.beams in (180, 181, 360, 361)):
        raise ValueError("FLASER carries 180° scans of 180/181 or 360/361 beams only; use "
                         "ROBOTLASER1 for this scanner")
    a = survey.angles
    res = float(a[1] - a[0])
    rate = 1 / np.median(np.diff(survey.stamps))
    lines = [f"{HEADER}: {survey.site.world.name}, {survey.lidar.beams} beams over "
             f"{math.degrees(survey.lidar.fov):g} deg, {rate:g} Hz"]
    for t, odo, r in zip(survey.stamps, survey.odometry, survey.ranges):
        if survey.odometry_stream:
            lines.append(odom_line(odo, t))
        if fmt == "flaser":
            lines.append(flaser_line(r, odo, odo, t))
        else:
            lines.append(robotlaser1_line(r, float(a[0]), res, survey.lidar.max_range, odo, t))
    return "\n".join(lines) + "\n"


HEADER = "# swarmslam simlog"  # a simlog log's first line begins so


def made_by_simlog(log: Path) -> bool:
    """Whether ``log`` (plain or gzip) is a log this command wrote (its first line)."""
    try:
        with (gzip.open(log, "rt", encoding="ascii", errors="replace") if log.name.endswith(".gz")
              else open(log, encoding="ascii", errors="replace")) as f:
            return f.readline().startswith(HEADER)
    except (OSError, EOFError):
        return False


def refuse_to_replace(out: Path, base: Path) -> None:
    """Raise FileExistsError when the log ``out`` or a file beside it that a simlog writes
    (``base``.relations, .truth.tum, .world) exists and is not of an earlier simlog of that
    name: a real log's relations beside (``simlog intel.clf``) are the user's."""
    ours = any(made_by_simlog(Path(f"{base}{suffix}")) for suffix in (".clf", ".clf.gz"))
    for path in (out, *(Path(f"{base}.{suffix}") for suffix in ("relations", "truth.tum",
                                                                   "world"))):
        if path.exists() and not ours:
            raise FileExistsError(f"{path}: exists and is not of an earlier simlog; a "
                                  f"simlog there would replace it (name another log)")


def write_simlog(out, kind: str = "building", seed: int = 0, lidar: str = "sick-0.5",
                 rate_hz: float = 10.0, odometry: str = "good", fmt: str = "auto",
                 sampling: RelationSampling = RelationSampling(),
                 seconds: float | None = None, effects: str | Effects = "none",
                 turning: str | Turning | None = None, max_turn: float | None = None) -> dict:
    """Survey the site (the whole route, or its first ``seconds``; with real-robot
    ``effects``, turning as :func:`run_survey` says) and write the log, relations, truth and
    world next to ``out`` (``.clf`` or ``.clf.gz``); returns the paths and the survey's
    figures."""
    out = Path(out)
    stem = out.name[: -len(".gz")] if out.name.endswith(".gz") else out.name
    stem = stem[: -len(".clf")] if stem.endswith(".clf") else stem
    base = out.parent / stem
    refuse_to_replace(out, base)  # before the survey, not after it
    survey = run_survey(site(kind, seed), lidar, rate_hz, odometry, seed, seconds=seconds,
                        effects=effects, turning=turning, max_turn=max_turn)
    text = log_text(survey, fmt).encode("ascii")
    write_bytes_atomic(out, gzip.compress(text, mtime=0) if out.name.endswith(".gz") else text)
    ij, delta = sample_relations(survey.stamps, survey.true_poses,
                                 np.random.default_rng([seed, 1]), sampling)
    paths = {"log": str(out), **{k: f"{base}.{suffix}" for k, suffix in (
        ("relations", "relations"), ("truth", "truth.tum"), ("world", "world"))}}
    write_text_atomic(paths["relations"], relations_text(survey.stamps[ij[:, 0]],
                                                         survey.stamps[ij[:, 1]], delta))
    write_text_atomic(paths["truth"], tum_lines(survey.stamps, survey.true_poses))
    save_world(survey.site.world, paths["world"])
    odo_end = between(survey.odometry[-1], survey.true_poses[-1])
    return {**paths, "scans": len(survey.stamps), "seconds": float(survey.stamps[-1]),
            "sweep_seconds": survey.sweep_seconds,
            "max_turn_deg_s": float(np.degrees(np.max(np.abs(np.diff(np.unwrap(
                survey.true_poses[:, 2]))), initial=0.0)) * rate_hz),
            "metres": survey.length, "relations_count": len(ij),
            "odometry_error_end_m": float(math.hypot(odo_end[0], odo_end[1])),
            "odometry_error_end_deg": float(abs(math.degrees(odo_end[2])))}
