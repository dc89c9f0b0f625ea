"""``swarmslam replay``: the SLAM over a CARMEN log or a ROS bag (swarmslam.replay)."""

from __future__ import annotations

from swarmslam.commands.common import (D, UNUSABLE, at_least_one, bag, bag_options, config_options,
                                       run_options, view_options, whole)
from swarmslam.runtime.config import DEFAULT_PRESET, OPTIMIZERS
from swarmslam.runtime.realtime.inbox import skipped_text
from swarmslam.view.run_view import RunWatch

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "replay": ("Run the SLAM over a CARMEN log (plain or .gz, a pipe, - for stdin) or a ROS bag "
               "(.bag, .mcap, a ROS 2 bag folder; extra 'bags'), as fast as it goes. With "
               "--relations, scores it (Kümmerle eT, eR). Writes map.pgm/.yaml/.png, "
               "trajectory.tum, graph.g2o, session.npz and metrics.json to --out. Exit 1 when "
               "the input was unusable.",
               f"swarmslam replay {D}/intel.clf.gz --relations {D}/intel.relations --out "
               "out/intel"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    rp = sub.add_parser("replay", help="run the SLAM over a CARMEN log or a ROS bag")
    rp.add_argument("log", help="CARMEN log (.clf, .log, plain or .gz; - for standard input) "
                                "or ROS bag (.bag, a ROS 2 bag folder, .mcap, .db3)")
    rp.add_argument("--relations", help="Kümmerle relations file to score against")
    rp.add_argument("--optimizer", choices=OPTIMIZERS,
                    help="swarm method (default: the configuration's, abc)")
    rp.add_argument("--no-odometry", action="store_true", help="scans only, as in the paper")
    rp.add_argument("--out", default="swarmslam-replay", help="output folder")
    rp.add_argument("--limit", type=at_least_one, help="only the first N scans")
    rp.add_argument("--seed", type=int, default=0)
    rp.add_argument("--start", type=whole, default=0, help="the first scan replayed")
    saved = rp.add_mutually_exclusive_group()
    saved.add_argument("--localize", metavar="SESSION",
                       help="localize in a saved session's map (never changed): trajectory "
                            "and localization.json; found with no prior")
    saved.add_argument("--resume", metavar="SESSION",
                       help="extend a saved session's map from wherever the log starts in it "
                            "(multi-session mapping)")
    bag_options(rp)
    config_options(rp, DEFAULT_PRESET, sessions=True)
    view_options(rp)
    rp.set_defaults(func=_replay)


def _replay(args) -> int:
    from swarmslam.outputs import UNUSABLE_REPORT
    from swarmslam.replay import replay, writes_outputs

    options = run_options(args, DEFAULT_PRESET, optimizer=args.optimizer, seed=args.seed)
    m = replay(args.log, args.relations, options, odometry=not args.no_odometry, out_dir=args.out,
               limit=args.limit, start=args.start, bag=bag(args), watch=RunWatch.from_args(args))
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
    if args.out and not writes_outputs(m):
        print(f"nothing written to {args.out}/ but {UNUSABLE_REPORT}: no scan was usable (what "
              f"it held is as it was)")
    elif args.out and args.localize:
        print(f"wrote {args.out}/trajectory.tum, localization.json (the session is unchanged)")
    elif args.out:
        print(f"wrote {args.out}/map.pgm, map.yaml, map.png, trajectory.tum, graph.g2o, metrics.json")
    if m["status"] != "ok":
        print(f"status: {m['status']}")
    return 1 if m["status"].startswith(UNUSABLE) else 0


