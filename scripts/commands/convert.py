"""``swarmslam convert``: a log from one format to another (swarmslam.convert)."""

from __future__ import annotations

import sys

from swarmslam.commands.common import D, bag, bag_options

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "convert": ("Convert a log: CARMEN ⇄ ROS 1 bag, ROS 2 bag (sqlite3 or MCAP). The format "
                "comes from OUTPUT's name (X.bag ROS 1, X.mcap MCAP, X.clf / X.gz CARMEN, "
                "anything else a ROS 2 sqlite3 bag folder) or --format. docs/formats.md §9.",
                f"swarmslam convert {D}/intel.clf.gz intel.mcap"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    cv = sub.add_parser("convert", help="a log from one format to another: CARMEN ⇄ ROS 1 "
                                        "bag, ROS 2 bag (sqlite3 or MCAP)")
    cv.add_argument("input", help="CARMEN log or ROS bag")
    cv.add_argument("output", help="X.clf / X.clf.gz: CARMEN; X.bag: ROS 1; X.mcap: MCAP "
                                   "(ROS 2); any other name: a ROS 2 sqlite3 bag folder")
    cv.add_argument("--format", choices=["carmen", "ros1", "sqlite3", "mcap"],
                    help="the output's format (default: from its name)")
    bag_options(cv)
    cv.set_defaults(func=_convert)


def _convert(args) -> int:
    from swarmslam.convert import convert

    written = convert(args.input, args.output, args.format, bag(args),
                      warn=lambda text: print(text, file=sys.stderr))
    print(f"wrote {written['output']} ({written['format']}): {written['scans']} scans, "
          f"{written['odometry']} odometry readings")
    return 0


