"""``swarmslam tune``: Ray Tune and Optuna over configuration fields (swarmslam.tune)."""

from __future__ import annotations

from pathlib import Path

from swarmslam.commands.common import at_least_one

# (what the command does, reads and writes; an example), shown by its --help
HELP = {
    "tune": ("Search configuration fields with Ray Tune and Optuna (extra 'scale'); the "
             "objective is the worst ratio of a log's eT to its reference. Writes the best "
             "configuration as TOML. docs/sweeps.md §3.", "swarmslam tune my-tuning.toml "
             "--trials 24"),
}


def add(sub) -> None:
    """The command's parser, under ``sub`` (the CLI's subparsers)."""
    tu = sub.add_parser("tune", help="Ray Tune + Optuna over configuration fields; objective: "
                                     "the worst ratio to the reference error over the logs")
    tu.add_argument("spec", help="the tuning's TOML spec (docs/sweeps.md)")
    tu.add_argument("--address", help="an existing Ray cluster (default: a local Ray)")
    tu.add_argument("--workers", type=at_least_one, help="trials at a time (default: all CPUs)")
    tu.add_argument("--trials", type=at_least_one, help="the budget (default: the spec's)")
    tu.add_argument("--out", help="the best configuration's TOML (default: the spec's)")
    tu.add_argument("--data", help="datasets folder (default: ../shared/datasets)")
    tu.set_defaults(func=_tune)


def _tune(args) -> int:
    from swarmslam.tune import read_tune_spec, tune_config

    spec = read_tune_spec(args.spec, args.data)
    if args.out:
        spec.out = Path(args.out).resolve()
    if args.trials:
        spec.trials = args.trials
    tune_config(spec, args.address, args.workers)
    return 0


