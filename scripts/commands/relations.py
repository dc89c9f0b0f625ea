"""``swarmslam relations``: relations files: ``relations audit`` (swarmslam.evaluation.relations_audit)."""

from __future__ import annotations

from swarmslam.commands.common import D

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "relations": ("Kümmerle relations files: check them against a log.",
                  f"swarmslam relations audit {D}/intel.clf.gz {D}/intel.relations"),
    "relations audit": ("Check each relation against the log's own scans (ICP between its two "
                        "scans) and, with --trajectory, list the worst relations of a run with "
                        "the turn rate and odometry's own error there. docs/method.md §7.1.",
                        f"swarmslam relations audit {D}/mit-csail.clf.gz "
                        f"{D}/mit-csail.relations --trajectory out/mit/trajectory.tum"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
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


def _relations_audit(args) -> int:
    from swarmslam.evaluation.relations_audit import audit_command

    if not 0 < args.min_gain <= 1:
        raise ValueError(f"--min-gain must be in (0, 1], got {args.min_gain}")
    audit_command(args.log, args.relations, args.trajectory, args.json, args.min_gain,
                  args.plots)
    return 0


