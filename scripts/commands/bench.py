"""``swarmslam bench``: the benchmarks (swarmslam.bench), each to JSON."""

from __future__ import annotations

from swarmslam.commands.common import (at_least_one, bench_outputs, config_options, non_negative,
                                       positive, run_config, whole)
from swarmslam.runtime.config import DEFAULT_PRESET, OPTIMIZERS

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "bench": ("Benchmarks: each prints a table and, with --json, writes its figures with the "
              "commit, date, command, machine and whether the machine was shared. "
              "docs/benchmarks.md.", "swarmslam bench slam --json bench-results/slam.json"),
    "bench matcher": ("Scan matching alone, with no initial guess, on the keyframe logs: "
                      "failure rate, error, time per match, per optimizer.",
                      "swarmslam bench matcher --optimizers abc --json bench-results/matcher.json"),
    "bench slam": ("The SLAM on the raw Intel, ACES3, fr-clinic, MIT-CSAIL and FR079 logs, scored by "
                   "their relations, mean and worst over seeds, beside published systems.",
                   "swarmslam bench slam --optimizers abc --modes odometry --json "
                   "bench-results/slam.json"),
    "bench generalization": ("SLAM on seeded simulated surveys, scored against the truth "
                             "(error, ATE, loop precision and recall, the perfect-matching "
                             "floor).", "swarmslam bench generalization --json "
                             "bench-results/generalization.json"),
    "bench localize": ("Global relocalization with no prior in maps of Intel, ACES3 and "
                       "fr-clinic: one scan, confirmed, and tracking.",
                       "swarmslam bench localize --json bench-results/localize.json"),
    "bench posegraph": ("Gauss–Newton on the g2o benchmark graphs, against g2o's χ² and time.",
                        "swarmslam bench posegraph --json bench-results/posegraph.json"),
    "bench env": ("SwarmSlam-v0 steps per second with and without SLAM, and the LiDAR caster's "
                  "speed.", "swarmslam bench env --json bench-results/env.json"),
    "bench runtime": ("The fixed-rate runtime at 10 Hz on a log: latency, deadline misses, "
                      "memory after warm-up, accuracy; --soak MIN: a long run on simulated "
                      "scans.", "swarmslam bench runtime --json bench-results/runtime.json"),
    "bench robustness": ("Every given log on seeds 0–9, and perturbed copies of it (thinned, "
                         "fewer beams, odometry drift, a start cut away) and simulated corridors: "
                         "median, worst and spread of eT, eR and the global eT; gross runs "
                         "counted.", "swarmslam bench robustness --json "
                         "bench-results/robustness.json"),
    "bench bags": ("What reading a ROS bag costs beside the replay it feeds, per format, and "
                   "whether the MCAP bag replays as the CARMEN log.",
                   "swarmslam bench bags --json bench-results/bags.json"),
    "bench report": ("Write docs/results.md and the README's results block from "
                     "bench-results/*.json (--check: only say whether they differ).",
                     "swarmslam bench report"),
    "bench sweep": ("A sweep spec run serially and on a local Ray: wall times, and whether "
                    "every run's figures agree.",
                    "swarmslam bench sweep bench-results/sweep-intel-aces.toml --workers 2"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    bench = sub.add_parser("bench", help="benchmarks (JSON + table)")
    bsub = bench.add_subparsers(dest="benchmark", required=True)
    m = bsub.add_parser("matcher", help="scan matching on keyframe logs, no initial guess")
    m.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    m.add_argument("--optimizers", default="abc,pso,fa")
    m.add_argument("--datasets", default="intel,aces")
    m.add_argument("--limit", type=at_least_one, help="match only the first N pairs per dataset")
    m.add_argument("--no-paper", action="store_true", help="skip the paper-form variants")
    m.add_argument("--seed", type=int, default=0)
    bench_outputs(m)
    m.set_defaults(func=_bench_matcher)
    s = bsub.add_parser("slam", help="SLAM on the raw Intel/ACES3/fr-clinic/MIT-CSAIL/FR079 logs, scored by "
                                     "relations over seeds")
    s.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    s.add_argument("--optimizers", default="abc,pso,fa")
    s.add_argument("--datasets", default="intel,aces,clinic,mit,fr079")
    s.add_argument("--seeds", default="0,1,2,3,4", help="seeds per run (mean and worst reported)")
    s.add_argument("--modes", default="both", choices=["both", "odometry", "scans"])
    s.add_argument("--limit", type=at_least_one, help="only the first N scans of each log")
    s.add_argument("--out", help="keep each run's map, trajectory and graph here")
    bench_outputs(s)
    config_options(s, DEFAULT_PRESET)
    s.set_defaults(func=_bench_slam)
    ge = bsub.add_parser("generalization", help="SLAM on seeded simulated surveys, scored "
                                                 "against the true poses")
    ge.add_argument("--cases", help="comma-separated names or parts of names (default: all); "
                                    "a full name with any seed makes that case "
                                    "(corridor-sick-0.5-10hz-noisy-s13)")
    ge.add_argument("--no-floor", action="store_true",
                    help="skip the perfect-scan-matching floor (halves the time)")
    ge.add_argument("--keep", metavar="DIR", help="keep the generated logs here")
    bench_outputs(ge)
    config_options(ge, DEFAULT_PRESET)
    ge.set_defaults(func=_bench_generalization)
    lo = bsub.add_parser("localize", help="global relocalization in maps of Intel/ACES3/"
                                          "fr-clinic, single scans and confirmed")
    lo.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    lo.add_argument("--datasets", default="intel,aces,clinic")
    lo.add_argument("--queries", type=at_least_one, default=200, help="scans relocalized per log")
    lo.add_argument("--seed", type=int, default=0, help="seeds which scans are drawn")
    lo.add_argument("--maps", metavar="DIR", help="where the mapping runs are kept and reused "
                                                  "while the defaults and the code are the same "
                                                  "(default: ./swarmslam-maps)")
    bench_outputs(lo)
    lo.set_defaults(func=_bench_localize)
    pg = bsub.add_parser("posegraph", help="Gauss-Newton on the g2o benchmark graphs")
    pg.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    pg.add_argument("--repeats", type=at_least_one, default=5)
    bench_outputs(pg)
    pg.set_defaults(func=_bench_posegraph)
    env = bsub.add_parser("env", help="SwarmSlam-v0 steps/s with SLAM off and on, LiDAR scans/s")
    env.add_argument("--world", default="office")
    env.add_argument("--steps", type=at_least_one, default=5000, help="steps timed without SLAM")
    env.add_argument("--slam-steps", type=at_least_one, default=1000, help="steps timed with SLAM")
    env.add_argument("--repeats", type=at_least_one, default=3,
                     help="runs of each single-env rate (the median is reported)")
    bench_outputs(env)
    env.set_defaults(func=_bench_env)
    rt = bsub.add_parser("runtime", help="the fixed-rate runtime on Intel: latency, misses, "
                                          "memory, accuracy; or --soak on simulated scans")
    rt.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    rt.add_argument("--log", default="intel", choices=("intel", "aces", "fr-clinic"),
                    help="the radish log replayed (default: intel)")
    rt.add_argument("--seed", type=whole, default=0, help="the max-speed pass's seed")
    rt.add_argument("--optimizer", default="abc", choices=OPTIMIZERS)
    rt.add_argument("--realtime-minutes", type=non_negative, default=2.0,
                    help="minutes of the log replayed at its recorded rate (0: skip; 45: all)")
    rt.add_argument("--traced-ticks", type=at_least_one, default=6000,
                    help="ticks measured under tracemalloc after warm-up")
    rt.add_argument("--limit", type=at_least_one, help="only the first N scans")
    rt.add_argument("--view-scans", type=whole, default=4000,
                    help="scans ticked with and without a recording view attached (0: skip)")
    rt.add_argument("--soak", type=positive, metavar="MINUTES",
                    help="instead: run this long on simulated scans, sampling memory")
    bench_outputs(rt)
    config_options(rt, DEFAULT_PRESET)
    rt.set_defaults(func=_bench_runtime)
    ro = bsub.add_parser("robustness", help="every given log on seeds 0–9 and perturbed: "
                                             "median, worst and spread; gross runs counted")
    ro.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    ro.add_argument("--datasets", default="intel,aces,clinic,mit,fr079,corridor",
                    help="logs (and 'corridor': simulated corridor surveys, a floor per seed)")
    ro.add_argument("--families", default="all",
                    help="perturbations of the given logs: raw, every-2nd, every-3rd, "
                         "half-beams, odometry-drift, start-cut (default: all; "
                         "docs/benchmarks.md)")
    ro.add_argument("--seeds", default="0-9", help="seeds: 0-9, or a list 0,3,7")
    ro.add_argument("--jobs", type=at_least_one, help="replays at a time (default: one a core)")
    ro.add_argument("--keep", metavar="DIR", help="keep each run's map, trajectory and graph here "
                                                  "(LOG-FAMILY-sSEED), to look at every seed's map")
    bench_outputs(ro)
    ro.set_defaults(func=_bench_robustness)
    bg = bsub.add_parser("bags", help="the cost of reading a ROS bag (ROS 1, sqlite3, MCAP) "
                                      "beside the replay it feeds; MCAP vs CARMEN trajectory")
    bg.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    bg.add_argument("--datasets", default="intel", help="logs converted and replayed")
    bg.add_argument("--repeats", type=at_least_one, default=3, help="reads timed per bag")
    bg.add_argument("--json", help="write results here (atomically)")  # (it draws nothing)
    bg.set_defaults(func=_bench_bags)
    br = bsub.add_parser("report", help="write docs/results.md and the README's results block "
                                         "from bench-results/*.json")
    br.add_argument("--results", default="bench-results", help="the benchmarks' JSON folder")
    br.add_argument("--page", default="docs/results.md", help="the results page written")
    br.add_argument("--readme", default="README.md", help="the README whose block is rewritten")
    br.add_argument("--check", action="store_true",
                    help="write nothing; exit 1 when either differs from what the JSON gives")
    br.set_defaults(func=_bench_report)
    bs = bsub.add_parser("sweep", help="a sweep spec run serially and on a local Ray: wall "
                                       "times and the runs' figures compared")
    bs.add_argument("spec", help="the sweep's TOML spec (its results file is not touched)")
    bs.add_argument("--workers", type=at_least_one, default=2, help="CPUs of the local Ray")
    bs.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    bench_outputs(bs)
    bs.set_defaults(func=_bench_sweep)


def _bench_matcher(args) -> int:
    from swarmslam.bench.matcher import DATASETS, bench_matcher
    from swarmslam.datasets import find_datasets

    data = find_datasets(args.data)
    optimizers = tuple(o.strip() for o in args.optimizers.split(",") if o.strip())
    datasets = tuple(d.strip() for d in args.datasets.split(",") if d.strip())
    for d in datasets:
        if d not in DATASETS:
            raise SystemExit(f"unknown dataset {d!r}; choose from {', '.join(DATASETS)}")
    bench_matcher(data, optimizers, datasets, paper=not args.no_paper, limit=args.limit,
                  seed=args.seed, json_path=args.json, plots=args.plots)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _bench_posegraph(args) -> int:
    from swarmslam.bench.posegraph import bench_posegraph
    from swarmslam.datasets import find_datasets

    bench_posegraph(find_datasets(args.data), args.repeats, args.json, plots=args.plots)
    return 0


def _logs(args) -> tuple[str, ...]:
    """The ``--datasets`` names, each one ``bench slam`` knows."""
    from swarmslam.bench.slam import LOGS

    logs = tuple(d.strip() for d in args.datasets.split(",") if d.strip())
    for d in logs:
        if d not in LOGS:
            raise SystemExit(f"unknown dataset {d!r}; choose from {', '.join(LOGS)}")
    return logs


def _bench_slam(args) -> int:
    from swarmslam.bench.slam import bench_slam
    from swarmslam.datasets import find_datasets

    logs = _logs(args)
    modes = {"both": (True, False), "odometry": (True,), "scans": (False,)}[args.modes]
    optimizers = tuple(o.strip() for o in args.optimizers.split(",") if o.strip())
    seeds = tuple(int(v) for v in args.seeds.split(",") if v.strip())
    bench_slam(find_datasets(args.data), optimizers, logs, modes, args.limit, args.out, args.json,
               config=run_config(args, DEFAULT_PRESET), seeds=seeds, plots=args.plots)
    return 0


def _seeds(text: str) -> tuple[int, ...]:
    """``0-9`` or ``0,3,7``."""
    first, dash, last = text.partition("-")
    if dash:
        return tuple(range(int(first), int(last) + 1))
    return tuple(int(v) for v in text.split(",") if v.strip())


def _bench_robustness(args) -> int:
    from swarmslam.bench.robustness import FAMILIES, SIMULATED, bench_robustness
    from swarmslam.bench.slam import LOGS
    from swarmslam.datasets import find_datasets

    logs = tuple(d.strip() for d in args.datasets.split(",") if d.strip())
    for d in logs:
        if d not in LOGS and d != SIMULATED:
            raise SystemExit(f"unknown dataset {d!r}; choose from {', '.join(LOGS)}, {SIMULATED}")
    families = FAMILIES if args.families == "all" else tuple(
        f.strip() for f in args.families.split(",") if f.strip())
    for f in families:
        if f not in FAMILIES:
            raise SystemExit(f"unknown family {f!r}; choose from {', '.join(FAMILIES)}")
    data = find_datasets(args.data) if any(d != SIMULATED for d in logs) else None
    bench_robustness(data, logs, families, _seeds(args.seeds), args.jobs, args.json,
                     args.plots, args.keep)
    return 0


def _bench_bags(args) -> int:
    from swarmslam.bench.bags import bench_bags, dataset_logs
    from swarmslam.datasets import find_datasets

    bench_bags(dataset_logs(find_datasets(args.data), _logs(args)), args.repeats, args.json)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _bench_report(args) -> int:
    from swarmslam.bench.report import bench_report

    return bench_report(args.results, args.page, args.readme, check=args.check)


def _bench_localize(args) -> int:
    from swarmslam.bench.localize import bench_localize
    from swarmslam.datasets import find_datasets

    logs = _logs(args)
    if args.queries < 1:
        raise SystemExit(f"--queries must be at least 1, got {args.queries}")
    bench_localize(find_datasets(args.data), logs, args.queries, args.seed, args.maps, args.json,
                   plots=args.plots)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _bench_generalization(args) -> int:
    from swarmslam.bench.generalization import bench_generalization, select

    cases = select([n.strip() for n in (args.cases or "").split(",") if n.strip()])
    bench_generalization(cases, args.json, args.keep, run_config(args, DEFAULT_PRESET),
                         floor=not args.no_floor, plots=args.plots)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _bench_env(args) -> int:
    from swarmslam.bench.env import bench_env

    bench_env(args.world, args.steps, args.slam_steps, args.json, plots=args.plots,
              repeats=args.repeats)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _bench_runtime(args) -> int:
    from swarmslam.bench.runtime import bench_runtime, bench_soak
    from swarmslam.datasets import find_datasets

    if args.soak is not None:
        bench_soak(args.soak, args.json, plots=args.plots)
    else:
        bench_runtime(find_datasets(args.data), args.optimizer, args.realtime_minutes,
                      args.traced_ticks, args.limit, args.json,
                      config=run_config(args, DEFAULT_PRESET), plots=args.plots,
                      view_scans=args.view_scans, log=args.log, seed=args.seed)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _bench_sweep(args) -> int:
    from swarmslam.bench.sweep import bench_sweep
    from swarmslam.sweep import read_spec

    bench_sweep(read_spec(args.spec, args.data), args.workers, args.json)
    return 0


