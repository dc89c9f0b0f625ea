"""``swarmslam``: the command-line entry point. It parses arguments and calls the packages,
which hold the logic; :data:`HELP` is what ``--help`` tells a user of each command."""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import textwrap
import time
from pathlib import Path

from swarmslam.runtime.config import (
    DEFAULT_PRESET,
    OPTIMIZERS,
    PRESETS,
    SlamConfig,
    field_names,
    load_config,
    preset,
    session_changes,
    shown,
    to_toml,
)
from swarmslam.runtime.realtime.inbox import skipped_text
from swarmslam.runtime.realtime.writers import write_bytes_atomic
from swarmslam.view.run_view import RunWatch


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
               config=_config(args, DEFAULT_PRESET), seeds=seeds, plots=args.plots)
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
    bench_generalization(cases, args.json, args.keep, _config(args, DEFAULT_PRESET),
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
                      config=_config(args, DEFAULT_PRESET), plots=args.plots,
                      view_scans=args.view_scans, log=args.log, seed=args.seed)
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _config(args, default_preset: str) -> SlamConfig | None:
    """``--config FILE`` over ``--preset`` (default: ``default_preset``); None when neither
    is given, so the command builds its own default."""
    if not (args.preset or args.config):
        return None
    base = preset(args.preset or default_preset)
    return load_config(args.config, base) if args.config else base


def _session_changes(args) -> dict | None:
    """With ``--localize``/``--resume``: the changes ``--config FILE`` makes to the session's
    own configuration (only its search and tracking: :data:`swarmslam.runtime.config.SESSION_SECTIONS`).
    None without a session."""
    if not (args.localize or args.resume):
        return None
    if args.preset:
        raise ValueError("--localize and --resume take the configuration saved in the session; "
                         "drop --preset (--config may change its [localization] and "
                         "[relocalization])")
    return session_changes(args.config) if args.config else {}


def _config_show(args) -> int:
    config = preset(args.preset or DEFAULT_PRESET)
    if args.config:
        config = load_config(args.config, config)
    level = "basic" if args.basic else "all" if args.all else "standard"
    text = to_toml(config, comments=not args.bare, level=level)
    if level != "all" and not args.bare:
        hidden = sum(not shown(key, level) for key in field_names(config))
        which = "all but the basic ones" if args.basic else "the stages' internals"
        text += f"\n# {hidden} more fields ({which}): swarmslam config show --all\n"
    sys.stdout.write(text)
    return 0


# A run's status starting so says its input could not be used: the command exits 1.
UNUSABLE = ("no usable scan", "mostly unusable input")


def _replay(args) -> int:
    from swarmslam.replay import replay

    changes = _session_changes(args)
    m = replay(args.log, args.relations, args.optimizer, not args.no_odometry, args.out,
               args.limit, args.seed,
               config=None if changes is not None else _config(args, DEFAULT_PRESET),
               localize=args.localize, resume=args.resume, start=args.start,
               watch=RunWatch.from_args(args), session_changes=changes, bag=_bag(args))
    if args.localize:
        r = m["runtime"]
        print(f"{m['scans']} scans localized in {args.localize}: {m['scans_with_pose']} with a "
              f"pose, {r['committed']} commits, {r['lost']} lost; latency "
              f"{m['latency_ms_median']:.1f} ms median / {m['latency_ms_p99']:.1f} ms p99")
    else:
        print(f"{m['scans']} scans, {m['nodes']} nodes, {m['loops_accepted']} loops closed, "
              f"{m['real_time_factor']:.1f}x real time, latency {m['latency_ms_median']:.1f} ms "
              f"median / {m['latency_ms_p99']:.1f} ms p99")
    seen = m.get("odometry_seen", {})
    if "translation_scale" in seen:
        print(f"odometry: the scans put the robot {seen['translation_scale']:.3f} times as far "
              "as odometry read (metrics.json: odometry_seen)")
    if "eT" in m:
        print(f"relations: eT {m['eT']:.4f} ± {m['eT_std']:.4f} m, "
              f"eR {m['eR_deg']:.3f} ± {m['eR_std']:.3f} deg ({m['relations_used']} used)")
    if m.get("records_skipped"):
        print("skipped " + ", ".join(f"{n} records with a bad {field}"
                                     for field, n in m["records_skipped"].items())
              + " (counted in the report)")
    if skipped_text(m["runtime"]):
        print(skipped_text(m["runtime"]) + " (counted in the report)")
    if args.localize:
        if args.out:
            print(f"wrote {args.out}/trajectory.tum, localization.json (the session is unchanged)")
        if m["status"] != "ok":
            print(f"status: {m['status']}")
        return 1 if m["status"].startswith(UNUSABLE) else 0
    if args.out:
        print(f"wrote {args.out}/map.pgm, map.yaml, map.png, trajectory.tum, graph.g2o, metrics.json")
    if m["status"] != "ok":
        print(f"status: {m['status']}")
    return 1 if m["status"].startswith(UNUSABLE) else 0


def _convert(args) -> int:
    from swarmslam.convert import convert

    written = convert(args.input, args.output, args.format, _bag(args),
                      warn=lambda text: print(text, file=sys.stderr))
    print(f"wrote {written['output']} ({written['format']}): {written['scans']} scans, "
          f"{written['odometry']} odometry readings")
    return 0


def _sweep(args) -> int:
    from swarmslam.sweep import format_summary, read_spec, summarise, sweep, write_summary

    spec = read_spec(args.spec, args.data)
    if args.results:
        spec.results = Path(args.results).resolve()
    records = sweep(spec, args.address, args.workers, args.serial)
    print(format_summary(summarise(records)))
    print(f"results in {spec.results}; summary in {write_summary(spec, records)}")
    return 0


def _tune(args) -> int:
    from swarmslam.tune import read_tune_spec, tune_config

    spec = read_tune_spec(args.spec, args.data)
    if args.out:
        spec.out = Path(args.out).resolve()
    if args.trials:
        spec.trials = args.trials
    tune_config(spec, args.address, args.workers)
    return 0


def _rllib(args) -> int:
    from swarmslam.train_rllib import train_ppo

    env_config = {"slam": args.slam, "world": args.world,
                  "max_episode_steps": args.episode_steps}
    result = train_ppo(args.iterations, args.env_runners, env_config, args.seed,
                       Path(args.checkpoint) if args.checkpoint else None, args.address)
    if result["checkpoint"]:
        print(f"checkpoint in {result['checkpoint']}")
    return 0


def _bench_sweep(args) -> int:
    from swarmslam.bench.sweep import bench_sweep
    from swarmslam.sweep import read_spec

    bench_sweep(read_spec(args.spec, args.data), args.workers, args.json)
    return 0


def _config_fields(args) -> int:
    from swarmslam.config_doc import fields_markdown

    sys.stdout.write(fields_markdown())
    return 0


def _relations_audit(args) -> int:
    from swarmslam.evaluation.relations_audit import audit_command

    if not 0 < args.min_gain <= 1:
        raise ValueError(f"--min-gain must be in (0, 1], got {args.min_gain}")
    audit_command(args.log, args.relations, args.trajectory, args.json, args.min_gain,
                  args.plots)
    return 0


def _simlog(args) -> int:
    from dataclasses import replace

    from swarmslam.simlog import write_simlog
    from swarmslam_sim.survey import EFFECT_HELP, EFFECTS

    if args.seconds is not None and not args.seconds > 0:
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
    if not args.rate > 0:
        raise ValueError(f"--rate must be > 0, got {args.rate}")
    given = {name: getattr(args, name) for name in EFFECT_HELP if getattr(args, name) is not None}
    if "sweep_seconds" in given:  # a sweep named is the sweep, a spinning scanner's too
        given["sweep_turn"] = False
    effects = replace(EFFECTS[args.effects], **given)
    r = write_simlog(args.out, args.site, args.seed, args.scanner, args.rate, args.odometry,
                     args.format, seconds=args.seconds, effects=effects,
                     max_turn=args.max_turn, turning=args.effects)
    print(f"{r['scans']} scans over {r['seconds']:.0f} s and {r['metres']:.0f} m; odometry "
          f"{r['odometry_error_end_m']:.2f} m / {r['odometry_error_end_deg']:.1f} deg off at "
          f"the end; {r['relations_count']} relations")
    print(f"wrote {r['log']}, {r['relations']}, {r['truth']}, {r['world']}")
    if r["sweep_seconds"] > 0:
        print(f"its scanner sweeps for {r['sweep_seconds']:.4g} s: a replay told so undoes "
              f"the turn over it (sensor.sweep_seconds = {r['sweep_seconds']:.17g} under "
              "[sensor] in a --config file)")
    return 0


@contextlib.contextmanager
def _sigterm_as_ctrl_c():
    """SIGTERM (how systemd, docker and kill stop a service) stops a live run as Ctrl-C does:
    the run ends and its outputs are written. The previous handler is back afterwards."""
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _lidar(args) -> int:
    from swarmslam.live import run_live

    with _sigterm_as_ctrl_c():
        changes = _session_changes(args)
        summary = run_live(
            args.port, args.model, args.mode, args.out, args.rate, args.seconds, args.resume,
            config=None if changes is not None else _config(args, f"rplidar-{args.model}"),
            localize=args.localize, watch=RunWatch.from_args(args), baud=args.baud,
            session_changes=changes, bag=args.bag)
    return 1 if summary["status"].startswith("no scans") else 0


def _emulate(args) -> int:
    from swarmslam.hardware.emulator import Faults, VirtualRPLidar

    if args.log:
        from swarmslam.emulator_sources import CarmenSource

        source, what = CarmenSource(args.log), f"log {args.log}"
    else:
        from swarmslam.emulator_sources import WorldSource

        source, what = WorldSource(args.world, seed=args.seed), f"world {args.world}"
    faults = Faults.parse(args.faults or "")
    emulator = VirtualRPLidar(source, args.model, faults, args.seed, args.link,
                              typical=args.typical)
    emulator.record = bool(args.record)
    with _sigterm_as_ctrl_c():
        path = emulator.start()
        print(f"virtual RPLidar {args.model.upper()} ({what}) on {path}")
        print(f"connect with: swarmslam lidar --port {path} --model {args.model}")
        if faults != Faults():
            print(f"faults: {faults}")
        print("Ctrl-C to stop", flush=True)
        try:
            while True:
                time.sleep(1.0)
        finally:
            emulator.stop()
            if args.record:
                write_bytes_atomic(args.record, bytes(emulator.sent))
            print(f"emulator: {emulator.stats}")


def _demo(args) -> int:
    if args.matcher_only:
        from swarmslam.matcher_demo import run_demo

        run_demo(out_dir=Path(args.out), optimizer=args.optimizer or "abc", seed=args.seed,
                 steps=args.steps or 120)
        return 0
    from swarmslam.demo import run_exploration_demo

    run_exploration_demo(Path(args.out), world=args.world, optimizer=args.optimizer,
                         seed=args.seed, max_steps=args.steps or 1500,
                         config=_config(args, "sim-rplidar-a1"), watch=RunWatch.from_args(args))
    return 0


def _config_options(parser, default: str, sessions: bool = False) -> None:
    also = (" (with --localize/--resume: only the session's [localization] and "
            "[relocalization])" if sessions else "")
    parser.add_argument("--config", metavar="FILE",
                        help="TOML file changing fields of the configuration "
                             f"(see: swarmslam config show){also}")
    parser.add_argument("--preset", choices=list(PRESETS), help=f"configuration preset "
                        f"(default: {default})")


def _bench_outputs(parser) -> None:
    parser.add_argument("--json", help="write results here (atomically)")
    parser.add_argument("--plots", metavar="DIR",
                        help="write the figures (PNG) here (extra 'plots')")


def _bag_options(parser) -> None:
    """Which topics and frames of a ROS bag to read."""
    parser.add_argument("--scan-topic", help="a bag's LaserScan topic (default: the only one)")
    parser.add_argument("--odom-topic", help="a bag's Odometry topic (default: the only one; "
                                             "none: tf)")
    parser.add_argument("--odom-frame", default="odom", help="odometry's frame in tf")
    parser.add_argument("--base-frame", default="base_link", help="the robot's frame in tf")


def _bag(args):
    from swarmslam.formats.logs import BagOptions

    return BagOptions(args.scan_topic, args.odom_topic, args.odom_frame, args.base_frame)


def _view_options(parser) -> None:
    parser.add_argument("--view", action="store_true",
                        help="watch it live in rerun (extra 'view'; without a display it serves "
                             "the web viewer and prints the address)")
    parser.add_argument("--record", metavar="FILE.rrd", help="save the rerun stream to open later")
    parser.add_argument("--mcap", metavar="FILE", help="an MCAP recording Foxglove opens "
                                                       "(scans, poses, frames, the map)")


DESCRIPTION = """SwarmSLAM: 2-D LiDAR graph SLAM whose scan matching is done by swarm optimizers
(particle swarm, artificial bee colony, firefly). Run it over a simulated robot (demo), a
recorded log or ROS bag (replay), or a live RPLidar (lidar); benchmark it on the public logs
(bench). Each command has its own --help."""

D = "../shared/datasets/radish"
# (what the command does, reads and writes; an example) per command, shown by its --help
HELP = {
    "config": ("The SLAM's configuration: one tree of validated fields, in presets per "
               "scanner. See docs/configuration.md.", "swarmslam config show --basic"),
    "config show": ("Print the effective configuration as TOML, each field with its meaning "
                    "(--basic: the fields a user sets; --all: with each stage's internals). "
                    "The output is a valid --config file.",
                    "swarmslam config show rplidar-a2 > mine.toml"),
    "config fields": ("Print every field as the Markdown tables of docs/configuration.md.",
                      "swarmslam config fields > fields.md"),
    "lidar": ("Live SLAM from a Slamtec RPLidar on a serial port at a fixed rate. Prints the "
              "scanner's info and a status line each second; on Ctrl-C or SIGTERM writes the "
              "map (PGM + YAML, PNG), trajectory (TUM), graph (g2o), session.npz and "
              "summary.json to --out. Wiring and udev: hardware/README.md.",
              "swarmslam lidar --port /dev/rplidar --model a2 --out my-run"),
    "emulate": ("A virtual RPLidar on a pseudo-terminal, answering the protocol and streaming "
                "scans of a simulated world (a robot exploring it) or a CARMEN log, with "
                "optional faults. Point `swarmslam lidar --port` at the link it prints.",
                "swarmslam emulate --world office --link /tmp/rplidar  # then: swarmslam "
                "lidar --port /tmp/rplidar"),
    "demo": ("A simulated robot with a 360° LiDAR explores a world on its own while the SLAM "
             "tracks it, until 90% is mapped. Prints coverage, collisions and the pose error "
             "against the truth; writes the map, both trajectories (TUM), trajectory.png and "
             "summary.json to --out (default swarmslam-demo/).",
             "swarmslam demo --world maze --seed 3"),
    "replay": ("Run the SLAM over a CARMEN log (plain or .gz, a pipe, - for stdin) or a ROS bag "
               "(.bag, .mcap, a ROS 2 bag folder; extra 'bags'), as fast as it goes. With "
               "--relations, scores it (Kümmerle eT, eR). Writes map.pgm/.yaml/.png, "
               "trajectory.tum, graph.g2o, session.npz and metrics.json to --out. Exit 1 when "
               "the input was unusable.",
               f"swarmslam replay {D}/intel.clf.gz --relations {D}/intel.relations --out "
               "out/intel"),
    "convert": ("Convert a log: CARMEN ⇄ ROS 1 bag, ROS 2 bag (sqlite3 or MCAP). The format "
                "comes from OUTPUT's name (X.bag ROS 1, X.mcap MCAP, X.clf / X.gz CARMEN, "
                "anything else a ROS 2 sqlite3 bag folder) or --format. docs/formats.md §9.",
                f"swarmslam convert {D}/intel.clf.gz intel.mcap"),
    "simlog": ("A CARMEN log, its Kümmerle relations, the true trajectory (TUM) and the world "
               "from a scripted survey of a generated floor, with a chosen scanner, rate, "
               "odometry and real-robot effects: logs with ground truth. docs/simulator.md.",
               "swarmslam simlog out/b.clf.gz --site building --scanner sick-0.5 --rate 10 "
               "--effects robot"),
    "relations": ("Kümmerle relations files: check them against a log.",
                  f"swarmslam relations audit {D}/intel.clf.gz {D}/intel.relations"),
    "relations audit": ("Check each relation against the log's own scans (ICP between its two "
                        "scans) and, with --trajectory, list the worst relations of a run with "
                        "the turn rate and odometry's own error there. docs/method.md §7.1.",
                        f"swarmslam relations audit {D}/mit-csail.clf.gz "
                        f"{D}/mit-csail.relations --trajectory out/mit/trajectory.tum"),
    "sweep": ("Replays over logs × optimizers × seeds × configuration variants as Ray tasks "
              "(extra 'scale'), each finished run appended to a results file at once; a sweep "
              "started again runs only what it lacks. docs/sweeps.md.",
              "swarmslam sweep bench-results/sweep-intel-aces.toml --workers 2"),
    "tune": ("Search configuration fields with Ray Tune and Optuna (extra 'scale'); the "
             "objective is the worst ratio of a log's eT to its reference. Writes the best "
             "configuration as TOML. docs/sweeps.md §3.", "swarmslam tune my-tuning.toml "
             "--trials 24"),
    "rllib": ("Train RLlib's PPO on SwarmSlam-v0 with env runners on Ray (extra 'rllib'). "
              "docs/sweeps.md §4.", "swarmslam rllib --env-runners 4 --iterations 20 --slam"),
    "bench": ("Benchmarks: each prints a table and, with --json, writes its figures with the "
              "commit, date, command, machine and whether the machine was shared. "
              "docs/benchmarks.md.", "swarmslam bench slam --json bench-results/slam.json"),
    "bench matcher": ("Scan matching alone, with no initial guess, on the keyframe logs: "
                      "failure rate, error, time per match, per optimizer.",
                      "swarmslam bench matcher --optimizers abc --json bench-results/matcher.json"),
    "bench slam": ("The SLAM on the raw Intel, ACES3, fr-clinic and MIT-CSAIL logs, scored by "
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


def _describe(parser, prefix=()) -> None:
    """Each command's --help: what it does, reads and writes, and an example."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                key = " ".join((*prefix, name))
                description, example = HELP[key]
                sub.description = textwrap.fill(description, 79)
                sub.epilog = f"example:\n  {example}"
                sub.formatter_class = argparse.RawDescriptionHelpFormatter
                _describe(sub, (*prefix, name))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="swarmslam", description=DESCRIPTION,
                                epilog="example:\n  swarmslam demo",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)

    cf = sub.add_parser("config", help="the SLAM's configuration")
    csub = cf.add_subparsers(dest="action", required=True)
    show = csub.add_parser("show", help="print the effective configuration as TOML "
                                        "(--basic, --all)")
    show.add_argument("preset", nargs="?", choices=list(PRESETS),
                      help=f"a preset (default: {DEFAULT_PRESET})")
    show.add_argument("--config", metavar="FILE", help="with this TOML file's changes")
    show.add_argument("--bare", action="store_true", help="without the comments")
    levels = show.add_mutually_exclusive_group()
    levels.add_argument("--basic", action="store_true",
                        help="only the fields a user is expected to set")
    levels.add_argument("--all", action="store_true",
                        help="every field, the stages' internals too")
    show.set_defaults(func=_config_show)
    csub.add_parser("fields", help="every field as the Markdown tables of "
                                   "docs/configuration.md").set_defaults(func=_config_fields)

    models = ["a1", "a2", "a3", "s1", "s2", "c1"]
    li = sub.add_parser("lidar", help="live SLAM from an RPLidar (or the emulator) at a fixed rate")
    li.add_argument("--port", required=True, help="serial port, e.g. /dev/rplidar or /dev/ttyUSB0")
    li.add_argument("--model", default="a1", choices=models)
    li.add_argument("--bag", metavar="FILE",
                    help="record every scan to a ROS bag (X.bag: ROS 1, X.mcap: MCAP, any other "
                         "name: a ROS 2 sqlite3 bag folder; extra 'bags')")
    li.add_argument("--baud", type=_at_least_one,
                    help="switch the link to this rate after connecting, where the model "
                         "allows (the A2: 256000)")
    li.add_argument("--mode", default="typical",
                    help="scan mode: 'typical' (the scanner's recommended mode, as Slamtec's "
                         "SDK starts; express on old firmware), 'standard', 'express', or a "
                         "mode name the scanner lists (Boost, Sensitivity, DenseBoost, ...)")
    li.add_argument("--out", default="swarmslam-live", help="output folder (written on Ctrl-C)")
    li.add_argument("--rate", type=_positive, help="SLAM ticks per second (default: the configuration's, 10)")
    li.add_argument("--seconds", type=_positive, help="stop after this long (default: Ctrl-C)")
    saved = li.add_mutually_exclusive_group()
    saved.add_argument("--resume", metavar="SESSION",
                       help="extend a saved session's map from wherever the scanner is in it")
    saved.add_argument("--localize", metavar="SESSION",
                       help="localize in a saved session's map (never changed), no prior")
    _config_options(li, "the model's preset", sessions=True)
    _view_options(li)
    li.set_defaults(func=_lidar)
    em = sub.add_parser("emulate", help="a virtual RPLidar on a pseudo-terminal")
    source = em.add_mutually_exclusive_group()
    source.add_argument("--world", default="office", help="simulated world it scans")
    source.add_argument("--log", help="a CARMEN log it replays instead")
    em.add_argument("--model", default="a1", choices=models)
    em.add_argument("--faults", help="e.g. garbage=0.01,corrupt=0.01,stall=10:2,vanish=30:1")
    em.add_argument("--link", help="also make this symlink point at the port (stable name)")
    em.add_argument("--seed", type=int, default=0)
    em.add_argument("--typical", metavar="MODE",
                    help="advertise this scan mode of the model as typical (to try a client)")
    em.add_argument("--record", metavar="FILE",
                    help="on stopping, write every byte the emulator sent to FILE")
    em.set_defaults(func=_emulate)

    demo = sub.add_parser("demo", help="a simulated robot explores the office world with SLAM")
    demo.add_argument("--out", default="swarmslam-demo", help="output folder")
    demo.add_argument("--world", default="office",
                      help="built-in world, generator (rooms, maze, clutter) or .world file")
    demo.add_argument("--optimizer", choices=OPTIMIZERS,
                      help="swarm method (default: the configuration's, abc)")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--steps", type=_at_least_one, help="step limit (default 1500; 120 with --matcher-only)")
    demo.add_argument("--matcher-only", action="store_true",
                      help="runtime only, no simulator: chain swarm matches around a synthetic loop")
    _config_options(demo, "the simulator's preset")
    _view_options(demo)
    demo.set_defaults(func=_demo)

    rp = sub.add_parser("replay", help="run the SLAM over a CARMEN log or a ROS bag")
    rp.add_argument("log", help="CARMEN log (.clf, .log, plain or .gz; - for standard input) "
                                "or ROS bag (.bag, a ROS 2 bag folder, .mcap, .db3)")
    rp.add_argument("--relations", help="Kümmerle relations file to score against")
    rp.add_argument("--optimizer", choices=OPTIMIZERS,
                    help="swarm method (default: the configuration's, abc)")
    rp.add_argument("--no-odometry", action="store_true", help="scans only, as in the paper")
    rp.add_argument("--out", default="swarmslam-replay", help="output folder")
    rp.add_argument("--limit", type=_at_least_one, help="only the first N scans")
    rp.add_argument("--seed", type=int, default=0)
    rp.add_argument("--start", type=_whole, default=0, help="the first scan replayed")
    saved = rp.add_mutually_exclusive_group()
    saved.add_argument("--localize", metavar="SESSION",
                       help="localize in a saved session's map (never changed): trajectory "
                            "and localization.json; found with no prior")
    saved.add_argument("--resume", metavar="SESSION",
                       help="extend a saved session's map from wherever the log starts in it "
                            "(multi-session mapping)")
    _bag_options(rp)
    _config_options(rp, DEFAULT_PRESET, sessions=True)
    _view_options(rp)
    rp.set_defaults(func=_replay)

    cv = sub.add_parser("convert", help="a log from one format to another: CARMEN ⇄ ROS 1 "
                                        "bag, ROS 2 bag (sqlite3 or MCAP)")
    cv.add_argument("input", help="CARMEN log or ROS bag")
    cv.add_argument("output", help="X.clf / X.clf.gz: CARMEN; X.bag: ROS 1; X.mcap: MCAP "
                                   "(ROS 2); any other name: a ROS 2 sqlite3 bag folder")
    cv.add_argument("--format", choices=["carmen", "ros1", "sqlite3", "mcap"],
                    help="the output's format (default: from its name)")
    _bag_options(cv)
    cv.set_defaults(func=_convert)

    from swarmslam_sim.survey import EFFECT_HELP, EFFECTS, ODOMETRY, SCANNERS, SITES

    sl = sub.add_parser("simlog", help="a CARMEN log + relations + truth from a simulated survey")
    sl.add_argument("out", help="log to write (.clf, or .clf.gz); relations, truth (TUM) and "
                                "world go beside it")
    sl.add_argument("--site", default="building", choices=SITES)
    sl.add_argument("--seed", type=int, default=0, help="seeds the floor plan and every noise")
    sl.add_argument("--scanner", default="sick-0.5", choices=list(SCANNERS))
    sl.add_argument("--rate", type=float, default=10.0, help="scans per second")
    sl.add_argument("--odometry", default="good", choices=list(ODOMETRY))
    sl.add_argument("--format", default="auto", choices=["auto", "flaser", "robotlaser1"],
                    help="laser lines (auto: FLASER for a 180° scanner, else ROBOTLASER1)")
    sl.add_argument("--seconds", type=float, help="only the route's first seconds")
    sl.add_argument("--effects", default="none", choices=list(EFFECTS),
                    help="real-robot effects (robot: stale odometry, fast turns, a moving "
                         "sweep, range bias, mixed pixels, people); the options below change "
                         "one each")
    sl.add_argument("--max-turn", type=float, help="rad/s the robot turns at most (default: "
                                                   "0.8; with --effects robot 2.0, stopping to "
                                                   "turn in place at corners)")
    for name, text in EFFECT_HELP.items():
        sl.add_argument(f"--{name.replace('_', '-')}", dest=name,
                        type=int if name == "people" else float, help=text)
    sl.set_defaults(func=_simlog)

    re_ = sub.add_parser("relations", help="relations files (Kümmerle et al.)")
    resub = re_.add_subparsers(dest="relations_command", required=True)
    au = resub.add_parser("audit", help="check each relation against the log's own scans "
                                        "and tell whose clock (the scans' or odometry's) its "
                                        "headings keep; with a trajectory, score it apart on "
                                        "the relations the scans confirm and those they "
                                        "contradict, and again on the reference's clock")
    au.add_argument("log", help="the CARMEN log the relations refer to")
    au.add_argument("relations", help="Kümmerle relations file")
    au.add_argument("--trajectory", help="a TUM trajectory of the log to score (e.g. a "
                                         "replay's trajectory.tum)")
    au.add_argument("--json", help="write the audit (and every contradicted relation) here")
    au.add_argument("--min-gain", type=float, default=0.2,
                    help="share of the second scan's points ICP (from the relation, or from "
                         "odometry's motion for a relation under 10 s) must fit in addition "
                         "for the scans to contradict it")
    au.add_argument("--plots", metavar="DIR", help="write the audit's figures (PNG) here: "
                    "fit over time and, with --trajectory, its gross short failures placed "
                    "by the relation, the trajectory and odometry (extra 'plots')")
    au.set_defaults(func=_relations_audit)

    sw = sub.add_parser("sweep", help="replays over logs × optimizers × seeds × configuration "
                                      "variants as Ray tasks, resumable (docs/sweeps.md)")
    sw.add_argument("spec", help="the sweep's TOML spec")
    sw.add_argument("--address", help="an existing Ray cluster (default: a local Ray started "
                                      "for the sweep)")
    sw.add_argument("--workers", type=_at_least_one,
                    help="CPUs of the local Ray (default: all)")
    sw.add_argument("--serial", action="store_true", help="one run after another in this "
                                                          "process, no Ray")
    sw.add_argument("--results", help="the results file (JSON lines; default: the spec's)")
    sw.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    sw.set_defaults(func=_sweep)
    tu = sub.add_parser("tune", help="Ray Tune + Optuna over configuration fields; objective: "
                                     "the worst ratio to the reference error over the logs")
    tu.add_argument("spec", help="the tuning's TOML spec (docs/sweeps.md)")
    tu.add_argument("--address", help="an existing Ray cluster (default: a local Ray)")
    tu.add_argument("--workers", type=_at_least_one, help="trials at a time (default: all CPUs)")
    tu.add_argument("--trials", type=_at_least_one, help="the budget (default: the spec's)")
    tu.add_argument("--out", help="the best configuration's TOML (default: the spec's)")
    tu.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    tu.set_defaults(func=_tune)
    rl = sub.add_parser("rllib", help="PPO on SwarmSlam-v0 with RLlib, env runners on Ray "
                                      "(extra 'rllib')")
    rl.add_argument("--iterations", type=_at_least_one, default=10)
    rl.add_argument("--env-runners", type=_at_least_one, default=2)
    rl.add_argument("--world", default="office")
    rl.add_argument("--slam", action="store_true", help="the SLAM's pose in the observation "
                                                        "(default: the true pose, faster)")
    rl.add_argument("--episode-steps", type=_at_least_one, default=500)
    rl.add_argument("--seed", type=int, default=0)
    rl.add_argument("--checkpoint", metavar="DIR", help="save the trained algorithm here")
    rl.add_argument("--address", help="an existing Ray cluster (default: a local Ray)")
    rl.set_defaults(func=_rllib)

    bench = sub.add_parser("bench", help="benchmarks (JSON + table)")
    bsub = bench.add_subparsers(dest="benchmark", required=True)
    m = bsub.add_parser("matcher", help="scan matching on keyframe logs, no initial guess")
    m.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    m.add_argument("--optimizers", default="abc,pso,fa")
    m.add_argument("--datasets", default="intel,aces")
    m.add_argument("--limit", type=_at_least_one, help="match only the first N pairs per dataset")
    m.add_argument("--no-paper", action="store_true", help="skip the paper-form variants")
    m.add_argument("--seed", type=int, default=0)
    _bench_outputs(m)
    m.set_defaults(func=_bench_matcher)
    s = bsub.add_parser("slam", help="SLAM on the raw Intel/ACES3/fr-clinic/MIT-CSAIL logs, scored by "
                                     "relations over seeds")
    s.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    s.add_argument("--optimizers", default="abc,pso,fa")
    s.add_argument("--datasets", default="intel,aces,clinic,mit")
    s.add_argument("--seeds", default="0,1,2", help="seeds per run (mean and worst reported)")
    s.add_argument("--modes", default="both", choices=["both", "odometry", "scans"])
    s.add_argument("--limit", type=_at_least_one, help="only the first N scans of each log")
    s.add_argument("--out", help="keep each run's map, trajectory and graph here")
    _bench_outputs(s)
    _config_options(s, DEFAULT_PRESET)
    s.set_defaults(func=_bench_slam)
    ge = bsub.add_parser("generalization", help="SLAM on seeded simulated surveys, scored "
                                                 "against the true poses")
    ge.add_argument("--cases", help="comma-separated names or parts of names (default: all); "
                                    "a full name with any seed makes that case "
                                    "(corridor-sick-0.5-10hz-noisy-s13)")
    ge.add_argument("--no-floor", action="store_true",
                    help="skip the perfect-scan-matching floor (halves the time)")
    ge.add_argument("--keep", metavar="DIR", help="keep the generated logs here")
    _bench_outputs(ge)
    _config_options(ge, DEFAULT_PRESET)
    ge.set_defaults(func=_bench_generalization)
    lo = bsub.add_parser("localize", help="global relocalization in maps of Intel/ACES3/"
                                          "fr-clinic, single scans and confirmed")
    lo.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    lo.add_argument("--datasets", default="intel,aces,clinic")
    lo.add_argument("--queries", type=_at_least_one, default=200, help="scans relocalized per log")
    lo.add_argument("--seed", type=int, default=0, help="seeds which scans are drawn")
    lo.add_argument("--maps", metavar="DIR", help="where the mapping runs are kept and reused "
                                                  "while the defaults and the code are the same "
                                                  "(default: ./swarmslam-maps)")
    _bench_outputs(lo)
    lo.set_defaults(func=_bench_localize)
    pg = bsub.add_parser("posegraph", help="Gauss-Newton on the g2o benchmark graphs")
    pg.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    pg.add_argument("--repeats", type=_at_least_one, default=5)
    _bench_outputs(pg)
    pg.set_defaults(func=_bench_posegraph)
    env = bsub.add_parser("env", help="SwarmSlam-v0 steps/s with SLAM off and on, LiDAR scans/s")
    env.add_argument("--world", default="office")
    env.add_argument("--steps", type=_at_least_one, default=5000, help="steps timed without SLAM")
    env.add_argument("--slam-steps", type=_at_least_one, default=1000, help="steps timed with SLAM")
    env.add_argument("--repeats", type=_at_least_one, default=3,
                     help="runs of each single-env rate (the median is reported)")
    _bench_outputs(env)
    env.set_defaults(func=_bench_env)
    rt = bsub.add_parser("runtime", help="the fixed-rate runtime on Intel: latency, misses, "
                                          "memory, accuracy; or --soak on simulated scans")
    rt.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    rt.add_argument("--log", default="intel", choices=("intel", "aces", "fr-clinic"),
                    help="the radish log replayed (default: intel)")
    rt.add_argument("--seed", type=_whole, default=0, help="the max-speed pass's seed")
    rt.add_argument("--optimizer", default="abc", choices=OPTIMIZERS)
    rt.add_argument("--realtime-minutes", type=_non_negative, default=2.0,
                    help="minutes of the log replayed at its recorded rate (0: skip; 45: all)")
    rt.add_argument("--traced-ticks", type=_at_least_one, default=6000,
                    help="ticks measured under tracemalloc after warm-up")
    rt.add_argument("--limit", type=_at_least_one, help="only the first N scans")
    rt.add_argument("--view-scans", type=_whole, default=4000,
                    help="scans ticked with and without a recording view attached (0: skip)")
    rt.add_argument("--soak", type=_positive, metavar="MINUTES",
                    help="instead: run this long on simulated scans, sampling memory")
    _bench_outputs(rt)
    _config_options(rt, DEFAULT_PRESET)
    rt.set_defaults(func=_bench_runtime)
    bg = bsub.add_parser("bags", help="the cost of reading a ROS bag (ROS 1, sqlite3, MCAP) "
                                      "beside the replay it feeds; MCAP vs CARMEN trajectory")
    bg.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    bg.add_argument("--datasets", default="intel", help="logs converted and replayed")
    bg.add_argument("--repeats", type=_at_least_one, default=3, help="reads timed per bag")
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
    bs.add_argument("--workers", type=_at_least_one, default=2, help="CPUs of the local Ray")
    bs.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    _bench_outputs(bs)
    bs.set_defaults(func=_bench_sweep)
    _describe(p)
    return p


def _whole_number(text: str, least: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"must be at least {least}, got {value}")
    return value


def _at_least_one(text: str) -> int:
    """A count argument: a whole number ≥ 1 (0 or −5 would silently mean "all" or "drop")."""
    return _whole_number(text, 1)


def _whole(text: str) -> int:
    """An index argument: a whole number ≥ 0."""
    return _whole_number(text, 0)


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def _positive(text: str) -> float:
    """A duration or rate: a finite number > 0."""
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value:g}")
    return value


def _non_negative(text: str) -> float:
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be ≥ 0, got {value:g}")
    return value


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "bench":  # what shared the machine goes into its JSON
        from swarmslam.bench.record import start_watch

        start_watch()
    try:
        return args.func(args)
    except (OSError, ValueError) as e:  # files, ports (pyserial's errors are OSErrors), input
        print(f"swarmslam: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("swarmslam: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
