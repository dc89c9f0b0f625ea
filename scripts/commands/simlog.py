"""``swarmslam simlog``: a simulated log with relations and truth (swarmslam.simlog)."""

from __future__ import annotations



# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "simlog": ("A CARMEN log, its Kümmerle relations, the true trajectory (TUM) and the world "
               "from a scripted survey of a generated floor, with a chosen scanner, rate, "
               "odometry and real-robot effects: logs with ground truth. docs/simulator.md.",
               "swarmslam simlog out/b.clf.gz --site building --scanner sick-0.5 --rate 10 "
               "--effects robot"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
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


def _simlog(args) -> int:
    from dataclasses import replace

    from swarmslam.simlog import write_simlog
    from swarmslam_sim.survey import EFFECT_HELP, EFFECTS, RATE_HZ

    if args.seconds is not None and not args.seconds > 0:
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
    if not RATE_HZ[0] <= args.rate <= RATE_HZ[1]:
        raise ValueError(f"--rate must be within {RATE_HZ[0]:g}–{RATE_HZ[1]:g} scans per "
                         f"second, got {args.rate}")
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


