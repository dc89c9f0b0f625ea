"""``swarmslam bench report``: ``docs/results.md`` and the README's headline block, written from
``bench-results/*.json`` and nothing else, so that no figure is typed by hand.

    swarmslam bench report            # rewrite both from bench-results/
    swarmslam bench report --check    # exit 1 (and say which) when either differs

Each benchmark gets a table, the command that made it, when and where it ran (commit, date,
machine, whether another benchmark shared it) and its targets, met or missed. The README's
block lies between :data:`BEGIN` and :data:`END`; the rest of the README is not touched.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from swarmslam.bench.localize import MEDIAN_MS_TARGET as LOCALIZE_MEDIAN_MS
from swarmslam.bench.runtime import TARGETS as RUNTIME_TARGETS
from swarmslam.bench.slam import PUBLISHED
from swarmslam.runtime.realtime.writers import write_text_atomic

BEGIN = "<!-- results:begin (swarmslam bench report writes this block) -->"
END = "<!-- results:end -->"
LOG_NAMES = {"intel": "Intel", "aces": "ACES3", "clinic": "fr-clinic", "mit": "MIT-CSAIL",
             "fr079": "FR079"}
REAL_TIME_TARGET = 30.0  # × real time on one core, every log
ROBUST_SPREAD = 1.25  # the worst seed's eT at most this many times the median seed's


@dataclass
class Section:
    """One benchmark's part of the page."""

    name: str
    title: str
    command: str
    meta: dict
    table: list[str]
    targets: list[tuple[str, bool]] = field(default_factory=list)
    key: str = ""  # the JSON file's stem

    def markdown(self) -> str:
        out = [f"## {self.title}", "", f"`{self.command}`", "", ran_where(self.meta), ""]
        out += self.table
        if self.targets:
            out += ["", "Targets: " + "; ".join(f"{text} — **{'met' if ok else 'missed'}**"
                                                 for text, ok in self.targets) + "."]
        return "\n".join(out)


def ran_where(meta: dict) -> str:
    if not meta:
        return "Run before runs were recorded (no commit, date or machine in its JSON)."
    commit = (meta.get("commit") or "unknown")[:7] + (" (uncommitted changes)"
                                                       if meta.get("dirty") else "")
    shared = {True: "shared with another benchmark or test run",
              False: "nothing else heavy running"}.get(meta.get("shared_machine"),
                                                       "sharing not recorded")
    return (f"Commit {commit}, {meta.get('date', '?')[:10]}, {meta.get('cpu', '?')}"
            f"{' (' + meta['cpu_target'] + ')' if meta.get('cpu_target') else ''} × "
            f"{meta.get('cores', '?')} cores, Python {meta.get('python', '?')}, numba "
            f"{meta.get('numba', '?')}; {shared}.")


def _row(*cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _head(*cells) -> list[str]:
    return [_row(*cells), "|" + "---|" * len(cells)]


# ---------------------------------------------------------------------- per benchmark
def _slam_parts(s: dict):
    """(label, published key, eT, eR, worst eT, worst eR) per scored part of a summary row."""
    if s["dataset"] == "clinic":
        for part, key in (("local", "Cartographer, local"), ("global", "Cartographer, global")):
            yield (f"fr-clinic {part}", key, s[f"eT_{part}_mean"], s[f"eR_{part}_deg_mean"],
                   s[f"eT_{part}_worst"], s[f"eR_{part}_deg_worst"])
    else:
        yield (LOG_NAMES.get(s["dataset"], s["dataset"]), "Cartographer", s["eT_mean"],
               s["eR_deg_mean"], s["eT_worst"], s["eR_deg_worst"])


def slam(data: dict) -> Section:
    table = _head("log", "eT m (worst seed)", "eR ° (worst seed)", "Cartographer eT / eR",
                  "short eR ° median / p99 / max",
                  "short, scans not contradicting: eR ° / p99 / > 10° (worst seed)",
                  "× real time (slowest)")
    targets = []
    for s in data["summary"]:
        published = PUBLISHED.get(s["dataset"], {})
        for label, key, et, er, et_w, er_w in _slam_parts(s):
            ref = published.get(key)
            ref_text = f"{ref[0]:.4f} / {ref[2]:.3f}" if ref else "—"
            global_part = label == "fr-clinic global"  # its relations are all long
            short = (f"{s['eR_short_median_deg_mean']:.2f} / {s['eR_short_p99_deg_mean']:.2f} / "
                     f"{s['eR_short_max_deg_mean']:.1f}" if not global_part else "")
            audited = _audited_short(s) if not global_part else ""
            table.append(_row(label, f"{et:.4f} ({et_w:.4f})", f"{er:.3f} ({er_w:.3f})",
                              ref_text, short, audited, f"{s['real_time_factor_min']:.1f}"))
            if ref:
                targets.append((f"{label} eT ≤ {ref[0]:.4f}", et <= ref[0]))
                targets.append((f"{label} eR ≤ {ref[2]:.3f}°", er <= ref[2]))
            if not global_part and "eR_short_over_10deg_confirmed_worst" in s:
                targets.append((f"{label}: no short relation above 10° that its scans do not "
                                "contradict", s["eR_short_over_10deg_confirmed_worst"] == 0))
        targets.append((f"{LOG_NAMES.get(s['dataset'], s['dataset'])} ≥ "
                        f"{REAL_TIME_TARGET:.0f}× real time", s["real_time_factor_min"]
                        >= REAL_TIME_TARGET))
    seeds = ", ".join(str(v) for v in data.get("seeds", []))
    table += ["", f"Mean over seeds {seeds}; Kümmerle et al.'s relation metric (eT, eR); short "
                  "relations: those under 10 s apart; scans not contradicting: the short "
                  "relations `swarmslam relations audit` does not find contradicted by the log's "
                  "own scans (docs/method.md §7.1). Cartographer: Hess et al. 2016, Table II."]
    return Section("slam", "SLAM on the raw logs", "swarmslam bench slam --optimizers abc "
                   "--modes odometry", data.get("meta", {}), table, targets)


def _audited_short(s: dict) -> str:
    """A summary row's short relations over those the scans do not contradict (bench slam's
    audit); a dash in results recorded before the audit."""
    if "eR_short_confirmed_deg_mean" not in s:
        return "—"
    return (f"{s['eR_short_confirmed_deg_mean']:.2f} / {s['eR_short_confirmed_p99_deg_mean']:.2f}"
            f" / {s['eR_short_over_10deg_confirmed_mean']:.1f} "
            f"({s['eR_short_over_10deg_confirmed_worst']:.0f})")


def generalization(data: dict) -> Section:
    table = _head("case", "eT m", "eR °", "ATE m", "loop precision", "on every axis", "recall",
                  "eT / floor")
    for r in data["cases"]:
        ratio = f"{r['eT_over_floor']:.2f}" if "eT_over_floor" in r else "—"
        axes = (f"{r['loop_precision_all_axes']:.3f}" if "loop_precision_all_axes" in r
                else "—")
        table.append(_row(r["case"], f"{r['eT']:.4f}", f"{r['eR_deg']:.3f}",
                          f"{r['ate_rmse_m']:.3f}", f"{r['loop_precision']:.3f}", axes,
                          f"{r['loop_recall']:.3f}", ratio))
    summary = data["summary"]
    groups = summary if "plain" in summary or "robot" in summary else {"all": summary}
    table.append("")
    for name, s in groups.items():
        table.append(f"- {name}: worst loop precision {s['worst_loop_precision']:.3f}, mean "
                     f"recall {s['mean_loop_recall']:.3f}, mean ATE {s['mean_ate_rmse_m']:.3f} m"
                     + (f", worst eT / floor {s['worst_eT_over_floor']:.2f}"
                        if s.get("worst_eT_over_floor") is not None else ""))
    table.append("")
    table.append("Simulated surveys scored against their true poses; the floor is the same run "
                 "with perfect scan matching. A closure is correct within 0.2 m and 2° of the "
                 "truth, its position judged along the directions the edge measures (along a "
                 "corridor's axis an edge keeps 1% of its information and holds the graph's "
                 "estimate: within 0.2 m / √0.01 there); \"on every axis\" judges the whole "
                 "position error (docs/method.md §7.2).")
    return Section("generalization", "Logs it was never tuned on (simulated)",
                   "swarmslam bench generalization", data.get("meta", {}), table)


def localize(data: dict) -> Section:
    table = _head("log", "one scan: found / wrong / ambiguous", "ms median / p99",
                  "confirmed: found / wrong", "tracking error m (mean / p99)")
    targets = []
    for r in data["logs"]:
        name = LOG_NAMES.get(r["dataset"], r["dataset"])
        table.append(_row(name, f"{r['success_rate']:.1%} / {r['wrong_rate']:.1%} / "
                          f"{r['ambiguous_rate']:.1%}", f"{r['ms_median']:.0f} / "
                          f"{r['ms_p99']:.0f}", f"{r['success_rate_confirmed']:.1%} / "
                          f"{r['wrong_rate_confirmed']:.1%}", f"{r['tracking_error_m']:.3f} / "
                          f"{r['tracking_error_m_p99']:.3f}"))
        targets.append((f"{name} one-scan median ≤ {LOCALIZE_MEDIAN_MS:.0f} ms",
                        r["ms_median"] <= LOCALIZE_MEDIAN_MS))
    table += ["", f"{data['queries']} queries per log (seed {data['seed']}); found within "
                  f"{data['success']['distance_m']} m and {data['success']['angle_deg']}° of "
                  "the mapping run's pose."]
    return Section("localize", "Map once, localize later", "swarmslam bench localize",
                   data.get("meta", {}), table, targets)


def runtime(data: dict) -> Section:
    m, t = data["max_speed"], data["traced"]
    log = Path(data["log"]).name
    table = _head("figure", "value")
    rows = [("log", log), ("× real time (as fast as it goes)", f"{m['real_time_factor']:.1f}"),
            ("tick latency ms median / p99 / max", f"{m['latency_ms_median']:.1f} / "
             f"{m['latency_ms_p99']:.1f} / {m['latency_ms_max']:.1f}"),
            ("deadline misses at 10 Hz", m["deadline_misses_10hz"]),
            ("RSS MiB committed at start / peak", f"{m['rss_mib_committed_at_start']:.0f} / "
             f"{m['rss_mib_peak']:.0f}"),
            ("RSS growth after warm-up MiB", f"{m['rss_mib_growth_after_warm_up']:.2f}"),
            ("traced bytes per tick after warm-up", f"{t['traced_bytes_per_tick']:.1f}")]
    if "eT" in m:
        rows.append(("eT m / eR °", f"{m['eT']:.4f} / {m['eR_deg']:.3f}"))
    if data.get("recorded_rate"):
        r = data["recorded_rate"]
        rows.append((f"at the recorded rate ({r['minutes']:g} min): misses, p99 ms",
                     f"{r['deadline_misses']}, {r['latency_ms_p99']:.1f}"))
    table += [_row(*row) for row in rows]
    targets = [(f"p99 ≤ {RUNTIME_TARGETS['p99_ms']:.0f} ms",
                m["latency_ms_p99"] <= RUNTIME_TARGETS["p99_ms"]),
               (f"{RUNTIME_TARGETS['misses']} deadline misses",
                m["deadline_misses_10hz"] <= RUNTIME_TARGETS["misses"]),
               (f"RSS growth ≤ {RUNTIME_TARGETS['rss_growth_mib']:.0f} MiB",
                m["rss_mib_growth_after_warm_up"] <= RUNTIME_TARGETS["rss_growth_mib"])]
    return Section("runtime", f"The fixed-rate runtime ({log})",
                   f"swarmslam bench runtime --log {data.get('log_name', log)}",
                   data.get("meta", {}), table, targets)


def soak(data: dict) -> Section:
    r = data["runtime"]
    table = _head("figure", "value")
    table += [_row("minutes, ticks", f"{data['minutes']:g}, {data['ticks']}"),
              _row("RSS growth after the first minute MiB",
                   f"{data['rss_mib_growth_after_first_minute']:.2f}"),
              _row("traced KiB growth after the first minute",
                   f"{data['traced_kib_growth_after_first_minute']:.1f}"),
              _row("latency ms median / p99 / max", f"{r['latency_ms_median']:.1f} / "
                   f"{r['latency_ms_p99']:.1f} / {r['latency_ms_max']:.1f}"),
              _row("deadline misses", r["deadline_misses"])]
    targets = [(f"RSS growth ≤ {RUNTIME_TARGETS['rss_growth_mib']:.0f} MiB",
                data["rss_mib_growth_after_first_minute"] <= RUNTIME_TARGETS["rss_growth_mib"])]
    return Section("runtime-soak", "A long run on simulated scans",
                   f"swarmslam bench runtime --soak {data['minutes']:g}", data.get("meta", {}),
                   table, targets)


def env(data: dict) -> Section:
    runs = data.get("runs", {})

    def rate(key):  # the median of the runs, and each run (files before repeats had one)
        each = runs.get(key.removeprefix("steps_per_s_"))
        return f"{data[key]:.0f}" + (f" (median of runs {', '.join(f'{v:.0f}' for v in each)})"
                                      if each and len(each) > 1 else "")

    table = _head("figure", "value")
    table += [_row("steps/s without SLAM", rate("steps_per_s_without_slam")),
              _row("steps/s with SLAM", rate("steps_per_s_with_slam")),
              _row("LiDAR scans/s: numba / pymunk", f"{data['lidar']['numba_scans_per_s']:.0f} / "
                   f"{data['lidar']['pymunk_scans_per_s']:.0f}")]
    labels = {"steps_per_s_without_slam": "steps/s without SLAM",
              "steps_per_s_with_slam": "steps/s with SLAM"}
    targets = [(f"{labels.get(k, k)} ≥ {v:,}", bool(data["met"][k]))
               for k, v in data["targets"].items()]
    return Section("env", f"SwarmSlam-v0 ({data['world']} world, {data['beams']} beams)",
                   "swarmslam bench env", data.get("meta", {}), table, targets)


def matcher(data: dict) -> Section:
    table = _head("keyframe pairs", "optimizer", "fail rate", "eT m (median)", "eR rad",
                  "ms median")
    for dataset, by_optimizer in data["datasets"].items():
        for name, r in by_optimizer.items():
            table.append(_row(dataset, name, f"{r['fail_rate']:.1%}",
                              f"{r['eT']:.4f} ({r['eT_median']:.4f})", f"{r['eR']:.4f}",
                              f"{r['ms_median']:.1f}"))
    table += ["", "Scan matching with no initial guess; `-paper`: the paper's form (Eq. 14)."]
    return Section("matcher", "Scan matching alone", "swarmslam bench matcher",
                   data.get("meta", {}), table)


def posegraph(data: dict) -> Section:
    table = _head("graph", "χ²", "g2o χ²", "ms median", "g2o ms")
    targets = []
    for name, r in data["graphs"].items():
        table.append(_row(name, f"{r['chi2']:.3f}", f"{r['chi2_g2o']:.3f}",
                          f"{r['ms_median']:.1f}", f"{r['g2o_ms']:.0f}"))
        targets.append((f"{name} χ² as g2o's", abs(r["chi2"] - r["chi2_g2o"])
                        <= 1e-3 * r["chi2_g2o"]))
    return Section("posegraph", "Gauss–Newton on the g2o benchmark graphs",
                   "swarmslam bench posegraph", data.get("meta", {}), table, targets)


def bags(data: dict) -> Section:
    table = _head("log", "format", "read s", "share of the replay's wall time")
    targets = []
    for name, entry in data["logs"].items():
        for fmt, r in entry["formats"].items():
            table.append(_row(LOG_NAMES.get(name, name), fmt, f"{r['read_seconds']:.2f}",
                              f"{r['share_of_replay']:.1%}"))
            targets.append((f"{name} {fmt} read ≤ {data['target_read_share']:.0%}",
                            r["target_met"]))
        targets.append((f"{name} MCAP replay identical to CARMEN's",
                        entry["trajectory_identical"]))
    return Section("bags", "Reading ROS bags", "swarmslam bench bags", data.get("meta", {}),
                   table, targets)


def sweep(data: dict) -> Section:
    table = _head("figure", "value")
    table += [_row("runs", data["runs"]), _row("serial s", f"{data['serial_seconds']:.0f}"),
              _row(f"Ray ({data['workers']} workers) s", f"{data['ray_seconds']:.0f}"),
              _row("same figures", "yes" if data["same_figures"] else "no")]
    return Section("sweep", "Many runs: serial and on Ray", "swarmslam bench sweep SPEC",
                   data.get("meta", {}), table,
                   [("same figures serial and on Ray", bool(data["same_figures"]))])


def robustness(data: dict) -> Section:
    table = _head("log / family", "runs", "eT m median / worst", "worst ÷ median",
                  "eR ° median / worst", "global eT m median / worst", "gross runs")
    targets = []
    for key, s in data["summary"].items():
        log, family = key.split("/")
        label = f"{LOG_NAMES.get(log, log)} / {family}"
        gross = s.get("gross", [])
        table.append(_row(label, s["runs"],
                          f"{s['eT_scored_median']:.4f} / {s['eT_scored_worst']:.4f}",
                          f"{s['eT_scored_spread']:.2f}",
                          f"{s['eR_deg_median']:.3f} / {s['eR_deg_worst']:.3f}",
                          f"{s['eT_global_median']:.3f} / {s['eT_global_worst']:.3f}",
                          ", ".join(f"seed {g['seed']}" for g in gross) or "none"))
        targets.append((f"{label}: no gross run", not gross))
        targets.append((f"{label}: worst ÷ median eT ≤ {ROBUST_SPREAD}",
                        s["eT_scored_spread"] <= ROBUST_SPREAD))
    seeds = ", ".join(str(v) for v in data.get("seeds", []))
    table += ["", f"Seeds {seeds}, the defaults; fr-clinic judged by its local relations. "
                  f"Gross: a global eT or p99 error above {data.get('gross_ratio', 2.0):g}× the "
                  f"median seed's, or an eT above {data.get('gross_eT', 0.1):g} m "
                  "(docs/benchmarks.md)."]
    return Section("robustness", "The map on every seed", "swarmslam bench robustness",
                   data.get("meta", {}), table, targets)

FORMATTERS = {"slam": slam, "generalization": generalization, "localize": localize,
              "runtime": runtime, "runtime-soak": soak, "env": env, "matcher": matcher,
              "posegraph": posegraph, "bags": bags, "sweep": sweep, "robustness": robustness}


def sections(results_dir) -> list[Section]:
    """A section per JSON in ``results_dir`` whose benchmark is known (runtime-*.json files
    other than the soak are runs of ``bench runtime`` on another log)."""
    out = []
    for path in sorted(Path(results_dir).glob("*.json")):
        data = json.loads(path.read_text(encoding="utf-8"))
        kind = data.get("benchmark") or path.stem
        if kind == "runtime" and path.stem != "runtime":
            data["log_name"] = path.stem.removeprefix("runtime-")
        if kind in FORMATTERS:
            section = FORMATTERS[kind](data)
            section.command = data.get("meta", {}).get("command", section.command)
            section.key = path.stem
            out.append(section)
    order = list(FORMATTERS)
    return sorted(out, key=lambda s: (order.index(s.name), s.title))


def results_page(results_dir) -> str:
    parts = ["# Results", "",
             "Generated by `swarmslam bench report` from `bench-results/*.json`; do not edit. "
             "Each table names the command that made it and where it ran. Speed figures "
             "taken while another benchmark shared the machine are not comparable with quiet "
             "ones.", ""]
    for section in sections(results_dir):
        parts += [section.markdown(), ""]
    return "\n".join(parts).rstrip("\n") + "\n"


def headline(results_dir) -> str:
    """The README's block: accuracy against Cartographer per log, and the speeds."""
    by_key = {s.key: s for s in sections(results_dir)}
    lines = [BEGIN, ""]
    path = Path(results_dir) / "slam.json"
    if path.exists():
        data = json.loads(path.read_text(encoding="utf-8"))
        seeds = ", ".join(str(v) for v in data.get("seeds", []))
        lines += [f"Accuracy on the public logs (`swarmslam bench slam`, ABC with odometry, mean "
                  f"of seeds {seeds}; Kümmerle et al.'s metric), beside Cartographer's published "
                  "figures:", ""]
        lines += _head("log", "eT (m)", "eR (°)", "Cartographer eT / eR",
                       "× real time (slowest seed)")
        for s in data["summary"]:
            for label, key, et, er, _, _ in _slam_parts(s):
                ref = PUBLISHED.get(s["dataset"], {}).get(key)
                lines.append(_row(label, f"{et:.4f}", f"{er:.3f}",
                                  f"{ref[0]:.4f} / {ref[2]:.3f}" if ref else "—",
                                  f"{s['real_time_factor_min']:.1f}"))
        lines.append("")
    for key in ("runtime", "env", "localize", "bags"):
        if key in by_key:
            met = by_key[key].targets
            missed = [text for text, ok in met if not ok]
            lines.append(f"- {by_key[key].title}: {len(met) - len(missed)} of {len(met)} "
                         "targets met" + (f" (missed: {'; '.join(missed)})" if missed else ""))
    lines += ["", "Every table, with its command and machine: [docs/results.md](docs/results.md).",
              "", END]
    return "\n".join(lines)


def with_headline(readme: str, block: str) -> str:
    if BEGIN not in readme or END not in readme:
        raise ValueError(f"the README has no results block ({BEGIN} ... {END})")
    head, rest = readme.split(BEGIN, 1)
    return head + block + rest.split(END, 1)[1]


def bench_report(results_dir="bench-results", page="docs/results.md", readme="README.md",
                 check: bool = False, echo=print) -> int:
    """Write (or ``check``) the results page and the README's block; 1 when a check fails."""
    want_page = results_page(results_dir)
    readme_path = Path(readme)
    text = readme_path.read_text(encoding="utf-8")
    want_readme = with_headline(text, headline(results_dir))
    stale = [str(p) for p, want in ((Path(page), want_page), (readme_path, want_readme))
             if not p.exists() or p.read_text(encoding="utf-8") != want]
    if check:
        for p in stale:
            echo(f"{p} differs from what {results_dir}/*.json gives: run swarmslam bench report")
        return 1 if stale else 0
    write_text_atomic(Path(page), want_page)
    write_text_atomic(readme_path, want_readme)
    echo(f"wrote {page} and the results block of {readme}")
    return 0
