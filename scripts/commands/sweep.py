"""``swarmslam sweep``: many replays as Ray tasks (swarmslam.sweep)."""

from __future__ import annotations

from pathlib import Path

from swarmslam.commands.common import at_least_one

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "sweep": ("Replays over logs × optimizers × seeds × configuration variants as Ray tasks "
              "(extra 'scale'), each finished run appended to a results file at once; a sweep "
              "started again runs only what it lacks. docs/sweeps.md.",
              "swarmslam sweep bench-results/sweep-intel-aces.toml --workers 2"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    sw = sub.add_parser("sweep", help="replays over logs × optimizers × seeds × configuration "
                                      "variants as Ray tasks, resumable (docs/sweeps.md)")
    sw.add_argument("spec", help="the sweep's TOML spec")
    sw.add_argument("--address", help="an existing Ray cluster (default: a local Ray started "
                                      "for the sweep)")
    sw.add_argument("--workers", type=at_least_one,
                    help="CPUs of the local Ray (default: all)")
    sw.add_argument("--serial", action="store_true", help="one run after another in this "
                                                          "process, no Ray")
    sw.add_argument("--results", help="the results file (JSON lines; default: the spec's)")
    sw.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    sw.set_defaults(func=_sweep)


def _sweep(args) -> int:
    from swarmslam.sweep import format_summary, read_spec, summarise, sweep, write_summary

    spec = read_spec(args.spec, args.data)
    if args.results:
        spec.results = Path(args.results).resolve()
    records = sweep(spec, args.address, args.workers, args.serial)
    print(format_summary(summarise(records)))
    print(f"results in {spec.results}; summary in {write_summary(spec, records)}")
    return 0


