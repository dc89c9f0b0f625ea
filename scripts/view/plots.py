"""The benchmarks' figures (``swarmslam bench ... --plots DIR``), as PNG files written
atomically. matplotlib is an optional extra (``pip install -e ".[plots]"``); asking for plots
without it is a clear error before the benchmark runs."""

from __future__ import annotations

import importlib.util
import io
from pathlib import Path

import numpy as np

from swarmslam.runtime.pose import transform_points
from swarmslam.runtime.realtime.writers import write_bytes_atomic


def require_matplotlib() -> None:
    if importlib.util.find_spec("matplotlib") is None:
        raise ValueError("--plots needs matplotlib: pip install -e \".[plots]\"")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only: no display needed
    import matplotlib.pyplot as plt

    return plt


def save(fig, path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    _pyplot().close(fig)
    return write_bytes_atomic(path, buf.getvalue())


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in text)


# ---------------------------------------------------------------------- bench slam
def slam_errors_over_time(out_dir, label: str, t, e_t, e_r_deg, is_local) -> Path:
    """Where a run's error comes from: each relation's translation and rotation error at the
    time of its first scan (from the log's start), local and global relations apart."""
    plt = _pyplot()
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    t, e_t, e_r_deg, is_local = map(np.asarray, (t, e_t, e_r_deg, is_local))
    for mask, name, color in ((is_local, "local", "tab:blue"), (~is_local, "global", "tab:red")):
        if np.any(mask):
            a.plot(t[mask], e_t[mask], ".", ms=3, color=color, label=f"{name} ({mask.sum()})")
            b.plot(t[mask], e_r_deg[mask], ".", ms=3, color=color)
    a.set_yscale("log")
    b.set_yscale("log")
    a.set_ylabel("translation error (m)")
    b.set_ylabel("rotation error (°)")
    b.set_xlabel("time of the relation's first scan (s from the log's start)")
    a.set_title(f"{label}: relation errors (mean {e_t.mean():.4f} m, {e_r_deg.mean():.3f}°)")
    a.legend(loc="upper left", fontsize=8)
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
    return save(fig, Path(out_dir) / f"slam-{_slug(label)}.png")


def relations_audit_figure(out_dir, label: str, t, fit, fit_aligned, contradicted,
                           e_r_deg=None) -> Path:
    """A relations file checked against its scans (``swarmslam relations audit``): each
    relation's fit and what ICP gained over it at the time of its first scan, contradicted
    ones in red; with a trajectory's rotation errors, those too, split the same way."""
    plt = _pyplot()
    rows = 2 if e_r_deg is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(9, 2.6 * rows + 0.4), sharex=True, squeeze=False)
    t, fit, fit_aligned, bad = map(np.asarray, (t, fit, fit_aligned, contradicted))
    a = axes[0, 0]
    for mask, name, color in ((~bad, "confirmed", "tab:blue"), (bad, "contradicted", "tab:red")):
        if np.any(mask):
            a.plot(t[mask], fit_aligned[mask] - fit[mask], ".", ms=3, color=color,
                   label=f"{name} ({mask.sum()})")
    a.set_ylabel("share of points ICP\nfits beyond the relation")
    a.set_title(f"{label}: {bad.sum()} of {len(bad)} relations contradicted by their scans")
    a.legend(loc="upper left", fontsize=8)
    if e_r_deg is not None:
        b = axes[1, 0]
        e = np.asarray(e_r_deg)
        for mask, name, color in ((~bad, "confirmed", "tab:blue"),
                                  (bad, "contradicted", "tab:red")):
            if np.any(mask):
                b.plot(t[mask], e[mask], ".", ms=3, color=color,
                       label=f"{name}: mean {np.nanmean(e[mask]):.3f}°")
        b.set_yscale("log")
        b.set_ylabel("trajectory's rotation error (°)")
        b.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("time of the relation's first scan (s from the log's start)")
    for ax in axes[:, 0]:
        ax.grid(True, which="both", alpha=0.3)
    return save(fig, Path(out_dir) / f"audit-{_slug(label)}.png")


GROSS_SHOWN = 6  # gross failures drawn at most, the first listed


# what placed the second scan, as a figure's title names it
PLACED_BY = {"relation": "the relation", "trajectory": "the trajectory", "odometry": "odometry"}


def gross_failures_figure(out_dir, label: str, gross: list[dict]) -> Path:
    """A trajectory's gross short failures the audit could not call contradicted
    (swarmslam.evaluation.relations_audit.fits_of_gross_failures): per relation, its second scan (red) on
    its first (blue) placed by the relation (left), by the trajectory and, where the audit had
    odometry, by odometry (right), each titled with the share of points that fits — which
    placement the surfaces the scans share side with."""
    plt = _pyplot()
    shown = gross[:GROSS_SHOWN]
    names = [n for n in ("relation", "trajectory", "odometry")
             if all(f"by_{n}" in g for g in shown)]
    fig, axes = plt.subplots(len(shown), len(names), figsize=(5 * len(names), 4.6 * len(shown)),
                             squeeze=False)
    for row, g in zip(axes, shown):
        first = np.asarray(g["first"])
        # framed, square, on where most returns lie: a few far ones would shrink the surfaces
        # to dots
        placed = [transform_points(np.asarray(g[f"by_{n}"]), np.asarray(g["second"]))
                  for n in names]
        lo, hi = np.percentile(np.vstack([first, *placed]), [3, 97], axis=0)
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo).max() + 2.0
        lo, hi = centre - half, centre + half
        for ax, name, second in zip(row, names, placed):
            fit = g[f"fit_{name}"]
            ax.plot(first[:, 0], first[:, 1], ".", ms=2.5, color="tab:blue", label="first scan")
            ax.plot(second[:, 0], second[:, 1], ".", ms=2.5, color="tab:red",
                    label="second scan")
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.grid(True, alpha=0.3)
            ax.set_title(f"t1 {g['t1']:.2f}, {g['t2'] - g['t1']:.1f} s, eR {g['eR_deg']:.1f}°:\n"
                         f"placed by {PLACED_BY[name]}, {fit:.0%} of its points fit", fontsize=9)
        row[0].legend(loc="upper left", fontsize=7)
    fig.suptitle(f"{label}: gross short failures the scans do not contradict by ICP's gain")
    return save(fig, Path(out_dir) / f"audit-{_slug(label)}-gross.png")


def slam_summary(out_dir, summary, published) -> list[Path]:
    """Per log: mean eT over seeds (bar) and worst seed (tick) per optimizer and input,
    beside the published systems (lines)."""
    plt = _pyplot()
    paths = []
    for name in dict.fromkeys(s["dataset"] for s in summary):
        rows = [s for s in summary if s["dataset"] == name]
        parts = [k[:-5] for k in rows[0] if k.startswith("eT") and k.endswith("_mean")]
        fig, axes = plt.subplots(1, len(parts), figsize=(4.5 * len(parts), 3.6), squeeze=False)
        for ax, part in zip(axes[0], parts):
            labels = [f"{s['optimizer']}\n{'odom' if s['odometry'] else 'scans'}" for s in rows]
            means = [s.get(f"{part}_mean", np.nan) for s in rows]
            worst = [s.get(f"{part}_worst", np.nan) for s in rows]
            x = np.arange(len(rows))
            ax.bar(x, means, color="tab:blue", label="mean over seeds")
            ax.plot(x, worst, "v", color="black", label="worst seed")
            which = part[2:].strip("_")  # "", "local", "global"
            for system, fig_ in published.get(name, {}).items():
                if not which or which in system:
                    ax.axhline(fig_[0], ls="--", lw=1, color="tab:gray")
                    ax.annotate(system, (x[-1] + 0.4, fig_[0]), fontsize=7, va="bottom",
                                ha="right")
            ax.set_xticks(x, labels, fontsize=8)
            ax.set_yscale("log")
            ax.set_ylabel(f"{part} (m)")
            ax.set_title(f"{name} {which}".strip())
            ax.legend(fontsize=7, loc="upper left")
        paths.append(save(fig, Path(out_dir) / f"slam-summary-{name}.png"))
    return paths


# ---------------------------------------------------------------------- bench robustness
def robustness_figure(out_dir, runs: list[dict], summary: dict) -> Path:
    """Every run's scored eT and global eT, one column per log and family, a dot a seed (red:
    a gross run), the median seed's marked."""
    plt = _pyplot()
    keys = list(summary)
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.7 * len(keys) + 2), 6.4), sharex=True)
    for ax, key, label in ((axes[0], "eT_scored", "eT (m)"),
                           (axes[1], "eT_global", "global eT, ≥ 300 s apart (m)")):
        for x, name in enumerate(keys):
            rows = [r for r in runs if f"{r['log']}/{r['family']}" == name]
            gross = {g["seed"] for g in summary[name]["gross"]}
            for r in rows:
                if r[key] is not None:
                    ax.plot(x, r[key], "o", ms=4, color="tab:red" if r["seed"] in gross
                            else "tab:blue", alpha=0.8)
            median = summary[name].get(f"{key}_median")
            if median is not None:
                ax.plot([x - 0.3, x + 0.3], [median, median], color="black", lw=1)
        ax.set_yscale("log")
        ax.set_ylabel(label)
    axes[1].set_xticks(range(len(keys)), keys, rotation=60, ha="right", fontsize=7)
    axes[0].set_title("bench robustness: a dot a seed (red: gross), the median's line")
    return save(fig, Path(out_dir) / "robustness.png")


# ---------------------------------------------------------------------- bench matcher
def matcher_errors(out_dir, dataset: str, errors: dict) -> Path:
    """Distribution of each matcher's translation and rotation errors on one log's pairs
    (``errors``: variant → (e_t m, e_r rad)), ICP beside the swarms."""
    plt = _pyplot()
    names = list(errors)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    floor = 1e-5  # a log scale shows exact matches at this floor
    a.boxplot([np.maximum(errors[n][0], floor) for n in names], showfliers=True)
    b.boxplot([np.maximum(np.degrees(errors[n][1]), floor) for n in names], showfliers=True)
    for ax, what in ((a, "translation error (m)"), (b, "rotation error (°)")):
        ax.set_yscale("log")
        ax.set_xticks(range(1, len(names) + 1), names, rotation=30, fontsize=8)
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"scan matching on {dataset}: {len(errors[names[0]][0])} keyframe pairs, "
                 "no initial guess")
    return save(fig, Path(out_dir) / f"matcher-{dataset}.png")


# ---------------------------------------------------------------------- bench runtime
def latency_histograms(out_dir, latencies_ms: dict, budget_ms: float, name: str,
                       budget_label: str = "tick budget", xlabel: str = "tick latency (ms)",
                       ylabel: str = "ticks") -> Path:
    """Latency histograms (``latencies_ms``: pass → array), the budget marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.8))
    values = [np.asarray(v, float) for v in latencies_ms.values()]
    hi = max(float(np.max(v)) for v in values if len(v))
    bins = np.geomspace(max(min(float(np.min(v)) for v in values if len(v)), 1e-3), hi, 80)
    for (label, _), v in zip(latencies_ms.items(), values):
        ax.hist(v, bins=bins, histtype="step", lw=1.5,
                label=f"{label}: p99 {np.percentile(v, 99):.2f} ms")
    ax.axvline(budget_ms, color="black", ls="--", lw=1, label=f"{budget_label} {budget_ms:g} ms")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return save(fig, Path(out_dir) / f"{name}.png")


# ---------------------------------------------------------------------- bars
def bars(out_dir, name: str, title: str, ylabel: str, groups: dict, log=False,
         targets: dict | None = None, stacked=False) -> Path:
    """A bar chart: ``groups`` label → value (or series name → {label → value} for grouped,
    or ``stacked``, bars); ``targets`` label → a target line over that bar."""
    plt = _pyplot()
    series = groups if all(isinstance(v, dict) for v in groups.values()) else {"": groups}
    labels = list(dict.fromkeys(k for s in series.values() for k in s))
    fig, ax = plt.subplots(figsize=(max(4.0, 1.1 * len(labels) * max(len(series), 1) ** 0.5
                                        + 2), 3.6))
    x = np.arange(len(labels))
    width = 0.6 if stacked else 0.8 / len(series)
    bottom = np.zeros(len(labels))
    for i, (sname, values) in enumerate(series.items()):
        v = np.array([values.get(k, 0.0 if stacked else np.nan) for k in labels], float)
        if stacked:
            ax.bar(x, v, width, bottom=bottom, label=sname or None)
            bottom += v
        else:
            ax.bar(x + (i - (len(series) - 1) / 2) * width, v, width, label=sname or None)
    for k, v in (targets or {}).items():
        j = labels.index(k)
        ax.plot([j - 0.45, j + 0.45], [v, v], color="black", ls="--", lw=1)
    ax.set_xticks(x, labels, rotation=20 if len(labels) > 4 else 0, fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if log:
        ax.set_yscale("log")
    if len(series) > 1:
        ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)
    return save(fig, Path(out_dir) / f"{name}.png")


def lines_plot(out_dir, name: str, title: str, xlabel: str, series: dict) -> Path:
    """One panel per series (``series``: label → (x, y)), sharing the x axis."""
    plt = _pyplot()
    fig, axes = plt.subplots(len(series), 1, figsize=(8, 2.4 * len(series)), sharex=True,
                             squeeze=False)
    for ax, (label, (x, y)) in zip(axes[:, 0], series.items()):
        ax.plot(x, y, ".-")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel(xlabel)
    return save(fig, Path(out_dir) / f"{name}.png")
