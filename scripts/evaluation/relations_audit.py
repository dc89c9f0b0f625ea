"""``swarmslam relations audit LOG RELATIONS``: do a relations file's relative poses agree with
the log's own scans? (docs/method.md §7.1)

A Kümmerle relation says where the scan at ``t2`` lies seen from the scan at ``t1``. Where the
two scans overlap, the scans themselves can check it: place the second on the first by the
relation and count the share of its points within ``inlier_distance`` of the first's; then let
ICP start from the relation (and from it turned by ``HEADING_STARTS_DEG``: a relation a few
degrees off is outside point-to-point ICP's reach) and, for a relation shorter than
``ODOMETRY_START_GAP``, from odometry's own motion between the two scans (a relation off by
more than those turns; over a few seconds odometry drifts far less), and count again at the
best it finds. A right relation is already at (or within a centimetre or two of) the best fit,
so ICP gains nothing; a relation the scans contradict gains ``min_gain`` or more once ICP moves
it. A relation whose scans do not overlap cannot be checked and is never flagged; one whose
second scan has not a single point near the first's at the relation's own pose, and that ICP
does not contradict, is *unsupported*: the scans do not show it, either way.

Scored apart on the relations the scans confirm and on those they contradict, a trajectory
shows how much of its relation error is the reference's own: an error there is not the SLAM's.
The audit also tells whose clock the reference's headings keep, the scans' or odometry's, and
scores the trajectory again on that clock (scripts/evaluation/relations_clock.py).

    >>> import numpy as np
    >>> from swarmslam.formats.relations import Relations
    >>> wall = np.c_[np.linspace(-2, 2, 81), np.full(81, 3.0)]   # a wall 3 m ahead ...
    >>> side = np.c_[np.full(61, 2.0), np.linspace(-1, 2, 61)]   # ... and one to the left
    >>> room = np.r_[wall, side]
    >>> seen_from = lambda x: room - [x, 0.0]                    # the robot moved x along x
    >>> relations = Relations(np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0]),
    ...                       np.array([[0.3, 0.0, 0.0], [0.6, 0.3, 0.0], [0.3, 9.0, 0.0]]))
    >>> audit = audit_scans([seen_from(0.0), seen_from(0.3)], np.array([0.0, 1.0]), relations)
    >>> audit.contradicted.tolist(), audit.unsupported.tolist()
    ([False, True, False], [False, False, True])
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from swarmslam.runtime.config import SensorConfig
from swarmslam.runtime.pose import between, compose, transform_points
from swarmslam.runtime.matching.scan import PointScan
from swarmslam.runtime.realtime.writers import write_json_atomic
from swarmslam.formats.carmen import read_carmen
from swarmslam.evaluation.icp import icp
from swarmslam.evaluation.metrics import LOCAL_GAP, SHORT_GAP, kummerle, match_relations, relation_errors
from swarmslam.view.plots import (gross_failures_figure, relations_audit_figure,
                             require_matplotlib)
from swarmslam.progress import Progress
from swarmslam.formats.relations import Relations, read_relations
from swarmslam.evaluation.relations_clock import AGREEMENT_DEG, reference_clock
from swarmslam.replay import robot_frame_scan
from swarmslam.formats.tum import read_tum

INLIER_DISTANCE = 0.2  # m: a point this near the other scan's points fits it
MIN_GAIN = 0.2  # share of points: ICP's best fitting this many more contradicts the relation
MAX_CORRESPONDENCE = 0.5  # m: ICP's pairing distance (a relation off by more is not refined)
MIN_POINTS = 10  # points a scan needs to be checked
# ICP's starts: the relation, and the relation turned this much (°). Wider turns flag right
# relations between scans that barely overlap (Intel: 2 of 2,984 at ±16°, none at ±8°).
HEADING_STARTS_DEG = (0.0, -8.0, 8.0)
# s: relations shorter than this are also refined from odometry's motion between their scans
# (fr-clinic: 6 s relations 11-17° off, in stretches where the scans fit odometry's motion and
# not the reference's; docs/method.md §7.1). Longer, odometry's drift makes it no better a start.
ODOMETRY_START_GAP = SHORT_GAP


@dataclass
class Audit:
    """Per relation: ``checked`` (both scans found, with points), the share of the second
    scan's points fitting the first placed by the relation (``fit``) and by ICP's best from
    it (``fit_aligned``), ICP's correction of the relation (``correction``: x, y, yaw),
    ``contradicted``: ICP gained at least ``min_gain``, and :attr:`unsupported`."""

    checked: np.ndarray
    fit: np.ndarray
    fit_aligned: np.ndarray
    correction: np.ndarray
    contradicted: np.ndarray
    min_gain: float

    @property
    def unsupported(self) -> np.ndarray:
        """Checked, not contradicted, and no point of the second scan fits the first at
        the relation's own pose (``fit`` 0): the scans do not show the relation."""
        return self.checked & ~self.contradicted & (self.fit == 0.0)

    def summary(self, relations: Relations) -> dict:
        local = np.abs(relations.t2 - relations.t1) < LOCAL_GAP
        out = {"relations": len(relations), "checked": int(self.checked.sum()),
               "contradicted": int(self.contradicted.sum()),
               "unsupported": int(self.unsupported.sum()), "min_gain": self.min_gain}
        for name, part in (("local", local), ("global", ~local)):
            out[f"checked_{name}"] = int((self.checked & part).sum())
            out[f"contradicted_{name}"] = int((self.contradicted & part).sum())
            out[f"unsupported_{name}"] = int((self.unsupported & part).sum())
        bad = self.contradicted
        if np.any(bad):
            c = self.correction[bad]
            out["correction_m_median"] = float(np.median(np.hypot(c[:, 0], c[:, 1])))
            out["correction_deg_median"] = float(np.degrees(np.median(np.abs(c[:, 2]))))
        return out


def scan_fit(reference_tree: cKDTree, points, pose, inlier_distance: float) -> float:
    """Share of ``points`` placed at ``pose`` within ``inlier_distance`` of the reference's."""
    d, _ = reference_tree.query(transform_points(pose, points),
                                distance_upper_bound=inlier_distance)
    return float(np.mean(np.isfinite(d)))


def audit_scans(scans, stamps, relations: Relations, inlier_distance: float = INLIER_DISTANCE,
                min_gain: float = MIN_GAIN, max_correspondence: float = MAX_CORRESPONDENCE,
                progress: Progress | None = None, odometry=None) -> Audit:
    """Each relation checked against ``scans`` (robot-frame points, one (n, 2) array per
    entry of ``stamps``): see the module's docstring. ``odometry``: the pose odometry gave
    with each scan ((n, 3), or None: no start from it)."""
    n = len(relations)
    i, j, found = match_relations(stamps, relations)
    fit, fit_aligned = np.zeros(n), np.zeros(n)
    correction = np.zeros((n, 3))
    checked = np.zeros(n, bool)
    for k in range(n):
        if progress is not None:
            progress.update()
        if not found[k]:
            continue
        a, b = scans[i[k]], scans[j[k]]
        if len(a) < MIN_POINTS or len(b) < MIN_POINTS:
            continue
        tree = cKDTree(a)
        checked[k] = True
        fit[k] = scan_fit(tree, b, relations.delta[k], inlier_distance)
        fit_aligned[k] = -1.0
        starts = [compose(relations.delta[k], np.array([0.0, 0.0, np.radians(turn)]))
                  for turn in HEADING_STARTS_DEG]
        if odometry is not None and abs(relations.t2[k] - relations.t1[k]) < ODOMETRY_START_GAP:
            starts.append(between(odometry[j[k]], odometry[i[k]]))  # δ = x_j ⊖ x_i
        for start in starts:
            aligned, _ = icp(a, b, start, max_correspondence=max_correspondence, tree=tree)
            aligned_fit = scan_fit(tree, b, aligned, inlier_distance)
            if aligned_fit > fit_aligned[k]:
                fit_aligned[k] = aligned_fit
                correction[k] = between(aligned, relations.delta[k])
    contradicted = checked & (fit_aligned - fit >= min_gain)
    return Audit(checked, fit, fit_aligned, correction, contradicted, min_gain)


def log_scans(log_path) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Every laser record's valid points in the robot's frame (as the SLAM's default sensor
    takes them), its timestamp and the odometry stamped with it."""
    lasers = read_carmen(log_path).lasers
    sensor = SensorConfig()
    scans = []
    for record in lasers:
        scan = robot_frame_scan(record, PointScan(len(record.ranges)), sensor)
        scans.append(scan.buffer[: scan.count].copy())
    return (scans, np.array([r.timestamp for r in lasers], dtype=np.float64),
            np.array([r.odometry for r in lasers], dtype=np.float64).reshape(-1, 3))


def audit_log(log_path, relations: Relations, min_gain: float = MIN_GAIN, label: str = "audit"):
    """``relations`` checked against ``log_path``'s own scans (:func:`audit_scans`, odometry's
    motion among ICP's starts), with progress: ``(audit, scans, scan stamps, odometry at
    each)``."""
    scans, scan_stamps, odometry = log_scans(log_path)
    progress = Progress(len(relations), label)
    audit = audit_scans(scans, scan_stamps, relations, min_gain=min_gain, progress=progress,
                        odometry=odometry)
    progress.close()
    return audit, scans, scan_stamps, odometry


def scored_apart(stamps, poses, relations: Relations, audit: Audit) -> dict:
    """:func:`kummerle` over all relations, and apart over those the scans do not contradict
    (``confirmed``), those they do (``contradicted``), those they do not show
    (``unsupported``: :attr:`Audit.unsupported`) and those they neither contradict nor fail to
    show (``supported``)."""
    def part(mask) -> Relations:
        return Relations(relations.t1[mask], relations.t2[mask], relations.delta[mask])

    out = {"all": kummerle(stamps, poses, relations)}
    parts = (("confirmed", ~audit.contradicted), ("contradicted", audit.contradicted),
             ("unsupported", audit.unsupported),
             ("supported", ~audit.contradicted & ~audit.unsupported))
    for name, mask in parts:
        if np.any(mask):
            try:
                out[name] = kummerle(stamps, poses, part(mask))
            except ValueError:  # none of them has both ends in the trajectory
                pass
    return out


# °: a short relation off by more is a gross failure, unless its scans contradict it
GROSS_DEG = 10.0


def short_tail_apart(stamps, poses, relations: Relations, audit: Audit,
                     short_gap: float = SHORT_GAP, gross_deg: float = GROSS_DEG) -> dict:
    """A trajectory's short relations (under ``short_gap`` s apart) over those the scans do not
    contradict: their mean and p99 heading error (``eR_short_confirmed_deg``,
    ``eR_short_confirmed_p99_deg``, ``relations_short_confirmed``); and its short relations off
    by more than ``gross_deg``°: how many (``eR_short_over_10deg``), how many of them the scans
    do not contradict (``eR_short_over_10deg_confirmed``: the trajectory's own gross failures)
    and those listed (``short_over_10deg_confirmed``: t1, t2, eR_deg, the relation's
    ``delta``). Empty without short relations."""
    ok, _, e_r = relation_errors(stamps, poses, relations)
    used = np.flatnonzero(ok)
    short = np.abs(relations.t2[used] - relations.t1[used]) < short_gap
    if not np.any(short):
        return {}
    confirmed = short & ~audit.contradicted[used]
    gross = short & (e_r > gross_deg)
    key = f"over_{gross_deg:g}deg"
    out = {f"eR_short_{key}": int(gross.sum()),
           f"eR_short_{key}_confirmed": int((gross & confirmed).sum()),
           f"short_{key}_confirmed": [
               {"t1": float(relations.t1[r]), "t2": float(relations.t2[r]), "eR_deg": float(e),
                "delta": [float(v) for v in relations.delta[r]]}
               for r, e in zip(used[gross & confirmed], e_r[gross & confirmed])],
           "relations_short_confirmed": int(confirmed.sum())}
    if np.any(confirmed):
        out["eR_short_confirmed_deg"] = float(np.mean(e_r[confirmed]))
        out["eR_short_confirmed_p99_deg"] = float(np.percentile(e_r[confirmed], 99))
    return out


def fits_of_gross_failures(short: dict, scans, scan_stamps, stamps, poses, odometry=None,
                           inlier_distance: float = INLIER_DISTANCE) -> list[dict]:
    """The gross short failures the scans do not contradict, as :func:`short_tail_apart` lists
    them in ``short`` (each with its relation's pose ``delta``), their two scans placed on each
    other twice: by the relation and by the trajectory (``stamps``, ``poses``). Each listed
    entry gains the share of the second scan's points within ``inlier_distance`` of the first's
    either way (``fit_relation``, ``fit_trajectory``); returned, for a figure, each entry with
    the scans and both placements (``first``, ``second``, ``by_relation``, ``by_trajectory``).
    A gross failure the scans do not contradict by ICP's gain may still fit them better placed
    by the trajectory: two scans that share little (a fast turn, a hall of clutter) leave ICP
    short of the gain, and this shows which of the two the surfaces they share side with.

    With ``odometry`` (the pose odometry gave with each scan, (n, 3)), a third witness that is
    neither the reference nor the trajectory: odometry's own motion between the two scans
    places the second a third time (``fit_odometry``, ``by_odometry``), and its heading's
    difference from the relation's and from the trajectory's is given (``odometry_eR_deg``,
    ``odometry_vs_trajectory_deg``)."""
    listed = short.get(f"short_over_{GROSS_DEG:g}deg_confirmed", [])
    if not listed:
        return []
    ends = Relations(np.array([r["t1"] for r in listed]), np.array([r["t2"] for r in listed]),
                     np.array([r["delta"] for r in listed]))
    i, j, found = match_relations(scan_stamps, ends)
    a, b, placed = match_relations(stamps, ends)
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    out = []
    for k, r in enumerate(listed):
        if not (found[k] and placed[k]):
            continue
        first, second = scans[i[k]], scans[j[k]]
        tree = cKDTree(first)
        by_trajectory = between(poses[b[k]], poses[a[k]])  # δ = x_2 ⊖ x_1
        by_relation = ends.delta[k]
        r.update(fit_relation=scan_fit(tree, second, by_relation, inlier_distance),
                 fit_trajectory=scan_fit(tree, second, by_trajectory, inlier_distance))
        placements = {"by_relation": by_relation, "by_trajectory": by_trajectory}
        if odometry is not None:
            by_odometry = between(odometry[j[k]], odometry[i[k]])
            r.update(fit_odometry=scan_fit(tree, second, by_odometry, inlier_distance),
                     odometry_eR_deg=heading_apart(by_odometry, by_relation),
                     odometry_vs_trajectory_deg=heading_apart(by_odometry, by_trajectory))
            placements["by_odometry"] = by_odometry
        out.append({**r, "first": first, "second": second, **placements})
    return out


def heading_apart(a, b) -> float:
    """The heading between two relative poses (°, in [0, 180])."""
    return float(np.degrees(abs(between(np.asarray(a), np.asarray(b))[2])))


WORST_SHOWN = 10  # the worst relations printed (the JSON keeps WORST_KEPT)
WORST_KEPT = 50
# what a relation's scans say of it, by (contradicted, unsupported)
SCANS_SAY = {(True, False): "contradict it", (False, True): "do not show it",
             (False, False): "agree"}


def worst_relations(stamps, poses, relations: Relations, scan_stamps, odometry, audit: Audit,
                    count: int = WORST_KEPT) -> list[dict]:
    """The ``count`` relations with the largest heading error of the trajectory, each with
    odometry's own error there, the fastest odometry turn between its two scans (°/s) and
    whether its scans contradict it or do not show it (:attr:`Audit.unsupported`): an error
    within a degree or two of odometry's, at a fast turn, is one where the trajectory rode
    odometry."""
    ok, e_t, e_r = relation_errors(stamps, poses, relations)
    ok_o, _, e_r_o = relation_errors(scan_stamps, odometry, relations)
    odometry_error = np.full(len(relations), np.nan)
    odometry_error[ok_o] = e_r_o
    i, j, _ = match_relations(scan_stamps, relations)
    order = np.argsort(scan_stamps, kind="stable")
    sorted_stamps, heading = scan_stamps[order], np.unwrap(odometry[order, 2])
    rate = np.abs(np.diff(heading)) / np.maximum(np.diff(sorted_stamps), 1e-3)
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    used = np.flatnonzero(ok)
    out = []
    for k in np.argsort(-e_r)[:count]:
        r = used[k]
        a, b = sorted((int(rank[i[r]]), int(rank[j[r]])))
        turn = float(np.degrees(rate[a:b].max())) if b > a else 0.0
        out.append({"t1": float(relations.t1[r]), "t2": float(relations.t2[r]),
                    "seconds": float(abs(relations.t2[r] - relations.t1[r])),
                    "eT": float(e_t[k]), "eR_deg": float(e_r[k]),
                    "odometry_eR_deg": float(odometry_error[r]), "turn_rate_deg_s": turn,
                    "contradicted": bool(audit.contradicted[r]),
                    "unsupported": bool(audit.unsupported[r])})
    return out


def audit_command(log_path, relations_path, trajectory_path=None, json_path=None,
                  min_gain: float = MIN_GAIN, plots=None) -> dict:
    """The audit of ``relations_path`` against ``log_path``'s scans and the reference's clock
    (``clock``: swarmslam.evaluation.relations_clock.reference_clock), printed; with a TUM
    ``trajectory_path``, that trajectory scored apart (:func:`scored_apart`) and on the
    reference's clock; ``plots``: a folder for the figure."""
    if plots:
        require_matplotlib()
    relations = read_relations(relations_path)
    stamps, poses = read_tum(trajectory_path) if trajectory_path else (None, None)
    audit, scans, scan_stamps, odometry = audit_log(log_path, relations, min_gain)
    result = {"log": str(log_path), "relations_file": str(relations_path),
              **audit.summary(relations)}
    print(f"{result['checked']} of {result['relations']} relations checked against their "
          f"scans; {result['contradicted']} contradicted (ICP from the relation or odometry fits "
          f"≥ {min_gain:.0%} more of the points): {result['contradicted_local']} of "
          f"{result['checked_local']} local, {result['contradicted_global']} of "
          f"{result['checked_global']} global")
    print(f"  {result['unsupported']} unsupported (not contradicted, and no point of the second "
          f"scan within {INLIER_DISTANCE} m of the first's at the relation's pose): "
          f"{result['unsupported_local']} local, {result['unsupported_global']} global")
    if "correction_m_median" in result:
        print(f"  the scans move a contradicted relation by {result['correction_m_median']:.3f} m"
              f" / {result['correction_deg_median']:.2f}° (median)")
    gross = []  # gross short failures, placed by the relation, the trajectory and odometry
    if trajectory_path:
        result["trajectory"] = str(trajectory_path)
        result["scores"] = scored_apart(stamps, poses, relations, audit)
        for name, s in result["scores"].items():
            line = (f"  {name:12} eT {s['eT']:.4f} m, eR {s['eR_deg']:.3f}° "
                    f"({s['relations_used']})")
            if "eT_local" in s:
                line += (f"; local eT {s['eT_local']:.4f} m, eR {s['eR_local_deg']:.3f}° "
                         f"({s['relations_local']})")
            print(line)
        result["short"] = short = short_tail_apart(stamps, poses, relations, audit)
        if "eR_short_confirmed_deg" in short:
            key = f"over_{GROSS_DEG:g}deg"
            print(f"  short (< {SHORT_GAP:g} s): eR {short['eR_short_confirmed_deg']:.3f}° "
                  f"(p99 {short['eR_short_confirmed_p99_deg']:.2f}°) over the "
                  f"{short['relations_short_confirmed']} the scans do not contradict; "
                  f"{short[f'eR_short_{key}']} above {GROSS_DEG:g}°, "
                  f"{short[f'eR_short_{key}_confirmed']} of them not contradicted")
        gross = fits_of_gross_failures(short, scans, scan_stamps, stamps, poses, odometry)
        for g in gross:
            print(f"    {g['t1']:.3f} ({g['t2'] - g['t1']:.2f} s, eR {g['eR_deg']:.2f}°): the "
                  f"second scan fits {g['fit_relation']:.0%} of its points on the first placed "
                  f"by the relation, {g['fit_trajectory']:.0%} placed by the trajectory, "
                  f"{g['fit_odometry']:.0%} by odometry (whose heading is "
                  f"{g['odometry_eR_deg']:.2f}° off the relation's and "
                  f"{g['odometry_vs_trajectory_deg']:.2f}° off the trajectory's)")
    if trajectory_path:
        result["worst"] = worst_relations(stamps, poses, relations, scan_stamps, odometry, audit)
        print(f"  the {WORST_SHOWN} worst relations of the trajectory (heading):")
        print(f"  {'t1':>17} {'s apart':>8} {'eR °':>6} {'odometry °':>10} {'turn °/s':>8}  "
              f"scans")
        for w in result["worst"][:WORST_SHOWN]:
            print(f"  {w['t1']:17.3f} {w['seconds']:8.2f} {w['eR_deg']:6.2f} "
                  f"{w['odometry_eR_deg']:10.2f} {w['turn_rate_deg_s']:8.1f}  "
                  f"{SCANS_SAY[(w['contradicted'], w['unsupported'])]}")
    clock = reference_clock(scan_stamps, odometry, relations,
                            (stamps, poses) if trajectory_path else None)
    result["clock"] = clock
    print(f"  clock: odometry's heading error over a local relation rises "
          f"{clock['odometry_slope_ms']:.1f} ms × the change of its turn rate (correlation "
          f"{clock['odometry_correlation']:.2f}); {clock['odometry_agreement']:.0%} of the local "
          f"relations agree with odometry's heading within {AGREEMENT_DEG}°")
    if trajectory_path:
        moved = clock["on_reference_clock"]
        print(f"  clock: the trajectory's {clock['trajectory_slope_ms']:.1f} ms (correlation "
              f"{clock['trajectory_correlation']:.2f}; {clock['trajectory_agreement']:.0%} within "
              f"{AGREEMENT_DEG}°); moved by odometry over that time: eR {moved['eR_deg']:.3f}°"
              + (f", local {moved['eR_local_deg']:.3f}°" if "eR_local_deg" in moved else ""))
    if plots:
        e_r = None
        if trajectory_path:
            ok, _, e_r_used = relation_errors(stamps, poses, relations)
            e_r = np.full(len(relations), np.nan)
            e_r[ok] = e_r_used
        c = audit.checked
        path = relations_audit_figure(plots, Path(relations_path).name, relations.t1[c]
                                      - scan_stamps.min(), audit.fit[c], audit.fit_aligned[c],
                                      audit.contradicted[c], None if e_r is None else e_r[c])
        print(f"wrote {path}")
        if gross:
            path = gross_failures_figure(plots, Path(relations_path).name, gross)
            print(f"wrote {path}")
    if json_path:
        result["contradicted_relations"] = [
            {"t1": float(relations.t1[k]), "t2": float(relations.t2[k]),
             "fit": float(audit.fit[k]), "fit_aligned": float(audit.fit_aligned[k]),
             "correction": [float(v) for v in audit.correction[k]]}
            for k in np.flatnonzero(audit.contradicted)]
        result["unsupported_relations"] = [
            {"t1": float(relations.t1[k]), "t2": float(relations.t2[k]),
             "fit_aligned": float(audit.fit_aligned[k])}
            for k in np.flatnonzero(audit.unsupported)]
        write_json_atomic(json_path, result)
        print(f"wrote {json_path}")
    return result
